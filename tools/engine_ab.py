"""3DGS training speed of an older commit against this checkout, interleaved in one run.

    python tools/engine_ab.py --old COMMIT [--at 0,450,1050] [--steps 12,8,5] [--reps 2] [--json]

The 3DGS of the former default run (schedule `early`, synthetic/extinguisher, 320x240) is sampled at the sizes it
passes through: its initial model (step 0) and the trained states of tools/engine_profile.py
(cached; after steps 450 and 1 050, about 40 000 and 300 000 Gaussians). From each, both code
versions run the same training steps (`train_step` + `refine`, each under its own Trainer's CPU
thread setting) in fresh processes: the old commit from a `git worktree` of it, this checkout
from its own tree. Arms alternate within every repetition (old first in even repetitions).

Each arm seeds the random generators alike after restoring its state, so densification rounds draw the same
splits. Each arm runs on the numba threading layer its own code selects (older commits: workqueue; this one:
OpenMP, passive); set NUMBA_THREADING_LAYER (and OMP_WAIT_POLICY) to give both arms the same threads. Printed per size: ms per step of each arm (median over repetitions), the ratio old / new (wall time,
and process CPU time of all threads, which a loaded machine disturbs less), and whether both arms
ended with bit-identical parameters (not expected across the float32 blend change: the float32 blends follow another
trajectory; `--new-backend cpu-f64` runs the new arm on the float64 kernels, whose parameters should
then be identical to the old commit's). Then an estimate of the whole training of
the default run: the per-step time of each arm interpolated linearly in the Gaussian count between
the sampled sizes, summed over the run's 1 050 steps with the Gaussian count each step has
(`--counts`, the counts logged every 50 steps by engine_profile's training; by default those of
the cached run).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from contextlib import nullcontext
from pathlib import Path

HERE = Path(__file__).resolve()
# numba's target as the user set it (if at all), before this process imports strings_bench: the import sets
# NUMBA_CPU_FEATURES on a CPU with AVX-512 (512-bit vectors), and an old commit's arm must not inherit that
# from here, only what its own code sets.
NUMBA_TARGET_ENV = {k: os.environ[k] for k in ("NUMBA_CPU_NAME", "NUMBA_CPU_FEATURES") if k in os.environ}


def worker(state: str, first: int, steps: int) -> int:
    """Run in the arm's tree (PYTHONPATH): restore `state` (or the initial model when 'init'), run
    `steps` steps, print JSON with ms/step and a hash of the parameters."""
    import torch

    try:
        from tools import engine_profile as E
    except ImportError:  # run as a file (python tools/engine_ab.py): its own folder is on the path
        import engine_profile as E

    try:
        from strings_bench.engine.trainer import cpu_threads as threads
    except ImportError:  # older commits: torch's own setting
        threads = nullcontext
    try:  # the Trainer's CPU memory setting, where the arm's version has one
        from strings_bench.engine.trainer import keep_freed_memory
        keep_freed_memory()
    except ImportError:
        pass
    from strings_bench.engine.trainer import seed_everything

    scene = E.load_scene("synthetic/extinguisher")
    if state == "init":
        method = E.build_method("early")
        seed_everything(method.config.seed)
        method.setup(scene, device="cpu")
    else:
        method = E.restore(scene, "early", Path(state))
        # the random draws of densification (split samples) alike in both arms: unseeded, two runs of the same
        # code over a densification round ended with different parameters
        seed_everything(method.config.seed)
    if os.environ.get("ENGINE_AB_BACKEND"):
        method.config.backend = os.environ["ENGINE_AB_BACKEND"]
    with threads():  # one untimed step: loading each compiled kernel from the cache is not a step's time
        method.train_step(first)
        method.refine(first)
    first += 1
    n0 = method.num_gaussians()
    with threads():
        t0, c0 = time.perf_counter(), time.process_time()
        for step in range(first, first + steps):
            method.train_step(step)
            method.refine(step)
        dt, dc = time.perf_counter() - t0, time.process_time() - c0
    print(json.dumps({"ms": dt / steps * 1e3, "cpu_ms": dc / steps * 1e3, "gaussians": n0,
                      "hash": E.params_hash(method)}))
    return 0


def run_arm(tree: Path, state: str, first: int, steps: int, backend: str | None = None) -> dict:
    env = {k: v for k, v in os.environ.items() if not k.startswith("NUMBA_CPU_")}
    env.update(NUMBA_TARGET_ENV, PYTHONPATH=str(tree))
    if backend:
        env["ENGINE_AB_BACKEND"] = backend
    out = subprocess.run([sys.executable, str(HERE), "--worker", state, str(first), str(steps)], env=env,
                         capture_output=True, text=True, cwd=str(tree))
    if out.returncode != 0:
        raise SystemExit(f"worker in {tree} failed:\n{out.stderr[-3000:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def default_counts(state_dir: Path) -> list[tuple[int, int]]:
    log = state_dir / "counts.json"
    return [tuple(x) for x in json.loads(log.read_text())] if log.is_file() else []


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--old", help="the older commit (a git worktree of it is made under $TMPDIR)")
    ap.add_argument("--old-tree", help="or a checkout of it")
    ap.add_argument("--at", default="0,450,1050")
    ap.add_argument("--steps", default="12,8,5", help="steps per size and arm")
    ap.add_argument("--reps", type=int, default=2)
    ap.add_argument("--total-steps", type=int, default=1050)
    ap.add_argument("--new-backend", default=None, help="rasterizer backend of the new arm (e.g. cpu-f64)")
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--worker", nargs=3, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.worker:
        return worker(args.worker[0], int(args.worker[1]), int(args.worker[2]))
    if not (args.old or args.old_tree):
        ap.error("give --old COMMIT or --old-tree PATH")
    try:
        from tools import engine_profile as E
    except ImportError:  # run as a file (python tools/engine_ab.py): its own folder is on the path
        import engine_profile as E
    from strings_bench.core.io import cache_root

    try:
        from tools.checkouts import ref_checkout
    except ImportError:  # run as a file (python tools/engine_ab.py): its own folder is on the path
        from checkouts import ref_checkout

    trees = {"old": Path(args.old_tree) if args.old_tree else ref_checkout(args.old), "new": HERE.parent.parent}
    at = [int(x) for x in args.at.split(",")]
    steps = [int(x) for x in args.steps.split(",")]
    state_dir = cache_root() / "engine_profile"
    scene = E.load_scene("synthetic/extinguisher")
    paths = E.trained_states(scene, "early", [s for s in at if s > 0], state_dir)
    for name, tree in trees.items():  # compile / load each tree's kernels once, untimed
        run_arm(tree, "init", 1, 1)
    rows = []
    for s, n_steps in zip(at, steps):
        state = "init" if s == 0 else str(paths[s])
        reps = []
        for r in range(args.reps):
            got = {}
            for arm in (("old", "new") if r % 2 == 0 else ("new", "old")):
                got[arm] = run_arm(trees[arm], state, s + 1, n_steps, args.new_backend if arm == "new" else None)
            reps.append(got)
            print(f"step {s}: old {got['old']['ms']:.0f} ms/step ({got['old']['cpu_ms']:.0f} CPU), "
                  f"new {got['new']['ms']:.0f} ms/step ({got['new']['cpu_ms']:.0f} CPU), "
                  f"same parameters {got['old']['hash'] == got['new']['hash']}", file=sys.stderr, flush=True)
        row = {"at": s, "gaussians": reps[0]["new"]["gaussians"], "steps": n_steps,
               "old_ms": statistics.median(x["old"]["ms"] for x in reps),
               "new_ms": statistics.median(x["new"]["ms"] for x in reps),
               "ratio": statistics.median(x["old"]["ms"] / x["new"]["ms"] for x in reps),
               "ratio_range": [min(x["old"]["ms"] / x["new"]["ms"] for x in reps),
                               max(x["old"]["ms"] / x["new"]["ms"] for x in reps)],
               "old_cpu_ms": statistics.median(x["old"]["cpu_ms"] for x in reps),
               "new_cpu_ms": statistics.median(x["new"]["cpu_ms"] for x in reps),
               "cpu_ratio": statistics.median(x["old"]["cpu_ms"] / x["new"]["cpu_ms"] for x in reps),
               "identical": all(x["old"]["hash"] == x["new"]["hash"] for x in reps)}
        rows.append(row)
    counts = default_counts(state_dir)
    estimate = None
    if counts:
        import numpy as np

        xs = [r["gaussians"] for r in rows]
        order = np.argsort(xs)
        steps_n = np.interp(np.arange(1, args.total_steps + 1), [c[0] for c in counts], [c[1] for c in counts])
        tot = {arm: float(np.interp(steps_n, np.array(xs)[order], np.array([r[f"{arm}_ms"] for r in rows])[order]).sum()) / 1e3
               for arm in ("old", "new")}
        estimate = {"old_s": tot["old"], "new_s": tot["new"], "ratio": tot["old"] / tot["new"]}
    if args.json:
        print(json.dumps({"rows": rows, "estimate": estimate}, indent=1))
        return 0
    print("| after step | Gaussians | steps | old ms/step | new ms/step | old / new | old / new, process CPU time "
          "| identical parameters |")
    print("|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['at']} | {r['gaussians']} | {r['steps']} | {r['old_ms']:.0f} | {r['new_ms']:.0f} | "
              f"{r['ratio']:.2f} ({r['ratio_range'][0]:.2f}-{r['ratio_range'][1]:.2f}) | {r['cpu_ratio']:.2f} | "
              f"{r['identical']} |")
    if estimate:
        print(f"default run's 3DGS training ({args.total_steps} steps), interpolated: old {estimate['old_s']:.0f} s, "
              f"new {estimate['new_s']:.0f} s, old / new {estimate['ratio']:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
