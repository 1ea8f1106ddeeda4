"""How often the verdict rule calls a difference that is not there, on simulated cells.

    python tools/verdict_false_calls.py [--trials 20000] [--csv docs/results/data/verdicts/false_calls.csv]

Plants cells the way `strings-bench verdicts` reads them: STRinGS and each method it is held against get n
replicate values (seeds x draws) drawn from ONE normal distribution (no difference at all), and the rule itself
(strings_bench/reports/verdicts.py, `judge`) gives its verdict. Counted per (n, methods held against): how often it
says "holding" and "not holding" when neither is true. Beside them: the exact chance that two samples of n
exchangeable values have ranges apart, 2 / C(2n, n), the reference the one-method rate must match; and, for the
rule's power, how often it calls "holding" when STRinGS is truly lower by 1 and by 2 standard deviations of a
replicate. The rule's floor of MIN_REPLICATES comes from this table (2 a side: a false call 1 time in 3).
"""

from __future__ import annotations

import argparse
from math import comb
from pathlib import Path

import numpy as np

from strings_bench.reports.doc_tables import show_and_save
from strings_bench.reports.verdicts import Claim, Figure, judge

# a CER claim with no character counts, so that only the replicate rule speaks (the floors are tested apart)
CLAIM_METRIC = "psnr_like"


def planted_claim(methods: int) -> Claim:
    return Claim("sim", "simulated", CLAIM_METRIC, "7K", tuple(f"m{i}" for i in range(methods)), "", "", "")


def figure(values: np.ndarray) -> Figure:
    return Figure(float(values.mean()), float(values.min()), float(values.max()), seeds=len(values))


def rates(n: int, methods: int, trials: int, shift: float, rng: np.random.Generator) -> dict:
    """The rule's calls on `trials` planted claims: n replicates a side, STRinGS lower by `shift` (0: no difference).
    The rule's own floor (MIN_REPLICATES) is lowered to n, so that the range test is measured below it too."""
    claim = planted_claim(methods)
    counts = {"holding": 0, "not holding": 0}
    for _ in range(trials):
        ref = figure(rng.standard_normal(n) - shift)
        others = {m: figure(rng.standard_normal(n)) for m in claim.against}
        v = judge(claim, ref, others, min_replicates=n).verdict
        if v in counts:
            counts[v] += 1
    return {k: c / trials for k, c in counts.items()}


def table(trials: int, seed: int = 0) -> list[dict]:
    rng = np.random.default_rng(seed)
    rows = []
    for n in (2, 3, 6):
        for methods in (1, 2, 5):
            null, power1, power2 = (rates(n, methods, trials, shift, rng) for shift in (0.0, 1.0, 2.0))
            rows.append({"replicates a side": n, "methods held against": methods, "trials": trials,
                         "false holding": f"{null['holding']:.4f}", "false not holding": f"{null['not holding']:.4f}",
                         "false call": f"{null['holding'] + null['not holding']:.4f}",
                         "exact, one method (2/C(2n,n))": f"{2 / comb(2 * n, n):.4f}",
                         "holding at 1 sd": f"{power1['holding']:.3f}", "holding at 2 sd": f"{power2['holding']:.3f}"})
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--trials", type=int, default=20000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--csv", type=Path, default=None)
    args = ap.parse_args(argv)
    show_and_save(table(args.trials, args.seed), args.csv)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
