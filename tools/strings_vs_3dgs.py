"""STRinGS vs vanilla 3DGS on the five synthetic scenes.

Runs `strings` and `3dgs` through the suite's runner (training, renders, OCR, CER, PSNR) and prints,
per scene and checkpoint: known-text CER (OCR of the render scored against the known words),
the paper-protocol CER (OCR of the render vs OCR of the ground-truth view, both masked), PSNR,
training time (optimisation, and total = preprocessing + optimisation) and the Gaussian count; then the check: at the 7K checkpoint,
STRinGS has lower known-text CER than 3DGS on >= 4 of 5 scenes and on their mean, and reaches 7K
in less training time.

    python tools/strings_vs_3dgs.py --schedule standard  # x0.05 schedule (350/1500 steps); default quick (x0.01)
    python tools/strings_vs_3dgs.py --schedule paper --scenes books   # full schedule, one scene
    python tools/strings_vs_3dgs.py --steps-scale 0.2 --only-7k --scenes extinguisher   # own scale
    python tools/strings_vs_3dgs.py --out runs/strings_vs_3dgs      # results folder (resumable)
    python tools/strings_vs_3dgs.py --schedule paper --checkpoints 3000 --scenes extinguisher \
        --methods strings,strings-pos-lr,3dgs                             # the paper's phase-1 ablation
    python tools/strings_vs_3dgs.py ... --set lr_means=1.6e-3 lr_means_final=1.6e-5 --out runs/lr10

Timings are noisy on a shared machine; the run folder keeps every number (results.csv).
"""

from __future__ import annotations

import strings_bench.bench as bench

import argparse
import math
import sys
from collections import defaultdict
from pathlib import Path

SCENES = ["books", "extinguisher", "globe", "chemicals", "shelf"]


def _f(x, fmt="{:.3f}"):
    return "-" if x is None or x == "" or (isinstance(x, float) and math.isnan(x)) else fmt.format(float(x))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--schedule", "--preset", dest="schedule", default="quick")
    ap.add_argument("--scenes", default=",".join(SCENES))
    ap.add_argument("--out", default="runs/strings_vs_3dgs")
    ap.add_argument("--ocr", default="rapidocr")
    ap.add_argument("--methods", default="strings,3dgs")
    ap.add_argument("--only-7k", action="store_true", help="train and evaluate the 7K checkpoint only (CPU budget)")
    ap.add_argument("--checkpoints", default=None,
                    help="paper iterations to evaluate, e.g. 3000 (end of STRinGS' phase 1, the paper's "
                         "position-LR ablation) or 3000,7000; default: the schedule's")
    ap.add_argument("--downscale", type=float, default=None)
    ap.add_argument("--steps-scale", type=float, default=None,
                    help="a schedule scale of your own (e.g. 0.2: 7K = 1400 steps) instead of the schedule's")
    ap.add_argument("--set", nargs="*", default=[], metavar="[METHOD.]KEY=VALUE",
                    help="settings as `strings-bench run --set`: KEY=VALUE for every method (e.g. lr_means=8e-4), "
                         "METHOD.KEY=VALUE for one (values parsed as JSON when possible); a run folder holds one set "
                         "of settings, so give these runs their own --out")
    ap.add_argument("--device", default="auto", help="auto (CUDA when torch sees a GPU; default), cpu, cuda, cuda:N")
    args = ap.parse_args(argv)

    import strings_bench.bench.runner as runner
    from strings_bench.store import cell_row, iter_cells
    from strings_bench.cli.run import parse_checkpoints, parse_settings

    methods = args.methods.split(",")
    scenes = [s.strip() for s in args.scenes.split(",") if s.strip()]
    # The schedule options are the runner's (`run --steps-scale/--checkpoints`); the folder is named after them.
    name = args.schedule if args.steps_scale is None else f"x{args.steps_scale:g}"
    if args.only_7k and args.checkpoints is None:
        args.checkpoints = "7000"
    paper_its = None
    if args.checkpoints is not None:
        paper_its = sorted(set(parse_checkpoints(args.checkpoints)))
        name += "-" + "-".join(f"{c // 1000}k" if c % 1000 == 0 else str(c) for c in paper_its)
    run_dir = Path(args.out) / name
    overrides = parse_settings(args.set)  # the CLI's --set parsing
    bench.run(methods, [f"synthetic/{s}" for s in scenes], run_dir=run_dir, schedule=args.schedule, ocr=args.ocr,
               with_lpips=False, write_report=False, downscale=args.downscale, method_overrides=overrides or None,
               steps_scale=args.steps_scale, checkpoints=paper_its, device=args.device)
    schedule = args.schedule + ("" if args.steps_scale is None else f" x{args.steps_scale:g}") + (
        "" if paper_its is None else f" at {','.join(map(str, paper_its))}")

    rows = [cell_row(r) for r in iter_cells(run_dir)]
    rows = [r for r in rows if r["scene"] in scenes and r["method"] in methods]
    rows.sort(key=lambda r: (scenes.index(r["scene"]), int(r["iteration"]), methods.index(r["method"])))
    print(f"\nSTRinGS vs 3DGS, schedule {schedule}, OCR {args.ocr} (run folder {run_dir})\n")
    print("| scene | ckpt | method | known-text CER | paper CER | PSNR | train s | total s | Gaussians |")
    print("|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['scene']} | {r['label']} | {r['method']} | {_f(r['cer_known'])} | {_f(r['cer'])} | "
              f"{_f(r['psnr'], '{:.2f}')} | {_f(r['train_seconds'], '{:.1f}')} | {_f(r['total_seconds'], '{:.1f}')} | "
              f"{r['gaussians']} |")

    by = defaultdict(dict)  # (label, scene) -> method -> row
    for r in rows:
        by[(r["label"], r["scene"])][r["method"]] = r
    labels = sorted({r["label"] for r in rows}, key=lambda lab: min(int(r["iteration"]) for r in rows if r["label"] == lab))
    ok = True
    for lab in labels:
        pairs = [(s, by[(lab, s)]) for s in scenes if {"strings", "3dgs"} <= set(by[(lab, s)])]
        if not pairs:
            continue

        def col(m, key):
            return [float(p[m][key]) if p[m][key] not in ("", None) else math.nan for _, p in pairs]

        ks, kg = col("strings", "cer_known"), col("3dgs", "cer_known")
        cs, cg = col("strings", "cer"), col("3dgs", "cer")
        # Whole runs, as the paper's minutes: preprocessing (masks, Algorithm 1, Eq. 1, init) + optimisation.
        ts, tg = col("strings", "total_seconds"), col("3dgs", "total_seconds")
        wins = sum(a < b for a, b in zip(ks, kg))
        mean = lambda v: sum(v) / len(v) if v else math.nan  # noqa: E731
        print(f"\n{lab}: known-text CER strings {mean(ks):.3f} vs 3dgs {mean(kg):.3f} (strings lower on {wins}/{len(pairs)} "
              f"scenes); paper CER {mean(cs):.3f} vs {mean(cg):.3f}; total time {sum(ts):.0f} s vs {sum(tg):.0f} s")
        if lab == "7K":
            target = wins >= min(4, len(pairs)) and mean(ks) < mean(kg) and sum(ts) < sum(tg)
            ok &= target
            print(f"7K target (lower known CER on >= 4/5 and on the mean, less training time): "
                  f"{'MET' if target else 'NOT MET'}")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
