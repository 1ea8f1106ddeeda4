"""strings-absgrad (issue 42): STRinGS with AbsGS' densification criterion, this suite's variant; and `strings`'
own criterion left as it was (3DGS' mean screen-space gradient).

References: the statistics are accumulated by hand here from each step's rasterizer output (the absolute gradient
itself is checked against a per-pixel brute force in tests/raster/test_raster.py), and the selection is worked out by
hand on constructed statistics.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch


def _build(name, **settings):
    from strings_bench.methods.registry import get_method

    return get_method(name).build(**settings)


def _small_model(n, big=()):
    from strings_bench.engine.gaussians import GaussianModel

    model = GaussianModel.from_points(np.random.default_rng(0).normal(size=(n, 3)), np.full((n, 3), 128, np.uint8),
                                      sh_degree=0)
    with torch.no_grad():
        model.params["log_scales"].fill_(math.log(0.001))
        for i in big:
            model.params["log_scales"][i] = math.log(0.5)
    return model


def test_strings_criterion_is_unchanged():
    """`strings` keeps 3DGS' rule: clone/split on the mean screen-space gradient >= 2e-4, no absolute gradient."""
    from strings_bench.engine.strategies import DefaultStrategy

    method = _build("strings")
    assert type(method.strategy) is DefaultStrategy
    assert method.strategy.get_raster_kwargs(100) == {}  # the rasterizer computes no absolute gradient
    assert (method.strategy.grow_grad2d, method.strategy.grow_scale3d, method.context.budget) == (2e-4, 0.01, None)
    n = 6
    model = _small_model(n, big=(0, 1))
    state = method.strategy.initialize_state(scene_extent=1.0)
    grad = torch.tensor([3e-4, 1e-4, 2e-4, 1.99e-4, 5e-4, 0.0]) * 3
    state.update(grad2d=grad, count=torch.full((n,), 3.0), max_radii=torch.ones(n),
                 grad2d_abs=torch.full((n,), 1.0))  # an absolute gradient in the state is not looked at
    clone, split = method.strategy._select(model, state, 600)
    # by hand: mean gradients 3, 1, 2, 1.99, 5, 0 (e-4); >= 2e-4: 0, 2, 4; 0 is large (split), 2 and 4 small (clone)
    assert clone.nonzero().squeeze(1).tolist() == [2, 4] and split.nonzero().squeeze(1).tolist() == [0]


def test_strings_absgrad_uses_absgs_thresholds_and_its_rule():
    from strings_bench.engine.strategies.absgs import AbsGSStrategy

    method = _build("strings-absgrad")
    s = method.strategy
    assert type(s) is AbsGSStrategy and (s.grow_grad2d, s.grow_grad2d_abs) == (2e-4, 4e-4)
    assert s.get_raster_kwargs(1) == {"compute_absgrad": True}
    n = 6
    model = _small_model(n, big=(0, 1, 2))
    state = s.initialize_state(scene_extent=1.0)
    state.update(grad2d=torch.tensor([9e-4, 0, 0, 2e-4, 1.5e-4, 0]), count=torch.ones(n), max_radii=torch.ones(n),
                 grad2d_abs=torch.tensor([1e-4, 4e-4, 3.9e-4, 9e-4, 9e-4, 9e-4]))
    clone, split = s._select(model, state, 600)
    # by hand: large (0-2) split when |grad| >= 4e-4 -> 1 only (0's ordinary gradient is high but does not count);
    # small (3-5) clone when the ordinary gradient >= 2e-4 -> 3 only (their absolute gradients do not count)
    assert split.nonzero().squeeze(1).tolist() == [1] and clone.nonzero().squeeze(1).tolist() == [3]
    # STRinGS' own settings are all there (a STRinGS method, not AbsGS)
    assert method.st.t1 == 3000 and method.st.text_densify


def test_strings_absgrad_accumulates_the_absolute_gradient_in_phase_1_by_hand():
    """Phase 1 (text Gaussians, masked L1, positions locked): the strategy's absolute-gradient sum equals, Gaussian
    by Gaussian, the NDC norm of the rasterizer's absgrad summed over the steps it was visible, done here by hand."""
    from strings_bench.bench.check import tiny_scene
    from strings_bench.scene.scene import Scene

    method = _build("strings-absgrad", t1=20, sh_degree=0)  # steps_scale 1: no densification before step 500
    method.progress = False
    torch.manual_seed(0)
    method.setup(Scene.load(tiny_scene()), device="cpu", seed=0)
    n = len(method.model)
    abs_sum = np.zeros(n)
    grad_sum = np.zeros(n)
    count = np.zeros(n)
    for step in range(1, 8):
        method.train_step(step)
        assert method.in_phase1(step)
        _, _, info = method._step_info
        w, h = info["width"], info["height"]
        visible = np.asarray(info["radii"]) > 0
        for stat, g in ((abs_sum, info["raster"].absgrad), (grad_sum, info["means2d"].grad)):
            g = g.detach().numpy().astype(np.float64)
            stat[visible] += np.hypot(g[visible, 0] * w / 2, g[visible, 1] * h / 2)
        count[visible] += 1
        method.refine(step)
    state = method.strategy_state
    assert count.sum() > 0 and abs_sum.max() > 0
    np.testing.assert_allclose(state["count"].numpy(), count)
    np.testing.assert_allclose(state["grad2d_abs"].numpy(), abs_sum, rtol=1e-5, atol=1e-12)
    np.testing.assert_allclose(state["grad2d"].numpy(), grad_sum, rtol=1e-5, atol=1e-12)
    # the absolute gradient is never below the ordinary one (a sum of norms >= the norm of the sum), and on text
    # strokes, where per-pixel gradients cancel, clearly above it
    assert (abs_sum >= grad_sum * (1 - 1e-5) - 1e-12).all()
    assert abs_sum.sum() > 1.5 * grad_sum.sum()


@pytest.mark.parametrize("name", ["strings", "strings-absgrad"])
def test_both_phases_run_with_their_criterion(name):
    """A few steps across T1: phase 2 starts, and each method keeps its criterion after the switch."""
    from strings_bench.bench.check import tiny_scene
    from strings_bench.scene.scene import Scene

    method = _build(name, t1=3, sh_degree=0)
    method.progress = False
    method.setup(Scene.load(tiny_scene()), device="cpu", seed=0)
    for step in range(1, 6):
        method.train_step(step)
        method.refine(step)
    assert method.phase == 2
    assert ("grad2d_abs" in method.strategy_state) == (name == "strings-absgrad")
