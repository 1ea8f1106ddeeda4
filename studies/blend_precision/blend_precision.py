"""The float32 blend kernels (backend "cpu") against the float64 ones ("cpu-f64") on blend inputs
captured from real training steps: agreement and speed of each blend.

    python -m studies.blend_precision.blend_precision [--at 450,1050] [--big-at 450] [--views 3] [--reps 5] [--json]

The captured steps are those of docs/engine.md's profile: the former default run's 3DGS
(schedule `early`, synthetic/extinguisher) restored from engine_profile's cached states after 450
and 1 050 steps at 320x240, and the 450-step state at 640x480 (`downscale=0.5`); for each, `--views`
consecutive training steps are run and the inputs of `RasterizeTiles` (means2d, conics, opacities,
features, radii, boxes, depths) and the gradients that reach its outputs are recorded: 3 x 3 = nine
steps by default.

Per captured step, both precisions run the forward and the backward blend on the same inputs and
output gradients:
- agreement: colour and alpha max absolute difference (values on [0, 1]); relative norm-wise error
  ||f32 - f64|| / ||f64|| of the depth feature and of every gradient (means2d, conics, opacities,
  features) and of absgrad — the tolerances are 1e-4 and 1e-3;
- speed: the blend kernels alone (`forward`, and `backward` + the per-Gaussian reduction), process
  CPU time (all threads) and wall time, arms alternating f64 / f32 / f32 / f64 ..., medians over
  `--reps`; the ratios f64 / f32 are printed (the machine is shared: ratios, not absolute times).
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

import numpy as np
import torch

HERE = Path(__file__).resolve()


def capture_steps(method, first_step: int, n: int) -> list[dict]:
    """Run n training steps from first_step with RasterizeTiles recorded; one record per step."""
    import strings_bench.raster.cpu as cpu

    real = cpu.RasterizeTiles
    recs = []

    class Capture:
        @staticmethod
        def apply(*args):
            feat, alpha = real.apply(*args)
            rec = {"args": [a.detach().clone() if isinstance(a, torch.Tensor) else a for a in args[:9]],
                   "grads": [None, None]}
            recs.append(rec)

            def keep(i):
                def hook(g):
                    rec["grads"][i] = g.detach().clone()
                return hook
            feat.register_hook(keep(0))
            alpha.register_hook(keep(1))
            return feat, alpha

    cpu.RasterizeTiles = Capture
    try:
        for step in range(first_step, first_step + n):
            method.train_step(step)
            method.refine(step)
    finally:
        cpu.RasterizeTiles = real
    return recs


def prepared(rec: dict, precision: str):
    """The kernel inputs of one record for one precision (pack + binning done here, untimed)."""
    import strings_bench.raster.cpu as cpu
    import strings_bench.raster.cpu_kernels as K

    KB = cpu.BLEND_KERNELS[precision]
    means2d, conics, opac, feats, radii, bbox, depths, W, H = rec["args"]
    vis = torch.nonzero(radii > 0).flatten()
    order = vis[torch.argsort(depths[vis], stable=True)].numpy()
    P, BB = KB.pack(order, means2d.numpy(), conics.numpy(), opac.numpy(), feats.numpy(), bbox.numpy())
    tx, ty = (W + K.TILE - 1) // K.TILE, (H + K.TILE - 1) // K.TILE
    ts, lst, gs, ip = K.bin_tiles(BB, tx, ty)
    f32 = precision == "f32"
    return dict(KB=KB, P=P, BB=BB, ts=ts, lst=lst, gs=gs, ip=ip, order=order, W=W, H=H, tx=tx, N=means2d.shape[0],
                out_f=np.empty((H, W, K.NF), np.float32), out_T=np.empty((H, W), np.float32 if f32 else np.float64),
                out_last=np.empty((H, W), np.int32 if f32 else np.int64),
                gF=np.ascontiguousarray(rec["grads"][0].numpy(), np.float32),
                gA=np.ascontiguousarray(rec["grads"][1].numpy(), np.float32))


def run_blends(x: dict) -> dict:
    """Forward, then backward + reduction; times (wall, CPU) and outputs."""
    import numba

    import strings_bench.raster.cpu as cpu
    import strings_bench.raster.cpu_kernels as K

    KB = x["KB"]
    N = x["N"]
    grads = [np.empty((N, 2), np.float32), np.empty((N, 3), np.float32), np.empty(N, np.float32),
             np.empty((N, K.NF), np.float32), np.zeros((N, 2), np.float32)]
    buf = np.empty((x["lst"].shape[0], K.N_GRAD), np.float32)
    with numba.parallel_chunksize(cpu.CHUNK):
        w0, c0 = time.perf_counter(), time.process_time()
        KB.forward(x["ts"], x["lst"], x["P"], x["BB"], x["W"], x["H"], x["tx"], x["out_f"], x["out_T"], x["out_last"])
        w1, c1 = time.perf_counter(), time.process_time()
        KB.backward(x["ts"], x["lst"], x["P"], x["BB"], x["W"], x["H"], x["tx"], x["out_T"], x["out_last"], x["gF"],
                    x["gA"], buf)
        K.reduce_intersections(buf, x["gs"], x["ip"], x["order"], *grads)
        w2, c2 = time.perf_counter(), time.process_time()
    return {"fwd_wall": w1 - w0, "fwd_cpu": c1 - c0, "bwd_wall": w2 - w1, "bwd_cpu": c2 - c1,
            "feat": x["out_f"].copy(), "alpha": 1.0 - x["out_T"].astype(np.float64), "grads": grads}


def rel(a, b) -> float:
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    nb = np.linalg.norm(b)
    return float(np.linalg.norm(a - b) / nb) if nb > 0 else float(np.linalg.norm(a))


def compare(rec: dict, reps: int) -> dict:
    xs = {p: prepared(rec, p) for p in ("f64", "f32")}
    runs = {"f64": [], "f32": []}
    for r in range(reps + 1):  # the first round warms caches and is dropped
        for p in (("f64", "f32") if r % 2 == 0 else ("f32", "f64")):
            got = run_blends(xs[p])
            if r > 0:
                runs[p].append(got)
            last = runs[p][-1] if r > 0 else got
            xs[p]["last"] = last
    a, b = xs["f32"]["last"], xs["f64"]["last"]
    agree = {"color_maxabs": float(np.abs(a["feat"][..., :3] - b["feat"][..., :3]).max()),
             "alpha_maxabs": float(np.abs(a["alpha"] - b["alpha"]).max()),
             "depth_feature_rel": rel(a["feat"][..., 3], b["feat"][..., 3])}
    for name, ga, gb in zip(("means2d", "conics", "opacities", "features", "absgrad"), a["grads"], b["grads"]):
        agree[f"grad_{name}_rel"] = rel(ga, gb)
    med = {p: {k: statistics.median(x[k] for x in runs[p]) * 1e3 for k in ("fwd_wall", "fwd_cpu", "bwd_wall", "bwd_cpu")}
           for p in runs}
    return {"agreement": agree, "ms": med, "intersections": int(xs["f32"]["lst"].shape[0]),
            "visible": int(xs["f32"]["order"].shape[0]), "size": [int(rec["args"][7]), int(rec["args"][8])]}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--at", default="450,1050")
    ap.add_argument("--big-at", type=int, default=450)
    ap.add_argument("--views", type=int, default=3)
    ap.add_argument("--reps", type=int, default=5)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    from tools import engine_profile as E
    from strings_bench.core.io import cache_root
    from strings_bench.engine.trainer import cpu_threads, keep_freed_memory

    keep_freed_memory()
    at = [int(x) for x in args.at.split(",") if x]
    cases = [(s, 1.0) for s in at] + ([(args.big_at, 0.5)] if args.big_at else [])
    scene = E.load_scene("synthetic/extinguisher")
    paths = E.trained_states(scene, "early", sorted({s for s, _ in cases}), cache_root() / "engine_profile")
    out = []
    with cpu_threads():
        for s, down in cases:
            method = E.restore(scene, "early", paths[s], downscale=down)
            n = method.num_gaussians()
            for i, rec in enumerate(capture_steps(method, s + 1, args.views)):
                r = compare(rec, args.reps)
                r.update(state=s, gaussians=n, step=s + 1 + i)
                out.append(r)
                m = r["ms"]
                print(f"state {s} ({n} Gaussians), {r['size'][0]}x{r['size'][1]}, step {r['step']}: "
                      f"fwd f64/f32 {m['f64']['fwd_cpu'] / m['f32']['fwd_cpu']:.2f} (CPU) "
                      f"{m['f64']['fwd_wall'] / m['f32']['fwd_wall']:.2f} (wall), "
                      f"bwd {m['f64']['bwd_cpu'] / m['f32']['bwd_cpu']:.2f} (CPU) "
                      f"{m['f64']['bwd_wall'] / m['f32']['bwd_wall']:.2f} (wall); worst agreement "
                      f"render {max(r['agreement']['color_maxabs'], r['agreement']['alpha_maxabs']):.2g}, grad "
                      f"{max(v for k, v in r['agreement'].items() if k.startswith('grad')):.2g}",
                      file=sys.stderr, flush=True)
    if args.json:
        print(json.dumps(out, indent=1))
        return 0
    print("| state | size | step | f64 fwd ms (CPU) | f32 fwd ms | fwd ratio CPU (wall) | f64 bwd ms | f32 bwd ms | "
          "bwd ratio CPU (wall) | colour / alpha max abs | worst gradient rel (which) |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for r in out:
        m, a = r["ms"], r["agreement"]
        g = {k: v for k, v in a.items() if k.startswith("grad") or k.startswith("depth")}
        worst = max(g, key=g.get)
        print(f"| {r['state']} ({r['gaussians']}) | {r['size'][0]}x{r['size'][1]} | {r['step']} | "
              f"{m['f64']['fwd_cpu']:.1f} | {m['f32']['fwd_cpu']:.1f} | {m['f64']['fwd_cpu'] / m['f32']['fwd_cpu']:.2f} "
              f"({m['f64']['fwd_wall'] / m['f32']['fwd_wall']:.2f}) | {m['f64']['bwd_cpu']:.1f} | {m['f32']['bwd_cpu']:.1f} | "
              f"{m['f64']['bwd_cpu'] / m['f32']['bwd_cpu']:.2f} ({m['f64']['bwd_wall'] / m['f32']['bwd_wall']:.2f}) | "
              f"{a['color_maxabs']:.1e} / {a['alpha_maxabs']:.1e} | {g[worst]:.1e} ({worst}) |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
