"""What shrinking the schedule does, and how well a miniature agrees with the full schedule.

    python benchmarks/miniature.py motion RUN_DIR [RUN_DIR ...] [--csv FILE]
    python benchmarks/miniature.py agreement --reference CSV_OR_RUN [...] CANDIDATE=CSV_OR_RUN [...] [--csv FILE]

`motion` reads run folders (any schedule scale and miniature) and prints, per method, scene and checkpoint: the
steps trained, Gaussians, the refinement rounds that changed the model's size, and the motion log
(strings_bench/engine/motion.py): the mean path of a Gaussian in early 3DGS position steps (1.6e-4 x extent) and
in the scene's text strokes (x rho, docs/difficulty.md), for all Gaussians and for STRinGS' text Gaussians.

`agreement` scores candidate miniatures against the full-schedule reference on the cells both have (same
method, scene and checkpoint label). For each checkpoint it compares every pair of methods on each scene: the
sign of their CER difference, a difference under --tie counting as a tie (a tie agrees only with a tie). It
prints, per candidate and checkpoint: pairs compared, the share of pairs ordered alike (known-text CER, and
OCR-CER), and the mean |CER difference| of the cells. **It never prints a CER or which method is ahead**, so a
miniature can be chosen on agreement without looking at the comparison it will run (`--show` lists the cells).
"""

from __future__ import annotations

import argparse
import csv
import itertools
import json
import sys
from pathlib import Path

from strings_bench.core.io import atomic_write_text

POSITION_STEP = 1.6e-4  # 3DGS' initial position LR, in scene extents (Kerbl et al. 2023, section 7.1)


def _rows(source: str) -> list[dict]:
    """results.csv rows of a run folder or of a CSV file."""
    path = Path(source)
    if path.is_dir():
        path = path / "results.csv"
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


def _rho(dataset: str, scene: str, cache: dict) -> float | None:
    key = (dataset, scene)
    if key not in cache:
        from strings_bench.scene.difficulty import recorded_difficulty
        from strings_bench.datasets.registry import resolve_scenes
        from strings_bench.scene.scene import Scene

        ref = resolve_scenes([f"{dataset}/{scene}"])[0]
        cache[key] = recorded_difficulty(Scene.load(ref.path, settings=ref.settings)).rho
    return cache[key]


def _cer(value) -> str:
    """A result.json CER entry ({"cer": x, ...}, a number, or None) as a table cell."""
    value = value.get("cer") if isinstance(value, dict) else value
    return "" if value is None else f"{float(value):.3f}"


def motion_rows(run_dirs: list[str]) -> list[dict]:
    rows, rhos = [], {}
    for run_dir in run_dirs:
        if not (Path(run_dir) / "run.json").is_file():
            print(f"{run_dir}: no run.json (not started yet), left out", file=sys.stderr)
            continue
        manifest = json.loads((Path(run_dir) / "run.json").read_text())
        sched = manifest["schedule"]
        for result in sorted(Path(run_dir).glob("cells/*/*/*/*/result.json")):
            rec = json.loads(result.read_text())
            extra = rec.get("extra") or {}
            if "position_path" not in extra:
                continue  # trained before the motion log existed
            rho = _rho(rec["dataset"], rec["scene"], rhos)
            steps = extra["position_path"] / POSITION_STEP
            text = extra.get("text_position_path")
            rows.append({
                "method": rec["method"], "scene": rec["scene"], "scale": sched["steps_scale"],
                "miniature": sched.get("miniature", "shrink"), "ckpt": rec["label"], "steps": rec["iteration"],
                "Gaussians": rec["gaussians"], "size changes": extra.get("count_changes", ""),
                "path (steps)": f"{steps:.1f}", "path (strokes)": "" if rho is None else f"{steps * rho:.2f}",
                "text path (steps)": "" if text is None else f"{text / POSITION_STEP:.1f}",
                "text path (strokes)": "" if text is None or rho is None else f"{text / POSITION_STEP * rho:.2f}",
                "logged from step": extra.get("motion_from_step", ""),
                "known-text CER": _cer(rec.get("cer_known")), "OCR-CER": _cer(rec.get("cer")),
            })
    return rows


def _sign(d: float, tie: float) -> int:
    return 0 if abs(d) < tie else (1 if d > 0 else -1)


def agreement(reference: list[dict], candidate: list[dict], tie: float) -> list[dict]:
    """Per checkpoint label: pairs compared, shares ordered alike, mean |CER difference| (module docstring)."""
    def table(rows):
        return {(r["method"], r["scene"], r["label"]): r for r in rows}

    ref, cand = table(reference), table(candidate)
    common = sorted(set(ref) & set(cand))
    out = []
    for label in sorted({k[2] for k in common}, key=lambda s: (len(s), s)):
        keys = [k for k in common if k[2] == label]
        row = {"ckpt": label, "cells": len(keys)}
        for col, name in (("cer_known", "known-text CER"), ("cer", "OCR-CER")):
            pairs = agree = 0
            diffs = []
            for scene in sorted({k[1] for k in keys}):
                cells = [k for k in keys if k[1] == scene and ref[k].get(col) not in ("", None)
                         and cand[k].get(col) not in ("", None)]
                diffs += [abs(float(cand[k][col]) - float(ref[k][col])) for k in cells]
                for a, b in itertools.combinations(cells, 2):
                    s_ref = _sign(float(ref[a][col]) - float(ref[b][col]), tie)
                    s_cand = _sign(float(cand[a][col]) - float(cand[b][col]), tie)
                    pairs += 1
                    agree += s_ref == s_cand
            row[f"pairs ({name})"] = pairs
            row[f"ordered alike ({name})"] = "" if not pairs else f"{agree / pairs:.2f}"
            row[f"mean abs. difference ({name})"] = "" if not diffs else f"{sum(diffs) / len(diffs):.3f}"
        out.append(row)
    return out


def _write(rows: list[dict], path: Path | None) -> None:
    if not rows:
        print("(no rows)")
        return
    header = list(rows[0])
    print("| " + " | ".join(header) + " |")
    print("|" + "---|" * len(header))
    for r in rows:
        print("| " + " | ".join(str(r[h]) for h in header) + " |")
    if path is not None:
        from io import StringIO

        buf = StringIO()
        w = csv.DictWriter(buf, fieldnames=header, lineterminator="\n")
        w.writeheader()
        w.writerows(rows)
        atomic_write_text(path, buf.getvalue())


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = ap.add_subparsers(dest="what", required=True)
    m = sub.add_parser("motion", help="shrinking's effects, read from run folders")
    m.add_argument("runs", nargs="+")
    m.add_argument("--csv", type=Path)
    a = sub.add_parser("agreement", help="candidate miniatures against the full-schedule reference (blind)")
    a.add_argument("--reference", action="append", required=True, help="a run folder or results.csv (repeatable)")
    a.add_argument("candidates", nargs="+", metavar="NAME=RUN_OR_CSV[+RUN_OR_CSV]")
    a.add_argument("--tie", type=float, default=0.02, help="CER differences under this are ties (default 0.02)")
    a.add_argument("--csv", type=Path)
    a.add_argument("--show", action="store_true", help="also list the CERs (not blind)")
    args = ap.parse_args(argv)
    if args.what == "motion":
        _write(motion_rows(args.runs), args.csv)
        return 0
    reference = [r for src in args.reference for r in _rows(src)]
    out = []
    for spec in args.candidates:
        name, _, sources = spec.partition("=")
        cand = [r for src in sources.split("+") for r in _rows(src)]
        for row in agreement(reference, cand, args.tie):
            out.append({"candidate": name, **row})
        if args.show:
            for r in cand:
                print(name, r["method"], r["scene"], r["label"], r.get("cer_known"), r.get("cer"))
    _write(out, args.csv)
    return 0


if __name__ == "__main__":
    sys.exit(main())
