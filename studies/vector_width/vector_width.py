"""The float32 blend kernels compiled for 256-bit against 512-bit vectors, on a CPU with AVX-512.

    python -m studies.vector_width.vector_width [--at 450,1050] [--reps 8] [--rounds 2] [--threads 1] [--json]

LLVM's tuning for Intel's AVX-512 CPUs prefers 256-bit vectors; strings_bench turns that preference off
(`core/cpus.py` `widen_numba_vectors`), so that numba's kernels use the 16-lane vectors. This benchmark measures
what that does to the two blend kernels (`raster/cpu_kernels_f32.py` `forward` and `backward`) on the inputs of a
real training step: the 3DGS states of tools/engine_profile.py (schedule `early`, synthetic/extinguisher,
320x240, after 450 and 1 050 steps; trained and cached on first use), one step's blend inputs each.

Each arm is a fresh process with NUMBA_CPU_FEATURES set to the host's features, with (512-bit) or without
(LLVM's default, 256-bit) `-prefer-256-bit`; the arms alternate `--rounds` times. Each times every kernel
`--reps` times on the same inputs (process CPU time, `--threads` numba threads) and keeps the minimum. Printed per
size and kernel: both arms' minimum over the rounds, the ratio 256-bit / 512-bit, and whether both arms wrote the
same bits (they must: no kernel leaves an operation's order to the compiler). On a CPU without AVX-512 there is
nothing to compare and it says so.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve()


def worker(at: int, reps: int, threads: int) -> None:
    """In a fresh process: the blend inputs of one training step from the state after `at` steps, each kernel
    timed `reps` times; prints one JSON line."""
    import numba
    import numpy as np

    from tools import engine_profile as E
    import strings_bench.raster.cpu_kernels_f32 as K32
    from strings_bench.core.io import cache_root

    scene = E.load_scene("synthetic/extinguisher")
    paths = E.trained_states(scene, "early", [at], cache_root() / "engine_profile")
    method = E.restore(scene, "early", paths[at])
    captured = {}
    real = {"forward": K32.forward, "backward": K32.backward}

    def capture(name):
        def run(*args):
            captured[name] = [a.copy() if isinstance(a, np.ndarray) else a for a in args]
            return real[name](*args)
        return run
    K32.forward, K32.backward = capture("forward"), capture("backward")
    try:
        method.train_step(at + 1)
    finally:
        K32.forward, K32.backward = real["forward"], real["backward"]
    numba.set_num_threads(threads)
    out = {"gaussians": method.num_gaussians(), "features": numba.config.CPU_FEATURES or ""}
    for name, n_out in (("forward", 3), ("backward", 1)):
        times = []
        for _ in range(reps + 1):  # the first call compiles or loads the kernel
            args = list(captured[name])
            for j in range(len(args) - n_out, len(args)):
                args[j] = np.zeros_like(args[j])
            t0 = time.process_time()
            real[name](*args)
            times.append(time.process_time() - t0)
        digest = hashlib.sha256(b"".join(a.tobytes() for a in args[-n_out:])).hexdigest()
        out[name] = {"ms": min(times[1:]) * 1e3, "sha256": digest}
    print("RESULT " + json.dumps(out), flush=True)


def run_arm(at: int, reps: int, threads: int, features: str) -> dict:
    env = dict(os.environ, NUMBA_CPU_FEATURES=features)
    env.pop("NUMBA_CPU_NAME", None)
    proc = subprocess.run([sys.executable, "-m", "studies.vector_width.vector_width", "--worker", str(at), str(reps),
                           str(threads)], env=env, capture_output=True, text=True, cwd=HERE.parents[2])
    if proc.returncode != 0:
        raise SystemExit(f"the worker failed:\n{proc.stderr[-3000:]}")
    line = next(ln for ln in proc.stdout.splitlines() if ln.startswith("RESULT "))
    return json.loads(line[len("RESULT "):])


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--at", default="450,1050", help="steps of the cached 3DGS states (engine_profile.py)")
    ap.add_argument("--reps", type=int, default=8, help="timed calls per kernel and arm")
    ap.add_argument("--rounds", type=int, default=2, help="times each arm runs, alternating")
    ap.add_argument("--threads", type=int, default=1, help="numba threads")
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--worker", nargs=3, type=int, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.worker:
        worker(*args.worker)
        return 0
    from strings_bench.core.cpus import WIDE_VECTORS, host_cpu_features

    host = [f for f in host_cpu_features().split(",") if f and f != WIDE_VECTORS]
    if "+avx512f" not in host:
        print("this CPU has no AVX-512: numba's kernels use its widest vectors already; nothing to compare")
        return 0
    arms = {"256-bit": ",".join(host), "512-bit": ",".join(host + [WIDE_VECTORS])}
    rows = []
    for at in (int(s) for s in args.at.split(",")):
        results = {arm: [] for arm in arms}
        for r in range(args.rounds):
            order = list(arms) if r % 2 == 0 else list(reversed(arms))
            for arm in order:
                results[arm].append(run_arm(at, args.reps, args.threads, arms[arm]))
                print(f"  step {at}, {arm}: " + ", ".join(f"{k} {results[arm][-1][k]['ms']:.1f} ms"
                                                          for k in ("forward", "backward")), file=sys.stderr)
        for kernel in ("forward", "backward"):
            ms = {arm: min(x[kernel]["ms"] for x in results[arm]) for arm in arms}
            same = len({x[kernel]["sha256"] for arm in arms for x in results[arm]}) == 1
            rows.append({"after step": at, "Gaussians": results["512-bit"][0]["gaussians"], "kernel": kernel,
                         "256-bit ms": round(ms["256-bit"], 1), "512-bit ms": round(ms["512-bit"], 1),
                         "256 / 512": round(ms["256-bit"] / ms["512-bit"], 2), "same bits": same})
    if args.json:
        print(json.dumps(rows, indent=1))
    else:
        keys = list(rows[0])
        print("| " + " | ".join(keys) + " |")
        print("|" + "---|" * len(keys))
        for row in rows:
            print("| " + " | ".join(str(row[k]) for k in keys) + " |")
    return 0 if all(row["same bits"] for row in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
