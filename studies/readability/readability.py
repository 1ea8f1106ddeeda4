"""Do the readability metrics tell `strings` and `3dgs` apart beyond seed-to-seed spread?

Runs the methods through the suite's runner on the given schedule and scenes once per seed (seeds 0, 1, 2
by default; `--set seed=N` for every method), one run folder per seed (resumable), then prints, per
method and checkpoint, the mean +- standard deviation over seeds of each metric's mean over scenes:
word_cer, word_acc, text_nll, text_psnr (word-crop readability and text-region PSNR, docs/ocr.md),
known-text CER and OCR-CER. Then, per metric and checkpoint, the difference of the first two methods
and whether it exceeds the spread (|mean difference| > std_a + std_b). Last, the evaluation cost per
cell: eval seconds, of which the word-crop recogniser, in the same runs.

    python studies/readability/readability.py                                     # the default run's table (its schedule and scenes)
    python studies/readability/readability.py --schedule tiny --scenes books        # a smoke check (CPU-heavy)
    python studies/readability/readability.py --schedule quick --scenes books,extinguisher,globe,chemicals,shelf
    python studies/readability/readability.py --seeds 0,1,2,3,4 --out runs/readability_s5
"""

from __future__ import annotations

import strings_bench.bench as bench
from strings_bench.bench.plan import ALL_METHODS

import argparse
import json
import math
import statistics
import sys
from collections import defaultdict
from pathlib import Path

SCENES = ["books", "extinguisher", "globe", "chemicals", "shelf"]
METRICS = [("word_cer", "lower"), ("word_acc", "higher"), ("text_nll", "lower"), ("text_psnr", "higher"),
           ("cer_known", "lower"), ("cer", "lower")]


def _num(x) -> float:
    try:
        v = float(x)
    except (TypeError, ValueError):
        return math.nan
    return v


def _ms(vals: list[float]) -> tuple[float, float, int]:
    v = [x for x in vals if not math.isnan(x)]
    if not v:
        return math.nan, math.nan, 0
    return statistics.fmean(v), (statistics.stdev(v) if len(v) > 1 else 0.0), len(v)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--schedule", "--preset", dest="schedule", default=None,
                    help="the run schedule (default: the default run's; --preset: the former name)")
    ap.add_argument("--scenes", default=None,
                    help=f"synthetic scene names, comma-separated, of {','.join(SCENES)} (default: the schedule's scenes)")
    ap.add_argument("--datasets", default=None, help="--datasets entries instead of --scenes (e.g. synthetic/books)")
    ap.add_argument("--methods", default="strings,3dgs")
    ap.add_argument("--seeds", default="0,1,2")
    ap.add_argument("--out", default="runs/readability")
    ap.add_argument("--ocr", default="rapidocr")
    ap.add_argument("--downscale", type=float, default=None)
    ap.add_argument("--no-lpips", action="store_true", help="skip LPIPS (a VGG pass per view at the last checkpoint)")
    args = ap.parse_args(argv)

    import strings_bench.bench.runner as runner
    from strings_bench.store import cell_row, iter_cells

    methods = args.methods.split(",")
    seeds = [int(s) for s in args.seeds.split(",")]
    from strings_bench.core.schedules import DEFAULT_SCHEDULE, get_schedule

    args.schedule = args.schedule or DEFAULT_SCHEDULE
    if args.datasets:
        datasets = args.datasets.split(",")
    elif args.scenes:
        datasets = [f"synthetic/{s}" for s in args.scenes.split(",")]
    else:
        datasets = get_schedule(args.schedule).default_datasets()
    # per_seed[(method, label)][metric][seed] = mean over scenes
    per_seed: dict = defaultdict(lambda: defaultdict(dict))
    costs = defaultdict(list)  # method -> [(eval seconds, recogniser seconds)]
    iterations = {}
    for seed in seeds:
        run_dir = Path(args.out) / f"seed{seed}"
        print(f"== seed {seed}: {run_dir}", file=sys.stderr, flush=True)
        bench.run(methods, datasets, run_dir=run_dir, schedule=args.schedule, ocr=args.ocr, downscale=args.downscale,
                   with_lpips=not args.no_lpips, progress=False, method_overrides={ALL_METHODS: {"seed": seed}})
        cells = defaultdict(lambda: defaultdict(list))
        for rec in iter_cells(run_dir):
            row = cell_row(rec)
            key = (row["method"], row["label"])
            iterations[key] = row["iteration"]
            for m, _ in METRICS:
                cells[key][m].append(_num(row[m]))
            rd = rec.get("readability") or {}
            costs[row["method"]].append((_num(row["eval_seconds"]), _num(rd.get("seconds"))))
        for key, ms in cells.items():
            for m, vals in ms.items():
                per_seed[key][m][seed] = _ms(vals)[0]

    labels = sorted({l for _, l in per_seed}, key=lambda l: float(l[:-1]) * 1000 if l.endswith("K") else float(l))
    print(f"\nSchedule {args.schedule}, scenes {', '.join(datasets)}, seeds {seeds}: mean +- std over seeds of the "
          "mean over scenes")
    head = f"{'method':<10} {'ckpt':>5} {'iter':>5} " + " ".join(f"{m:>17}" for m, _ in METRICS)
    print(head)
    print("-" * len(head))
    for label in labels:
        for meth in methods:
            key = (meth, label)
            if key not in per_seed:
                continue
            cells = []
            for m, _ in METRICS:
                mean, std, n = _ms(list(per_seed[key][m].values()))
                cells.append("n/a".rjust(17) if n == 0 else f"{mean:8.3f} +- {std:5.3f}")
            print(f"{meth:<10} {label:>5} {iterations.get(key, ''):>5} " + " ".join(cells))
    if len(methods) >= 2:
        a, b = methods[:2]
        print(f"\n{a} - {b} (mean over seeds of the per-seed difference; 'apart' = |mean difference| > std_{a} + std_{b})")
        for label in labels:
            parts = []
            for m, better in METRICS:
                sa, sb = per_seed[(a, label)][m], per_seed[(b, label)][m]
                common = [s for s in seeds if s in sa and s in sb and not math.isnan(sa[s]) and not math.isnan(sb[s])]
                if not common:
                    parts.append(f"{m} n/a")
                    continue
                d, dstd, _ = _ms([sa[s] - sb[s] for s in common])
                _, stda, _ = _ms([sa[s] for s in common])
                _, stdb, _ = _ms([sb[s] for s in common])
                # One seed has no spread: nothing can be said to be apart.
                apart = len(common) >= 2 and abs(statistics.fmean([sa[s] for s in common])
                                                  - statistics.fmean([sb[s] for s in common])) > stda + stdb
                parts.append(f"{m} {d:+.3f}+-{dstd:.3f}{' apart' if apart else ''}")
            print(f"  {label:>5}: " + "; ".join(parts))
    print("\nEvaluation cost per cell (wall s, this machine, same runs): eval total / of it the word-crop recogniser")
    for meth, vals in costs.items():
        ev, rc = _ms([v[0] for v in vals])[0], _ms([v[1] for v in vals])[0]
        print(f"  {meth:<10} {ev:7.2f} / {rc:6.2f}  ({rc / ev:.0%})" if ev == ev and rc == rc and ev > 0
              else f"  {meth:<10} {ev:7.2f} / n/a")
    summary = {"schedule": args.schedule, "datasets": datasets, "seeds": seeds,
               "per_seed": {f"{k[0]}@{k[1]}": {m: v for m, v in d.items()} for k, d in per_seed.items()}}
    out = Path(args.out) / "readability_summary.json"
    out.write_text(json.dumps(summary, indent=1, default=str))
    print(f"\nper-seed values: {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
