"""SSIM of one view with torch on two threads and on one, alternating, and whether the bits agree.

    python studies/ssim_threads/ssim_threads.py [--size 320x240] [--reps 2]

The evaluation's SSIM (eval.metrics.ssim and masked_ssim: float64, 32-row strips) of a random 8-bit-grid
render against its GT, timed with torch.set_num_threads(2) and (1) in turn. The one-pass metrics
(eval.metrics.view_metrics) run the SSIM map on one thread and its sums on the caller's threads.
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np
import torch

from strings_bench.eval import metrics


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", default="320x240")
    ap.add_argument("--reps", type=int, default=2)
    args = ap.parse_args()
    w, h = (int(v) for v in args.size.lower().split("x"))
    rng = np.random.default_rng(0)
    gt = (rng.integers(0, 256, (h, w, 3)) / 255).astype(np.float32)
    img = (np.clip(np.round(gt * 255 + rng.normal(0, 20, gt.shape)), 0, 255) / 255).astype(np.float32)
    mask = np.zeros((h, w), bool)
    mask[h // 5: h // 2, w // 10: 2 * w // 3] = True
    print(f"{w}x{h}; load {' '.join(f'{x:.1f}' for x in os.getloadavg())}")
    print("| torch threads | ssim s | masked_ssim s | view_metrics s | ssim bits | masked bits |\n|---|---|---|---|---|---|")
    before = torch.get_num_threads()
    try:
        for rep in range(args.reps):
            for n in ((2, 1) if rep % 2 == 0 else (1, 2)):
                torch.set_num_threads(n)
                t0 = time.perf_counter()
                s = metrics.ssim(img, gt)
                t1 = time.perf_counter()
                ms = metrics.masked_ssim(img, gt, mask)
                t2 = time.perf_counter()
                metrics.view_metrics(img, gt, mask, with_lpips=False)
                t3 = time.perf_counter()
                print(f"| {n} | {t1 - t0:.3f} | {t2 - t1:.3f} | {t3 - t2:.3f} | {s.hex()} | {ms.hex()} |", flush=True)
    finally:
        torch.set_num_threads(before)
    print(f"load after: {' '.join(f'{x:.1f}' for x in os.getloadavg())}")


if __name__ == "__main__":
    main()
