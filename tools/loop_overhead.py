"""The training loop's overhead over the bare 3DGS step, measured side by side in one run.

    python tools/loop_overhead.py [--scene synthetic/books] [--steps 40] [--rounds 5]
                                       [--steps-scale 0.01] [--densify-steps 150] [--json]

Scene: synthetic/books at 320x240, its SfM points as the model (~2.9k Gaussians). Densification is
OFF for the comparison (refine_start_iter and reset_every huge), so the model size is fixed.

- bare: the step as `tools/raster.py` times it, with the suite's pieces and nothing else:
  rasterize + gs_loss + backward + the means2d-gradient statistic the strategy keeps + GaussianAdam.step.
  Training images are preloaded as tensors and cameras built before the clock starts. It follows the
  loop's schedule exactly (same initial model, view order, position LR and SH degree per step), so
  it does the same arithmetic: the script checks that both end with the same parameters.
- loop: `Trainer(GS3D(...), scene, [steps], progress=False)`; per step = train_seconds / steps
  (optimisation only, as reported in results.csv), and wall = the whole Trainer call / steps
  (set-up, the checkpoint's test renders and everything else included).

Each round runs both arms from step 1 (order alternating between rounds, so that a drift in the
machine's load hits both); figures are medians over rounds, the ratio is the median of the per-round
ratios, and min-max over rounds is printed as the noise. A last block trains with densification ON
at the given schedule (loop only, for information).
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time

import numpy as np
import torch

HUGE = 10 ** 9


def make_method(steps_scale: float, densify: bool):
    from strings_bench.engine.train_config import TrainConfig
    from strings_bench.engine.strategies.default import DefaultStrategy
    from strings_bench.methods.gs3d import GS3D

    strategy = DefaultStrategy() if densify else DefaultStrategy(refine_start_iter=HUGE, reset_every=HUGE)
    return GS3D(TrainConfig(steps_scale=steps_scale), strategy)


def run_loop(scene, steps: int, steps_scale: float, densify: bool = False) -> dict:
    from strings_bench.engine.trainer import Trainer
    from strings_bench.scene.scene import clear_image_cache

    method = make_method(steps_scale, densify)
    clear_image_cache()  # a real run decodes each training image once: do not hide that
    t0 = time.perf_counter()
    results = list(Trainer(method, scene, [steps], progress=False).train())
    wall = time.perf_counter() - t0
    r = results[-1]
    return {"step_ms": r.train_seconds / steps * 1e3, "cpu_ms": r.train_cpu_seconds / steps * 1e3,  # the Trainer's clocks
            "wall_ms": wall / steps * 1e3,
            "preprocess_ms": r.preprocess_seconds * 1e3, "gaussians": r.gaussians,
            "params": {k: v.detach().clone() for k, v in method.model.params.items()}}


def run_bare(scene, steps: int, steps_scale: float) -> dict:
    """`steps` bare steps from the loop's initial model, on the loop's schedule (see the docstring)."""
    from strings_bench.engine.gaussians import GaussianModel
    from strings_bench.engine.losses import gs_loss
    from strings_bench.engine.optim import GaussianAdam, exponential_lr
    from strings_bench.raster import rasterize

    method = make_method(steps_scale, densify=False)  # only for its settings and schedules
    cfg = method.config
    seed = cfg.seed
    torch.manual_seed(seed)
    extent = float(scene.extent)
    method.extent = extent
    model = GaussianModel.from_points(scene.model.xyz, scene.model.rgb, sh_degree=cfg.sh_degree,
                                      init_opacity=cfg.init_opacity)
    params = model.params
    opt = GaussianAdam(params, cfg.lrs.group_lrs(extent))
    bg = torch.tensor(cfg.background, dtype=torch.float32)
    views = list(scene.train_idx)
    rng = np.random.default_rng(seed)
    order: list[int] = []
    while len(order) < steps:  # the loop's view order: a fresh permutation per epoch
        order += [views[i] for i in rng.permutation(len(views))]
    targets = {i: torch.from_numpy(np.array(scene.load_image(i), dtype=np.float32)) for i in views}
    cams = {i: scene.camera(i) for i in views}
    lr_steps = method.at(cfg.position_lr_steps)
    n = len(model)
    grad2d, count = torch.zeros(n), torch.zeros(n)

    t0, c0 = time.perf_counter(), time.process_time()
    for step in range(1, steps + 1):
        view = order[step - 1]
        cam = cams[view]
        opt.set_lr("means", exponential_lr(step, cfg.lrs.means * extent, cfg.lrs.means_final * extent, lr_steps))
        sh = torch.cat([params["sh0"], params["shN"]], dim=1)
        out = rasterize(params["means"], params["quats"], params["log_scales"], params["opacity_logits"], sh,
                        cam, bg, sh_degree=method.sh_degree_for_step(step))
        out.means2d.retain_grad()
        loss = gs_loss(out.color, targets[view], cfg.lambda_dssim)
        loss.backward()
        with torch.no_grad():
            g = out.means2d.grad * torch.tensor([cam.width / 2.0, cam.height / 2.0])
            vis = out.radii > 0
            grad2d[vis] += g[vis].norm(dim=-1)
            count[vis] += 1
        opt.step()
        opt.zero_grad()
    seconds, cpu = time.perf_counter() - t0, time.process_time() - c0
    return {"step_ms": seconds / steps * 1e3, "cpu_ms": cpu / steps * 1e3, "params": {k: v.detach().clone() for k, v in params.items()}}


def raster_reference_step(iters: int) -> float:
    """tools/raster.py's full step at 320x240x5000 (random Gaussians, SH degree 3), median ms:
    the figure the trainer was compared with."""
    try:
        from tools.raster import run_one
    except ImportError:  # run as a file (python tools/loop_overhead.py): its own folder is on the path
        from raster import run_one

    return run_one(320, 240, 5000, iters, "cpu", reference=False)["step_ms"]


def _spread(xs: list[float]) -> str:
    return f"{statistics.median(xs):7.1f}  ({min(xs):.1f}-{max(xs):.1f})"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scene", default="synthetic/books")
    ap.add_argument("--steps", type=int, default=40, help="steps per arm and round")
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--steps-scale", type=float, default=0.01, help="schedule scale (SH degree, LR decay)")
    ap.add_argument("--densify-steps", type=int, default=150, help="steps of the densification-ON run (0: skip)")
    ap.add_argument("--raster-iters", type=int, default=5, help="iterations of raster.py's 5k step (0: skip)")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)

    from strings_bench.datasets.registry import resolve_scenes

    scene = resolve_scenes([args.scene])[0].load()
    # Warm-up: numba kernels compiled/loaded.
    run_bare(scene, 3, args.steps_scale)
    run_loop(scene, 3, args.steps_scale)

    rows = []
    for r in range(args.rounds):
        arms = ("bare", "loop") if r % 2 == 0 else ("loop", "bare")
        got = {}
        for arm in arms:
            got[arm] = run_bare(scene, args.steps, args.steps_scale) if arm == "bare" else \
                run_loop(scene, args.steps, args.steps_scale)
        same = all(torch.equal(got["bare"]["params"][k], got["loop"]["params"][k]) for k in got["bare"]["params"])
        bare, loop = got["bare"], got["loop"]
        row = {"round": r, "bare_ms": bare["step_ms"], "loop_ms": loop["step_ms"], "loop_wall_ms": loop["wall_ms"],
               "bare_cpu_ms": bare["cpu_ms"], "loop_cpu_ms": loop["cpu_ms"], "preprocess_ms": loop["preprocess_ms"],
               "ratio": loop["step_ms"] / bare["step_ms"], "cpu_ratio": loop["cpu_ms"] / bare["cpu_ms"],
               "same_params": same}
        rows.append(row)
        if args.json:
            print(json.dumps(row), flush=True)
        else:
            print(f"round {r}: bare {row['bare_ms']:.1f} ms (cpu {row['bare_cpu_ms']:.1f}), loop {row['loop_ms']:.1f} "
                  f"(cpu {row['loop_cpu_ms']:.1f}, wall {row['loop_wall_ms']:.1f}), ratio {row['ratio']:.3f} "
                  f"(cpu {row['cpu_ratio']:.3f}), same parameters: {same}", file=sys.stderr, flush=True)

    dens = run_loop(scene, args.densify_steps, args.steps_scale, densify=True) if args.densify_steps else None
    raster_ms = raster_reference_step(args.raster_iters) if args.raster_iters else None

    def med(key):
        return statistics.median(x[key] for x in rows)

    summary = {"scene": args.scene, "gaussians": int(got["loop"]["gaussians"]), "steps": args.steps,
               "rounds": args.rounds, "threads": torch.get_num_threads(), "same_params": all(x["same_params"] for x in rows)}
    for key in ("bare_ms", "loop_ms", "loop_wall_ms", "bare_cpu_ms", "loop_cpu_ms", "preprocess_ms", "ratio", "cpu_ratio"):
        summary[key] = med(key)
        summary[key + "_range"] = [min(x[key] for x in rows), max(x[key] for x in rows)]
    if dens is not None:
        summary.update(densify_steps=args.densify_steps, densify_ms=dens["step_ms"], densify_cpu_ms=dens["cpu_ms"],
                       densify_wall_ms=dens["wall_ms"], densify_gaussians=dens["gaussians"])
    summary["raster_5k_step_ms"] = raster_ms
    if args.json:
        print(json.dumps(summary))
        return 0
    col = lambda key: _spread([x[key] for x in rows])  # noqa: E731
    print(f"{args.scene}: {summary['gaussians']} Gaussians (fixed), {args.steps} steps x {args.rounds} rounds, "
          f"steps_scale {args.steps_scale}, torch threads {summary['threads']}; median (min-max) ms per step")
    print(f"{'':48s} {'wall':>22s} {'process CPU':>24s}")
    print(f"  bare step (raster + loss + Adam + means2d stat) {col('bare_ms')}  {col('bare_cpu_ms')}")
    print(f"  loop, train_seconds / steps                     {col('loop_ms')}  {col('loop_cpu_ms')}")
    print(f"  loop / bare (per-round ratio)                   {summary['ratio']:7.3f}  "
          f"({summary['ratio_range'][0]:.3f}-{summary['ratio_range'][1]:.3f})  {summary['cpu_ratio']:7.3f}  "
          f"({summary['cpu_ratio_range'][0]:.3f}-{summary['cpu_ratio_range'][1]:.3f})")
    print(f"  loop, wall incl. set-up and checkpoint renders  {col('loop_wall_ms')}")
    print(f"  loop set-up (preprocess_seconds), ms total      {col('preprocess_ms')}")
    print(f"  same parameters after the run (bare vs loop): {summary['same_params']}")
    if dens is not None:
        print(f"  densification ON ({args.densify_steps} steps, quick schedule): {dens['step_ms']:.1f} ms/step "
              f"(cpu {dens['cpu_ms']:.1f}), wall {dens['wall_ms']:.1f}, {dens['gaussians']} Gaussians at the end")
    if raster_ms is not None:
        print(f"  tools/raster.py full step at 320x240x5000 (random scene, SH 3): {raster_ms:.1f} ms")
    return 0


if __name__ == "__main__":
    sys.exit(main())
