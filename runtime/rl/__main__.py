"""``python -m myriad.runtime.rl [--write] [--check] [--systems NAME ...]``: the reference scores (see cli.py)."""

import sys

from .cli import main

if __name__ == "__main__":  # the registry meta-test imports every runtime module: importing must not run it
    sys.exit(main())
