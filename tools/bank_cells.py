"""Bank the finished cells of run folders in the repository, so that a comparison can be made again from them.

    python tools/bank_cells.py RUN_DIR [RUN_DIR ...] --out docs/results/data/captures/cells

A run folder holds renders, training states and OCR crops (gigabytes) and lives on one machine; its cells' records
(`result.json`, a few kilobytes each: every figure a table reads, the method's settings with its seed, the OCR of
each view) are what a comparison needs. This copies them to OUT/<run folder's name>/cells/<method>/<dataset>/
<scene>/<steps>/result.json, which is a run folder as far as every reader of cells goes (`strings-bench compare`,
tools/captures_compare.py), and the next session can add its folders beside the banked ones.

A cell already banked with the same content is left alone; one banked with other content is an error (another run
folder of the same name, or a cell evaluated again with other figures) unless --replace. Unfinished cells (no
result.json yet) are skipped: bank again when they finish. Prints one line per run folder.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from strings_bench.core.errors import StringsBenchError
from strings_bench.core.io import atomic_write_text
from strings_bench.core.results import RESULT_FILE
from strings_bench.store import check_cell, read_json


def bank(run_dir: Path, out: Path, replace: bool = False) -> tuple[int, int]:
    """Copy RUN_DIR's finished cells' records under OUT/RUN_DIR's name; returns (written, already banked)."""
    cells = Path(run_dir) / "cells"
    if not cells.is_dir():
        raise StringsBenchError(f"{run_dir} has no cells/ folder", hint="give folders made by strings-bench run")
    written = same = 0
    for src in sorted(cells.glob(f"*/*/*/*/{RESULT_FILE}")):
        check_cell(read_json(src, "cell result"), src)  # a damaged record is not banked
        text = src.read_text(encoding="utf-8")
        dst = out / Path(run_dir).name / src.relative_to(run_dir)
        if dst.exists():
            if dst.read_text(encoding="utf-8") == text:
                same += 1
                continue
            if not replace:
                raise StringsBenchError(f"{dst} is banked with other content than {src}",
                                        hint="a run folder of the same name was banked before; rename one, or "
                                             "--replace to overwrite")
        dst.parent.mkdir(parents=True, exist_ok=True)
        atomic_write_text(dst, text)
        written += 1
    return written, same


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("run_dirs", nargs="+", type=Path)
    ap.add_argument("--out", type=Path, required=True, help="the bank: one sub-folder per run folder")
    ap.add_argument("--replace", action="store_true", help="overwrite banked cells whose content differs")
    args = ap.parse_args(argv)
    for d in args.run_dirs:
        try:
            written, same = bank(d, args.out, args.replace)
        except StringsBenchError as exc:  # a clear message, not a traceback; the folders before it stay banked
            print(f"error: {exc}", file=sys.stderr)
            return 2
        print(f"{d}: {written} cell(s) banked, {same} already banked -> {args.out / d.name}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
