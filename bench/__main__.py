"""``python -m bench`` is the ``armbench`` command."""

import sys

from bench.cli import main

if __name__ == "__main__":  # not when a worker process imports it (bench/workers.py)
    sys.exit(main())
