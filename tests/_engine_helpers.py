"""Test-local helpers for the engine tests: a dense pure-torch rasterizer used only while
strings_bench.raster is missing (same call signature and 3DGS rules, SH degree 0 only), and a tiny
synthetic COLMAP scene built on disk."""

from __future__ import annotations

import contextlib
import json
import math
import sys
import types
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from PIL import Image

SH_C0 = 0.28209479177387814


@dataclass
class DenseRasterOutput:
    color: torch.Tensor
    alpha: torch.Tensor
    depth: torch.Tensor
    radii: torch.Tensor
    means2d: torch.Tensor
    absgrad: torch.Tensor | None = None


def dense_rasterize(means, quats, log_scales, opacity_logits, sh, camera, background, sh_degree=None,
                    backend="auto", mip_filter=False, compute_absgrad=False):
    dt = means.dtype
    R = torch.tensor(camera.R, dtype=dt)
    t = torch.tensor(camera.t, dtype=dt)
    pc = means @ R.T + t
    X, Y, Z = pc.unbind(-1)
    valid = Z > 0.2
    Zs = torch.where(valid, Z, torch.ones_like(Z))
    u = camera.fx * X / Zs + camera.cx
    v = camera.fy * Y / Zs + camera.cy
    means2d = torch.stack([u, v], -1)
    q = quats / quats.norm(dim=-1, keepdim=True)
    w, x, y, z = q.unbind(-1)
    Rq = torch.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
                      2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
                      2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1).reshape(-1, 3, 3)
    M = Rq * torch.exp(log_scales)[:, None, :]
    cov3 = M @ M.transpose(1, 2)
    zero = torch.zeros_like(Zs)
    J = torch.stack([camera.fx / Zs, zero, -camera.fx * X / Zs ** 2,
                     zero, camera.fy / Zs, -camera.fy * Y / Zs ** 2], -1).reshape(-1, 2, 3)
    T = J @ R
    cov2 = T @ cov3 @ T.transpose(1, 2) + 0.3 * torch.eye(2, dtype=dt)
    a, b, c = cov2[:, 0, 0], cov2[:, 0, 1], cov2[:, 1, 1]
    det = a * c - b * b
    mid = 0.5 * (a + c)
    lam = mid + torch.sqrt(torch.clamp(mid * mid - det, min=0.1))
    radii = torch.where(valid, torch.ceil(3 * torch.sqrt(lam)), torch.zeros_like(lam)).detach().long()
    ia, ib, ic = c / det, -b / det, a / det
    H, W = camera.height, camera.width
    py, px = torch.meshgrid(torch.arange(H, dtype=dt) + 0.5, torch.arange(W, dtype=dt) + 0.5, indexing="ij")
    dx = px.reshape(1, -1) - u[:, None]
    dy = py.reshape(1, -1) - v[:, None]
    power = -0.5 * (ia[:, None] * dx * dx + 2 * ib[:, None] * dx * dy + ic[:, None] * dy * dy)
    alpha = torch.clamp(torch.sigmoid(opacity_logits)[:, None] * torch.exp(power), max=0.99)
    keep = (alpha >= 1 / 255) & (power <= 0) & valid[:, None]
    alpha = torch.where(keep, alpha, torch.zeros_like(alpha))
    order = torch.argsort(Z.detach())
    alpha = alpha[order]
    colour = torch.clamp(sh[:, 0, :] * SH_C0 + 0.5, min=0)[order]
    trans = torch.cumprod(torch.cat([torch.ones_like(alpha[:1]), 1 - alpha[:-1]]), 0)
    wgt = trans * alpha  # (N, P)
    img = wgt.T @ colour
    acc = wgt.sum(0)
    img = img + (1 - acc)[:, None] * torch.as_tensor(background, dtype=dt)
    depth = wgt.T @ Z[order]
    return DenseRasterOutput(img.reshape(H, W, 3), acc.reshape(H, W), depth.reshape(H, W), radii, means2d)


@contextlib.contextmanager
def raster_or_stand_in():
    """Use strings_bench.raster when it exists; else register the dense stand-in under that name for
    the duration of the block only (other test modules must not see it)."""
    try:
        import strings_bench.raster  # noqa: F401
        yield False
        return
    except ImportError:
        pass
    mod = types.ModuleType("strings_bench.raster")
    mod.rasterize = dense_rasterize
    sys.modules["strings_bench.raster"] = mod
    try:
        yield True
    finally:
        if sys.modules.get("strings_bench.raster") is mod:
            del sys.modules["strings_bench.raster"]


def install_stand_in_raster() -> bool:
    """Register the stand-in for the rest of the session if strings_bench.raster is missing.

    Prefer `raster_or_stand_in()`: a session-wide stand-in is also seen by other test modules.
    """
    try:
        import strings_bench.raster  # noqa: F401
        return False
    except ImportError:
        mod = types.ModuleType("strings_bench.raster")
        mod.rasterize = dense_rasterize
        sys.modules["strings_bench.raster"] = mod
        return True


def look_at(center, target, up=(0.0, -1.0, 0.0)):
    """World->camera R, t for a camera at `center` looking at `target` (y down)."""
    center, target, up = (np.asarray(a, dtype=np.float64) for a in (center, target, up))
    zc = target - center
    zc /= np.linalg.norm(zc)
    xc = np.cross(up, zc)
    xc /= np.linalg.norm(xc)
    yc = np.cross(zc, xc)
    R = np.stack([xc, yc, zc])
    return R, -R @ center


def make_tiny_scene(root: Path, n_views: int = 9, width: int = 32, height: int = 24, n_points: int = 120,
                    seed: int = 0):
    """A plane of coloured Gaussian blobs seen by cameras on an arc; images rendered with the model's
    renderer; SfM points = blob centres + noise, observed in every view."""
    from strings_bench.scene.camera import Camera
    from strings_bench.scene.colmap import ColmapModel, write_model
    from strings_bench.engine.gaussians import GaussianModel
    from strings_bench.scene.scene import Scene

    rng = np.random.default_rng(seed)
    xyz = np.stack([rng.uniform(-1, 1, n_points), rng.uniform(-0.75, 0.75, n_points), rng.uniform(-0.1, 0.1, n_points)], 1)
    rgb = rng.integers(20, 235, (n_points, 3)).astype(np.uint8)
    gt = GaussianModel.from_points(xyz, rgb, sh_degree=0, init_opacity=0.9)
    with torch.no_grad():
        gt.params["log_scales"].fill_(math.log(0.08))
    cams = []
    f = 0.9 * width
    for i in range(n_views):
        ang = -1.0 + 2.0 * i / max(1, n_views - 1)
        center = np.array([3 * math.sin(ang), 0.3 * math.cos(3 * ang), -3 * math.cos(ang)])
        R, t = look_at(center, np.zeros(3))
        cams.append(Camera(f, f, width / 2, height / 2, width, height, R, t, name=f"view_{i:03d}.png"))
    (root / "images").mkdir(parents=True, exist_ok=True)
    for cam in cams:
        with torch.no_grad():
            img = gt.render(cam, (0.0, 0.0, 0.0), sh_degree=0).color.clamp(0, 1).numpy()
        Image.fromarray((img * 255 + 0.5).astype(np.uint8)).save(root / "images" / cam.name)
    noisy = xyz + rng.normal(0, 0.03, xyz.shape)
    track_view = np.tile(np.arange(n_views, dtype=np.int32), n_points)
    track_xy = np.concatenate([np.nan_to_num(c.project(noisy)[0]) for c in cams])
    order = np.argsort(track_view, kind="stable")  # keep per-point order: rebuild per point
    xy_pp = np.stack([cams[v].project(noisy[i:i + 1])[0][0] for i in range(n_points) for v in range(n_views)])
    model = ColmapModel(cameras=cams, xyz=noisy, rgb=rng.integers(0, 255, (n_points, 3)).astype(np.uint8),
                        track_ptr=np.arange(0, n_points * n_views + 1, n_views, dtype=np.int64),
                        track_view=track_view, track_xy=np.nan_to_num(xy_pp), point_ids=np.arange(1, n_points + 1))
    del order, track_xy
    write_model(model, root / "sparse" / "0")
    # Interior test views (the default every-8th split would hold out the ends of the arc).
    (root / "split.json").write_text(json.dumps({"test": [cams[i].name for i in range(2, n_views, 4)]}))
    return Scene.load(root)
