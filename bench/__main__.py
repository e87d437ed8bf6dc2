"""``python -m bench`` is the ``armbench`` command."""

import sys

from bench.cli import main

sys.exit(main())
