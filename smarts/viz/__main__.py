"""``python -m smarts.viz [PATH]``: the same as ``smarts viz``."""

import sys

from smarts.viz.cli import main

if __name__ == "__main__":
    sys.exit(main())
