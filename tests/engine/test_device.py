"""Device correctness without a GPU (docs/raster.md, "Device correctness without a GPU").

With `torch.set_default_device("meta")` in effect and the parameters on the CPU (device="cpu" given
explicitly), every tensor that code creates without naming a device lands on `meta`, and the first
operation mixing it with a CPU tensor, or reading its value, fails. On a CUDA machine the same
omission puts the tensor on the CPU next to CUDA parameters, so these tests find, on a CPU-only
machine, the places that would break on CUDA.
"""

from __future__ import annotations

import strings_bench.bench as bench

import collections
import contextlib
import math
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

import runner_fakes as rf  # noqa: E402
from _engine_helpers import make_tiny_text_scene  # noqa: E402
from strings_bench.core.errors import StringsBenchError  # noqa: E402
from strings_bench.engine.trainer import SaveEvery, Trainer  # noqa: E402
from strings_bench.methods.registry import get_method  # noqa: E402
from strings_bench.scene.scene import Scene  # noqa: E402


@contextlib.contextmanager
def default_device_meta():
    torch.set_default_device("meta")
    try:
        yield
    finally:
        torch.set_default_device(None)


# Settings that make every densification path run within a few dozen steps (steps_scale 1, nominal
# iterations small): clone, split, prune (opacity, world and screen size), opacity reset; MCMC
# relocation and growth; EDC recovery pruning; Mip-Splatting's filter updates; STRinGS phase 2.
_DEFAULT = dict(steps_scale=1.0, sh_degree=1, refine_start_iter=1, refine_every=3, refine_stop_iter=11,
                reset_every=5, screen_prune_after=4, grow_grad2d=1e-7, prune_screen_px=30.0)
_STRINGS = {**_DEFAULT, "t1": 4, "mask_dilation_fraction": 0.0, "n_max": 3}
SETTINGS = {
    "3dgs": _DEFAULT,
    "absgs": {**_DEFAULT, "grow_grad2d_abs": 1e-7},
    # 1e-4, not 1e-7: the absolute gradient is real here (it stayed zero on a meta default device until
    # the rasterizer made its buffer on the parameters' device), and at 1e-7 every Gaussian splits each
    # round until the recovery pruning would remove them all.
    "edc-absgs": {**_DEFAULT, "grow_grad2d_abs": 1e-4, "recovery_delay": 2, "recovery_min_steps": 1},
    "mip-splatting": {**_DEFAULT, "filter_every": 2},
    # every rule within 12 steps: budget ramp, edge score, long-axis split, early/recovery pruning,
    # opacity reset, the late (gradient-scored) rounds and both multi-step update intervals
    "improved-gs": dict(steps_scale=1.0, sh_degree=1, refine_start_iter=1, refine_every=3, refine_stop_iter=11,
                        reset_every=5, grow_grad2d_abs=1e-4, growth_full_iter=6, late_iter=8, prune_stop_iter=11,
                        early_prune_iter=2, recovery_delay=2, recovery_min_steps=1, recovery_stop_iter=11,
                        score_views=2, multi_step_from=7, multi_step_mid_every=2, multi_step_late_from=9,
                        multi_step_late_every=3),
    # HD and MD rounds, the trans statistic, the BCE term, the classification at step 4
    "perceptual-gs": {**_DEFAULT, "hd_interval": 3, "md_interval": 6, "hd_md_from": 3, "sensitivity_until": 11,
                      "classify_iter": 4, "complex_transaction": 0.0, "mix_transaction": 0.0},
    "mcmc": dict(steps_scale=1.0, sh_degree=1, refine_start_iter=1, refine_every=3, min_opacity=0.2, seed=3),
    "strings": _STRINGS,
    "strings-no-densify": _STRINGS,
    "strings-pos-lr": _STRINGS,
}
# What must have happened for a method's run to count (ops of strategies/ops.py called).
EXPECTED_OPS = {"3dgs": {"sample_children", "reset_opacity", "rebuild"}, "mcmc": {"replace_rows", "rebuild"},
                "strings": {"sample_children", "reset_opacity", "rebuild"}, "mip-splatting": {"sample_children", "rebuild"}}


@pytest.fixture(scope="module")
def text_scene(tmp_path_factory) -> Path:
    return make_tiny_text_scene(tmp_path_factory.mktemp("device") / "scene")


@pytest.fixture
def op_calls(monkeypatch):
    import strings_bench.engine.strategies.ops as ops

    calls = collections.Counter()
    for name in ("rebuild", "reset_opacity", "replace_rows", "sample_children"):
        real = getattr(ops, name)

        def counted(*a, _real=real, _name=name, **k):
            calls[_name] += 1
            return _real(*a, **k)

        monkeypatch.setattr(ops, name, counted)
    return calls


def test_meta_default_device_catches_a_deviceless_tensor():
    """The harness itself: a tensor made without a device fails next to CPU parameters."""
    p = torch.zeros(3, device="cpu")
    with default_device_meta(), pytest.raises((RuntimeError, NotImplementedError)):
        float((p + torch.ones(3)).sum())


def test_cpu_rasterizer_gradients_and_absgrad_stay_on_the_parameters_device():
    """A buffer made without a device (absgrad was one) would be meta here: `cpu += meta` is silently a
    no-op, so AbsGS' statistic stayed zero; every output and gradient must be real CPU values."""
    from strings_bench.raster import rasterize
    from strings_bench.scene.camera import Camera

    g = torch.Generator().manual_seed(0)
    n = 40
    leaves = [(torch.randn(n, 3, generator=g) * 0.4 + torch.tensor([0.0, 0.0, 3.0])), torch.randn(n, 4, generator=g),
              torch.full((n, 3), -2.5), torch.zeros(n), torch.randn(n, 4, 3, generator=g) * 0.3]
    leaves = [x.requires_grad_() for x in leaves]
    cam = Camera(fx=30.0, fy=30.0, cx=16.0, cy=12.0, width=32, height=24, R=np.eye(3), t=np.zeros(3))
    with default_device_meta():
        out = rasterize(*leaves, cam, torch.zeros(3, device="cpu"), compute_absgrad=True)
        out.color.sum().backward()
    assert out.absgrad.device.type == "cpu" and float(out.absgrad.sum()) > 0
    assert all(x.grad.device.type == "cpu" and torch.isfinite(x.grad).all() for x in leaves)
    assert float(leaves[0].grad.abs().sum()) > 0


@pytest.mark.parametrize("name", sorted(SETTINGS))
def test_method_trains_resumes_and_saves_with_meta_default_device(name, text_scene, tmp_path, op_calls):
    state = tmp_path / "state.pt"

    def trainer():
        return Trainer(get_method(name).build(None, **SETTINGS[name]), Scene.load(text_scene), [6, 12], device="cpu",
                       progress=False, state_path=state, save_every=SaveEvery(minutes=None, steps=5),
                       model_path=lambda step: tmp_path / f"model_{step}.ply")

    with default_device_meta():
        first = trainer()
        for _ in first.train():  # stopped at the first checkpoint; the state was saved at step 5
            break
        second = trainer()
        results = list(second.train())  # continues from the saved state
    assert [r.iteration for r in results] == [6, 12] and results[1].resumed_from_step == 5
    assert all(np.isfinite(img).all() for r in results for img in r.renders.values())
    assert (tmp_path / "model_12.ply").stat().st_size > 0
    assert all(p.device.type == "cpu" for p in second.method.model.params.values())
    assert EXPECTED_OPS.get(name, {"rebuild"}) <= set(op_calls), dict(op_calls)


def test_runner_evaluation_with_meta_default_device(tmp_path):
    """Training through the runner, then metrics, LPIPS, OCR-CER and the result files, on meta defaults."""
    import strings_bench.bench.runner as runner

    scene_dir = rf.make_scene(tmp_path / "scenes")
    with default_device_meta():
        out = bench.run(["3dgs"], [str(scene_dir)], run_dir=tmp_path / "run", schedule="tiny", ocr="fake",
                         ocr_backend=rf.FakeOCR(), with_lpips=True, progress=False, steps_scale=1.0,
                         checkpoints=(3, 6), device="cpu", method_overrides={"3dgs": {"sh_degree": 0}})
    results = sorted((out / "cells").rglob("result.json"))
    assert len(results) == 2
    import json

    cell = max((json.loads(p.read_text()) for p in results), key=lambda c: c["iteration"])  # LPIPS is at the last
    assert cell["device"] == "cpu" and cell["gpu"] is None and math.isfinite(cell["metrics"]["lpips"])
    manifest = json.loads((out / "run.json").read_text())
    assert manifest["device"] == "cpu" and manifest["resolved_device"] == {"device": "cpu", "gpu": None}


@pytest.mark.skipif(torch.cuda.is_available(), reason="checks the message shown on a machine without CUDA")
def test_device_cuda_without_cuda_is_a_clear_error(tmp_path, capsys):
    from strings_bench.cli import main

    rc = main(["run", "--methods", "3dgs", "--datasets", str(tmp_path / "nowhere"), "--device", "cuda",
               "--out", str(tmp_path / "run"), "--no-progress"])
    err = capsys.readouterr().err
    assert rc == 1
    assert "error: device 'cuda' asked for, but torch sees no CUDA GPU" in err and "Traceback" not in err
    assert not (tmp_path / "run").exists()  # refused before anything was planned or written


@pytest.mark.skipif(torch.cuda.is_available(), reason="checks the message shown on a machine without CUDA")
def test_render_device_cuda_without_cuda_is_a_clear_error(tmp_path, capsys):
    from strings_bench.cli import main

    rc = main(["render", "--ply", str(tmp_path / "m.ply"), "--scene", str(tmp_path), "--out", str(tmp_path / "o"),
               "--device", "cuda:0"])
    assert rc == 1 and "torch sees no CUDA GPU" in capsys.readouterr().err


def test_unknown_device_is_refused():
    import strings_bench.bench.runner as runner

    with pytest.raises(StringsBenchError, match="unknown device"):
        bench.run(["3dgs"], ["synthetic/books"], device="gpu0", progress=False)


def test_scene_given_as_a_path_is_labelled_by_its_folder(tmp_path):
    """`run --datasets ../data/watch_clock`: the scene folder's name labels it, not its parent's ("data")."""
    from strings_bench.datasets.registry import resolve_scenes

    scene_dir = rf.make_scene(tmp_path / "scenes", name="watch_clock")
    relative = Path("..") / scene_dir.parent.name / scene_dir.name
    import os

    here = os.getcwd()
    os.chdir(scene_dir.parent / "..")  # a relative path with '..' in it
    try:
        os.makedirs("sub", exist_ok=True)
        os.chdir("sub")
        (ref,) = resolve_scenes([str(relative)])
    finally:
        os.chdir(here)
    assert (ref.dataset, ref.scene) == ("watch_clock", "watch_clock") and ref.path == scene_dir.resolve()
