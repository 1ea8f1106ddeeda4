"""Numerical extremes through the whole trainer (issue 19, item 4).

A tiny scene (32x24, 9 views) is broken one way at a time: no text at all, text masks that are all
empty, one SfM point, duplicate SfM points (a zero 3-NN distance), a camera at the scene centre,
learning rates x100. STRinGS and 3DGS train through `engine.trainer.Trainer` past a densification
and an opacity reset. Each case must either train with finite parameters, losses and renders, or stop
with the documented `TrainingError` (engine/splatting.py: a non-finite loss, gradient or parameter
names the iteration and the parameter groups) - never hand NaN renders to the evaluation.
"""

from __future__ import annotations

import json
import math
import os
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image

from _engine_helpers import look_at, make_tiny_scene  # noqa: E402
from strings_bench.core.errors import TrainingError  # noqa: E402
from strings_bench.engine.trainer import Trainer  # noqa: E402
from strings_bench.methods.registry import get_method  # noqa: E402
from strings_bench.scene.scene import Scene  # noqa: E402

# Default run: a few steps each (the initial model, the first updates, two checkpoints). The slow variant
# trains past the first densification (every 50 steps at steps_scale 0.002) and the SH degree increase.
CHECKPOINTS = [6, 12]
SLOW_CHECKPOINTS = [30, 60]
BASE = {"3dgs": dict(steps_scale=0.002, sh_degree=1),
        "strings": dict(steps_scale=0.002, sh_degree=1, mask_dilation_fraction=0.0, n_max=3)}
LR_KEYS = ("lr_means", "lr_means_final", "lr_sh0", "lr_shN", "lr_opacity_logits", "lr_log_scales", "lr_quats")
OUTCOMES: list[dict] = []


def _masks(root: Path, scene: Scene, box: bool) -> None:
    (root / "masks").mkdir(exist_ok=True)
    for c in scene.model.cameras:
        m = np.zeros((c.height, c.width), np.uint8)
        if box:
            m[6:14, 8:20] = 255
        Image.fromarray(m).save(root / "masks" / c.name)


def _scene(root: Path, case: str) -> Path:
    if case == "one SfM point":
        make_tiny_scene(root, n_points=1, sfm_xyz=[[0.1, -0.05, 0.0]], sfm_rgb=[[200, 90, 40]])
    elif case == "duplicate SfM points":
        rng = np.random.default_rng(1)
        xyz = rng.uniform(-0.8, 0.8, (15, 3)) * [1, 0.75, 0.1]
        xyz = np.repeat(xyz, 4, axis=0)  # every point four times: its 3 nearest neighbours are at distance 0
        make_tiny_scene(root, n_points=60, sfm_xyz=xyz, sfm_rgb=np.full((60, 3), 128))
    else:
        make_tiny_scene(root, n_points=60)
    scene = Scene.load(root)
    if case == "camera at the scene centre":
        from strings_bench.scene.camera import Camera
        from strings_bench.scene.colmap import read_model, write_model

        model = read_model(root)
        centre = model.xyz.mean(0)  # inside the point cloud: points at depth ~0 and behind the camera
        R, t = look_at(centre, centre + np.array([0.0, 0.0, 1.0]))
        c0 = model.cameras[0]
        name = "view_009.png"
        model.cameras.append(Camera(c0.fx, c0.fy, c0.cx, c0.cy, c0.width, c0.height, R, t, name=name))
        model.track_view = np.concatenate([model.track_view, [len(model.cameras) - 1]]).astype(np.int32)
        model.track_xy = np.concatenate([model.track_xy, [[c0.cx, c0.cy]]])
        model.track_ptr = model.track_ptr.copy()
        model.track_ptr[-1] += 1  # the last point is seen by the new camera too
        write_model(model, root / "sparse" / "0")
        shutil.copy(root / "images" / "view_004.png", root / "images" / name)
        scene = Scene.load(root)
    if case == "no text":
        # Known text, and there is none: no view holds a word (the synthetic benchmark's mask source).
        (root / "text_annotations.json").write_text(json.dumps({"views": {n: [] for n in scene.names}}))
    else:
        _masks(root, scene, box=case != "all text masks empty")
    return root


def _settings(method: str, case: str) -> dict:
    s = dict(BASE[method])
    if method == "strings" and case == "no text":
        s["mask_source"] = "gt"  # known text (the synthetic benchmark's source); no view holds a word
    if case == "learning rates x100":
        from strings_bench.engine.optim import LearningRates

        lrs = LearningRates()
        for key in LR_KEYS:
            s[key] = 100 * getattr(lrs, key[3:])
    return s


CASES = ["no text", "all text masks empty", "one SfM point", "duplicate SfM points", "camera at the scene centre",
         "learning rates x100"]


pytestmark = pytest.mark.usefixtures("private_cache")  # tests/conftest.py


@pytest.mark.parametrize("method", ["3dgs", "strings"])
@pytest.mark.parametrize("case", CASES)
def test_extreme_scene_trains_finite_or_stops_with_training_error(case, method, tmp_path):
    check_extreme(case, method, tmp_path, CHECKPOINTS)


@pytest.mark.slow
@pytest.mark.parametrize("method", ["3dgs", "strings"])
@pytest.mark.parametrize("case", CASES)
def test_extreme_scene_through_densification(case, method, tmp_path):
    check_extreme(case, method, tmp_path, SLOW_CHECKPOINTS)


def check_extreme(case: str, method: str, tmp_path: Path, checkpoints: list[int]) -> None:
    root = _scene(tmp_path / "scene", case)
    scene = Scene.load(root)
    adapter = get_method(method).build(None, **_settings(method, case))
    trainer = Trainer(adapter, scene, checkpoints, device="cpu", progress=False)
    results = []
    outcome = {"case": case, "method": method, "steps": checkpoints[-1]}
    try:
        for r in trainer.train():
            results.append(r)
    except TrainingError as exc:
        # The documented stop: it names the iteration and what went non-finite, and nothing was yielded after.
        assert "step" in str(exc) or "iteration" in str(exc) or "Gaussians" in str(exc), str(exc)
        outcome.update(result="TrainingError", detail=str(exc).splitlines()[0][:200], checkpoints=len(results))
    else:
        assert [r.iteration for r in results] == checkpoints
        outcome.update(result="finite", gaussians=results[-1].gaussians)
    for r in results:  # whatever reached a checkpoint is finite: no NaN render goes on to the evaluation
        assert r.renders and all(np.all(np.isfinite(img)) for img in r.renders.values()), (case, method, r.iteration)
        assert r.gaussians > 0
    if outcome["result"] == "finite":
        params = adapter.model.params
        assert all(torch.isfinite(p).all() for p in params.values()), (case, method)
        assert math.isfinite(adapter.last_loss)
    OUTCOMES.append(outcome)
    summary = os.environ.get("STRINGS_BENCH_EXTREMES_SUMMARY")  # docs/reliability.md counts these
    if summary:
        Path(summary).write_text(json.dumps(OUTCOMES, indent=1))
