"""The evaluation of a run's checkpoints, split into its parts, with the code of a reference commit and of this
checkout alternating on the same renders: the ratio new / reference, and the floor the OCR's inference sets.

    python tools/evaluation_split.py RUN [--ref f2de671] [--ref-dir DIR] [--reps 2] [--json OUT.json]
                                         [--table TABLE.csv]

RUN is a finished run folder (e.g. the default run's, `strings-bench run --methods strings,3dgs --out RUN`). Each
arm, in a fresh process (the reference first in odd repetitions), imports what a run imports, builds the
`Evaluator` of the run's scene folder as the runner does (RapidOCR, no OCR cache: every GT view and render is read,
as on a fresh clone) and scores the saved renders of every cell in the order the run wrote them, with LPIPS where
the run's cell has it. Timed, per checkpoint and in all:

- the whole `Evaluator.evaluate` call (what the run records as eval_seconds, less the writing of the cell);
- its parts: the OCR of the views (`read_views`), the word-crop readability, the image metrics (`view_metrics`,
  LPIPS included);
- ONNX Runtime inference in flight: the union of the intervals in which some `InferenceSession.run` call runs
  (RapidOCR's detector, classifier and recogniser, and the word-crop recogniser), and the part of it in which two
  calls ran at once. While the models, their inputs and the calls that share a batch stay as they are (they fix
  the figures' last bits), and the calls run as concurrently as they do, an evaluation takes at least this long;
  divided by the reference's evaluation, it is the lowest ratio reachable with the same figures;
- the process CPU time of every thread, and that over the evaluation's wall time: how many cores it kept busy (near
  the machine's cores, more concurrency cannot shorten the inference either).

Both arms' results are compared, every figure of every checkpoint (the evaluation's dict, its `seconds` left
out): any difference is printed and the script exits with status 1. The medians over the repetitions are
printed as a table (--table: also as CSV, for the docs); --json writes every repetition.
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
PARTS = ("read_views", "readability", "view_metrics")  # Evaluator.read_views, Evaluator.readability, metrics.view_metrics

ARM = r"""
import hashlib, json, math, sys, threading, time
from pathlib import Path
import numpy as np
from PIL import Image
import strings_bench.bench.runner  # what a run imports (torch, the kernels' settings) before it evaluates
import onnxruntime
import strings_bench.eval.metrics as metrics
import strings_bench.eval.protocol as protocol
from strings_bench.eval.ocr import get_backend
from strings_bench.scene.scene import Scene

spans, lock = {"ort": [], "read_views": [], "readability": [], "view_metrics": []}, threading.Lock()

def timed(owner, attr, key):
    inner = getattr(owner, attr)
    def wrapper(*a, **k):
        t = time.perf_counter()
        try:
            return inner(*a, **k)
        finally:
            with lock:
                spans[key].append((t, time.perf_counter()))
    setattr(owner, attr, wrapper)

timed(onnxruntime.InferenceSession, "run", "ort")
timed(protocol.Evaluator, "read_views", "read_views")
timed(protocol.Evaluator, "readability", "readability")
for attr in (("view_metrics",) if hasattr(metrics, "view_metrics") else ("image_metrics", "text_region_metrics")):
    timed(metrics, attr, "view_metrics")  # older versions: the two per-view functions the one-pass metrics replaced

cells = json.loads(sys.argv[1])
scene = Scene.load(cells[0]["scene_path"], name=cells[0]["scene"], settings=cells[0]["scene_settings"])
ev = protocol.Evaluator.for_scene(scene, [get_backend("rapidocr", cache=False)], cells[0]["downscale"],
                                  with_lpips=True, cer_profile=cells[0]["cer_profile"], device="cpu")

def drop_seconds(x):
    if isinstance(x, dict):
        return {k: drop_seconds(v) for k, v in x.items() if k != "seconds"}
    if isinstance(x, (list, tuple)):
        return [drop_seconds(v) for v in x]
    return x

out = []
for cell in cells:
    renders = {p.name: np.asarray(Image.open(p).convert("RGB")) for p in sorted(Path(cell["renders"]).glob("*.png"))}
    for v in spans.values():
        v.clear()
    t, cpu = time.perf_counter(), time.process_time()
    res = ev.evaluate(cell["method"], renders, with_lpips=cell["lpips"])
    seconds, cpu = time.perf_counter() - t, time.process_time() - cpu
    figures = json.dumps(drop_seconds(res), sort_keys=True, default=str)
    out.append({"cell": cell["name"], "seconds": seconds, "cpu_seconds": cpu, "spans": {k: list(v) for k, v in spans.items()},
                "figures_sha256": hashlib.sha256(figures.encode()).hexdigest(), "figures": figures})
print(json.dumps(out))
"""


def overlap_seconds(spans: list, at_least: int = 2) -> float:
    """The time during which at least `at_least` of the (start, end) intervals ran at once."""
    events = sorted([(a, 1) for a, _ in spans] + [(b, -1) for _, b in spans])
    total, depth, last = 0.0, 0, None
    for x, step in events:
        if last is not None and depth >= at_least:
            total += x - last
        depth, last = depth + step, x
    return total


def union_seconds(spans: list) -> float:
    """The length of the union of (start, end) intervals: the time during which at least one of them ran."""
    return overlap_seconds(spans, at_least=1)


def run_cells(run: Path) -> list[dict]:
    """The run's cells in the order they were written (their result.json's modification time), with what the
    evaluation of each needs: the scene folder, its settings, the renders' folder, and whether LPIPS was scored."""
    import math

    cells = []
    for res in run.glob("cells/*/*/*/*/result.json"):
        rec = json.loads(res.read_text(encoding="utf-8"))
        if rec.get("evaluation", "full") != "full":
            continue  # a dense checkpoint's word-crop evaluation: not the run's full evaluation
        lp = rec["metrics"].get("lpips")
        cells.append({"name": f"{rec['method']} {rec['label']}", "method": rec["method"], "scene": rec["scene"],
                      "scene_path": rec["config"]["scene"]["path"], "scene_settings": rec["config"]["scene"]["settings"],
                      "downscale": float(rec["config"].get("downscale") or 1.0),
                      "cer_profile": rec["config"].get("cer_profile") or "paper",
                      "lpips": lp is not None and not (isinstance(lp, float) and math.isnan(lp)),
                      "renders": str(res.parent / "renders"), "mtime": res.stat().st_mtime})
    if not cells:
        raise SystemExit(f"{run} holds no evaluated cell (cells/<method>/<dataset>/<scene>/<iteration>/result.json)")
    if len({(c["scene_path"], json.dumps(c["scene_settings"], sort_keys=True)) for c in cells}) != 1:
        raise SystemExit(f"{run} holds cells of several scenes: give a run of one scene")
    return [{k: v for k, v in c.items() if k != "mtime"} for c in sorted(cells, key=lambda c: c["mtime"])]


def summarize(arm_out: list[dict]) -> dict:
    """Seconds in all: the evaluation, each part, and ONNX Runtime inference in flight (summed over checkpoints)."""
    return {"evaluation": sum(c["seconds"] for c in arm_out),
            **{p: sum(union_seconds(c["spans"][p]) for c in arm_out) for p in PARTS},
            "inference": sum(union_seconds(c["spans"]["ort"]) for c in arm_out),
            "inference_two_at_once": sum(overlap_seconds(c["spans"]["ort"]) for c in arm_out),
            "cpu": sum(c.get("cpu_seconds", 0.0) for c in arm_out)}


def run_arm(src: Path, cells: list[dict]) -> list[dict]:
    env = {**os.environ, "PYTHONPATH": str(src)}
    p = subprocess.run([sys.executable, "-c", ARM, json.dumps(cells)], cwd=src, env=env, capture_output=True, text=True)
    if p.returncode != 0:
        raise SystemExit(f"the evaluation failed in {src}:\n{p.stderr[-3000:]}")
    return json.loads(p.stdout.strip().splitlines()[-1])


def table_rows(med: dict[str, dict[str, float]], reps: int) -> list[tuple]:
    ref, new = med["reference"], med["new"]
    labels = {"evaluation": "evaluation, every checkpoint (Evaluator.evaluate)",
              "read_views": "  of it: the OCR of the views (read_views)",
              "readability": "  of it: the word-crop readability",
              "view_metrics": "  of it: the image metrics, LPIPS included (view_metrics)",
              "inference": "ONNX Runtime inference in flight (OCR and word crops)",
              "inference_two_at_once": "  of it: two inference calls at once",
              "cpu": "process CPU time of the evaluation, every thread"}
    rows = [("measure (median of %d)" % reps, "reference", "new", "new / reference")]
    for k, label in labels.items():
        rows.append((label, f"{ref[k]:.1f} s", f"{new[k]:.1f} s", f"{new[k] / ref[k]:.2f}x" if ref[k] else "n/a"))
    rows.append(("cores busy on average: CPU time / evaluation", f"{ref['cpu'] / ref['evaluation']:.2f}",
                 f"{new['cpu'] / new['evaluation']:.2f}", ""))
    rows.append(("the floor with these figures: new inference / reference evaluation", "", "",
                 f"{new['inference'] / ref['evaluation']:.2f}x"))
    return rows


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("run", type=Path, help="a finished run folder")
    ap.add_argument("--ref", default="f2de671")
    ap.add_argument("--ref-dir", type=Path, help="a checkout of --ref (default: a git worktree made for it)")
    ap.add_argument("--new-dir", type=Path, help="the checkout to time (default: this one)")
    ap.add_argument("--reps", type=int, default=2)
    ap.add_argument("--json", type=Path, help="write every repetition's seconds here")
    ap.add_argument("--table", type=Path, help="also write the table as CSV here (for the docs)")
    args = ap.parse_args()
    cells = run_cells(args.run)
    try:
        from tools.checkouts import ref_checkout
    except ImportError:  # run as a file (python tools/evaluation_split.py): its own folder is on the path
        from checkouts import ref_checkout

    ref_src = ref_checkout(args.ref, args.ref_dir)
    arms = {"reference": ref_src.resolve(), "new": (args.new_dir or REPO).resolve()}
    print(f"{len(cells)} checkpoints of {args.run} ({', '.join(c['name'] for c in cells)}); reference {args.ref} at "
          f"{arms['reference']}, new {arms['new']}; load {' '.join(f'{x:.1f}' for x in os.getloadavg())}", flush=True)
    reps: dict[str, list] = {"reference": [], "new": []}
    figures_differ = []
    for rep in range(args.reps):
        for name in (list(arms) if rep % 2 == 0 else list(arms)[::-1]):
            t = time.perf_counter()
            out = run_arm(arms[name], cells)
            s = summarize(out)
            per_checkpoint = " ".join(f"{c['seconds']:.1f}" for c in out)
            reps[name].append({"summary": s, "checkpoints": [{"cell": c["cell"], "seconds": c["seconds"], "cpu_seconds": c["cpu_seconds"]} for c in out],
                               "figures": [c["figures"] for c in out], "wall_s": time.perf_counter() - t,
                               "load": os.getloadavg()[0]})
            print(f"  rep {rep} {name:9s}: evaluation {s['evaluation']:.1f} s (OCR {s['read_views']:.1f}, readability "
                  f"{s['readability']:.1f}, metrics {s['view_metrics']:.1f}; inference in flight {s['inference']:.1f}, two at once "
                  f"{s['inference_two_at_once']:.1f}; CPU {s['cpu']:.1f}), "
                  f"per checkpoint {per_checkpoint}; load {os.getloadavg()[0]:.1f}",
                  flush=True)
    base = reps["reference"][0]["figures"]
    for name, runs in reps.items():
        for k, r in enumerate(runs):
            for cell, a, b in zip(cells, base, r["figures"]):
                if a != b:
                    figures_differ.append(f"{name} rep {k}: {cell['name']}")
    med = {name: {k: statistics.median(r["summary"][k] for r in runs) for k in runs[0]["summary"]}
           for name, runs in reps.items()}
    rows = table_rows(med, args.reps)
    print("\n| " + " | ".join(rows[0]) + " |\n|---|---|---|---|")
    print("\n".join("| " + " | ".join(row) + " |" for row in rows[1:]))
    if args.table:
        with open(args.table, "w", newline="", encoding="utf-8") as fh:
            csv.writer(fh).writerows(rows)
    if args.json:
        for runs in reps.values():
            for r in runs:
                r.pop("figures")
        args.json.write_text(json.dumps({"run": str(args.run), "cells": [c["name"] for c in cells], "ref": args.ref,
                                         "arms": {k: str(v) for k, v in arms.items()}, "reps": reps}, indent=1),
                             encoding="utf-8")
    if figures_differ:
        print("figures DIFFER from the reference's first repetition: " + "; ".join(figures_differ))
        return 1
    print(f"figures: every checkpoint's evaluation is the same in both arms and every repetition ({len(cells)} checkpoints)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
