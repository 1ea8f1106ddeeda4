"""Perceptual-GS (engine/strategies/perceptual.py, methods/perceptual_gs.py): each rule against an
independent computation (loops, the float64 reference rasterizer, torch.optim.Adam), then a short training."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

import _engine_helpers as eh
from strings_bench.engine.gaussians import GaussianModel
from strings_bench.engine.optim import ADAM_EPS, GaussianAdam
from strings_bench.engine.strategies.contrib import blend_weight_sums
from strings_bench.engine.strategies.perceptual import (SENSITIVITY_KEY, PerceptualGSStrategy, opacity_decline,
                                                        sensitivity_map)
from strings_bench.raster.reference import rasterize_reference
from strings_bench.raster.sh import SH_C0
from strings_bench.scene.camera import Camera

W, H, F = 40, 30, 40.0


def camera(tx: float = 0.0) -> Camera:
    return Camera(fx=F, fy=F, cx=W / 2, cy=H / 2, width=W, height=H, R=np.eye(3), t=np.array([tx, 0.0, 0.0]))


def sensitivity_by_loop(img: np.ndarray, gamma=1.5, te=0.05, ts=0.3, pool=5) -> np.ndarray:
    h, w = img.shape[:2]
    rgb8 = np.round(img * 255).astype(np.int64)
    grey = (19595 * rgb8[..., 0] + 38470 * rgb8[..., 1] + 7471 * rgb8[..., 2] + 0x8000) >> 16  # PIL "L"
    lut = np.floor(255 * (np.arange(256) / 255) ** (1 / gamma) + 0.5)  # PIL's point table, rounded
    x = np.pad(lut[grey] / 255.0, 1)  # zero padding
    kx = np.array([[-1, 0, 1], [-2, 0, 2], [-1, 0, 1]], dtype=np.float64)
    edge = np.zeros((h, w))
    for y in range(h):
        for xx in range(w):
            patch = x[y:y + 3, xx:xx + 3]
            edge[y, xx] = math.hypot((patch * kx).sum(), (patch * kx.T).sum()) > te
    hp, wp = h // pool, w // pool
    pooled = np.array([[edge[i * pool:(i + 1) * pool, j * pool:(j + 1) * pool].mean() for j in range(wp)]
                       for i in range(hp)])
    up = np.array([[pooled[(y * hp) // h, (xx * wp) // w] for xx in range(w)] for y in range(h)])
    return (up > ts).astype(np.float32)


def test_sensitivity_map_matches_a_loop():
    rng = np.random.default_rng(2)
    img = np.zeros((17, 23, 3), np.float32)
    img[:, :9] = rng.uniform(0, 1, (17, 9, 3))  # texture on the left, flat elsewhere
    img[:, 9:] = 0.4
    img[12:, 15:] = 0.9  # one step edge
    got = sensitivity_map(img).numpy()
    np.testing.assert_array_equal(got, sensitivity_by_loop(img))
    assert got[:, :5].all() and not got[:10, 12:].any()  # textured: sensitive; flat: not


def test_opacity_decline_formula():
    o = torch.tensor([0.5, 0.9, 0.01])
    of = o.double() ** 1.2
    np.testing.assert_allclose(opacity_decline(o).double().numpy(), (of / (1 + torch.sqrt(1 - of))).numpy(), rtol=1e-6)
    assert opacity_decline(torch.tensor([0.5])).item() == pytest.approx(0.5 ** 1.2 / (1 + math.sqrt(1 - 0.5 ** 1.2)))
    assert torch.all(opacity_decline(o) < o)


def model_at(xyz, scale=0.05, opacity=0.5, sens=0.1) -> GaussianModel:
    xyz = np.asarray(xyz, dtype=np.float64)
    model = GaussianModel.from_points(xyz, np.full((len(xyz), 3), 128, np.uint8), sh_degree=0)
    with torch.no_grad():
        model.params["log_scales"].copy_(torch.log(torch.as_tensor(scale, dtype=torch.float32)).reshape(-1, 1)
                                         .expand(len(xyz), 3))
        model.params["opacity_logits"].fill_(math.log(opacity / (1 - opacity)))
    s = torch.as_tensor(sens, dtype=torch.float32).expand(len(xyz)).clone()
    model.extras[SENSITIVITY_KEY] = torch.logit(s)
    return model


def attached(strategy, maps=None, cams=None):
    cams = cams or {0: camera(), 1: camera(0.2)}
    maps = maps or {v: torch.ones(H, W) for v in cams}
    strategy.attach_views(cams, maps, background=(0.0, 0.0, 0.0), backend="cpu")
    return strategy


def test_bce_term_against_the_reference_rasterizer_and_its_adam_step():
    xyz = [[0.1, 0.0, 2.0], [-0.2, 0.05, 2.5], [0.0, -0.1, 3.0]]
    sens = torch.tensor([0.2, 0.6, 0.9])
    model = model_at(xyz, 0.08, 0.6, sens)
    target = torch.zeros(H, W)
    target[:, : W // 2] = 1.0
    strategy = attached(PerceptualGSStrategy(), {0: target, 1: target})
    state = strategy.initialize_state(1.0)
    info = {"camera": camera(), "view_idx": 0}
    term = strategy.loss_terms(model, info, step=10)
    # by hand: render (1 - s) with the float64 reference rasterizer, p = 1 - red, BCE averaged over pixels
    p = {k: v.detach().double() for k, v in model.params.items()}
    dc = ((1 - sens.double() - 0.5) / SH_C0)[:, None, None].expand(-1, 1, 3)
    red = rasterize_reference(p["means"], p["quats"], p["log_scales"], p["opacity_logits"], dc, camera(),
                              torch.zeros(3, dtype=torch.float64))["color"][..., 0]
    pred = 1 - red
    t = target.double()
    # torch's BCE (the release's nn.BCELoss) clamps each log at -100: empty pixels (pred 1) with target 0 cost 100
    bce = -(t * torch.log(pred).clamp_min(-100) + (1 - t) * torch.log(1 - pred).clamp_min(-100)).mean()
    assert float(term.detach()) == pytest.approx(0.1 * float(bce), rel=1e-4)
    # the gradient of the term reaches the geometry (one loss, as the release) and the sensitivity leaf
    term.backward()
    assert model.params["means"].grad is not None and model.params["means"].grad.abs().sum() > 0
    leaf_grad = strategy._leaf[1].grad.clone()
    before = model.extras[SENSITIVITY_KEY].clone()
    reference = torch.nn.Parameter(before.clone())
    adam = torch.optim.Adam([reference], lr=0.05, eps=ADAM_EPS)
    reference.grad = leaf_grad
    adam.step()
    strategy._sensitivity_adam_step(model, state)
    np.testing.assert_allclose(model.extras[SENSITIVITY_KEY].numpy(), reference.detach().numpy(), rtol=1e-6)
    assert state["sens_step"] == 1
    # after sensitivity_until (15 000) the term is off and the 3DGS loss has its full weight
    assert strategy.loss_terms(model, info, step=15_001) == 0.0
    assert strategy.rgb_weight(15_000) == pytest.approx(0.9) and strategy.rgb_weight(15_001) == 1.0


def test_trans_is_the_largest_blend_weight_sum_over_views():
    model = model_at([[0.1, 0.0, 2.0], [0.5, 0.0, 2.0], [-0.4, 0.1, 2.2]], 0.05, 0.5)
    cams = {0: camera(), 1: camera(0.4)}
    strategy = attached(PerceptualGSStrategy(), cams=cams)
    state = strategy.initialize_state(1.0)
    strategy.update_trans(model, state)
    per_view = torch.stack([blend_weight_sums(model, c, backend="cpu") for c in cams.values()])
    np.testing.assert_allclose(state["trans"].numpy(), per_view.max(0).values.numpy(), rtol=1e-6)
    assert not torch.allclose(per_view[0], per_view[1])  # the views differ: the max picks per Gaussian


def _selection_case(split_only=False):
    # sensitivities: high, high, mixed, mixed, low, high (small ones 0-4; 5 large)
    sens = torch.tensor([0.95, 0.95, 0.5, 0.5, 0.1, 0.95])
    model = model_at([[0.1 * i, 0.0, 2.0] for i in range(6)], [0.005] * 5 + [0.05], 0.5, sens)
    strategy = PerceptualGSStrategy()
    state = strategy.initialize_state(1.0)  # extent 1: small <= 0.01
    state.update(grad2d=torch.zeros(6), count=torch.ones(6), max_radii=torch.zeros(6), split_only=split_only,
                 trans=torch.tensor([30.0, 20.0, 30.0, 5.0, 30.0, 30.0]))
    return model, strategy, state


def test_hd_and_md_selection_by_hand():
    model, strategy, state = _selection_case()
    clone, split = strategy._select(model, state, 3_000)  # a multiple of 1 000 and 1 500: HD and MD
    # HD: s >= 0.9 and trans > 25: 0 (small: clone) and 5 (large: split); 1 has trans 20
    # MD: 0.3 < s < 0.9 and trans > 10: 2 (split whatever its size); 3 has trans 5
    assert clone.tolist() == [True, False, False, False, False, False]
    assert split.tolist() == [False, False, True, False, False, True]
    clone, split = strategy._select(model, state, 2_000)  # HD only
    assert split.tolist() == [False, False, False, False, False, True]
    clone, split = strategy._select(model, state, 1_500)  # MD only
    assert not clone.any() and split.tolist() == [False, False, True, False, False, False]
    clone, split = strategy._select(model, state, 2_100)  # neither
    assert not clone.any() and not split.any()
    model, strategy, state = _selection_case(split_only=True)
    clone, split = strategy._select(model, state, 2_000)  # split-only scene: HD splits small ones too
    assert not clone.any() and split.tolist() == [True, False, False, False, False, True]


def test_grow_declines_cloned_opacity_and_starts_new_rows_fresh():
    model, strategy, state = _selection_case()
    opt = GaussianAdam(model.params, {k: 1e-3 for k in model.params})
    state["sens_exp_avg"] = torch.ones(6)
    state["sens_exp_avg_sq"] = torch.ones(6)
    sens_before = model.extras[SENSITIVITY_KEY].clone()
    o_before = model.opacities.detach().clone()
    clone = torch.tensor([True, False, False, False, False, False])
    split = torch.tensor([False, False, True, False, False, True])
    strategy._grow(model, opt, state, clone, split)
    # kept 0, 1, 3, 4, then the clone of 0, then 2 children each of 2 and 5
    assert len(model) == 6 - 2 + 1 + 4
    declined = opacity_decline(o_before[0:1])
    np.testing.assert_allclose(model.opacities.detach()[[0, 4]].numpy(), declined.expand(2).numpy(), rtol=1e-5)
    np.testing.assert_allclose(model.opacities.detach()[1:4].numpy(), o_before[[1, 3, 4]].numpy(), rtol=1e-6)
    np.testing.assert_array_equal(model.extras[SENSITIVITY_KEY].numpy(), sens_before[[0, 1, 3, 4, 0, 2, 2, 5, 5]].numpy())
    np.testing.assert_array_equal(state["sens_exp_avg"].numpy(), [1, 1, 1, 1, 0, 0, 0, 0, 0])
    assert state["trans"][4] == 0  # the clone is new


def test_scene_classification_by_hand():
    sens = torch.tensor([0.5, 0.5, 0.95, 0.1, 0.5, 0.5, 0.5, 0.5])
    scales = [0.2, 0.1, 0.3, 0.01, 0.01, 0.01, 0.01, 0.01]  # the 25 % largest: 2 (0.3) and 0 (0.2)
    model = model_at([[0.05 * i, 0.0, 2.0] for i in range(8)], scales, 0.5, sens)
    mostly = torch.ones(H, W)
    mostly[:2] = 0  # 93 % non-zero
    strategy = attached(PerceptualGSStrategy(), {0: mostly, 1: mostly})
    state = strategy.initialize_state(1.0)
    strategy.classify_scene(model, state)
    assert state["split_only"] and state["mix_rate"] == pytest.approx(0.5) and not state["sparse"]
    half = torch.zeros(H, W)
    half[:, :20] = 1
    strategy = attached(PerceptualGSStrategy(), {0: half, 1: half})
    model.extras[SENSITIVITY_KEY][2] = torch.logit(torch.tensor(0.6))
    state = strategy.initialize_state(1.0)
    strategy.classify_scene(model, state)
    assert not state["split_only"] and state["mix_rate"] == 1.0 and state["sparse"]


def test_perceptual_gs_trains_and_learns_sensitivity(tmp_path):
    from strings_bench.methods.registry import get_method

    scene = eh.make_tiny_scene(tmp_path / "scene")
    method = get_method("perceptual-gs").build(None, steps_scale=0.01, sh_degree=0, refine_every=1, hd_interval=20,
                                               md_interval=30, hd_md_from=20, complex_transaction=0.01,
                                               mix_transaction=0.01)  # the 32x24 views' Gaussians cover < 1 px
    results = eh.train(method, scene, [60, 120])
    state = method.strategy_state
    sens = torch.sigmoid(method.model.extras[SENSITIVITY_KEY])
    assert sens.shape == (len(method.model),) and state["sens_step"] > 0
    assert float((sens - 0.1).abs().max()) > 0.05  # learnt away from the initial 0.1
    assert state["classified"] and state["n_hd"] + state["n_md"] > 0
    for r in results:
        for img in r.renders.values():
            assert np.isfinite(img).all()
