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


def _prefer_openmp_threads() -> None:
    """numba's OpenMP threading layer (its own default where no TBB is installed), with its threads sleeping as
    soon as a kernel ends (OMP_WAIT_POLICY=passive), rather than the workqueue layer. Measured on a 2-core Xeon
    (studies/threading_layer/threading_layer.py; docs/results/engine-speed.md, "numba's threads"), 3DGS training steps at 63k
    and 336k Gaussians: idle, workqueue 91 and 287 ms, OpenMP 55 and 232 ms; beside two other trainings,
    workqueue 190 and 619 ms, OpenMP 105 and 473 ms, the same bits in every arm. libgomp's default spin-wait is
    as fast when the cores are free but up to 2.8x slower than workqueue when they are not (its threads spin for
    cores another process needs): hence passive. A user's OMP_WAIT_POLICY or GOMP_SPINCOUNT wins, and so does
    NUMBA_THREADING_LAYER. Where numba's OpenMP pool cannot load (no libgomp), numba picks its layer itself.
    The variable itself is set when the package is imported, before torch loads its own libgomp
    (`strings_bench.core.cpus.passive_omp_waits`)."""
    if os.environ.get("NUMBA_THREADING_LAYER"):
        return
    try:
        import numba.core.config as nconfig
        import numba.np.ufunc.omppool  # noqa: F401  (raises where libgomp is missing)
    except (ImportError, OSError):
        return
    nconfig.THREADING_LAYER = "omp"


_ensure_numba_cache_dir()
_prefer_openmp_threads()


def _check_inputs(means, quats, log_scales, opacity_logits, sh, background, sh_degree, sh_rest=None):
    named = [("means", means), ("quats", quats), ("log_scales", log_scales), ("opacity_logits", opacity_logits),
             ("sh", sh)] + ([("sh_rest", sh_rest)] if sh_rest is not None else [])
    for name, x in named:
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
    if sh_rest is not None:
        if k != 1 or sh_rest.ndim != 3 or sh_rest.shape[0] != n or sh_rest.shape[2] != 3:
            raise RasterInputError(
                f"rasterize: with sh_rest, sh must be (N, 1, 3) and sh_rest (N, K - 1, 3); got {tuple(sh.shape)} "
                f"and {tuple(sh_rest.shape)}", hint="pass the DC band as sh and the other bands as sh_rest")
        k = 1 + sh_rest.shape[1]
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


CPU_BACKENDS = {"cpu": "f32", "cpu-f64": "f64"}  # name -> blend kernels' precision (raster/cpu.py)
BACKENDS = ("auto", *CPU_BACKENDS, "gsplat")


def pick_backend(backend: str, device: torch.device) -> str:
    """The backend `rasterize` uses for tensors on `device`.

    Args:
        backend: "auto", "cpu", "cpu-f64" or "gsplat". "auto" gives "gsplat" when `device` is CUDA
            and gsplat imports, else "cpu"; the others are returned as given.
        device: the device of the input tensors (`means.device`).

    Returns:
        "cpu", "cpu-f64" or "gsplat".

    Raises:
        RasterInputError: `backend` is not one of those names.

    Example:
        >>> import torch
        >>> from strings_bench.raster import pick_backend
        >>> pick_backend("auto", torch.device("cpu"))
        'cpu'
    """
    if backend not in BACKENDS:
        raise RasterInputError(f"rasterize: unknown backend {backend!r}",
                               hint="use " + ", ".join(repr(b) for b in BACKENDS))
    if backend == "auto":
        if device.type == "cuda":
            from strings_bench.raster.gsplat_backend import gsplat_available

            if gsplat_available():
                return "gsplat"
        return "cpu"
    return backend


def rasterize(means, quats, log_scales, opacity_logits, sh, camera, background, sh_degree=None,
              backend="auto", mip_filter=False, compute_absgrad=False, near=0.01, far=1e10,
              sh_rest=None) -> RasterOutput:
    """Render N 3D Gaussians into `camera`, differentiably (3DGS splatting; rules in docs/raster.md).

    Every input is a raw (pre-activation) parameter, as 3DGS stores it; all floating tensors must be
    on one device. Units: world units for positions and scales, pixels for everything on the image.
    Gradients flow to every floating input, `background` included.

    Args:
        means: (N, 3) float, Gaussian centres in world coordinates.
        quats: (N, 4) float, rotations as quaternions (w, x, y, z), any norm: normalised inside; a
            zero quaternion is the identity rotation (with zero gradient).
        log_scales: (N, 3) float, natural log of the standard deviations along the Gaussian's own
            axes, in world units: Sigma = R diag(exp(log_scales))^2 R^T.
        opacity_logits: (N,) or (N, 1) float, opacity = sigmoid(opacity_logits).
        sh: (N, K, 3) float, spherical-harmonics colour coefficients per RGB channel,
            K = (d + 1)^2 for degree d in 0..3 (1, 4, 9 or 16), 3DGS basis and order. The colour is
            max(SH(dir) + 0.5, 0) with dir the unit vector from the camera centre to the mean.
        camera: a `strings_bench.scene.camera.Camera` (duck-typed: fx, fy, cx, cy, width, height,
            R, t, center, K, viewmat): pinhole, world -> camera p = R x + t, pixel centres at
            integer + 0.5, u = fx x / z + cx.
        background: (3,) RGB in [0, 1], a tensor or a sequence (converted to the dtype and device
            of `means`); composited as color + (1 - alpha) * background.
        sh_degree: int or None. Use SH bands 0..sh_degree only (None: every band `sh` holds);
            inactive bands get zero gradient.
        backend: "auto" (gsplat for CUDA tensors when gsplat imports, else "cpu"), "cpu" (numba
            preprocessing and tile kernels with a hand-written backward; float32 blending on the
            vector units), "cpu-f64" (the same with the float64 blend kernels: the reference the
            tests hold "cpu" to; slower: docs/raster.md) or "gsplat" (CUDA only).
        mip_filter: bool. Mip-Splatting's 2D filter: a 0.1 px^2 dilation with opacity compensation
            sqrt(det Sigma2D / det(Sigma2D + 0.1 I)) instead of 3DGS's plain 0.3 px^2 dilation.
        compute_absgrad: bool. Allocate `absgrad` and fill it during backward with the AbsGS
            statistic sum_pixels |dL_pixel / d means2d| per component (pixel units).
        near: float, camera-space depth z (world units) at or below which a Gaussian is culled
            (z <= near). Needs 0 < near < far.
        far: float, camera-space depth z (world units) at or beyond which a Gaussian is culled
            (z >= far).
        sh_rest: None, or (N, K - 1, 3) float: the SH bands above the DC one, with `sh` then only
            the DC band (N, 1, 3) — the model's sh0 / shN as they are stored. Same result as
            passing their concatenation as `sh`; the CPU backends then read both in place (no
            (N, K, 3) copy each step, no split of its gradient).

    Dtypes: float32 is the usual input; the CPU backends project in float64, blend in float32
    ("cpu") or float64 ("cpu-f64") and return the input dtype. `radii` is int32.

    Returns:
        RasterOutput with
            color: (H, W, 3), sum_i w_i c_i + (1 - alpha) * background (H, W = camera.height, width);
            alpha: (H, W), 1 - final transmittance;
            depth: (H, W), expected camera z, sum_i w_i z_i / alpha (0 where alpha = 0);
            radii: (N,) int32, screen radius in pixels, 0 = culled;
            means2d: (N, 2), projected centres (u, v) in pixels, in the autograd graph: call
                `out.means2d.retain_grad()` before backward to read dL/d(u, v) in pixels (NDC units,
                as the 3DGS threshold 2e-4, are grad * 0.5 * [W, H]);
            absgrad: (N, 2) or None (None unless compute_absgrad), filled by backward;
            visible: (N,) bool, radii > 0;
            backend: "cpu", "cpu-f64" or "gsplat", the backend that ran.

    Raises:
        RasterInputError (a StringsBenchError with a hint): an input is not a floating torch
            tensor; inconsistent shapes; K not in (1, 4, 9, 16); sh_degree above what `sh` holds;
            background not of shape (3,); not 0 < near < far; an unknown backend; CPU backend
            with non-CPU tensors; gsplat backend without gsplat or without CUDA tensors.

    Example:
        >>> import numpy as np, torch
        >>> from strings_bench.raster import rasterize
        >>> from strings_bench.scene.camera import Camera
        >>> cam = Camera(fx=40.0, fy=40.0, cx=24.0, cy=16.0, width=48, height=32, R=np.eye(3), t=np.zeros(3))
        >>> means = torch.tensor([[0.0, 0.0, 2.0], [0.5, 0.0, 2.0], [0.0, -0.25, 4.0]], requires_grad=True)
        >>> quats = torch.tensor([[1.0, 0.0, 0.0, 0.0]]).repeat(3, 1)         # identity rotations
        >>> log_scales = torch.full((3, 3), float(np.log(0.05)))              # 5 cm standard deviation
        >>> opacity_logits = torch.zeros(3)                                   # opacity 0.5
        >>> sh = torch.zeros(3, 1, 3)                                         # degree 0: grey 0.5
        >>> out = rasterize(means, quats, log_scales, opacity_logits, sh, cam, background=[1.0, 1.0, 1.0])
        >>> out.color.shape, out.alpha.shape, out.radii.dtype, out.backend
        (torch.Size([32, 48, 3]), torch.Size([32, 48]), torch.int32, 'cpu')
        >>> out.means2d.tolist()                                              # u = fx x / z + cx, pixels
        [[24.0, 16.0], [34.0, 16.0], [24.0, 13.5]]
        >>> out.color[0, 0].tolist()                                          # no Gaussian there: background
        [1.0, 1.0, 1.0]
        >>> out.means2d.retain_grad()
        >>> out.color.sum().backward()
        >>> out.means2d.grad.shape, means.grad.shape
        (torch.Size([3, 2]), torch.Size([3, 3]))
    """
    background = torch.as_tensor(background, dtype=means.dtype, device=means.device)
    deg = _check_inputs(means, quats, log_scales, opacity_logits, sh, background, sh_degree, sh_rest)
    if not near > 0 or not far > near:
        raise RasterInputError(f"rasterize: need 0 < near < far, got near={near}, far={far}",
                               hint="the default near plane is 0.01")
    chosen = pick_backend(backend, means.device)
    opacity_logits = opacity_logits.reshape(-1)
    if sh_rest is not None and (chosen == "gsplat" or sh_rest.shape[1] == 0):
        sh, sh_rest = torch.cat([sh, sh_rest], dim=1), None
    if chosen == "gsplat":
        from strings_bench.raster.gsplat_backend import rasterize_gsplat

        colors = sh_to_color(sh, means, _cam_center(camera, means), deg)
        return rasterize_gsplat(means, quats, log_scales, opacity_logits, colors, camera, background,
                                mip_filter=mip_filter, compute_absgrad=compute_absgrad, near=near, far=far)
    return _rasterize_cpu(means, quats, log_scales, opacity_logits, sh, deg, camera, background,
                          mip_filter=mip_filter, compute_absgrad=compute_absgrad, near=near, far=far,
                          backend=chosen, sh_rest=sh_rest)


def _cam_center(camera, like: torch.Tensor) -> torch.Tensor:
    return torch.as_tensor(camera.center, dtype=like.dtype, device=like.device)


def _rasterize_cpu(means, quats, log_scales, opacity_logits, sh, deg, camera, background, mip_filter,
                   compute_absgrad, near, far, preprocess="numba", backend="cpu", sh_rest=None) -> RasterOutput:
    """preprocess="numba" (default, fast) or "torch" (projection.py + sh.py through autograd; the
    tests use it as an independent check of the hand-written preprocessing backward). backend:
    "cpu" (float32 blend kernels) or "cpu-f64" (float64)."""
    from strings_bench.raster.cpu import Preprocess, RasterizeTiles

    if means.device.type != "cpu":
        raise RasterInputError(f"rasterize: the cpu backend got tensors on {means.device}",
                               hint="move the tensors to the CPU, or use backend='gsplat' on CUDA")
    n = means.shape[0]
    if preprocess == "numba":
        means2d, conics, opacities, feats, radii, bbox = Preprocess.apply(
            means, quats, log_scales, opacity_logits, sh, deg, camera, mip_filter, near, far, sh_rest)
    else:
        if sh_rest is not None:
            sh = torch.cat([sh, sh_rest], dim=1)
        from strings_bench.raster.projection import project

        proj = project(means, quats, log_scales, opacity_logits, camera, mip_filter=mip_filter, near=near, far=far)
        colors = sh_to_color(sh, means, _cam_center(camera, means), deg)
        means2d, conics, opacities, radii, bbox = proj.means2d, proj.conics, proj.opacities, proj.radii, proj.bbox
        feats = torch.cat([colors, proj.depths[:, None]], dim=1)
    absgrad = torch.zeros((n, 2), dtype=means.dtype, device=means.device) if compute_absgrad else None
    feat_img, alpha = RasterizeTiles.apply(means2d, conics, opacities, feats, radii, bbox, feats[:, 3].detach(),
                                           camera.width, camera.height, absgrad, CPU_BACKENDS[backend])
    color = feat_img[..., :3] + (1.0 - alpha)[..., None] * background
    depth = feat_img[..., 3] / alpha.clamp_min(1e-10)
    return RasterOutput(color=color, alpha=alpha, depth=depth, radii=radii, means2d=means2d,
                        absgrad=absgrad, visible=radii > 0, backend=backend)


__all__ = ["rasterize", "RasterOutput", "RasterInputError", "pick_backend"]
