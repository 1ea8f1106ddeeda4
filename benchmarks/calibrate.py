"""`strings-bench calibrate`, under its former name: every argument is passed on (strings_bench/cli/calibrate.py).

    python benchmarks/calibrate.py --regime cpu --dataset synthetic360-cpu --out runs/s360cpu-compare --methods strings,3dgs
"""

import sys

from strings_bench.cli import main

if __name__ == "__main__":
    sys.exit(main(["calibrate", *sys.argv[1:]]))
