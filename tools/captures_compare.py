"""The methods compared on the real captures, per capture, and the paper's claims held against them.

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
- `verdicts.csv`: each claim of the paper (the verdict table of docs/results/cpu-long.md) on each capture (on a
  capture below the floor only the claims on counts, COUNT_CLAIMS; its CER claims are `not scored`):
  `holding` when STRinGS is on the claimed side of every method it is held against and the seeds' ranges do not
  overlap (reports/compare `decided`), `not holding` when some method is on the other side with ranges apart,
  `not decided` otherwise (ranges overlap, or a single seed, or, for a CER, both sides reading nothing: an
  OCR-CER of at least READS_NOTHING on every seed, where the figures differ only by the spurious characters OCR
  adds), `not measured` when a method the claim needs was not run; with the figures behind each verdict (training
  time: in CPU seconds where every cell it needs recorded them, else wall seconds; `time_claim`);
- `compare-NAME.md`: `strings-bench compare`'s tables of each capture;
- `cells.csv`: every cell compared, one row each (capture, method, seed, checkpoint): the commit of the code that
  made it (`source_commit`; empty for cells written before runs recorded it), the step its training resumed from,
  its training wall and CPU seconds, evaluation seconds, Gaussians and peak memory: where each figure came from.
A capture that none of the RUN_DIRs holds keeps its rows of the comparison.csv and verdicts.csv already in --out
(each capture's rows come from the folders given for it). Prints comparison.csv and verdicts.csv.
"""

from __future__ import annotations

import argparse
import csv
import io
from pathlib import Path

from strings_bench.core.io import atomic_write_text
from strings_bench.reports.compare import compare, comparison_markdown, decided
from strings_bench.reports.doc_tables import set_table_column
from strings_bench.store import cell_row, iter_cells

REFERENCE = "strings"
BASELINES = ("3dgs", "edc-absgs", "improved-gs")
LOCK_ABLATION = "strings-pos-lr"
TEXT_DENSIFICATION_ABLATION = "strings-no-td"
LABELS = ("3K", "7K", "30K")
# An OCR-CER this high on every seed reads at most 1 GT character in 100: nothing. Two such figures differ only by
# how many spurious characters OCR added (CERs above 1), so a claim about them is not decided.
READS_NOTHING = 0.99


def _fmt(x, digits=3) -> str:
    return "" if x is None else f"{x:.{digits}f}"


def side(a: dict | None, b: dict | None, floor: float | None = None) -> str:
    """Whether `a` is below `b` with the seeds' ranges apart ("below"), above them ("above"), or neither
    ("undecided"; also with one seed, or when both are at or above `floor` on every seed: a CER of two methods
    that read nothing); "missing" when either has no figure."""
    verdict = decided(a, b)
    if not verdict:
        return "missing"
    if verdict != "decided" or (floor is not None and a["min"] >= floor and b["min"] >= floor):
        return "undecided"
    return "below" if a["max"] < b["min"] else "above"


def _seeds(n: int) -> str:
    return f"{n} seed{'s' * (n != 1)}"


def claim(c, value: str, label: str, others, want: str = "below") -> tuple[str, str]:
    """The verdict of "STRinGS is `want` every method of `others` in `value` at `label`" and its figures."""
    ref = c.get(REFERENCE, label, value)
    digits = 3 if value not in ("gaussians", "train_seconds", "train_cpu_seconds") else 0
    figures, sides = [], []
    for m in others:
        o = c.get(m, label, value)
        s = side(ref, o, READS_NOTHING if value == "cer" else None)
        sides.append(s)
        if o is not None:
            other_seeds = "" if ref is None or o["seeds"] == ref["seeds"] else f" ({_seeds(o['seeds'])})"
            figures.append(f"{m} {_fmt(o['mean'], digits)}{other_seeds}")
    if ref is None or "missing" in sides:
        return "not measured", ""
    # the seeds once, after STRinGS' figure; a method with another count names its own
    text = f"STRinGS {_fmt(ref['mean'], digits)} ({_seeds(ref['seeds'])}) against " + ", ".join(figures)
    opposite = "above" if want == "below" else "below"
    if all(s == want for s in sides):
        return "holding", text
    if any(s == opposite for s in sides):
        return "not holding", text
    return "not decided", text


def time_claim(c, label: str = "30K", others=("3dgs",)) -> tuple[str, str]:
    """"Less training time", in the training's CPU seconds where every cell of STRinGS and of `others` at `label`
    recorded them, else in wall seconds. A cell trains on one thread (tools/captures_cells.py), so its CPU
    seconds are its wall seconds less the time its process waited for a core or was stopped: the same measure,
    without what other work on the machine added to it."""
    def complete(m):
        cpu, count = c.get(m, label, "train_cpu_seconds"), c.get(m, label, "gaussians")
        return cpu is not None and count is not None and cpu["replicates"] == count["replicates"]

    if all(complete(m) for m in (REFERENCE, *others)):
        verdict, figures = claim(c, "train_cpu_seconds", label, others)
        return verdict, f"CPU seconds: {figures}"
    verdict, figures = claim(c, "train_seconds", label, others)
    return verdict, figures and f"wall seconds: {figures}"


CLAIMS = (
    ("lower CER than every baseline at 7K", lambda c: claim(c, "cer", "7K", BASELINES)),
    ("lower CER at 30K", lambda c: claim(c, "cer", "30K", BASELINES)),
    ("less training time", time_claim),
    ("fewer Gaussians", lambda c: claim(c, "gaussians", "30K", ("3dgs",))),
    ("text densification helps", lambda c: claim(c, "cer", "30K", (TEXT_DENSIFICATION_ABLATION,))),
    ("the phase-1 position lock helps", lambda c: claim(c, "cer", "30K", (LOCK_ABLATION,))),
)


# The claims a capture below its floor on GT characters is still held to: counts, not CER (its OCR-CER is not scored).
COUNT_CLAIMS = ("less training time", "fewer Gaussians")
NOT_SCORED = "not scored"


def kept_rows(path: Path, compared: set) -> list[dict]:
    """The rows of a banked comparison.csv or verdicts.csv whose capture is not in `compared`, in their order: each
    capture's rows come from the folders given for it, and a capture compared before keeps its rows."""
    if not path.is_file():
        return []
    return [r for r in csv.DictReader(path.open(newline="")) if r["capture"] not in compared]


REAL_CAPTURES_COLUMN = "real captures (`cpu`, full size)"


def set_column(table: Path, verdicts: list[dict]) -> None:
    """Set (add or replace) the real captures' column of a verdict table: per claim, each scored capture's verdict
    and figures."""
    texts = {}
    for v in verdicts:
        if v["verdict"] == NOT_SCORED:
            continue
        text = f"{v['capture']}: {v['verdict']}" + (f" ({v['figures']})" if v["figures"] else "")
        texts[v["claim"]] = f"{texts[v['claim']]}; {text}" if v["claim"] in texts else text
    set_table_column(table, REAL_CAPTURES_COLUMN, texts)


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
    ap.add_argument("--out", type=Path, default=None, help="write comparison.csv, verdicts.csv and compare-NAME.md here")
    ap.add_argument("--verdict-table", type=Path, default=None,
                    help="a verdict table's CSV (first column: the claims): set its column REAL_CAPTURES_COLUMN from "
                         "the verdicts (the docs' verdict tables are made by `strings-bench verdicts` instead)")
    args = ap.parse_args(argv)

    rows, verdicts = [], []
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
        scored = any(c.get(m, lab, "cer") for m in c.methods for lab in LABELS)  # its GT clears the floor
        for name, fn in CLAIMS:
            if scored or name in COUNT_CLAIMS:
                verdict, figures = fn(c)
            else:
                verdict, figures = NOT_SCORED, ""
            verdicts.append({"claim": name, "capture": scene, "verdict": verdict, "figures": figures})
        if args.out:
            args.out.mkdir(parents=True, exist_ok=True)
            atomic_write_text(args.out / f"compare-{scene}.md", comparison_markdown(c))
    compared = {r["capture"] for r in rows}
    cells = [r for r in cell_rows(args.run_dirs) if r["capture"] in compared]
    if args.out:  # the captures not compared this time keep their banked rows
        rows = kept_rows(args.out / "comparison.csv", compared) + rows
        verdicts = kept_rows(args.out / "verdicts.csv", compared) + verdicts
        cells = kept_rows(args.out / "cells.csv", compared) + cells
    if args.verdict_table:
        set_column(args.verdict_table, verdicts)
    for name, table in (("comparison.csv", rows), ("verdicts.csv", verdicts), ("cells.csv", cells)):
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
