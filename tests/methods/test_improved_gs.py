"""Improved-GS (engine/strategies/improved.py, methods/improved_gs.py): each rule against an
independent computation (per-pixel loops, scipy rotations, torch.optim.Adam), then a short training."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

import _engine_helpers as eh
from strings_bench.engine.gaussians import GaussianModel
from strings_bench.engine.optim import ADAM_EPS, GaussianAdam
from strings_bench.engine.strategies.contrib import blend_weight_sums
from strings_bench.engine.strategies.improved import (ImprovedGSStrategy, edge_map, growth_budget,
                                                      improved_long_axis_split_params, normalise_by_positive_mean)
from strings_bench.methods.improved_gs import MultiStepAdam
from strings_bench.scene.camera import Camera

W, H, F = 40, 30, 40.0


def camera() -> Camera:
    return Camera(fx=F, fy=F, cx=W / 2, cy=H / 2, width=W, height=H, R=np.eye(3), t=np.zeros(3))


def isotropic_model(xyz, scale, opacity) -> GaussianModel:
    model = GaussianModel.from_points(np.asarray(xyz, dtype=np.float64), np.full((len(xyz), 3), 128, np.uint8),
                                      sh_degree=0)
    with torch.no_grad():
        model.params["log_scales"].fill_(math.log(scale))
        model.params["opacity_logits"].copy_(torch.logit(torch.as_tensor(opacity, dtype=torch.float32)))
    return model


def blend_sums_by_loop(xyz, scale, opacity, weights) -> np.ndarray:
    """sum_p w(p) alpha_i T_i per Gaussian with an explicit loop over pixels and depth-sorted Gaussians:
    isotropic 3D Gaussians seen by a camera at the origin looking down +z (R = I), 2D covariance
    J (s^2 I) J^T + 0.3 I, alpha = min(0.99, o exp(-d^T S^-1 d / 2)), skipped below 1/255, stop when
    T (1 - alpha) < 1e-4; pixel centres at integer + 0.5."""
    xyz = np.asarray(xyz, dtype=np.float64)
    covs, centres = [], []
    for x, y, z in xyz:
        J = np.array([[F / z, 0, -F * x / z ** 2], [0, F / z, -F * y / z ** 2]])
        covs.append(scale ** 2 * J @ J.T + 0.3 * np.eye(2))
        centres.append([F * x / z + W / 2, F * y / z + H / 2])
    order = np.argsort(xyz[:, 2])
    out = np.zeros(len(xyz))
    for py in range(H):
        for px in range(W):
            T = 1.0
            for i in order:
                d = np.array([px + 0.5, py + 0.5]) - centres[i]
                alpha = min(0.99, opacity[i] * math.exp(-0.5 * d @ np.linalg.inv(covs[i]) @ d))
                if alpha < 1 / 255:
                    continue
                if T * (1 - alpha) < 1e-4:
                    break
                out[i] += weights[py, px] * alpha * T
                T *= 1 - alpha
    return out


@pytest.mark.parametrize("backend", ["cpu-f64", "cpu"])
def test_blend_weight_sums_match_a_per_pixel_loop(backend):
    # two overlapping Gaussians at different depths (the back one is partly hidden) and one off-image
    xyz = [[0.05, 0.02, 2.0], [-0.03, 0.0, 3.0], [5.0, 0.0, 2.0]]
    opacity = [0.3, 0.25, 0.3]  # o e^{-4.5} < 1/255: every drawn pixel lies within the 3-sigma tile radius
    weights = np.random.default_rng(0).uniform(0, 1, (H, W))
    model = isotropic_model(xyz, 0.1, opacity)
    got = blend_weight_sums(model, camera(), torch.tensor(weights, dtype=torch.float32), backend=backend).double()
    expected = blend_sums_by_loop(xyz, 0.1, opacity, weights)
    assert expected[0] > 1 and expected[1] > 1 and expected[2] == 0
    np.testing.assert_allclose(got.numpy(), expected, rtol=2e-4 if backend == "cpu" else 1e-6, atol=1e-6)
    # unweighted: the sum of the per-Gaussian sums is the rendered alpha summed over the image
    plain = blend_weight_sums(model, camera(), backend=backend)
    alpha = model.render(camera(), backend=backend).alpha.detach().sum()
    assert float(plain.sum()) == pytest.approx(float(alpha), rel=1e-4)


def test_edge_map_matches_a_loop_laplacian():
    rng = np.random.default_rng(1)
    img = rng.uniform(0, 1, (9, 11, 3)).astype(np.float32)
    rgb8 = (img * 255).astype(np.int64)  # truncation, as torchvision's ToPILImage
    # PIL's "L" conversion: L = (19595 R + 38470 G + 7471 B + 0x8000) >> 16 (ITU-R 601-2 in fixed point)
    grey = (19595 * rgb8[..., 0] + 38470 * rgb8[..., 1] + 7471 * rgb8[..., 2] + 0x8000) >> 16
    edges = grey.astype(np.float64).copy()  # PIL's 3x3 filters copy the border pixels
    for y in range(1, 8):
        for x in range(1, 10):
            value = 8 * grey[y, x] - (grey[y - 1:y + 2, x - 1:x + 2].sum() - grey[y, x])
            edges[y, x] = min(255, max(0, value))
    edges /= 255.0
    expected = (edges - edges.min()) / (edges.max() - edges.min())
    np.testing.assert_allclose(edge_map(img).numpy(), expected, atol=1e-6)
    # a flat image: no edges inside, but the copied border (the grey level) is the maximum (the release's quirk)
    flat = edge_map(np.full((4, 5, 3), 0.5, np.float32))
    assert torch.all(flat[1:-1, 1:-1] == 0) and torch.all(flat[0] == 1) and torch.all(flat[:, 0] == 1)
    assert torch.equal(edge_map(np.zeros((4, 5, 3), np.float32)), torch.zeros(4, 5))  # max = min: zeros


def test_normalise_by_positive_mean():
    values = torch.tensor([0.0, 2.0, 4.0, 0.0, 6.0, float("nan")])
    np.testing.assert_allclose(normalise_by_positive_mean(values).numpy(), [0, 0.5, 1.0, 0, 1.5, 0])


def test_long_axis_split_geometry():
    q = Rotation.from_euler("zyx", [0.4, 0.9, -0.6]).as_quat()  # xyzw
    scales = np.array([0.3, 0.05, 0.1])  # the longest local axis is x
    params = {
        "means": torch.tensor([[1.0, -2.0, 0.5]], dtype=torch.float64),
        "quats": torch.tensor(np.array([q[3], q[0], q[1], q[2]])[None] * 3.0, dtype=torch.float64),
        "log_scales": torch.tensor(np.log(scales)[None], dtype=torch.float64),
        "opacity_logits": torch.tensor([math.log(0.8 / 0.2)], dtype=torch.float64),
        "sh0": torch.full((1, 1, 3), 0.7, dtype=torch.float64),
        "shN": torch.zeros(1, 3, 3, dtype=torch.float64),
    }
    new = improved_long_axis_split_params(params, torch.tensor([0]), split_distance=0.45, opacity_reduction=0.6)
    axis = Rotation.from_quat(q).as_matrix()[:, 0]
    mean = np.array([1.0, -2.0, 0.5])
    np.testing.assert_allclose(new["means"][0].numpy(), mean + 3 * 0.45 * 0.3 * axis, atol=1e-12)
    np.testing.assert_allclose(new["means"][1].numpy(), mean - 3 * 0.45 * 0.3 * axis, atol=1e-12)
    shrink = math.sqrt(1 - 0.45 ** 2)
    for c in range(2):
        np.testing.assert_allclose(np.exp(new["log_scales"][c].numpy()), [0.3 * 0.55, 0.05 * shrink, 0.1 * shrink],
                                   rtol=1e-12)
        assert torch.sigmoid(new["opacity_logits"][c]).item() == pytest.approx(0.48, rel=1e-12)
        assert torch.equal(new["quats"][c], params["quats"][0]) and torch.equal(new["sh0"][c], params["sh0"][0])


def test_growth_budget_is_the_square_root_ramp():
    assert growth_budget(500, 500, 14_500, 1000) == 0
    assert growth_budget(500 + 14_000 // 4, 500, 14_500, 1000) == 500  # sqrt(1/4)
    assert growth_budget(500 + 14_000 * 9 // 16 - 0, 500, 14_500, 1000) == 750
    assert growth_budget(14_500, 500, 14_500, 1000) == 1000
    assert growth_budget(14_900, 500, 14_500, 1000) == 1000


def test_final_budget_sources():
    from strings_bench.engine.strategies import StrategyContext

    state = {"n_initial": 30}
    assert ImprovedGSStrategy().final_budget(state) == 300  # budget_multiple 10 x initial
    assert ImprovedGSStrategy(budget=120).final_budget(state) == 120  # the release's per-scene --budget
    assert ImprovedGSStrategy(budget=120, context=StrategyContext(budget=50)).final_budget(state) == 50  # the cap wins
    with pytest.raises(Exception, match="gaussian_budget"):
        ImprovedGSStrategy(context=StrategyContext(budget=0))


def test_selection_draws_scored_candidates_in_proportion():
    score = torch.tensor([0.0, 1.0, 3.0, 2.0, 5.0])
    candidates = torch.tensor([True, True, True, True, False])
    # more than available: every candidate with a positive score, never a non-candidate or a zero score
    assert ImprovedGSStrategy.select(score, candidates, 10).tolist() == [False, True, True, True, False]
    assert not ImprovedGSStrategy.select(score, candidates, 0).any()
    torch.manual_seed(0)
    counts = np.zeros(5)
    for _ in range(3000):
        counts += ImprovedGSStrategy.select(score, candidates, 1).numpy()
    np.testing.assert_allclose(counts[1:4] / 3000, [1 / 6, 3 / 6, 2 / 6], atol=0.03)


def _attached(strategy, model, weights=None):
    cam = camera()
    strategy.attach_views({0: cam, 1: cam}, {0: torch.ones(H, W) if weights is None else weights,
                                             1: torch.ones(H, W) if weights is None else weights}, backend="cpu")
    return strategy


def _grid_model(n=20, opacity=0.5):
    xs = np.linspace(-0.5, 0.5, n)
    xyz = np.stack([xs, 0.1 * np.sin(7 * xs), 2.0 + 0.2 * np.cos(5 * xs)], 1)
    model = isotropic_model(xyz, 0.05, [opacity] * n)
    return model, GaussianAdam(model.params, {k: 1e-3 for k in model.params})


def test_round_splits_up_to_the_budget_and_the_runs_budget():
    from strings_bench.engine.strategies import StrategyContext

    model, opt = _grid_model()
    strategy = _attached(ImprovedGSStrategy(context=StrategyContext(budget=26)), model)
    state = strategy.initialize_state(1.0)
    state["n_initial"] = 20
    state.update(grad2d_abs=torch.full((20,), 1e-3), count=torch.ones(20))
    strategy.densify(model, opt, state, step=14_500)  # the ramp is over: budget = the run's budget = 26
    assert len(model) == 26 and state["n_split"] == 6
    # halfway through the ramp's square root: budget int(sqrt(0.25) x 26) = 13 < N: nothing grows
    model, opt = _grid_model()
    strategy = _attached(ImprovedGSStrategy(context=StrategyContext(budget=26)), model)
    state = strategy.initialize_state(1.0)
    state["n_initial"] = 20
    state.update(grad2d_abs=torch.full((20,), 1e-3), count=torch.ones(20))
    strategy.densify(model, opt, state, step=500 + 14_000 // 4)
    assert len(model) == 20 and state["last_budget"] == 13
    # below the threshold nothing is a candidate, whatever the budget
    model, opt = _grid_model()
    strategy = _attached(ImprovedGSStrategy(budget=100), model)
    state = strategy.initialize_state(1.0)
    state["n_initial"] = 20
    state.update(grad2d_abs=torch.full((20,), 2.9e-4), count=torch.ones(20))
    strategy.densify(model, opt, state, step=14_000)
    assert len(model) == 20
    # ... but after 14 500, below the budget, the threshold is / 1.5 and the score is the gradient
    state.update(grad2d_abs=torch.full((20,), 2.9e-4), count=torch.ones(20))
    strategy._views = None  # the late rounds render nothing
    strategy.densify(model, opt, state, step=14_600)
    assert len(model) == 40


def test_edge_score_only_counts_weighted_pixels():
    model, opt = _grid_model(n=6)
    left = torch.zeros(H, W)
    left[:, : W // 2] = 1.0  # edges only on the left half of the image
    strategy = _attached(ImprovedGSStrategy(), model, left)
    score = strategy.edge_score(model, [0, 1])
    xs = model.means[:, 0].detach()
    assert torch.all(score[xs < -0.2] > 0) and torch.all(score[xs > 0.2] == 0)
    # per view: the positive sums divided by their mean, then averaged over the views
    sums = blend_weight_sums(model, camera(), left, backend="cpu")
    np.testing.assert_allclose(score.numpy(), (sums / sums[sums > 0].mean()).clamp_min(0).numpy() * (sums > 0).numpy(),
                               rtol=1e-5)


def test_schedule_early_prune_reset_and_recovery_pruning():
    model, opt = _grid_model(n=10)
    with torch.no_grad():
        model.params["opacity_logits"].copy_(torch.logit(torch.linspace(0.011, 0.9, 10)))
    strategy = _attached(ImprovedGSStrategy(budget=10), model)
    state = strategy.initialize_state(1.0)
    info = lambda: {"means2d": torch.zeros(len(model), 2), "radii": torch.zeros(len(model)), "width": W,  # noqa: E731
                    "height": H, "raster": None}
    strategy.step_post_backward(model, opt, state, 299, info())
    assert len(model) == 10
    strategy.step_post_backward(model, opt, state, 300, info())  # one-off: opacity < 0.02 goes
    assert len(model) == 9
    strategy.step_post_backward(model, opt, state, 3_000, info())  # reset to min(o, 0.05)
    assert float(model.opacities.detach().max()) == pytest.approx(0.05, rel=1e-5)
    with torch.no_grad():
        model.params["opacity_logits"].copy_(torch.logit(torch.linspace(0.01, 0.05, len(model))))
    strategy.step_post_backward(model, opt, state, 3_299, info())
    assert len(model) == 9
    opacities = model.opacities.detach().numpy().copy()
    strategy.step_post_backward(model, opt, state, 3_300, info())  # the 20 % least opaque go
    expected = np.sort(opacities[opacities >= np.quantile(opacities.astype(np.float64), 0.2)])
    np.testing.assert_allclose(np.sort(model.opacities.detach().numpy()), expected, rtol=1e-6)
    assert len(model) == 7
    strategy.step_post_backward(model, opt, state, 9_300, info())  # none after 9 000
    assert len(model) == 7


def test_recovery_window_in_scaled_schedules():
    from strings_bench.engine.strategies import StrategyContext

    assert ImprovedGSStrategy(context=StrategyContext(steps_scale=1.0)).recovery_step() == 300
    assert ImprovedGSStrategy(context=StrategyContext(steps_scale=0.05)).recovery_step() == 100


def test_multi_step_adam_takes_one_step_on_the_summed_gradients():
    torch.manual_seed(3)
    start = torch.randn(4, 3)
    grads = [torch.randn(4, 3) for _ in range(5)]
    it = {"i": 0}
    param = torch.nn.Parameter(start.clone())
    opt = MultiStepAdam({"means": param}, {"means": 0.01}, lambda: (it["i"], 5))
    reference = torch.nn.Parameter(start.clone())
    torch_adam = torch.optim.Adam([reference], lr=0.01, eps=ADAM_EPS)
    for i, g in enumerate(grads, start=16):  # iterations 16..20: the step comes at 20
        it["i"] = i
        param.grad = g.clone()
        opt.step()
        param.grad = None
        if i < 20:
            assert torch.equal(param.detach(), start)
    reference.grad = torch.stack(grads).sum(0)
    torch_adam.step()
    np.testing.assert_allclose(param.detach().numpy(), reference.detach().numpy(), rtol=1e-6, atol=1e-7)
    # the pending sum survives a save and load
    it["i"] = 21
    param.grad = grads[0].clone()
    opt.step()
    state = opt.state_dict()
    other = MultiStepAdam({"means": param}, {"means": 0.01}, lambda: (it["i"], 5))
    other.load_state_dict(state)
    assert torch.equal(other.pending["means"], grads[0])


def test_improved_gs_trains_within_its_budget(tmp_path):
    from strings_bench.methods.registry import get_method

    scene = eh.make_tiny_scene(tmp_path / "scene")
    # scale 0.01: densification in (5, 150), the budget ramp ends at 145, multi-step updates after 150;
    # a low threshold so that the 32x24 views' small gradients select candidates
    method = get_method("improved-gs").build(None, steps_scale=0.01, sh_degree=0, refine_every=1, score_views=2,
                                             grow_grad2d_abs=1e-6, gaussian_budget=200)
    results = eh.train(method, scene, [100, 160])
    state = method.strategy_state
    assert state["n_refine"] > 0 and state["n_split"] > 0  # it densified ...
    assert max(r.gaussians for r in results) <= 200 and len(method.model) <= 200  # ... never past the cap
    assert state["last_budget"] == 200
    for r in results:
        for img in r.renders.values():
            assert np.isfinite(img).all()
