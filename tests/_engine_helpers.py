"""Test-local helpers for the engine tests: a tiny synthetic COLMAP scene built on disk (its images
rendered with the real rasterizer, strings_bench.raster)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import torch
from PIL import Image


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
                    seed: int = 0, sfm_xyz=None, sfm_rgb=None, tracks=None):
    """A plane of coloured Gaussian blobs seen by cameras on an arc; images rendered with the model's
    renderer; SfM points = blob centres + noise, observed in every view.

    sfm_xyz / sfm_rgb / tracks (a list of view indices per point) replace the SfM points, their colours
    and their tracks (observed in every view by default); the images stay those of the blobs."""
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
    sfm_colours = rng.integers(0, 255, (n_points, 3)).astype(np.uint8)
    if sfm_xyz is not None:
        noisy = np.asarray(sfm_xyz, dtype=np.float64)
        sfm_colours = np.asarray(sfm_rgb, dtype=np.uint8)
    if tracks is None:
        tracks = [list(range(n_views))] * len(noisy)
    track_view = np.concatenate([np.asarray(t, dtype=np.int32) for t in tracks])
    track_ptr = np.concatenate([[0], np.cumsum([len(t) for t in tracks])]).astype(np.int64)
    xy = np.stack([cams[v].project(noisy[i:i + 1])[0][0] for i, t in enumerate(tracks) for v in t])
    model = ColmapModel(cameras=cams, xyz=noisy, rgb=sfm_colours, track_ptr=track_ptr, track_view=track_view,
                        track_xy=np.nan_to_num(xy), point_ids=np.arange(1, len(noisy) + 1))
    write_model(model, root / "sparse" / "0")
    # Interior test views (the default every-8th split would hold out the ends of the arc).
    (root / "split.json").write_text(json.dumps({"test": [cams[i].name for i in range(2, n_views, 4)]}))
    return Scene.load(root)


def train(method, scene, checkpoints, **kwargs) -> list:
    """All checkpoint results of `method` trained on `scene` by the framework's loop (CPU, no bar)."""
    from strings_bench.engine.trainer import Trainer

    kwargs.setdefault("progress", False)
    kwargs.setdefault("device", "cpu")
    return list(Trainer(method, scene, checkpoints, **kwargs).train())


def make_tiny_text_scene(root: Path, n_views: int = 9, n_points: int = 60) -> Path:
    """`make_tiny_scene` with a text mask per view (rows 6-13, columns 8-19 of each 32x24 image): a scene whose
    text masks the methods and the evaluation read. Returns `root`."""
    scene = make_tiny_scene(root, n_views=n_views, n_points=n_points)
    (root / "masks").mkdir()
    for c in scene.model.cameras:
        m = np.zeros((c.height, c.width), np.uint8)
        m[6:14, 8:20] = 255
        Image.fromarray(m).save(root / "masks" / c.name)
    return root
