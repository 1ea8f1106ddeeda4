"""CLI: `strings-bench verdicts [--check] [--root DIR]`: the paper's claims judged from the banked data.

Builds the banked records of the captures' cells (docs/results/data/captures/cells/*/result.json), judges every
claim of the paper at every scale by one rule (strings_bench/reports/verdicts.py) and writes the tables under
docs/results/data/verdicts/; `strings-bench docs refresh` then renders the pages from them. `--check` writes
nothing and exits with status 1 when a committed file differs from what the banked data give.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from strings_bench.cli import command_help


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "verdicts", help=command_help("verdicts"),
        description="Judges every claim of the paper (its scope and figures listed once, in "
                    "strings_bench/reports/verdicts.py) at every scale the suite measured, by one rule: replicate "
                    "ranges apart -> holding / not holding, overlapping -> not decided, fewer than 3 replicates -> "
                    "not judged, below a signal floor -> not scorable; time only on CPU seconds of cells run "
                    "interleaved on one machine. Writes docs/results/data/verdicts/ (records, verdicts.csv, "
                    "figures.csv, findings.csv, readme.csv) from the banked data of a source checkout.")
    p.add_argument("--check", action="store_true",
                   help="write nothing; exit status 1 when a committed file differs from what the banked data give")
    p.add_argument("--root", default=".", help="the source checkout (default: the current folder)")
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    from strings_bench.core.io import atomic_write_text
    from strings_bench.reports.verdicts import outputs

    root = Path(args.root)
    files = outputs(root)
    stale = [rel for rel, text in files.items()
             if not (root / rel).is_file() or (root / rel).read_text(encoding="utf-8") != text]
    if args.check:
        if stale:
            print("out of date (run `strings-bench verdicts`): " + ", ".join(map(str, stale)))
            return 1
        print("the verdicts match the banked data")
        return 0
    for rel in stale:
        (root / rel).parent.mkdir(parents=True, exist_ok=True)
        atomic_write_text(root / rel, files[rel])
    print("rewrote: " + ", ".join(map(str, stale)) if stale else "nothing to rewrite")
    return 0
