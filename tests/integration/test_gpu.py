"""GPU tests (marker `gpu`; the default run deselects them, `pytest -m gpu` runs them; without CUDA
they skip with reason "no CUDA"). What they check is in docs/guide/gpu.md:

- the gsplat backend against the CPU backend: images and gradients on 2 000 random Gaussians;
- every registered trainable method trains 100 steps on CUDA through `strings-bench run --device cuda`;
- GPU memory stays flat over 1 000 steps (the gsplat hook's reference cycle kept every step's graph).
"""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch


pytestmark = [pytest.mark.gpu, pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA")]


def _needs_gsplat():
    from strings_bench.raster.gsplat_backend import gsplat_available

    if not gsplat_available():
        pytest.skip("gsplat does not import (pip install -e .[cuda])")


def _cos(a: torch.Tensor, b: torch.Tensor) -> float:
    a, b = a.detach().double().flatten().cpu(), b.detach().double().flatten().cpu()
    return float(a @ b / (a.norm() * b.norm()).clamp_min(1e-300))


def test_gsplat_matches_cpu_images_and_gradients():
    """2 000 random Gaussians, SH degree 3, 320x240: measured 75.9 dB and cosine >= 0.99995 on an H100
    (issue 13); the bounds leave room for the documented tile-support and alpha-clamp differences."""
    _needs_gsplat()
    from tests.raster.test_raster import random_scene

    from strings_bench.raster import rasterize
    from strings_bench.scene.camera import Camera

    params = random_scene(n=2000, deg=3, seed=5, scale=(0.005, 0.05))
    cam = Camera(fx=300.0, fy=300.0, cx=160.3, cy=119.6, width=320, height=240, R=np.eye(3), t=np.zeros(3))
    weights = torch.rand(240, 320, 3, generator=torch.Generator().manual_seed(2))
    outs, grads = {}, {}
    for backend, dev in (("cpu", "cpu"), ("gsplat", "cuda")):
        leaves = [p.detach().to(dev).requires_grad_() for p in params[:5]]
        out = rasterize(*leaves, cam, params[5].to(dev), backend=backend)
        out.means2d.retain_grad()
        (out.color * weights.to(dev)).sum().backward()
        outs[backend] = out.color.detach().cpu()
        grads[backend] = [leaf.grad for leaf in leaves] + [out.means2d.grad]
    mse = float(((outs["cpu"] - outs["gsplat"]) ** 2).mean())
    assert -10 * np.log10(max(mse, 1e-30)) > 60.0
    for name, a, b in zip(("means", "quats", "log_scales", "opacity_logits", "sh", "means2d"), grads["cpu"],
                          grads["gsplat"]):
        assert _cos(a, b) >= 0.999, name


def _trainable_methods() -> list[str]:
    from strings_bench.core.method import Method
    from strings_bench.methods.registry import list_methods

    names = []
    for spec in list_methods():
        try:
            built = spec.build()
        except Exception:  # noqa: BLE001 - adapters that need settings (ply_path, command) are not trainable
            continue
        if isinstance(built, Method):
            names.append(spec.name)
    return names


@pytest.mark.parametrize("method", _trainable_methods())
def test_every_method_trains_100_steps_on_cuda(method, tmp_path):
    """`strings-bench run --device cuda --schedule tiny` (x0.005), checkpoint 20K = 100 steps."""
    _needs_gsplat()
    from strings_bench.cli import main

    out = tmp_path / "run"
    rc = main(["run", "--methods", method, "--datasets", "synthetic/books", "--schedule", "tiny", "--checkpoints", "20000",
               "--device", "cuda", "--out", str(out), "--no-progress", "--no-lpips"])
    assert rc == 0
    (cell,) = list(out.rglob("result.json"))
    record = json.loads(cell.read_text())
    assert record["iteration"] == 100 and record["device"].startswith("cuda") and record["gpu"]
    assert record["extra"]["device"].startswith("cuda") and record["gaussians"] > 0
    assert np.isfinite(record["metrics"]["psnr"])
    assert json.loads((out / "run.json").read_text())["resolved_device"]["gpu"] == record["gpu"]


def test_gpu_memory_flat_over_1000_steps():
    """3DGS without densification (a constant number of Gaussians): the memory allocated after step
    1 000 is that after step 100, within 10 % + 8 MiB, and the peak of steps 900-1000 that of 100-200."""
    _needs_gsplat()
    from strings_bench.datasets.synthetic import build_scene
    from strings_bench.engine.trainer import Trainer
    from strings_bench.methods.registry import get_method
    from strings_bench.scene.scene import Scene

    scene = Scene.load(build_scene("books", progress=False))
    method = get_method("3dgs").build(None, steps_scale=1.0, refine_start_iter=10_000, reset_every=10_000)
    allocated, peaks = {}, {}
    torch.cuda.reset_peak_memory_stats()
    for result in Trainer(method, scene, list(range(100, 1001, 100)), device="cuda", progress=False,
                          render_test=False).train():
        torch.cuda.synchronize()
        allocated[result.iteration] = torch.cuda.memory_allocated()
        peaks[result.iteration] = torch.cuda.max_memory_allocated()
        torch.cuda.reset_peak_memory_stats()
    slack = 8 * 2 ** 20
    assert allocated[1000] <= 1.1 * allocated[100] + slack, allocated
    assert peaks[1000] <= 1.1 * peaks[200] + slack, peaks
