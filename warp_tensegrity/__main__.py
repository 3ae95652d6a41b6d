"""``python -m warp_tensegrity``: the ``warp-tensegrity`` command line (see :mod:`warp_tensegrity.cli`)."""

import sys

from .cli import main

if __name__ == "__main__":
    sys.exit(main())
