"""``python -m armbench`` is the ``armbench`` command."""

import sys

from armbench.cli.main import main

if __name__ == "__main__":  # not when a worker process imports it (bench/workers/)
    sys.exit(main())
