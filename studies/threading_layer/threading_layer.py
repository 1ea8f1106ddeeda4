"""numba's threading layers against each other: kernel launches and whole training steps.

    python -m studies.threading_layer.threading_layer [--at 450,1050] [--steps 10,6] [--rounds 2]
                                         [--arms workqueue,omp-spin,omp-passive] [--json]

strings_bench runs numba on its OpenMP layer with the threads sleeping as soon as a kernel ends
(OMP_WAIT_POLICY=passive; `strings_bench/raster/__init__.py`); it used to select the workqueue layer. The arms:
`workqueue`; `omp-spin`, OpenMP with libgomp's default spin-wait (GOMP_SPINCOUNT=300000: a thread busy-waits for
the next kernel before it sleeps); `omp-spin10k`, a shorter spin; `omp-passive`, the package's default. This
benchmark measures what the choice costs, in fresh processes, one per arm and round, the arms alternating, every
other setting as the Trainer has it on the CPU (torch on CPU_TORCH_THREADS threads, numba on all cores). Run it on
an idle machine and again beside other work (e.g. another training): spinning threads compete for the cores.
Measured:
- the launch of a parallel kernel: a prange over 2 items that does nothing (median of 300 calls);
- two small kernels of every step: the finite check (`optim_kernels.sums_finite`) of 62 674 floats and the
  motion log (`motion.note_motion`) over 62 674 positions (median of 300 calls each);
- training steps (`train_step` + `refine`) from the 3DGS states of tools/engine_profile.py (schedule `early`,
  synthetic/extinguisher, 320x240, after 450 and 1 050 steps; about 63k and 336k Gaussians), one untimed step
  first, then the median ms per step, and a hash of the parameters at the end (it must be the same under both
  layers: the kernels split their work by index, never by thread).
Printed: each measure's median over the rounds per arm (us for the first three, ms per step after) and its ratio to
the first arm's.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve()
# arm -> environment: numba's two layers, and OpenMP with its threads' spin-wait bounded (GOMP_SPINCOUNT: busy-wait
# iterations before a thread sleeps; libgomp's default is 300 000) or off (OMP_WAIT_POLICY=passive)
ARMS = {"workqueue": {"NUMBA_THREADING_LAYER": "workqueue"},
        "omp-spin": {"NUMBA_THREADING_LAYER": "omp", "GOMP_SPINCOUNT": "300000"},
        "omp-spin10k": {"NUMBA_THREADING_LAYER": "omp", "GOMP_SPINCOUNT": "10000"},
        "omp-passive": {"NUMBA_THREADING_LAYER": "omp", "OMP_WAIT_POLICY": "passive"}}
DEFAULT_ARMS = "workqueue,omp-spin,omp-passive"


def _median_us(fn, args, calls: int = 300) -> float:
    fn(*args)
    ts = []
    for _ in range(calls):
        t0 = time.perf_counter()
        fn(*args)
        ts.append(time.perf_counter() - t0)
    return statistics.median(ts) * 1e6


def worker(at: list[int], steps: list[int]) -> None:
    import numba
    import numpy as np
    import torch
    from numba import njit, prange

    from tools import engine_profile as E
    import strings_bench.raster  # noqa: F401  (the package's threading-layer choice, here overridden by the env)
    from strings_bench.core.io import cache_root
    from strings_bench.engine.motion import new_motion_log, note_motion
    from strings_bench.engine.optim_kernels import sums_finite
    from strings_bench.engine.trainer import CPU_TORCH_THREADS, cpu_threads, keep_freed_memory, seed_everything

    keep_freed_memory()

    @njit(parallel=True)
    def nothing(x):
        for i in prange(2):
            x[i] += 1.0

    out = {"launch_us": _median_us(nothing, (np.zeros(2),)),
           "finite_sum_62k_us": _median_us(sums_finite, ([torch.ones(62674)],)),
           "motion_sums_62k_us": _median_us(note_motion, (new_motion_log(), torch.ones(62674, 3),
                                                          torch.zeros(62674, 3), 1.0))}
    scene = E.load_scene("synthetic/extinguisher")
    paths = E.trained_states(scene, "early", at, cache_root() / "engine_profile")
    for s, n in zip(at, steps):
        method = E.restore(scene, "early", paths[s])
        seed_everything(method.config.seed)
        ts = []
        with cpu_threads(CPU_TORCH_THREADS):
            method.train_step(s + 1)
            method.refine(s + 1)
            for step in range(s + 2, s + 2 + n):
                t0 = time.perf_counter()
                method.train_step(step)
                method.refine(step)
                ts.append(time.perf_counter() - t0)
        out[f"step_ms_{s}"] = statistics.median(ts) * 1e3
        out[f"gaussians_{s}"] = method.num_gaussians()
        out[f"hash_{s}"] = E.params_hash(method)[:16]
    out["layer"] = numba.threading_layer()
    print(json.dumps(out))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--at", default="450,1050")
    ap.add_argument("--steps", default="10,6", help="timed steps per state")
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--arms", default=DEFAULT_ARMS, help=f"comma-separated, of {', '.join(ARMS)}; the first is the "
                                                          "reference of the ratios")
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--worker", nargs=2, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.worker:
        worker([int(x) for x in args.worker[0].split(",")], [int(x) for x in args.worker[1].split(",")])
        return 0
    at = [int(x) for x in args.at.split(",")]
    arms = args.arms.split(",")
    unknown = [a for a in arms if a not in ARMS]
    if unknown:
        ap.error(f"unknown arms {unknown}; known: {', '.join(ARMS)}")
    spin_env = ("NUMBA_THREADING_LAYER", "GOMP_SPINCOUNT", "OMP_WAIT_POLICY")
    base = {k: v for k, v in os.environ.items() if k not in spin_env}
    runs = {arm: [] for arm in arms}
    for r in range(args.rounds):
        for arm in (arms if r % 2 == 0 else arms[::-1]):
            env = {**base, **ARMS[arm]}
            layer = ARMS[arm]["NUMBA_THREADING_LAYER"]
            proc = subprocess.run([sys.executable, "-m", "studies.threading_layer.threading_layer", "--worker", args.at,
                                   args.steps], env=env, capture_output=True, text=True, cwd=str(HERE.parents[2]))
            if proc.returncode != 0:
                raise SystemExit(f"{layer} worker failed:\n{proc.stderr[-3000:]}")
            res = json.loads(proc.stdout.strip().splitlines()[-1])
            if res["layer"] != layer:
                raise SystemExit(f"asked for numba's {layer} layer, got {res['layer']}")
            runs[arm].append(res)
            print(f"round {r}: {arm}: " + ", ".join(f"{k} {v:.1f}" if isinstance(v, float) else f"{k} {v}"
                                                      for k, v in res.items() if k != "layer"), file=sys.stderr,
                  flush=True)
    keys = ["launch_us", "finite_sum_62k_us", "motion_sums_62k_us"] + [f"step_ms_{s}" for s in at]
    ref = arms[0]
    rows = []
    for k in keys:
        med = {arm: statistics.median(x[k] for x in runs[arm]) for arm in arms}
        rows.append({"measure": k, **med, **{f"{arm} / {ref}": med[arm] / med[ref] for arm in arms[1:]}})
    same = {s: len({x[f"hash_{s}"] for arm in arms for x in runs[arm]}) == 1 for s in at}
    if args.json:
        print(json.dumps({"rows": rows, "same_parameters": same, "runs": runs}, indent=1))
        return 0
    ratios = [f"{arm} / {ref}" for arm in arms[1:]]
    print("| measure | " + " | ".join(arms + ratios) + " |")
    print("|---" * (len(arms) + len(ratios) + 1) + "|")
    for row in rows:
        print(f"| {row['measure']} | " + " | ".join(f"{row[c]:.1f}" for c in arms) + " | "
              + " | ".join(f"{row[c]:.2f}" for c in ratios) + " |")
    for s in at:
        n = runs[arms[0]][0][f"gaussians_{s}"]
        print(f"after step {s} ({n} Gaussians): same parameters in every arm: {same[s]}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
