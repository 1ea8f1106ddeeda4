"""Rasterizer speed and memory: forward, forward+backward and a full training step per configuration.

    python tools/raster.py [--json] [--iters 5] [--configs 320x240x5000 640x480x50000 ...]
                                [--backend cpu] [--no-reference]

Scene: N random Gaussians in front of a pinhole camera (depths 2-10, fov ~ 60 deg), SH degree 3,
anisotropic log-normal scales chosen so that the 3-sigma discs cover each pixel about 15 times on
average (a trained scene's depth complexity) - fewer, larger Gaussians at 5k, tiny ones at 200k;
opacities sigmoid(N(0, 2)). Target image: a fixed random image.

Full training step = render (SH deg 3) + loss 0.8 L1 + 0.2 (1 - SSIM) (strings_bench.engine.losses.gs_loss,
11x11 Gaussian window) + backward + reading means2d.grad (as densification does) + torch Adam step.
Times are medians over --iters after 2 warm-up steps (kernels are compiled / loaded before that);
step_cpu_ms is the process CPU time of a step (all threads), loss_ms the loss alone (fwd+bwd).

Peak memory: each configuration runs in a fresh subprocess; peak_mb = (max RSS of that process,
from resource.getrusage) - (RSS after imports and a warm-up render of a tiny scene). It therefore
counts the scene tensors, Adam state, autograd graph and all temporaries of the steps.

The float64 brute-force reference (strings_bench.raster.reference, every Gaussian x every pixel)
is timed on the small configurations where it fits in memory; the ratio column is reference / fast.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import resource
import statistics
import subprocess
import sys
import time

import numpy as np
import torch

DEFAULT_CONFIGS = ["320x240x5000", "320x240x50000", "320x240x200000",
                   "640x480x5000", "640x480x50000", "640x480x200000"]
REFERENCE_CONFIGS = ["80x60x500", "160x120x500"]
COVERAGE = 15.0  # mean number of 3-sigma discs over a pixel


def make_scene(n: int, width: int, height: int, seed: int = 0, coverage: float = COVERAGE):
    from strings_bench.scene.camera import Camera

    g = torch.Generator().manual_seed(seed)
    f = 0.5 * width / math.tan(math.radians(30))
    cam = Camera(fx=f, fy=f, cx=width / 2, cy=height / 2, width=width, height=height, R=np.eye(3), t=np.zeros(3))
    z = 2 + 8 * torch.rand(n, generator=g)
    u = torch.rand(n, generator=g) * width * 1.1 - 0.05 * width
    v = torch.rand(n, generator=g) * height * 1.1 - 0.05 * height
    means = torch.stack([(u - cam.cx) * z / f, (v - cam.cy) * z / f, z], dim=1)
    spread = 0.5
    sigma_px = math.sqrt(coverage * width * height / (n * math.pi * 9 * math.exp(2 * spread ** 2)))
    s_px = sigma_px * torch.exp(spread * torch.randn(n, 3, generator=g))
    log_scales = torch.log(s_px * z[:, None] / f)
    quats = torch.randn(n, 4, generator=g)
    opacity_logits = 2 * torch.randn(n, generator=g)
    sh = torch.randn(n, 16, 3, generator=g) * torch.tensor([1.0] + [0.1] * 15)[None, :, None]
    return cam, {"means": means, "quats": quats, "log_scales": log_scales, "opacity_logits": opacity_logits, "sh": sh}


def _rss_mb() -> float:
    with open("/proc/self/statm") as fh:
        return int(fh.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2 ** 20


def _peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def run_one(width: int, height: int, n: int, iters: int, backend: str, reference: bool) -> dict:
    from strings_bench.engine.losses import gs_loss
    from strings_bench.raster import rasterize
    from strings_bench.raster.reference import rasterize_reference

    bg = torch.zeros(3)
    # Warm-up on a tiny scene: loads / compiles the kernels before the baseline is taken.
    cam0, p0 = make_scene(50, 32, 24)
    rasterize(*[p0[k].requires_grad_() for k in ("means", "quats", "log_scales", "opacity_logits", "sh")],
              cam0, bg, backend=backend).color.sum().backward()
    base_rss = _rss_mb()

    cam, p = make_scene(n, width, height)
    params = {k: v.clone().requires_grad_() for k, v in p.items()}
    keys = ("means", "quats", "log_scales", "opacity_logits", "sh")
    target = torch.rand(height, width, 3, generator=torch.Generator().manual_seed(1))
    opt = torch.optim.Adam([params[k] for k in keys], lr=1e-3, eps=1e-15)

    def render():
        return rasterize(*[params[k] for k in keys], cam, bg, backend=backend)

    def fwd():
        with torch.no_grad():
            render()

    def fwd_bwd():
        out = render()
        out.color.sum().backward()

    def step():
        opt.zero_grad(set_to_none=True)
        out = render()
        out.means2d.retain_grad()
        loss = gs_loss(out.color, target)
        loss.backward()
        _ = out.means2d.grad.norm(dim=-1)[out.radii > 0]
        opt.step()
        return out

    cpu_ms = {}

    def timed(fn):
        for _ in range(2):
            fn()
        ts, cs = [], []
        for _ in range(iters):
            t0, c0 = time.perf_counter(), time.process_time()
            fn()
            ts.append((time.perf_counter() - t0) * 1e3)
            cs.append((time.process_time() - c0) * 1e3)
        cpu_ms[fn.__name__] = statistics.median(cs)
        return statistics.median(ts)

    res = {"width": width, "height": height, "gaussians": n, "backend": backend}
    res["fwd_ms"] = timed(fwd)
    res["fwd_bwd_ms"] = timed(fwd_bwd)
    res["step_ms"] = timed(step)
    res["step_cpu_ms"] = cpu_ms["step"]  # CPU time of all threads: a load-independent cost figure
    img = torch.rand(height, width, 3, requires_grad=True)

    def loss_only():
        gs_loss(img, target).backward()

    res["loss_ms"] = timed(loss_only)
    out = step()
    res["visible"] = int((out.radii > 0).sum())
    res["peak_mb"] = _peak_rss_mb() - base_rss
    res["threads"] = {"torch": torch.get_num_threads(), "numba": _numba_threads()}
    if reference:
        def ref_step():
            q = {k: params[k].detach().double().requires_grad_() for k in keys}
            r = rasterize_reference(*[q[k] for k in keys], cam, bg.double())
            gs_loss(r["color"], target.double()).backward()

        res["reference_step_ms"] = timed(ref_step) if iters else None
        res["ratio"] = res["reference_step_ms"] / res["step_ms"]
    return res


def _numba_threads() -> int:
    import numba

    return numba.get_num_threads()


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--json", action="store_true", help="one JSON object per line instead of a table")
    ap.add_argument("--iters", type=int, default=5)
    ap.add_argument("--configs", nargs="*", default=None, help="WxHxN items (default: the six standard ones)")
    ap.add_argument("--backend", default="cpu")
    ap.add_argument("--no-reference", action="store_true", help="skip the brute-force reference rows")
    ap.add_argument("--one", default=None, help=argparse.SUPPRESS)  # internal: run one config in this process
    ap.add_argument("--with-reference", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)

    if args.one:
        w, h, n = (int(x) for x in args.one.split("x"))
        print(json.dumps(run_one(w, h, n, args.iters, args.backend, args.with_reference)))
        return 0

    configs = [(c, False) for c in (args.configs or DEFAULT_CONFIGS)]
    if not args.no_reference and args.configs is None:
        configs = [(c, True) for c in REFERENCE_CONFIGS] + configs
    rows = []
    from tqdm import tqdm

    for cfg, with_ref in tqdm(configs, desc="configs", disable=args.json, file=sys.stderr):
        cmd = [sys.executable, __file__, "--one", cfg, "--iters", str(args.iters), "--backend", args.backend]
        if with_ref:
            cmd.append("--with-reference")
        proc = subprocess.run(cmd, capture_output=True, text=True)
        if proc.returncode != 0:
            print(f"config {cfg} failed:\n{proc.stderr[-2000:]}", file=sys.stderr)
            return 1
        row = json.loads(proc.stdout.strip().splitlines()[-1])
        rows.append(row)
        if args.json:
            print(json.dumps(row), flush=True)
    if not args.json:
        print(f"backend {args.backend}; threads torch {rows[0]['threads']['torch']}, numba {rows[0]['threads']['numba']}; "
              f"loss 0.8 L1 + 0.2 (1 - SSIM); median of {args.iters} after 2 warm-ups")
        hdr = (f"{'size':>9} {'N':>7} {'visible':>7} {'fwd ms':>8} {'fwd+bwd':>8} {'step ms':>8} {'step cpu':>8} "
               f"{'loss ms':>8} {'peak MB':>8} {'ref step':>9} {'ratio':>6}")
        print(hdr)
        for r in rows:
            ref = f"{r['reference_step_ms']:9.1f} {r['ratio']:6.1f}" if "reference_step_ms" in r else f"{'-':>9} {'-':>6}"
            print(f"{r['width']}x{r['height']:<5} {r['gaussians']:>7} {r['visible']:>7} {r['fwd_ms']:8.1f} "
                  f"{r['fwd_bwd_ms']:8.1f} {r['step_ms']:8.1f} {r['step_cpu_ms']:8.1f} {r['loss_ms']:8.1f} {r['peak_mb']:8.1f} {ref}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
