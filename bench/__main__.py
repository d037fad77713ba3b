"""``python -m bench [--quick] [sensitivity | fusion]``: the same as ``signmap bench``."""

import sys

from bench.cli import main

if __name__ == "__main__":  # the pipeline spawns processes that re-import the main module
    sys.exit(main(sys.argv[1:]))
