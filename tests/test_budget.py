"""The equal Gaussian budget (issue 42): `Strategy.max_gaussians`, honoured by every trainable method at every step.

The selection under a budget is checked against by-hand references (plain sorting of constructed statistics); the
per-step test trains every registered trainable method a few dozen steps with densification made aggressive, so
that the cap binds, and fails as soon as one holds more Gaussians than the cap after any step.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from strings_bench.core.errors import StringsBenchError
from strings_bench.engine.strategies.base import keep_within_budget


# ---- keep_within_budget against brute force --------------------------------------------------------------------
def _by_hand(candidates, scores, cost, room):
    order = sorted((i for i, c in enumerate(candidates) if c), key=lambda i: (-scores[i], i))
    kept, used = set(), 0
    for i in order:
        if used + cost[i] > room:
            break
        kept.add(i)
        used += cost[i]
    return [i in kept for i in range(len(candidates))]


@pytest.mark.parametrize("seed", range(6))
def test_keep_within_budget_matches_a_by_hand_greedy(seed):
    rng = np.random.default_rng(seed)
    n = 40
    cand = rng.random(n) < 0.6
    scores = np.round(rng.random(n), 1)  # ties on purpose: the lower index first
    cost = rng.integers(1, 3, n)
    room = int(rng.integers(0, 30))
    got = keep_within_budget(torch.from_numpy(cand), torch.from_numpy(scores), torch.from_numpy(cost), room)
    assert got.tolist() == _by_hand(cand.tolist(), scores.tolist(), cost.tolist(), room)
    assert int((torch.from_numpy(cost) * got).sum()) <= room


def test_keep_within_budget_without_budget_or_with_room_keeps_every_candidate():
    cand = torch.tensor([True, False, True])
    assert keep_within_budget(cand, torch.zeros(3), 1, None).tolist() == [True, False, True]
    assert keep_within_budget(cand, torch.zeros(3), 1, 2).tolist() == [True, False, True]
    assert keep_within_budget(cand, torch.zeros(3), 1, 0).tolist() == [False, False, False]


def test_budget_must_be_a_positive_count():
    from strings_bench.engine.strategies import DefaultStrategy

    for bad in (0, -5, 2.5):
        with pytest.raises(StringsBenchError, match="max_gaussians must be a positive"):
            DefaultStrategy(max_gaussians=bad)


# ---- each strategy's selection under a budget, on constructed statistics ----------------------------------------
def _model(n, big=()):
    from strings_bench.engine.gaussians import GaussianModel

    rng = np.random.default_rng(0)
    model = GaussianModel.from_points(rng.normal(size=(n, 3)), np.full((n, 3), 128, np.uint8), sh_degree=0)
    with torch.no_grad():
        model.params["log_scales"].fill_(math.log(0.001))
        for i in big:
            model.params["log_scales"][i] = math.log(0.5)  # > grow_scale3d x extent (0.01 x 1): a split
    return model


def test_default_strategy_grows_the_largest_mean_gradients_first():
    from strings_bench.engine.strategies import DefaultStrategy

    n = 10
    model = _model(n, big=(1, 6))
    strategy = DefaultStrategy(max_gaussians=n + 3)
    state = strategy.initialize_state(scene_extent=1.0)
    grad = [5, 9, 1, 8, 0.5, 7, 6, 0.1, 4, 3]  # x 1e-4; threshold 2e-4 -> candidates 0,1,3,5,6,8,9
    state.update(grad2d=torch.tensor(grad) * 1e-4 * 2, count=torch.full((n,), 2.0), max_radii=torch.ones(n))
    clone, split = strategy._fit_budget(model, state, 600, *strategy._select(model, state, 600))
    # by hand: candidates by decreasing mean gradient: 1 (split), 3, 5, 6 (split), ...; room 3, each costs 1
    assert clone.nonzero().squeeze(1).tolist() == [3, 5] and split.nonzero().squeeze(1).tolist() == [1]
    assert state["budget_dropped"] == 7 - 3


def test_absgs_ranks_clones_and_splits_by_their_statistic_over_its_threshold():
    from strings_bench.engine.strategies.absgs import AbsGSStrategy

    n = 6
    model = _model(n, big=(0, 1, 2))
    strategy = AbsGSStrategy(max_gaussians=n + 2)
    state = strategy.initialize_state(scene_extent=1.0)
    # large (0-2) split on |grad| >= 4e-4; small (3-5) clone on grad >= 2e-4
    grad = torch.tensor([0, 0, 0, 3e-4, 5e-4, 2.2e-4])
    absgrad = torch.tensor([9e-4, 5e-4, 4.4e-4, 0, 0, 0])
    state.update(grad2d=grad, grad2d_abs=absgrad, count=torch.ones(n), max_radii=torch.ones(n))
    clone, split = strategy._fit_budget(model, state, 600, *strategy._select(model, state, 600))
    # over threshold: 0: 2.25, 1: 1.25, 2: 1.1, 3: 1.5, 4: 2.5, 5: 1.1 -> the two best: 4 (clone), 0 (split)
    assert clone.nonzero().squeeze(1).tolist() == [4] and split.nonzero().squeeze(1).tolist() == [0]


@pytest.mark.parametrize("release", [False, True])
def test_edc_ranks_by_the_absolute_gradient_it_selects_on(release):
    from strings_bench.engine.strategies.edc import EDCStrategy

    n = 5
    model = _model(n)
    strategy = EDCStrategy(max_gaussians=n + 2, release_schedule=release)
    state = strategy.initialize_state(scene_extent=1.0)
    count = torch.tensor([1.0, 100, 1, 1, 1])
    absgrad = torch.tensor([9e-4, 5e-4, 8e-4, 4e-4, 2e-4]) * count
    state.update(grad2d=torch.zeros(n), grad2d_abs=absgrad, count=count, max_radii=torch.ones(n))
    clone, split = strategy._fit_budget(model, state, 20_000, *strategy._select(model, state, 20_000))
    assert not clone.any()
    # mean |grad|: 9, 5, 8, 4, 2 (e-4); the release multiplies the 100-view one by 1.3 -> 6.5 (still below 8)
    assert split.nonzero().squeeze(1).tolist() == [0, 2]
    strategy.grow_grad2d_abs = 1e-5
    clone, split = strategy._fit_budget(model, state, 20_000, *strategy._select(model, state, 20_000))
    assert split.nonzero().squeeze(1).tolist() == [0, 2]


def test_mcmc_takes_the_budget_as_its_cap():
    from strings_bench.engine.strategies.mcmc import MCMCStrategy

    assert MCMCStrategy(max_gaussians=1234, cap_max=99).initialize_state(1.0)["cap"] == 1234
    assert MCMCStrategy(cap_max=99).initialize_state(1.0)["cap"] == 99


def test_eq1_under_a_budget_densifies_the_least_observed_points_first():
    from strings_bench.methods.strings.densify import fit_factors_to_budget

    k = np.array([3, 15, 1, 8, 15, 2])
    # 6 Gaussians, budget 25 -> 19 children to spare: 15 (index 1, +14) then 15 (index 4, +14) does not fit: stop
    assert fit_factors_to_budget(k, 25).tolist() == [1, 15, 1, 1, 1, 1]
    assert fit_factors_to_budget(k, 34).tolist() == [1, 15, 1, 1, 15, 1]
    assert fit_factors_to_budget(k, 1000).tolist() == k.tolist()
    assert fit_factors_to_budget(k, None).tolist() == k.tolist()


# ---- every trainable method, every step -------------------------------------------------------------------------
# Settings that make densification aggressive in a few dozen steps at steps_scale 1 (each applied where the method
# has the key). A new method whose growth these keys do not reach must add its own: the test also checks that the
# cap was reached, so a method that never grows cannot pass unnoticed.
DENSIFY_FAST = {
    "steps_scale": 1.0, "refine_start_iter": 2, "refine_every": 5, "grow_grad2d": 1e-9, "grow_grad2d_abs": 1e-9,
    "grow_rate": 0.5, "t1": 15, "sh_degree": 0,
}
STEPS = 40
CAP = 1800  # the check scene has 1429 SfM points (340 text points, 1089 non-text)


def _trainable():
    from strings_bench.core.method import Method
    from strings_bench.methods.registry import list_methods

    return [s.name for s in list_methods() if isinstance(s.load(), type) and issubclass(s.load(), Method)]


def _train_capped(name, cap, steps=STEPS):
    from strings_bench.bench.check import tiny_scene
    from strings_bench.methods.registry import get_method
    from strings_bench.scene.scene import Scene

    spec = get_method(name)
    keys = {s.name for s in spec.settings()}
    settings = {k: v for k, v in DENSIFY_FAST.items() if k in keys}
    method = spec.build(max_gaussians=cap, **settings)
    method.progress = False
    torch.manual_seed(0)
    method.setup(Scene.load(tiny_scene()), device="cpu", seed=0)
    counts = [method.num_gaussians()]
    for step in range(1, steps + 1):
        method.train_step(step)
        counts.append(method.num_gaussians())
        method.refine(step)
        counts.append(method.num_gaussians())
    return method, counts


SLOW_METHODS = {"strings-no-densify", "strings-pos-lr"}  # STRinGS' ablations: the same growth code as strings


@pytest.mark.parametrize("name", [pytest.param(n, marks=pytest.mark.slow) if n in SLOW_METHODS else n
                                  for n in _trainable()])
def test_no_method_exceeds_the_budget_at_any_step(name):
    method, counts = _train_capped(name, CAP)
    over = [(i // 2, c) for i, c in enumerate(counts) if c > CAP]
    assert not over, f"{name} exceeded the budget of {CAP} Gaussians at (step, count) {over[:5]}"
    assert max(counts) >= 0.95 * CAP, (f"{name} never came near the cap ({max(counts)} < 0.95 x {CAP}): "
                                       "add the settings that make it densify fast to DENSIFY_FAST")


def test_strings_keeps_room_for_the_non_text_points_in_phase_1():
    method, counts = _train_capped("strings", CAP, steps=16)
    n_non_text = int((~method.segmentation.is_text).sum())
    phase1 = counts[:2 * 15 + 1]
    assert max(phase1) <= CAP - n_non_text
    assert method.densify_stats["text_densify_budget"] == CAP - n_non_text
    assert method.phase == 2 and counts[-1] <= CAP


def test_a_budget_below_the_initial_model_is_a_clear_error():
    with pytest.raises(StringsBenchError, match="cannot remove initial Gaussians"):
        _train_capped("3dgs", 1000, steps=1)
    with pytest.raises(StringsBenchError, match="and 1089 it adds later"):
        _train_capped("strings", 1200, steps=1)  # 340 text points + 1089 non-text > 1200
