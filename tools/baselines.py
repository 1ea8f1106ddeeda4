"""Train 3DGS and the four baselines on one scene and print PSNR, training time and Gaussians.

    python tools/baselines.py                         # synthetic/books, quick schedule
    python tools/baselines.py --methods 3dgs mcmc --schedule tiny --small --json out.json

PSNR is the mean over the scene's test views of the checkpoint renders (strings_bench.eval.metrics.psnr).
Training time is the trainer's optimisation time (no checkpoint renders); preprocess time (the
initial model) is in the JSON. `--schedule` takes the suite's run schedules (strings_bench/core/schedules.py:
quick x0.01, standard x0.05, ...), the scale a run of that schedule trains every method with. `--small` uses the 160x120,
24-view variant of the synthetic scene (the one the tests use).
"""

from __future__ import annotations

from strings_bench.core.schedules import get_schedule

import argparse
import json
import sys
import time

import numpy as np

DEFAULT_METHODS = ["3dgs", "absgs", "edc-absgs", "mip-splatting", "mcmc"]


def parser() -> argparse.ArgumentParser:
    from strings_bench.core.schedules import SCHEDULES  # the suite's one table (quick = x0.01)

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scene", default="synthetic/books", help="dataset/scene spec or a scene folder")
    ap.add_argument("--methods", nargs="+", default=DEFAULT_METHODS)
    ap.add_argument("--schedule", "--preset", dest="schedule", default="quick", choices=sorted(SCHEDULES),
                    help="the run schedule whose scale every method trains with (--preset: the former name): " +
                         ", ".join(f"{k} x{v.steps_scale:g}" for k, v in SCHEDULES.items()))
    ap.add_argument("--downscale", type=float, default=1)
    ap.add_argument("--small", action="store_true", help="synthetic scenes at 160x120 with 24 views")
    ap.add_argument("--seed", type=int, default=None, help="trainer seed (default 0; for mcmc also its sampling RNG)")
    ap.add_argument("--device", default="auto", help="auto (CUDA when torch sees a GPU; default), cpu, cuda, cuda:N")
    ap.add_argument("--paper-checkpoints", nargs="+", type=int, default=[7000, 30000],
                    help="paper iterations to evaluate (scaled by the schedule's steps_scale)")
    ap.add_argument("--set", nargs="*", default=[], metavar="KEY=VALUE",
                    help="setting for every method, e.g. steps_scale=0.02 (values parsed as JSON when possible)")
    ap.add_argument("--json", help="also write the figures to this JSON file")
    return ap


def main(argv=None) -> int:
    return run(parser().parse_args(argv))


def build(method: str, schedule: str, paper_checkpoints, **settings):
    """(adapter, steps_scale, checkpoints): the checkpoints follow the scale the method actually trains
    with (its schedule's from strings_bench/core/schedules.py, or a given steps_scale)."""
    from strings_bench.methods.registry import get_method

    adapter = get_method(method).build(**{"steps_scale": get_schedule(schedule).steps_scale, **settings})
    s = float(adapter.settings["steps_scale"])
    return adapter, s, sorted({max(1, round(c * s)) for c in paper_checkpoints})


def run(args) -> int:
    from strings_bench.core.io import atomic_write_json
    from strings_bench.engine.trainer import Trainer, resolve_device
    from strings_bench.eval.metrics import psnr
    from strings_bench.scene.scene import Scene

    args.device = resolve_device(args.device)  # a missing GPU is refused before the scene is built
    if args.small and args.scene.startswith("synthetic/"):
        from strings_bench.datasets.synthetic import build_scene, settings_with

        name = args.scene.split("/", 1)[1]
        scene = Scene.load(build_scene(name, settings_with(width=160, height=120, n_views=24), progress=True),
                           name=name, settings={"n_max": 15})
    else:
        from strings_bench.datasets.registry import resolve_scenes

        ref = resolve_scenes([args.scene])[0]
        scene = ref.load()

    overrides = {}
    for item in args.set:
        key, _, value = item.partition("=")
        try:
            overrides[key] = json.loads(value)
        except ValueError:
            overrides[key] = value
    gts = {scene.names[i]: scene.load_image(i, args.downscale) for i in scene.test_idx}
    rows = []
    seed = {} if args.seed is None else {"seed": args.seed}
    for method in args.methods:
        adapter, s, checkpoints = build(method, args.schedule, args.paper_checkpoints, **seed, **overrides)
        t0 = time.perf_counter()
        for res in Trainer(adapter, scene, checkpoints, downscale=args.downscale, device=args.device,
                           progress=False).train():
            vals = [psnr(img, gts[name]) for name, img in res.renders.items()]
            rows.append({"method": method, "iteration": res.iteration, "psnr": float(np.mean(vals)),
                         "train_seconds": res.train_seconds, "preprocess_seconds": res.preprocess_seconds,
                         "gaussians": res.gaussians,
                         "wall_seconds": time.perf_counter() - t0})
            r = rows[-1]
            print(f"{method:14s} it {r['iteration']:6d}  PSNR {r['psnr']:6.2f} dB  train {r['train_seconds']:7.1f} s  "
                  f"Gaussians {r['gaussians']:7d}", flush=True)
    print(f"\n{scene.name}, schedule {args.schedule} (steps x {s}), {len(gts)} test views, downscale {args.downscale}, "
          f"device {args.device}")
    print(f"{'method':14s} {'iter':>6s} {'PSNR':>7s} {'train s':>8s} {'Gaussians':>10s}")
    for r in rows:
        print(f"{r['method']:14s} {r['iteration']:6d} {r['psnr']:7.2f} {r['train_seconds']:8.1f} {r['gaussians']:10d}")
    if args.json:
        atomic_write_json(args.json, {"scene": scene.name, "schedule": args.schedule, "downscale": args.downscale,
                                      "device": args.device,
                                      "seed": args.seed, "rows": rows})
    return 0


if __name__ == "__main__":
    sys.exit(main())
