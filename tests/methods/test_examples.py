"""The add-a-method tutorial's example (examples/opacity-splat): it passes `methods check`, its entry point names its
spec, and the tutorial shows the file's own code."""

from __future__ import annotations

import importlib
import re
import sys
from pathlib import Path

import pytest

from strings_bench.bench.check import check_method
from strings_bench.methods.registry import registered

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE = ROOT / "examples" / "opacity-splat"
TUTORIAL = ROOT / "docs" / "guide" / "adding-a-method.md"


@pytest.fixture
def example(monkeypatch):
    monkeypatch.syspath_prepend(str(EXAMPLE))
    sys.modules.pop("opacity_splat", None)
    yield importlib.import_module("opacity_splat")
    sys.modules.pop("opacity_splat", None)


def test_example_method_passes_the_check(example):
    with registered(example.SPEC):
        results = check_method(example.SPEC.name, devices=["cpu"], with_lpips=False)
    failed = {r.check: r.detail for r in results if r.failed}
    assert not failed, failed
    passed = {r.check for r in results if r.status == "pass"}
    assert {"settings", "builds", "trains (cpu)", "renders (cpu)", "save/load", "re-save", "runner"} <= passed


def test_example_setting_changes_the_loss(example):
    """The example's one setting reaches its loss: a larger penalty gives a larger loss on the same model."""
    from types import SimpleNamespace

    import torch

    from strings_bench.bench.check import tiny_scene
    from strings_bench.core.schedules import get_schedule
    from strings_bench.scene.scene import Scene

    scene = Scene.load(tiny_scene())
    torch.manual_seed(0)
    color, gt = torch.rand(72, 96, 3), torch.rand(72, 96, 3)
    losses = []
    for reg in (0.0, 10.0):
        with registered(example.SPEC):
            method = example.SPEC.build(steps_scale=get_schedule("tiny").steps_scale, opacity_reg=reg)
        method.setup(scene)
        losses.append(method.loss(SimpleNamespace(color=color), gt, scene.train_idx[0], 1).item())
    assert losses[1] > losses[0]


def test_entry_point_names_the_spec(example):
    tomllib = pytest.importorskip("tomllib")
    project = tomllib.loads((EXAMPLE / "pyproject.toml").read_text())["project"]
    eps = project["entry-points"]["strings_bench.methods"]
    assert eps == {example.SPEC.name: "opacity_splat:SPEC"}


def test_tutorial_code_is_the_example_file():
    """Every Python block of the tutorial is a verbatim part of the example file, so the two cannot drift."""
    source = (EXAMPLE / "opacity_splat.py").read_text()
    blocks = re.findall(r"```python\n(.*?)```", TUTORIAL.read_text(), re.S)
    assert blocks, "the tutorial shows no Python code"
    for block in blocks:
        assert block.strip() in source, block[:200]
