"""Differentiable Gaussian-splat rasterizer with two backends behind one function.

    out = rasterize(means, quats, log_scales, opacity_logits, sh, camera, background)

- backend "cpu": torch projection + numba tile kernels with a hand-written backward (multi-threaded).
- backend "gsplat": gsplat.rasterization on CUDA tensors (optional extra `cuda`).
- backend "auto": gsplat for CUDA tensors when gsplat imports, else cpu.

Gradients w.r.t. `out.means2d` are in pixels: call `out.means2d.retain_grad()` before backward, then
`out.means2d.grad` is dL/d(u, v). NDC units (3DGS densification threshold 2e-4) are
grad_px * 0.5 * [W, H]. With compute_absgrad=True, `out.absgrad` (N, 2) is filled during backward
with the AbsGS statistic sum_pixels |dL_pixel/dmean2d| per component, in the same pixel units.
See docs/raster.md for the rules and the behaviour at extremes.
"""

from __future__ import annotations

import os

import torch

from strings_bench.core.errors import StringsBenchError
from strings_bench.core.io import cache_root
from strings_bench.raster.sh import sh_to_color
from strings_bench.raster.types import RasterInputError, RasterOutput


def _ensure_numba_cache_dir() -> None:
    """Compiled kernels persist under cache_root()/numba unless NUMBA_CACHE_DIR says otherwise."""
    if os.environ.get("NUMBA_CACHE_DIR"):
        return
    path = str(cache_root() / "numba")
    os.environ["NUMBA_CACHE_DIR"] = path
    try:  # numba reads the variable at import; if it is already imported, set its config too
        import numba.core.config as nconfig

        nconfig.CACHE_DIR = path
    except ImportError:
        pass


def _prefer_workqueue_threads() -> None:
    """numba's OpenMP layer brings a second libgomp next to torch's; both spin-wait after each
    parallel region and starve each other on few cores. The workqueue layer sleeps instead.
    NUMBA_THREADING_LAYER, when set, wins."""
    if os.environ.get("NUMBA_THREADING_LAYER"):
        return
    try:
        import numba.core.config as nconfig

        nconfig.THREADING_LAYER = "workqueue"
    except ImportError:
        pass


_ensure_numba_cache_dir()
_prefer_workqueue_threads()


def _check_inputs(means, quats, log_scales, opacity_logits, sh, background, sh_degree):
    for name, x in (("means", means), ("quats", quats), ("log_scales", log_scales),
                    ("opacity_logits", opacity_logits), ("sh", sh)):
        if not isinstance(x, torch.Tensor):
            raise RasterInputError(f"rasterize: {name} must be a torch tensor, got {type(x).__name__}",
                                   hint="pass torch tensors (float32)")
        if not x.is_floating_point():
            raise RasterInputError(f"rasterize: {name} must be floating point, got {x.dtype}",
                                   hint="convert with .float()")
    n = means.shape[0] if means.ndim == 2 else -1
    shapes_ok = (means.ndim == 2 and means.shape[1] == 3 and quats.shape == (n, 4) and log_scales.shape == (n, 3)
                 and opacity_logits.shape in ((n,), (n, 1)) and sh.ndim == 3 and sh.shape[0] == n
                 and sh.shape[2] == 3)
    if not shapes_ok:
        raise RasterInputError(
            "rasterize: inconsistent shapes means %s quats %s log_scales %s opacity_logits %s sh %s"
            % tuple(tuple(x.shape) for x in (means, quats, log_scales, opacity_logits, sh)),
            hint="expected (N,3), (N,4) wxyz, (N,3), (N,) or (N,1), (N,K,3) with K = (deg+1)^2")
    k = sh.shape[1]
    deg_avail = {1: 0, 4: 1, 9: 2, 16: 3}.get(k)
    if deg_avail is None:
        raise RasterInputError(f"rasterize: sh has {k} coefficients per channel",
                               hint="K must be 1, 4, 9 or 16 (SH degree 0..3)")
    if sh_degree is None:
        deg = deg_avail
    else:
        deg = int(sh_degree)
        if not 0 <= deg <= deg_avail:
            raise RasterInputError(f"rasterize: sh_degree={sh_degree} but sh holds degree {deg_avail}",
                                   hint=f"use 0 <= sh_degree <= {deg_avail}")
    if background.shape != (3,):
        raise RasterInputError(f"rasterize: background must have shape (3,), got {tuple(background.shape)}",
                               hint="pass e.g. torch.zeros(3)")
    return deg


def pick_backend(backend: str, device: torch.device) -> str:
    if backend not in ("auto", "cpu", "gsplat"):
        raise RasterInputError(f"rasterize: unknown backend {backend!r}", hint="use 'auto', 'cpu' or 'gsplat'")
    if backend == "auto":
        if device.type == "cuda":
            from strings_bench.raster.gsplat_backend import gsplat_available

            if gsplat_available():
                return "gsplat"
        return "cpu"
    return backend


def rasterize(means, quats, log_scales, opacity_logits, sh, camera, background, sh_degree=None,
              backend="auto", mip_filter=False, compute_absgrad=False, near=0.01, far=1e10) -> RasterOutput:
    """Render Gaussians into `camera`; see the module docstring and docs/raster.md."""
    background = torch.as_tensor(background, dtype=means.dtype, device=means.device)
    deg = _check_inputs(means, quats, log_scales, opacity_logits, sh, background, sh_degree)
    if not near > 0 or not far > near:
        raise RasterInputError(f"rasterize: need 0 < near < far, got near={near}, far={far}",
                               hint="the default near plane is 0.01")
    chosen = pick_backend(backend, means.device)
    opacity_logits = opacity_logits.reshape(-1)
    if chosen == "gsplat":
        from strings_bench.raster.gsplat_backend import rasterize_gsplat

        colors = sh_to_color(sh, means, _cam_center(camera, means), deg)
        return rasterize_gsplat(means, quats, log_scales, opacity_logits, colors, camera, background,
                                mip_filter=mip_filter, compute_absgrad=compute_absgrad, near=near, far=far)
    return _rasterize_cpu(means, quats, log_scales, opacity_logits, sh, deg, camera, background,
                          mip_filter=mip_filter, compute_absgrad=compute_absgrad, near=near, far=far)


def _cam_center(camera, like: torch.Tensor) -> torch.Tensor:
    return torch.as_tensor(camera.center, dtype=like.dtype, device=like.device)


def _rasterize_cpu(means, quats, log_scales, opacity_logits, sh, deg, camera, background, mip_filter,
                   compute_absgrad, near, far, preprocess="numba") -> RasterOutput:
    """preprocess="numba" (default, fast) or "torch" (projection.py + sh.py through autograd; the
    tests use it as an independent check of the hand-written preprocessing backward)."""
    from strings_bench.raster.cpu import Preprocess, RasterizeTiles

    if means.device.type != "cpu":
        raise RasterInputError(f"rasterize: the cpu backend got tensors on {means.device}",
                               hint="move the tensors to the CPU, or use backend='gsplat' on CUDA")
    n = means.shape[0]
    if preprocess == "numba":
        means2d, conics, opacities, feats, radii, bbox = Preprocess.apply(
            means, quats, log_scales, opacity_logits, sh, deg, camera, mip_filter, near, far)
    else:
        from strings_bench.raster.projection import project

        proj = project(means, quats, log_scales, opacity_logits, camera, mip_filter=mip_filter, near=near, far=far)
        colors = sh_to_color(sh, means, _cam_center(camera, means), deg)
        means2d, conics, opacities, radii, bbox = proj.means2d, proj.conics, proj.opacities, proj.radii, proj.bbox
        feats = torch.cat([colors, proj.depths[:, None]], dim=1)
    absgrad = torch.zeros((n, 2), dtype=means.dtype) if compute_absgrad else None
    feat_img, alpha = RasterizeTiles.apply(means2d, conics, opacities, feats, radii, bbox, feats[:, 3].detach(),
                                           camera.width, camera.height, absgrad)
    color = feat_img[..., :3] + (1.0 - alpha)[..., None] * background
    depth = feat_img[..., 3] / alpha.clamp_min(1e-10)
    return RasterOutput(color=color, alpha=alpha, depth=depth, radii=radii, means2d=means2d,
                        absgrad=absgrad, visible=radii > 0, backend="cpu")


__all__ = ["rasterize", "RasterOutput", "RasterInputError", "pick_backend"]
