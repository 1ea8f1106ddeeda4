"""STRinGS: text densification (Eq. 1), phases, LR factors, fallback."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from strings_bench.errors import StringsBenchError, TrainingError
from strings_bench.gaussians import GaussianModel, quat_to_rotmat
from strings_bench.text_densify import densification_factors, densify_text_model


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
