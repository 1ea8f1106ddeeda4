"""`strings-bench evaluate` throughput on renders made elsewhere: views per second, GT OCR cold and cached, of a
reference commit and of this checkout, alternating in one run.

    python tools/evaluate_throughput.py [--ref f2de671] [--ref-dir DIR] [--views 6] [--size 1280x960]
                                             [--reps 2] [--out DIR] [--lpips]

The predictions are an Inria 3DGS output folder (MODEL/test/ours_30000/renders and gt/, files 00000.png ...),
as the authors' render.py writes it: each GT view is generated text (random vocabulary words, Pillow's bundled
font, eval.ocr.sample.random_text_image) on a --size canvas; its render is the view blurred (Gaussian, radius
1.5) with noise, so the OCR reads something between the GT and nothing. Without a scene the evaluation reads
the whole images (no mask) and has no known text, as for any model trained elsewhere.

Per repetition and arm (reference and new alternate; the reference first in odd repetitions), in a fresh
process each, with its own cache folder (STRINGS_BENCH_CACHE):

- cold: an empty cache: the GT views and the renders are all read by the OCR;
- GT cached: the same GT views again with renders of another noise draw, into a new output folder: the GT's
  reads come from the OCR cache, the renders' are read.

Printed: the wall seconds of the `evaluate` command (process start, imports and the report left out with
--no-report; the time of `evaluate()` itself, as the command measures it in eval_seconds, is printed too),
views per second, and the ratio new / reference. Also checked: the two arms' results.csv agree in every column
but the times. LPIPS is left out unless --lpips (the VGG pass is the same code in both arms).
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]

RUNNER = r"""
import json, sys, time
t0 = time.perf_counter()
from strings_bench.bench.evaluate import EvaluateOptions, evaluate
t1 = time.perf_counter()
pred, out, lpips = sys.argv[1], sys.argv[2], sys.argv[3] == "1"
evaluate(pred, EvaluateOptions(out=out, report=False, with_lpips=lpips, method="external"), say=lambda *a: None)
t2 = time.perf_counter()
print(json.dumps({"import_s": t1 - t0, "evaluate_s": t2 - t1}))
"""


def make_predictions(root: Path, views: int, size: tuple[int, int], seed: int) -> None:
    """MODEL/test/ours_30000/{gt,renders}: GT text views (the same for every seed) and renders of noise draw `seed`."""
    from PIL import Image, ImageFilter

    from strings_bench.eval.ocr.sample import random_text_image

    ck = root / "test" / "ours_30000"
    (ck / "gt").mkdir(parents=True, exist_ok=True)
    (ck / "renders").mkdir(parents=True, exist_ok=True)
    rng_gt = np.random.default_rng(0)
    rng = np.random.default_rng(1000 + seed)
    for i in range(views):
        img, _ = random_text_image(rng_gt, n_lines=4, size=size)
        gt = np.clip(img + rng_gt.normal(0, 3, img.shape), 0, 255).astype(np.uint8)
        blurred = np.asarray(Image.fromarray(gt).filter(ImageFilter.GaussianBlur(1.5)), dtype=np.float64)
        render = np.clip(blurred + rng.normal(0, 6, gt.shape), 0, 255).astype(np.uint8)
        Image.fromarray(gt).save(ck / "gt" / f"{i:05d}.png")
        Image.fromarray(render).save(ck / "renders" / f"{i:05d}.png")


def run_arm(src: Path, pred: Path, out: Path, cache: Path, lpips: bool) -> dict:
    env = {**os.environ, "PYTHONPATH": str(src), "STRINGS_BENCH_CACHE": str(cache)}
    shutil.rmtree(out, ignore_errors=True)
    t = time.perf_counter()
    p = subprocess.run([sys.executable, "-c", RUNNER, str(pred), str(out), "1" if lpips else "0"], cwd=src, env=env,
                       capture_output=True, text=True)
    wall = time.perf_counter() - t
    if p.returncode != 0:
        raise SystemExit(f"evaluate failed in {src}:\n{p.stderr[-3000:]}")
    rec = json.loads(p.stdout.strip().splitlines()[-1])
    with open(out / "results.csv", newline="", encoding="utf-8") as fh:
        rows = list(csv.DictReader(fh))
    rec.update(wall_s=wall, eval_seconds=sum(float(r["eval_seconds"]) for r in rows), rows=rows,
               load=os.getloadavg()[0])
    return rec


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--ref", default="f2de671")
    ap.add_argument("--ref-dir", type=Path, help="a checkout of --ref (default: a git worktree made for it)")
    ap.add_argument("--new-dir", type=Path, help="the checkout to time (default: this one)")
    ap.add_argument("--views", type=int, default=6)
    ap.add_argument("--size", default="1280x960")
    ap.add_argument("--reps", type=int, default=2)
    ap.add_argument("--out", type=Path)
    ap.add_argument("--lpips", action="store_true")
    ap.add_argument("--table", type=Path, help="also write the table as CSV here (for the docs)")
    args = ap.parse_args()
    size = tuple(int(v) for v in args.size.lower().split("x"))
    try:
        from tools.checkouts import ref_checkout
    except ImportError:  # run as a file (python tools/evaluate_throughput.py): its own folder is on the path
        from checkouts import ref_checkout

    ref_src = ref_checkout(args.ref, args.ref_dir)
    arms = {"reference": ref_src.resolve(), "new": (args.new_dir or REPO).resolve()}
    work = args.out or Path(tempfile.mkdtemp(prefix="evaluate-throughput-"))
    preds = {}
    for seed in (0, 1):
        preds[seed] = work / f"pred-{seed}"
        if not preds[seed].exists():
            make_predictions(preds[seed], args.views, size, seed)
    print(f"{args.views} views at {size[0]}x{size[1]}; reference {args.ref} at {arms['reference']}, new {arms['new']}; "
          f"load {' '.join(f'{x:.1f}' for x in os.getloadavg())}", flush=True)
    results: dict[tuple[str, str], list[dict]] = {}
    for rep in range(args.reps):
        order = list(arms) if rep % 2 == 0 else list(arms)[::-1]
        for phase, seed in (("cold", 0), ("GT cached", 1)):
            for name in order:
                cache = work / f"cache-{name}-{rep}"
                if phase == "cold":
                    shutil.rmtree(cache, ignore_errors=True)
                rec = run_arm(arms[name], preds[seed], work / f"out-{name}-{rep}-{seed}", cache, args.lpips)
                results.setdefault((phase, name), []).append(rec)
                print(f"  rep {rep} {phase:9s} {name:9s}: evaluate {rec['evaluate_s']:.1f} s "
                      f"({args.views / rec['evaluate_s']:.3f} views/s), load {rec['load']:.1f}", flush=True)
    table = [(f"GT OCR ({args.views} views at {size[0]}x{size[1]})", "reference: s (views/s)", "new: s (views/s)",
              "new / reference")]
    for phase in ("cold", "GT cached"):
        r = statistics.median(x["evaluate_s"] for x in results[(phase, "reference")])
        n = statistics.median(x["evaluate_s"] for x in results[(phase, "new")])
        table.append((phase, f"{r:.1f} ({args.views / r:.3f})", f"{n:.1f} ({args.views / n:.3f})", f"{n / r:.2f}x"))
    print("\n" + "\n".join("| " + " | ".join(row) + " |" for row in table[:1]) + "\n|---|---|---|---|")
    print("\n".join("| " + " | ".join(row) + " |" for row in table[1:]))
    if args.table:
        with open(args.table, "w", newline="", encoding="utf-8") as fh:
            csv.writer(fh).writerows(table)
    same = True
    for phase in ("cold", "GT cached"):
        for a, b in zip(results[(phase, "reference")], results[(phase, "new")]):
            for ra, rb in zip(a["rows"], b["rows"]):
                diff = [c for c in ra if not c.endswith("_seconds") and c != "peak_memory_mb" and ra[c] != rb.get(c)]
                if diff:
                    same = False
                    print(f"{phase}: columns differ: {diff}")
    print("results.csv: every column but the times " + ("is the same in both arms" if same else "DIFFERS (above)"))
    return 0 if same else 1


if __name__ == "__main__":
    sys.exit(main())
