"""``python -m sanav_mj``: the ``sanav-mj`` command (see :mod:`sanav_mj.cli`)."""

import sys

from sanav_mj.cli import main

if __name__ == "__main__":
    sys.exit(main())
