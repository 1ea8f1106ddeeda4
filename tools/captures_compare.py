"""The methods compared on the real captures, per capture. The paper's claims are judged from the same banked cells by
`strings-bench verdicts` (one rule for every scale, docs/results/README.md), not here.

    python tools/captures_compare.py RUN_DIR ... [--out docs/results/data/captures]

RUN_DIRs: run folders of the captures' regime (`strings-bench run --schedule cpu --downscale 1 --datasets
captures/NAME --set seed=N`), one seed each (several folders may hold one seed's methods); folders of different
captures may be given together; banked folders (tools/bank_cells.py) count as run folders.
Each capture is compared on its own (`strings-bench compare --scenes NAME`, reports/compare/): its GT is read by its
own engine (saharov32: Tesseract, Russian), so a mean over captures would add up two different measurements.

Writes into --out:
- `comparison.csv`: per capture, method and checkpoint, the seeds, OCR-CER (mean over seeds, min, max), PSNR, SSIM,
  Gaussians, training seconds and training CPU seconds (means over seeds; the CPU seconds over the cells that
  recorded them, empty where none did), and the largest `peak_memory_mb` of its cells with its scope
  (`training`: each cell's own peak; `process`: some cell records `process` or no scope (written before the peak
  was reset per training) and holds its run process's peak so far, an upper bound for every method but a run's
  first); captures below their floor on GT characters have no OCR-CER;
- `compare-NAME.md`: `strings-bench compare`'s tables of each capture;
- `cells.csv`: every cell compared, one row each (capture, method, seed, checkpoint): the commit of the code that
  made it (`source_commit`; empty for cells written before runs recorded it), the step its training resumed from,
  its training wall and CPU seconds, evaluation seconds, Gaussians and peak memory: where each figure came from.
A capture that none of the RUN_DIRs holds keeps its rows of the comparison.csv and cells.csv already in --out (each
capture's rows come from the folders given for it). Prints comparison.csv.
"""

from __future__ import annotations

import argparse
import csv
import io
from pathlib import Path

from strings_bench.core.io import atomic_write_text
from strings_bench.reports.compare import compare, comparison_markdown
from strings_bench.store import cell_row, iter_cells

LABELS = ("3K", "7K", "30K")


def _fmt(x, digits=3) -> str:
    return "" if x is None else f"{x:.{digits}f}"


def kept_rows(path: Path, compared: set) -> list[dict]:
    """The rows of a banked comparison.csv or cells.csv whose capture is not in `compared`, in their order: each
    capture's rows come from the folders given for it, and a capture compared before keeps its rows."""
    if not path.is_file():
        return []
    return [r for r in csv.DictReader(path.open(newline="")) if r["capture"] not in compared]


def peak_memory(run_dirs) -> dict:
    """{(method, capture, checkpoint): (the largest `peak_memory_mb` of its cells over the folders, scope)}, from
    the cells' records (run folders or banked ones). The scope is `training` when every one of those cells measured
    its own training's peak (`peak_memory_scope`, engine/trainer.py), else `process`: some cell holds its run
    process's peak so far, the cell's own only for the first method of a run and an upper bound for the others."""
    out: dict = {}
    for d in run_dirs:
        for rec in iter_cells(d):
            r = cell_row(rec)
            if r["dataset"] == "captures" and r["peak_memory_mb"] != "":
                key = (r["method"], r["scene"], r["label"])
                mb, scope = out.get(key, (0.0, "training"))
                cell_scope = r.get("peak_memory_scope") or "process"
                out[key] = (max(mb, float(r["peak_memory_mb"])), scope if cell_scope == "training" else "process")
    return out


def _peak(entry: tuple[float, str] | None) -> dict:
    """A cell's peak memory columns (MB, scope) as the comparison prints them; empty where none was recorded."""
    mb, scope = ("", "") if entry is None else (_fmt(entry[0], 0), entry[1])
    return {"peak memory MB": mb, "peak memory scope": scope}


CELL_FIELDS = ("capture", "method", "seed", "checkpoint", "source commit", "resumed from step", "training s",
               "training CPU s", "evaluation s", "Gaussians", "peak memory MB")


def _whole(x) -> str:
    """A results.csv figure rounded to a whole number ("" where the cell has none)."""
    return "" if x in ("", None) else f"{float(x):.0f}"


def cell_rows(run_dirs) -> list[dict]:
    """One row per fully evaluated captures cell of the folders (CELL_FIELDS), in the order of capture, method, seed
    and checkpoint."""
    from strings_bench.reports.compare.collect import cell_seed

    rows = []
    for d in run_dirs:
        for rec in iter_cells(d):
            r = cell_row(rec)
            if r["dataset"] != "captures" or r["evaluation"] != "full":
                continue
            versions = (rec.get("config") or {}).get("versions") or {}
            rows.append({"capture": r["scene"], "method": r["method"], "seed": cell_seed(rec), "checkpoint": r["label"],
                         "source commit": (versions.get("source_commit") or "")[:7]
                         + ("+modified" if versions.get("source_modified") else ""),
                         "resumed from step": rec.get("resumed_from_step", 0), "training s": _whole(r["train_seconds"]),
                         "training CPU s": _whole(r["train_cpu_seconds"]), "evaluation s": _whole(r["eval_seconds"]),
                         "Gaussians": r["gaussians"], "peak memory MB": _whole(r["peak_memory_mb"]),
                         "_iteration": int(r["iteration"])})
    rows.sort(key=lambda r: (r["capture"], r["method"], r["seed"], r["_iteration"]))
    return [{k: v for k, v in r.items() if k != "_iteration"} for r in rows]


def captures_of(run_dirs) -> list[str]:
    from strings_bench.reports.compare import collect

    return sorted({scene for (_, _), per_seed in collect(run_dirs, "captures").items()
                   for by_scene in per_seed.values() for scene in by_scene})


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("run_dirs", nargs="+", type=Path)
    ap.add_argument("--out", type=Path, default=None, help="write comparison.csv, cells.csv and compare-NAME.md here")
    args = ap.parse_args(argv)

    rows = []
    memory = peak_memory(args.run_dirs)
    for scene in captures_of(args.run_dirs):
        c = compare(args.run_dirs, dataset="captures", scenes=[scene])
        for m in c.methods:
            for label in LABELS:
                cer = c.get(m, label, "cer")
                g = c.get(m, label, "gaussians")
                if g is None:
                    continue
                rows.append({"capture": scene, "method": m, "checkpoint": label, "seeds": g["seeds"],
                             "OCR-CER": _fmt(cer and cer["mean"]), "OCR-CER min": _fmt(cer and cer["min"]),
                             "OCR-CER max": _fmt(cer and cer["max"]),
                             **{name: _fmt((c.get(m, label, v) or {}).get("mean"), d) for name, v, d in
                                (("PSNR", "psnr", 2), ("SSIM", "ssim", 3), ("Gaussians", "gaussians", 0),
                                 ("training s", "train_seconds", 0), ("training CPU s", "train_cpu_seconds", 0))},
                             **_peak(memory.get((m, scene, label)))})
        if args.out:
            args.out.mkdir(parents=True, exist_ok=True)
            atomic_write_text(args.out / f"compare-{scene}.md", comparison_markdown(c))
    compared = {r["capture"] for r in rows}
    cells = [r for r in cell_rows(args.run_dirs) if r["capture"] in compared]
    if args.out:  # the captures not compared this time keep their banked rows
        rows = kept_rows(args.out / "comparison.csv", compared) + rows
        cells = kept_rows(args.out / "cells.csv", compared) + cells
    for name, table in (("comparison.csv", rows), ("cells.csv", cells)):
        buf = io.StringIO()
        if table:
            # the columns of this version first (the new rows are last), then any a kept row has besides
            fields = list(dict.fromkeys(k for r in table[::-1] for k in r))
            w = csv.DictWriter(buf, fieldnames=fields, lineterminator="\n")
            w.writeheader()
            w.writerows(table)
        if name != "cells.csv":  # written, not printed: a row per cell
            print(f"# {name}\n{buf.getvalue()}")
        if args.out:
            atomic_write_text(args.out / name, buf.getvalue())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
