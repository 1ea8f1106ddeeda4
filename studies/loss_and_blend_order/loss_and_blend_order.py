"""What the reproducible kernels cost, and what the numba loss saves, measured side by side in one process.

    python studies/loss_and_blend_order/loss_and_blend_order.py [--old 142d0ce] [--sizes 62000,337000] [--reps 7] [--csv DIR]

1. The float32 blends of this checkout (every sum in a written order: the backward's gradient sums in 16
   fixed lanes, no fastmath) against those of `--old` (their vector sums left to LLVM under fastmath
   `reassoc`), loaded from that commit's raster/cpu_kernels_f32.py into a temporary module. Same inputs
   (random Gaussians of the trained models' sizes at 320x240, the blend inputs of a real `rasterize`
   call), forward and backward kernels timed alone, arms alternating.
2. The training loss at 320x240 and 640x480: `gs_loss` by the numba kernels against torch's operations
   (STRINGS_BENCH_TORCH_LOSS's path), forward + backward, arms alternating, torch at one thread as in
   training.

Prints medians of process CPU time per call and the ratio old / new (and torch / numba), as this
machine is shared and noisy; `--csv DIR` also writes them as DIR/blends.csv and DIR/loss.csv (the tables of
docs/results/engine-speed.md).
"""

from __future__ import annotations

import argparse
import importlib.util
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numba
import numpy as np
import torch

import strings_bench  # noqa: F401 - pins torch's CPU kernels before any torch call
from strings_bench.engine import losses
from strings_bench.raster import cpu as cpu_backend
from strings_bench.raster import cpu_kernels as K
from strings_bench.raster import cpu_kernels_f32 as K32
from strings_bench.scene.camera import Camera

REPO = Path(__file__).resolve().parents[2]


def old_kernels(commit: str, folder: Path):
    src = subprocess.run(["git", "-C", str(REPO), "show", f"{commit}:strings_bench/raster/cpu_kernels_f32.py"],
                         check=True, capture_output=True, text=True).stdout
    path = folder / f"old_kernels_f32_{commit}.py"
    path.write_text(src)
    spec = importlib.util.spec_from_file_location(path.stem, path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def random_gaussians(n: int, seed: int = 3):
    g = torch.Generator().manual_seed(seed)
    means = torch.randn(n, 3, generator=g) * torch.tensor([0.6, 0.5, 0.5]) + torch.tensor([0.0, 0.0, 3.0])
    quats = torch.randn(n, 4, generator=g)
    # world scales of 4-30 mm at 3 m: a few pixels, as in the trained states
    log_scales = torch.log(torch.rand(n, 3, generator=g) * 0.026 + 0.004)
    logits = torch.randn(n, generator=g)
    sh = torch.randn(n, 16, 3, generator=g) * 0.3
    return means, quats, log_scales, logits, sh


def blend_inputs(n: int):
    """The arguments of the blend kernels for n random Gaussians at 320x240 (captured from `rasterize`)."""
    from strings_bench.raster import rasterize

    cam = Camera(fx=300.0, fy=300.0, cx=160.0, cy=120.0, width=320, height=240, R=np.eye(3), t=np.zeros(3))
    captured = {}
    real = cpu_backend.RasterizeTiles

    class Capture(real):
        @staticmethod
        def forward(ctx, *args):
            out = real.forward(ctx, *args)
            captured["saved"] = ctx.saved
            return out

    cpu_backend.RasterizeTiles = Capture
    try:
        with torch.no_grad():
            rasterize(*random_gaussians(n), cam, torch.zeros(3), sh_degree=3, backend="cpu")
    finally:
        cpu_backend.RasterizeTiles = real
    tile_start, lst, g_start, isect_pos, P, BB, _, _, tiles_x = captured["saved"]
    return tile_start, lst, P, BB, tiles_x


def cpu_time(fn) -> float:
    t0 = time.process_time()
    fn()
    return time.process_time() - t0


def bench_blends(mod_old, n: int, reps: int) -> dict:
    tile_start, lst, P, BB, tiles_x = blend_inputs(n)
    W, H = 320, 240
    rng = np.random.default_rng(0)
    gF = rng.standard_normal((H, W, K.NF)).astype(np.float32)
    gA = rng.standard_normal((H, W)).astype(np.float32)
    times = {("old", "fwd"): [], ("new", "fwd"): [], ("old", "bwd"): [], ("new", "bwd"): []}
    for rep in range(reps + 1):
        for arm in (("old", "new") if rep % 2 == 0 else ("new", "old")):
            KB = mod_old if arm == "old" else K32
            out_f = np.empty((H, W, K.NF), np.float32)
            out_T = np.empty((H, W), np.float32)
            out_last = np.empty((H, W), np.int32)
            buf = np.empty((lst.shape[0], K.N_GRAD), np.float32)
            with numba.parallel_chunksize(cpu_backend.CHUNK):
                tf = cpu_time(lambda: KB.forward(tile_start, lst, P, BB, W, H, tiles_x, out_f, out_T, out_last))
                tb = cpu_time(lambda: KB.backward(tile_start, lst, P, BB, W, H, tiles_x, out_T, out_last, gF, gA,
                                                  buf))
            if rep:  # the first repetition compiles or loads the kernels
                times[(arm, "fwd")].append(tf)
                times[(arm, "bwd")].append(tb)
    return {k: statistics.median(v) * 1e3 for k, v in times.items()} | {"intersections": int(lst.shape[0])}


def bench_loss(H: int, W: int, reps: int) -> dict:
    g = torch.Generator().manual_seed(0)
    y = torch.rand(H, W, 3, generator=g)
    x = (y + 0.1 * torch.randn(H, W, 3, generator=g)).clamp(0, 1).requires_grad_(True)
    times = {"numba": [], "torch": []}
    torch.set_num_threads(1)
    for rep in range(reps + 1):
        for arm in (("numba", "torch") if rep % 2 == 0 else ("torch", "numba")):
            losses.FUSED_CPU_LOSS = arm == "numba"

            def step():
                x.grad = None
                losses.gs_loss(x, y, 0.2).backward()

            t = cpu_time(step)
            if rep:
                times[arm].append(t)
    losses.FUSED_CPU_LOSS = True
    return {k: statistics.median(v) * 1e3 for k, v in times.items()}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--old", default="142d0ce", help="commit whose float32 blend kernels are the reference arm")
    ap.add_argument("--sizes", default="62000,337000", help="Gaussian counts of the blend inputs")
    ap.add_argument("--reps", type=int, default=7)
    ap.add_argument("--csv", type=Path, default=None, help="folder to write blends.csv and loss.csv into")
    args = ap.parse_args(argv)
    blend_rows, loss_rows = [], []
    print(f"numba threads {numba.get_num_threads()}, torch CPU kernels {torch.backends.cpu.get_cpu_capability()}")
    with tempfile.TemporaryDirectory() as tmp:
        old = old_kernels(args.old, Path(tmp))
        print("| Gaussians | intersections | blend | old ms (CPU) | new ms (CPU) | old / new |")
        print("|---|---|---|---|---|---|")
        for n in (int(s) for s in args.sizes.split(",")):
            r = bench_blends(old, n, args.reps)
            for part in ("fwd", "bwd"):
                o, nw = r[("old", part)], r[("new", part)]
                print(f"| {n} | {r['intersections']} | {part} | {o:.1f} | {nw:.1f} | {o / nw:.2f} |")
                blend_rows.append([n, r["intersections"], {"fwd": "forward", "bwd": "backward"}[part],
                                   f"{o:.1f}", f"{nw:.1f}", f"{o / nw:.2f}"])
    print()
    print("| image | torch loss ms (CPU) | numba loss ms (CPU) | torch / numba |")
    print("|---|---|---|---|")
    for H, W in ((240, 320), (480, 640)):
        r = bench_loss(H, W, args.reps)
        print(f"| {W}x{H} | {r['torch']:.1f} | {r['numba']:.1f} | {r['torch'] / r['numba']:.2f} |")
        loss_rows.append([f"{W}x{H}", f"{r['torch']:.1f}", f"{r['numba']:.1f}", f"{r['torch'] / r['numba']:.2f}"])
    if args.csv is not None:
        from strings_bench.core.io import atomic_write_text

        def csv_text(header, rows):
            return "\n".join(",".join(str(c) for c in row) for row in [header, *rows]) + "\n"

        atomic_write_text(args.csv / "blends.csv", csv_text(
            ["Gaussians", "tile intersections", "blend", f"{args.old} ms (CPU)", "this version ms (CPU)",
             f"{args.old} / this"], blend_rows))
        atomic_write_text(args.csv / "loss.csv", csv_text(
            ["image", "torch's loss ms (CPU)", "numba loss ms (CPU)", "torch / numba"], loss_rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
