"""STRinGS: text densification (Eq. 1), phases, LR factors, fallback."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from strings_bench.errors import StringsBenchError, TrainingError
from strings_bench.text_densify import densification_factors, densify_by_factors, quat_to_rotmat


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


def random_params(n, seed=0):
    g = torch.Generator().manual_seed(seed)
    return {
        "means": torch.randn(n, 3, generator=g, dtype=torch.float64),
        "quats": torch.randn(n, 4, generator=g, dtype=torch.float64),
        "log_scales": torch.randn(n, 3, generator=g, dtype=torch.float64) * 0.5 - 2,
        "opacity_logits": torch.randn(n, generator=g, dtype=torch.float64),
        "sh0": torch.randn(n, 1, 3, generator=g, dtype=torch.float64),
        "shN": torch.randn(n, 15, 3, generator=g, dtype=torch.float64),
    }


def test_children_counts_copies_and_scales():
    p = random_params(4)
    k = np.array([1, 3, 1, 5])
    out, parent = densify_by_factors(p, k, torch.Generator().manual_seed(1))
    assert parent.tolist() == [0, 1, 1, 1, 2, 3, 3, 3, 3, 3]
    for name in ("quats", "opacity_logits", "sh0", "shN"):
        assert torch.equal(out[name], p[name][parent])
    # N = 1: unchanged; N > 1: log-scale - log(0.8 N).
    assert torch.equal(out["means"][0], p["means"][0]) and torch.equal(out["log_scales"][4], p["log_scales"][2])
    assert torch.allclose(out["log_scales"][1:4], p["log_scales"][1] - np.log(0.8 * 3))
    assert torch.allclose(out["log_scales"][5:], p["log_scales"][3] - np.log(0.8 * 5))
    assert not torch.equal(out["means"][1], out["means"][2])


def test_quat_to_rotmat_is_rotation():
    R = quat_to_rotmat(torch.randn(50, 4, dtype=torch.float64))
    eye = torch.eye(3, dtype=torch.float64).expand(50, 3, 3)
    assert torch.allclose(R @ R.transpose(1, 2), eye, atol=1e-12)
    assert torch.allclose(torch.linalg.det(R), torch.ones(50, dtype=torch.float64))
    # 90 degrees about z (wxyz): x -> y.
    Rz = quat_to_rotmat(torch.tensor([[np.cos(np.pi / 4), 0, 0, np.sin(np.pi / 4)]], dtype=torch.float64))[0]
    assert torch.allclose(Rz @ torch.tensor([1.0, 0, 0], dtype=torch.float64),
                          torch.tensor([0.0, 1, 0], dtype=torch.float64), atol=1e-12)


def test_child_positions_follow_parent_distribution():
    """Sample mean and covariance over many children match the parent Gaussian."""
    p = random_params(1, seed=3)
    p["log_scales"] = torch.log(torch.tensor([[0.5, 0.1, 0.02]], dtype=torch.float64))
    n = 20000
    out, _ = densify_by_factors(p, np.array([n]), torch.Generator().manual_seed(7))
    x = out["means"].numpy()
    R = quat_to_rotmat(p["quats"])[0].numpy()
    cov = R @ np.diag(np.exp(2 * p["log_scales"][0].numpy())) @ R.T
    se = np.sqrt(np.diag(cov) / n)
    assert np.all(np.abs(x.mean(0) - p["means"][0].numpy()) < 5 * se)
    emp = np.cov(x.T)
    assert np.allclose(emp, cov, atol=0.05 * 0.25)  # 5 % of the largest variance
    assert np.allclose(np.linalg.eigvalsh(emp), np.sort(np.exp(2 * p["log_scales"][0].numpy())), rtol=0.05, atol=1e-5)


@pytest.mark.parametrize("n_max", [1, 100])
def test_extreme_n_max_finite_and_bounded(n_max):
    rng = np.random.default_rng(0)
    counts = rng.integers(1, 30, size=500)
    p = random_params(500)
    k = densification_factors(counts, n_max)
    out, parent = densify_by_factors(p, k, torch.Generator().manual_seed(0))
    assert len(parent) == int(k.sum()) <= n_max * 500
    assert all(torch.isfinite(t).all() for t in out.values())
    if n_max == 1:
        assert all(torch.equal(out[name], p[name]) for name in p)


def test_memory_cap_refuses_clearly():
    p = random_params(10)
    with pytest.raises(TrainingError, match="n_max"):
        densify_by_factors(p, np.full(10, 100), max_gaussians=500)
