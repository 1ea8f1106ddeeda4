"""Do the word-crop readability metrics rank cells as the paper's CER does?

Trains the methods on the scenes through the suite's runner with a schedule long enough for OCR to
read (default: x0.2 of the paper's schedule, 7K = 1 400 steps, evaluated at five checkpoints), then
reports the Spearman rank correlation of `word_cer` and of `text_nll` with known-text CER and with
OCR-CER over the cells where OCR-CER is below 1 (where the detector reads something). The run
folder is resumable; `--run DIR` only analyses an existing one.

    python studies/readability_validation/readability_validation.py                       # train (~20 min on 2 idle cores) and report
    python studies/readability_validation/readability_validation.py --run runs/validate_x02   # report on a finished run
    python studies/readability_validation/readability_validation.py --run runs/validate_x02 --also runs/readability/seed0 runs/readability/seed1
"""

from __future__ import annotations

import strings_bench.bench as bench

import argparse
import sys
from pathlib import Path

PAIRS = [("word_cer", "cer_known"), ("word_cer", "cer"), ("text_nll", "cer_known"), ("text_nll", "cer")]


def spearman_table(df, pairs=PAIRS) -> list[dict]:
    """Spearman's rho (scipy) of each (metric, reference) pair over the rows where OCR-CER < 1 and
    both values are finite."""
    from scipy.stats import spearmanr

    rows = []
    read = df[df["cer"] < 1.0]
    for metric, ref in pairs:
        sub = read[[metric, ref]].dropna()
        if len(sub) < 3:
            rows.append({"metric": metric, "reference": ref, "n": len(sub), "rho": float("nan"), "p": float("nan")})
            continue
        res = spearmanr(sub[metric], sub[ref])
        rows.append({"metric": metric, "reference": ref, "n": len(sub), "rho": float(res.statistic),
                     "p": float(res.pvalue)})
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--run", default=None, help="analyse this finished run folder instead of training")
    ap.add_argument("--out", default="runs/validate_x02", help="run folder to train into (resumable)")
    ap.add_argument("--datasets", default="synthetic/extinguisher,synthetic/books")
    ap.add_argument("--methods", default="strings,3dgs")
    ap.add_argument("--steps-scale", type=float, default=0.2)
    ap.add_argument("--checkpoints", default="1000,2000,3000,5000,7000", help="paper iterations")
    ap.add_argument("--also", nargs="*", default=[], metavar="RUN_DIR",
                    help="more finished run folders whose cells join the correlation (e.g. the seed runs of "
                         "studies/readability/readability.py: runs/readability/seed0 ...)")
    args = ap.parse_args(argv)

    import pandas as pd

    run_dir = Path(args.run or args.out)
    if args.run is None:
        import strings_bench.bench.runner as runner

        bench.run(args.methods.split(","), args.datasets.split(","), run_dir=run_dir, schedule="quick",
                   steps_scale=args.steps_scale, checkpoints=[int(c) for c in args.checkpoints.split(",")],
                   progress=True)
    df = pd.concat([pd.read_csv(Path(d) / "results.csv") for d in [run_dir, *args.also]], ignore_index=True)
    cols = ["method", "scene", "label", "iteration", "cer", "cer_known", "word_cer", "text_nll", "word_cer_gt"]
    print(df[cols].sort_values(["scene", "method", "iteration"]).to_string(index=False, float_format="%.3f"))
    n_read = int((df["cer"] < 1.0).sum())
    print(f"\n{n_read} of {len(df)} cells with OCR-CER < 1 (the detector reads something)")
    print("\n| metric | against | cells | Spearman rho | p |\n|---|---|---|---|---|")
    for r in spearman_table(df):
        print(f"| {r['metric']} | {r['reference']} | {r['n']} | {r['rho']:.3f} | {r['p']:.2g} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
