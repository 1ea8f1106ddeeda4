"""STRinGS: text densification (Eq. 1), phases, LR factors, fallback."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from strings_bench.core.errors import StringsBenchError, TrainingError
from strings_bench.engine.gaussians import GaussianModel, quat_to_rotmat
from strings_bench.methods.strings.densify import densification_factors, densify_text_model


def eq1_reference(counts, n_max):
    """Eq. 1 written out per point in float64 (release: 1/0 -> 0)."""
    inv = [0.0 if c == 0 else 1.0 / c for c in counts]
    lo, hi = min(inv), max(inv)
    return [int(np.floor(1 + (n_max - 1) * (x - lo) / (hi - lo) + 0.5)) for x in inv]


@pytest.mark.parametrize("n_max", [2, 15, 25, 100])
def test_factors_match_formula(n_max):
    rng = np.random.default_rng(n_max)
    counts = rng.integers(1, 40, size=300)
    counts[:2] = [1, 39]
    got = densification_factors(counts, n_max)
    assert got.tolist() == eq1_reference(counts.tolist(), n_max)
    assert got.min() == 1 and got.max() == n_max
    assert got[counts.argmin()] == n_max and got[counts.argmax()] == 1


def test_factor_values_by_hand():
    # 1/c = 1, 0.5, 0.25 -> t = 1, 1/3, 0 -> 1 + 14 t = 15, 5.67, 1.
    assert densification_factors(np.array([1, 2, 4]), 15).tolist() == [15, 6, 1]


def test_zero_counts_taken_as_zero_inverse():
    # Release: 1/0 = 0, so a zero-count point is like the best-observed one.
    got = densification_factors(np.array([0, 1, 2]), 11)
    assert got.tolist() == eq1_reference([0, 1, 2], 11) == [1, 11, 6]


def test_equal_counts_and_single_point():
    assert densification_factors(np.array([3, 3, 3]), 15).tolist() == [15, 15, 15]
    assert densification_factors(np.array([3, 3]), 15, equal_counts="one").tolist() == [1, 1]
    assert densification_factors(np.array([5]), 20).tolist() == [20]
    assert densification_factors(np.array([0, 0]), 7).tolist() == [7, 7]
    assert densification_factors(np.array([], int), 7).tolist() == []
    assert densification_factors(np.array([1, 4, 9]), 1).tolist() == [1, 1, 1]
    with pytest.raises(StringsBenchError):
        densification_factors(np.array([1, 2]), 0)


def random_model(n, seed=0):
    g = torch.Generator().manual_seed(seed)
    params = {
        "means": torch.randn(n, 3, generator=g),
        "quats": torch.randn(n, 4, generator=g),
        "log_scales": torch.randn(n, 3, generator=g) * 0.5 - 2,
        "opacity_logits": torch.randn(n, generator=g),
        "sh0": torch.randn(n, 1, 3, generator=g),
        "shN": torch.randn(n, 15, 3, generator=g),
    }
    return GaussianModel(params, extras={"uid": torch.arange(n), "is_text": torch.ones(n, dtype=torch.bool)})


def snapshot(model):
    return {k: v.detach().clone() for k, v in model.params.items()}


def test_children_counts_copies_and_scales():
    model = random_model(4)
    p = snapshot(model)
    k = np.array([1, 3, 1, 5])
    densify_text_model(model, k, torch.Generator().manual_seed(1))
    uid = model.extras["uid"]
    assert len(model) == 10 and model.extras["is_text"].all()
    assert sorted(uid.tolist()) == [0, 1, 1, 1, 2, 3, 3, 3, 3, 3]
    for name in ("quats", "opacity_logits", "sh0", "shN"):
        assert torch.equal(model.params[name].detach(), p[name][uid])
    ls = model.params["log_scales"].detach()
    means = model.params["means"].detach()
    for i in range(10):
        u = int(uid[i])
        if k[u] == 1:  # unchanged
            assert torch.equal(means[i], p["means"][u]) and torch.equal(ls[i], p["log_scales"][u])
        else:  # scales / (0.8 N), new positions
            assert torch.allclose(ls[i], p["log_scales"][u] - np.log(0.8 * k[u]), atol=1e-6)
            assert not torch.equal(means[i], p["means"][u])


def test_child_positions_follow_parent_distribution():
    """Sample mean and covariance over many children match the parent Gaussian."""
    model = random_model(1, seed=3)
    with torch.no_grad():
        model.params["log_scales"].copy_(torch.log(torch.tensor([[0.5, 0.1, 0.02]])))
    R = quat_to_rotmat(model.params["quats"].detach().double())[0].numpy()
    mu = model.params["means"].detach().double()[0].numpy()
    var = np.array([0.5, 0.1, 0.02]) ** 2
    n = 20000
    densify_text_model(model, np.array([n]), torch.Generator().manual_seed(7))
    x = model.params["means"].detach().double().numpy()
    assert x.shape == (n, 3)
    cov = R @ np.diag(var) @ R.T
    se = np.sqrt(np.diag(cov) / n)
    assert np.all(np.abs(x.mean(0) - mu) < 5 * se)
    emp = np.cov(x.T)
    assert np.allclose(emp, cov, atol=0.05 * var.max())
    assert np.allclose(np.linalg.eigvalsh(emp), np.sort(var), rtol=0.05, atol=1e-5)
    # Children's scales: parent / (0.8 n).
    assert np.allclose(np.exp(model.params["log_scales"].detach().double().numpy()),
                       np.array([0.5, 0.1, 0.02]) / (0.8 * n), rtol=1e-5)


@pytest.mark.parametrize("n_max", [1, 100])
def test_extreme_n_max_finite_and_bounded(n_max):
    rng = np.random.default_rng(0)
    counts = rng.integers(1, 30, size=500)
    model = random_model(500)
    p = snapshot(model)
    k = densification_factors(counts, n_max)
    densify_text_model(model, k, torch.Generator().manual_seed(0))
    assert len(model) == int(k.sum()) <= n_max * 500
    assert all(torch.isfinite(t).all() for t in model.params.values())
    if n_max == 1:
        assert all(torch.equal(model.params[name].detach(), p[name]) for name in p)


def test_memory_cap_refuses_clearly():
    with pytest.raises(TrainingError, match="n_max"):
        densify_text_model(random_model(10), np.full(10, 100), max_gaussians=500)


# ---- the method: phases, learning rates, fallback ---------------------------------------------------
import logging  # noqa: E402
import math  # noqa: E402

from PIL import Image  # noqa: E402

from _engine_helpers import install_stand_in_raster, make_tiny_scene  # noqa: E402
from strings_bench.methods.strings.masks import MissingMasksError  # noqa: E402
from strings_bench.methods.registry import get_method  # noqa: E402
from strings_bench.methods.strings.method import StringsMethod, text_lr_factor  # noqa: E402
from strings_bench.engine.optim import exponential_lr  # noqa: E402
from strings_bench.scene.scene import Scene  # noqa: E402

install_stand_in_raster()

TEXT_BOX = (8, 6, 20, 14)  # x0, y0, x1, y1 on the 32 x 24 views


def _write_masks(root, scene, box, empty_views=()):
    (root / "masks").mkdir(exist_ok=True)
    x0, y0, x1, y1 = box
    for i, c in enumerate(scene.model.cameras):
        m = np.zeros((c.height, c.width), np.uint8)
        if i not in empty_views:
            m[y0:y1, x0:x1] = 255
        Image.fromarray(m).save(root / "masks" / c.name)


@pytest.fixture(scope="module")
def tiny_text_scene(tmp_path_factory):
    root = tmp_path_factory.mktemp("strings") / "scene"
    scene = make_tiny_scene(root, n_views=9, n_points=60)
    _write_masks(root, scene, TEXT_BOX, empty_views=(3,))
    return Scene.load(root)


@pytest.fixture(autouse=True)
def _cache(tmp_path, monkeypatch):
    monkeypatch.setenv("STRINGS_BENCH_CACHE", str(tmp_path / "cache"))


FAST = dict(steps_scale=0.002, mask_dilation_fraction=0.0, n_max=3, progress=False, sh_degree=1)  # T1 = 6 steps


def test_registered_names_and_presets():
    for name in ("strings", "strings-no-densify", "strings-pos-lr"):
        spec = get_method(name)
        assert {"paper", "quick", "release"} <= set(spec.presets)
    assert get_method("strings-no-densify").build().settings["text_densify"] is False
    assert get_method("strings-pos-lr").build().settings["phase1_position_lr"] == 1.0
    rel = get_method("strings").build("release").settings
    assert rel["gamma"] == 12000 and rel["mask_dilation_px"] == 225 and rel["phase2_schedules"] == "restart"
    with pytest.raises(Exception, match="unknown setting"):
        list(StringsMethod(steps_scale=0.002, no_such_setting=1).train(None, [6]))


def test_text_lr_factor_values():
    # Paper constants: gamma 15000 -> alpha / 2 there; far before, ~0; far after, alpha.
    assert text_lr_factor(15000, 0.5, 0.0005, 15000) == pytest.approx(0.25)
    assert text_lr_factor(3000, 0.5, 0.0005, 15000) == pytest.approx(0.5 / (1 + math.exp(6)))
    assert text_lr_factor(30000, 0.5, 0.0005, 15000) == pytest.approx(0.5 / (1 + math.exp(-7.5)))
    assert text_lr_factor(-1e9, 0.5, 0.0005, 15000) == 0.0  # no overflow


def test_lr_schedule_in_both_phases(tiny_text_scene):
    scene = tiny_text_scene
    m = StringsMethod(**{**FAST, "steps_scale": 0.01})  # T1 = 30, gamma -> 150, beta -> 0.05
    trainer = m.build_trainer(scene, [70, 300], 1)
    assert trainer.t1 == 30
    ext = trainer.extent
    for t in (1, 15, 30):
        assert trainer.position_lr(t) == 0.0
    for t in (31, 100, 150, 300):
        assert trainer.position_lr(t) == pytest.approx(exponential_lr(t - 30, 1.6e-4 * ext, 1.6e-6 * ext, 300))
        text, non_text = trainer.lr_factors(t)
        assert non_text == 0.5
        assert text == pytest.approx(0.5 / (1 + math.exp(-0.0005 / 0.01 * (t - 15000 * 0.01))))
    assert trainer.lr_factors(150)[0] == pytest.approx(0.25)
    # Ablation: the 3DGS schedule in phase 1.
    t2 = StringsMethod(**{**FAST, "steps_scale": 0.01, "phase1_position_lr": 1.0}).build_trainer(scene, [70], 1)
    assert t2.position_lr(10) == pytest.approx(exponential_lr(10, 1.6e-4 * ext, 1.6e-6 * ext, 300))


def test_restart_schedules(tiny_text_scene):
    trainer = StringsMethod(**{**FAST, "steps_scale": 0.01}).build_trainer(
        tiny_text_scene, [70], 1)
    assert trainer.strategy_step(20) == 20 and trainer.strategy_step(35) == 5
    # SH degree +1 every max(1000 x 0.01, 50) = 50 steps, counted from the start of phase 2 (step 30)
    assert trainer.sh_degree_for_step(79) == 0 and trainer.sh_degree_for_step(80) == 1
    glob = StringsMethod(**{**FAST, "steps_scale": 0.01, "phase2_schedules": "global"}).build_trainer(
        tiny_text_scene, [70], 1)
    assert glob.strategy_step(35) == 35 and glob.sh_degree_for_step(50) == 1 and glob.sh_degree_for_step(49) == 0


def _spy(trainer):
    """Record, per step: phase, view, means LR, model size, and the per-row scale given to Adam."""
    log = []
    from strings_bench.engine.optim import GaussianAdam

    orig_step = GaussianAdam.step

    def step(opt, row_scale=None):
        scale = None if not row_scale else row_scale.get("means")
        log.append({"phase": trainer.phase, "lr": opt.lrs["means"], "n": len(trainer.model),
                    "scale": None if scale is None else scale.clone(),
                    "is_text": trainer.model.extras["is_text"].clone()})
        return orig_step(opt, row_scale)

    return log, step


def test_phase1_positions_frozen_and_text_views_only(tiny_text_scene, monkeypatch):
    scene = tiny_text_scene
    # No densification or opacity reset in this run: every Gaussian exists throughout phase 1.
    m = StringsMethod(**FAST, refine_start_iter=10 ** 9, reset_every=10 ** 9)
    trainer = m.build_trainer(scene, [6], 1)
    init = {}
    orig_init = trainer.initial_model

    def initial_model(s):
        model = orig_init(s)
        init.update({k: v.detach().clone() for k, v in model.params.items()})
        return model

    trainer.initial_model = initial_model
    views = []
    orig_views = trainer.views_for_step
    trainer.views_for_step = lambda step: views.append(orig_views(step)) or views[-1]
    (result,) = list(trainer.train())
    assert result.extra["phase"] == 1 and result.iteration == 6
    assert torch.equal(trainer.model.params["means"].detach(), init["means"])  # position LR 0
    assert not torch.equal(trainer.model.params["sh0"].detach(), init["sh0"])  # colours did train
    assert 3 not in views and set(views) <= set(scene.train_idx)  # view 3 has an empty mask
    assert trainer.model.extras["is_text"].all()
    # Only text points, densified (all counts equal here -> N_max each).
    seg = trainer.segmentation
    assert 0 < seg.num_text < scene.model.num_points
    assert len(trainer.model) == seg.num_text * 3


def test_phases_with_densification(tiny_text_scene, monkeypatch):
    scene = tiny_text_scene
    m = StringsMethod(**FAST)
    trainer = m.build_trainer(scene, [6, 14], 1)
    from strings_bench.engine.optim import GaussianAdam

    log, step = _spy(trainer)
    monkeypatch.setattr(GaussianAdam, "step", step)
    results = list(trainer.train())
    assert [r.iteration for r in results] == [6, 14]
    p1 = [e for e in log if e["phase"] == 1]
    p2 = [e for e in log if e["phase"] == 2]
    assert len(p1) == 6 and len(p2) == 8
    assert all(e["lr"] == 0.0 and e["scale"] is None for e in p1)
    assert all(e["is_text"].all() for e in p1)
    # Phase 2: non-text Gaussians joined; per-row factors alpha (non-text) and the sigmoid (text).
    n_non_text = int((~trainer.segmentation.is_text).sum())
    first = p2[0]
    assert int((~first["is_text"]).sum()) == n_non_text
    text_f, non_f = trainer.lr_factors(7)
    assert torch.allclose(first["scale"][first["is_text"]], torch.tensor(text_f))
    assert torch.allclose(first["scale"][~first["is_text"]], torch.tensor(non_f))
    assert all(e["lr"] > 0 for e in p2)
    assert results[-1].extra["text_gaussians"] == int(trainer.model.extras["is_text"].sum()) > 0
    assert "fallback" not in results[-1].extra


def test_is_text_follows_clone_split_prune():
    from strings_bench.engine.strategies import ops

    model = random_model(6)
    model.extras["is_text"] = torch.tensor([True, False, True, False, True, False])
    ops.duplicate(model, None, torch.tensor([True, True, False, False, False, False]))
    assert model.extras["is_text"].tolist() == [True, False, True, False, True, False, True, False]
    ops.split(model, None, torch.tensor([False, False, True, True, False, False, False, False]), n_children=2)
    assert model.extras["is_text"].tolist() == [True, False, True, False, True, False, True, True, False, False]
    ops.remove(model, None, torch.tensor([True] + [False] * 9))
    assert int(model.extras["is_text"].sum()) == 4 and len(model.extras["is_text"]) == 9


def test_no_text_points_falls_back_to_3dgs(tmp_path, caplog):
    root = tmp_path / "scene"
    scene = make_tiny_scene(root, n_views=9, n_points=40)
    _write_masks(root, scene, TEXT_BOX, empty_views=range(9))
    scene = Scene.load(root)
    with caplog.at_level(logging.WARNING):
        results = list(StringsMethod(**FAST).train(scene, [4]))
    assert "no SfM point" in caplog.text and "plain 3DGS" in caplog.text
    (r,) = results
    assert r.extra["fallback"] == "no_text_points" and r.extra["text_gaussians"] == 0
    assert r.iteration == 4 and len(r.renders) == len(scene.test_idx)


def test_missing_masks_is_a_clear_error(tmp_path):
    scene = make_tiny_scene(tmp_path / "scene", n_views=9, n_points=20)
    with pytest.raises(MissingMasksError, match="masks/"):
        list(StringsMethod(**FAST).train(scene, [4]))
