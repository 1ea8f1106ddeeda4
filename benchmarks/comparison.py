"""`strings-bench compare`, under its former name: every argument is passed on (strings_bench/reports/compare/).

    python benchmarks/comparison.py runs/s360cpu-compare runs/s360cpu-seed1 runs/s360cpu-seed2-7k --per-scene cer_known
"""

import sys

from strings_bench.cli import main

if __name__ == "__main__":
    sys.exit(main(["compare", *sys.argv[1:]]))
