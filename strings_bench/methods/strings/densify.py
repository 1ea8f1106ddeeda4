"""One-time visibility-based densification of text Gaussians (STRinGS Eq. 1).

With c_i the visibility count of point i (size of its COLMAP track),

    N_i = round(1 + (N_max - 1) * (1/c_i - min_k 1/c_k) / (max_k 1/c_k - min_k 1/c_k))

and every Gaussian with N_i > 1 is replaced by N_i children drawn from it: positions sampled from
the normal distribution with the parent's mean and covariance, scales divided by 0.8 * N_i (as the
3DGS split does for N = 2), every other parameter copied.

Edge cases (documented in docs/strings.md):
- c_i = 0 (a point with no observations): 1/0 is taken as 0, as the authors' release does, so such a
  point is treated like the best-observed one (nothing to say it is under-represented).
- all 1/c_i equal (including a single text point): the denominator is 0. Every point is then at the
  same time the least observed (N_max) and the most observed (1); we give N_max, so the step the
  method relies on is not silently switched off, and it is the limit of the formula for the least
  observed point. `equal_counts="one"` gives 1 instead.
- rounding is half-up (floor(x + 0.5)), the usual reading of the paper's nearest-integer bracket.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import torch

from strings_bench.core.errors import StringsBenchError, TrainingError

if TYPE_CHECKING:
    from strings_bench.engine.gaussians import GaussianModel

DEFAULT_N_MAX = 15
DEFAULT_MAX_TEXT_GAUSSIANS = 10_000_000  # refuse to build more (memory); a setting of the method


def densification_factors(counts: np.ndarray, n_max: int, equal_counts: str = "n_max") -> np.ndarray:
    """N_i of Eq. 1 for visibility counts `counts` (int array), each in [1, n_max]."""
    counts = np.asarray(counts, dtype=np.float64).reshape(-1)
    if n_max < 1 or int(n_max) != n_max:
        raise StringsBenchError(f"N_max must be an integer >= 1, got {n_max}",
                                hint="the paper uses 15-25 (25 for STRinGS-360, 20 Truck, 15 Train)")
    if equal_counts not in ("n_max", "one"):
        raise StringsBenchError(f"equal_counts must be 'n_max' or 'one', got {equal_counts!r}")
    if len(counts) == 0:
        return np.zeros(0, dtype=np.int64)
    if (counts < 0).any() or not np.isfinite(counts).all():
        raise StringsBenchError("visibility counts must be finite and >= 0", hint="counts come from COLMAP tracks")
    with np.errstate(divide="ignore"):
        inv = np.where(counts > 0, 1.0 / np.maximum(counts, 1e-300), 0.0)  # release: 1/0 -> 0
    lo, hi = inv.min(), inv.max()
    if hi - lo <= 0:
        return np.full(len(counts), int(n_max) if equal_counts == "n_max" else 1, dtype=np.int64)
    x = 1.0 + (n_max - 1) * (inv - lo) / (hi - lo)
    return np.clip(np.floor(x + 0.5), 1, n_max).astype(np.int64)


def fit_factors_to_budget(n_children: np.ndarray, budget: int | None) -> np.ndarray:
    """Eq. 1's factors cut to the Gaussian budget (run --budget): when sum(N_i) exceeds `budget`, the parents with the
    largest N_i (the least observed text points, Eq. 1's own priority; ties: the lower index) keep their N_i while
    the total fits, every later one keeps N_i = 1 (itself, undensified). None: unchanged."""
    k = np.asarray(n_children, dtype=np.int64).reshape(-1)
    if budget is None or int(k.sum()) <= budget:
        return k
    from strings_bench.engine.strategies.base import keep_within_budget

    keep = keep_within_budget(torch.from_numpy(k > 1), torch.from_numpy(k.astype(np.float64)),
                              torch.from_numpy(k - 1), max(0, int(budget) - len(k)))
    return np.where(keep.numpy(), k, 1)


def densify_text_model(model: "GaussianModel", n_children: np.ndarray | torch.Tensor,
                       generator: torch.Generator | None = None,
                       memory_limit: int = DEFAULT_MAX_TEXT_GAUSSIANS, budget: int | None = None) -> "GaussianModel":
    """Replace Gaussian i of `model` by n_children[i] samples of itself, in place (n = 1 keeps it).

    Children are drawn by `strategies.ops.sample_children` from N(mean, R S^2 R^T) of the parent
    (unshrunk scales), log-scales reduced by log(0.8 n), other parameters and extras copied.
    Row order afterwards: the kept (n = 1) Gaussians, then the children grouped by parent.
    `budget`: at most this many Gaussians afterwards (`fit_factors_to_budget`); `memory_limit` is the memory guard
    (more is an error: the setting max_text_gaussians).
    """
    from strings_bench.engine.strategies import ops

    n = len(model)
    k = torch.as_tensor(np.asarray(n_children), dtype=torch.int64, device=model.device).reshape(-1)
    if k.shape[0] != n:
        raise StringsBenchError(f"{k.shape[0]} densification factors for {n} Gaussians")
    if n and int(k.min()) < 1:
        raise StringsBenchError("densification factors must be >= 1")
    if budget is not None:
        k = torch.from_numpy(fit_factors_to_budget(k.cpu().numpy(), budget)).to(model.device)
    total = int(k.sum())
    if total > memory_limit:
        raise TrainingError(
            f"text densification would make {total} Gaussians from {n} (more than max_text_gaussians={memory_limit})",
            hint="lower the scene's n_max setting, or raise max_text_gaussians if you have the memory")
    split = k > 1
    if not bool(split.any()):
        return model
    parents = split.nonzero().squeeze(1)
    new, child_parent = ops.sample_children(model, parents, k[parents], generator=generator)
    ops.rebuild(model, None, (~split).nonzero().squeeze(1), new_params=new, parents=child_parent)
    return model
