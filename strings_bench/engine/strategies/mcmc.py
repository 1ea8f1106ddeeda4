"""3DGS-MCMC (Kheradmand et al., NeurIPS 2024; docs/sources.md §4) as a strategy of the shared trainer.

No clone/split/prune heuristics. Instead, every `refine_every` steps from `refine_start_iter` to
`refine_stop_iter`:

1. relocation: "dead" Gaussians (opacity <= `min_opacity`) are moved onto live ones, sampled with
   probability proportional to opacity (with replacement). A live Gaussian picked c times ends up as
   n = c + 1 copies (itself and c relocated ones), all with the new opacity and scale of eq. 9:

       o_new = 1 - (1 - o_old)^(1/n)
       scale_new = scale_old * o_old / D,   D = sum_{i=1}^{n} sum_{k=0}^{i-1} C(i-1, k) (-1)^k o_new^(k+1) / sqrt(k+1)

   (the paper's Sigma_new = o_old^2 / D^2 * Sigma_old). o_new makes n stacked copies as opaque at the
   centre as the original (1 - (1 - o_new)^n = o_old); D makes the summed opacity profile
   1 - prod(1 - o_new g_new(x)) integrate (per axis) to the same value as o_old g_old(x).
2. growth: the count grows by `grow_rate` (5 %) up to `cap_max`, new Gaussians being copies of live
   ones sampled the same way (same eq. 9 update for the sampled ones and their copies).

The Adam moments of every row whose parameters changed (sources, relocated rows, new rows) are
zeroed. Loss terms: `opacity_reg` * mean(opacity) + `scale_reg` * mean(scale) (activated values).
After every optimizer step the positions get SGLD-style noise

    noise = Sigma @ eps * sigmoid(k * ((1 - o) - x0)) * noise_lr * position_lr,   eps ~ N(0, I)

with Sigma = R S S R^T the Gaussian's covariance, k = 100, x0 = 0.995, noise_lr = 5e5: almost
transparent Gaussians explore, opaque ones stay put.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import torch

from strings_bench.core.errors import StringsBenchError
from strings_bench.engine.gaussians import GaussianModel, logit
from strings_bench.engine.optim import GaussianAdam
import strings_bench.engine.strategies.ops as ops
from strings_bench.engine.strategies.base import Strategy

N_MAX = 51  # largest n in the eq. 9 update (as the public implementations); more copies are clamped


@lru_cache(maxsize=4)
def _binomial_table(n_max: int) -> torch.Tensor:
    """(n_max, n_max) float64 table, entry [i, k] = C(i, k) (0 for k > i)."""
    table = torch.zeros((n_max, n_max), dtype=torch.float64, device="cpu")  # cached on the host, moved per call
    for i in range(n_max):
        for k in range(i + 1):
            table[i, k] = math.comb(i, k)
    return table


def relocation_denominator(opacity_new: torch.Tensor, n: torch.Tensor, n_max: int = N_MAX) -> torch.Tensor:
    """D = sum_{i=1}^{n} sum_{k=0}^{i-1} C(i-1, k) (-1)^k o_new^(k+1) / sqrt(k+1), vectorised, float64."""
    o = opacity_new.to(torch.float64)
    n = n.to(torch.long).clamp(1, n_max)
    table = _binomial_table(n_max).to(o.device)  # [i-1, k]
    k = torch.arange(n_max, dtype=torch.float64, device=o.device)
    # term[p, i-1, k] = C(i-1, k) (-1)^k o^(k+1) / sqrt(k+1); rows i > n masked out
    powers = o[:, None] ** (k[None, :] + 1)                                  # (P, K)
    signs = torch.where(k.long() % 2 == 0, 1.0, -1.0).to(torch.float64)
    per_k = signs * powers / torch.sqrt(k + 1)                               # (P, K)
    inner = per_k @ table.T                                                  # (P, I): sum over k for each i-1
    i_idx = torch.arange(n_max, device=o.device)
    return (inner * (i_idx[None, :] < n[:, None])).sum(dim=1)


def relocation_update(opacity_old: torch.Tensor, scale_old: torch.Tensor, n: torch.Tensor,
                      n_max: int = N_MAX, min_opacity: float = 0.005) -> tuple[torch.Tensor, torch.Tensor]:
    """Eq. 9 of 3DGS-MCMC: opacity and scales for each of n copies of a Gaussian (activated values).

    opacity_old (P,), scale_old (P, 3), n (P,) total number of copies (>= 1). The new opacity is
    clamped to [min_opacity, 1 - float32 eps] as the public implementation does, after the scale is
    computed from the unclamped value.
    """
    n = n.to(torch.long).clamp(1, n_max)
    o = opacity_old.to(torch.float64)
    o_new = 1.0 - (1.0 - o) ** (1.0 / n.to(torch.float64))
    denom = relocation_denominator(o_new, n, n_max)
    factor = o / denom
    scale_new = scale_old.to(torch.float64) * factor[:, None]
    o_new = o_new.clamp(min_opacity, 1.0 - torch.finfo(torch.float32).eps)
    return o_new.to(opacity_old.dtype), scale_new.to(scale_old.dtype)


def sample_by_opacity(opacity: torch.Tensor, candidates: torch.Tensor, num: int,
                      generator: torch.Generator | None = None) -> torch.Tensor:
    """`num` indices from `candidates`, drawn with replacement with probability proportional to opacity."""
    probs = opacity[candidates].to(torch.float64)
    if probs.sum() <= 0:
        probs = torch.ones_like(probs)
    picks = torch.multinomial(probs, num, replacement=True, generator=generator)
    return candidates[picks]


def position_noise(model: GaussianModel, position_lr: float, noise_lr: float = 5e5, k: float = 100.0,
                   x0: float = 0.995, generator: torch.Generator | None = None) -> torch.Tensor:
    """The SGLD position noise of 3DGS-MCMC (see module docstring); (N, 3), no gradient."""
    with torch.no_grad():
        cov = model.covariances()
        o = model.opacities
        gate = torch.sigmoid(k * ((1.0 - o) - x0))
        eps = torch.randn(model.means.shape, generator=generator, device=model.device, dtype=model.means.dtype)
        eps = eps * (gate * noise_lr * position_lr)[:, None]
        return torch.einsum("nij,nj->ni", cov, eps)


@dataclass
class MCMCStrategy(Strategy):
    """3DGS-MCMC: dead Gaussians relocated onto live ones (`relocate`, eq. 9), growth by `grow_rate` up to its cap
    (`grow`), opacity and scale L1 in the loss, position noise (the module docstring).

    Its cap is `cap_max`, else `cap_multiple` x the initial count; the run's Gaussian budget (`StrategyContext.budget`)
    replaces it. State: cap, int (None until the first step without `cap_max`), generator (the seeded sampler or
    None), n_relocated and n_added, int totals."""
    refine_start_iter: int = 500  # first relocation step (nominal)
    refine_stop_iter: int = 25_000  # last relocation step (nominal)
    refine_every: int = 100  # relocation interval (nominal)
    min_opacity: float = 0.005      # "dead" threshold
    grow_rate: float = 0.05  # grow the count by this fraction per refinement, up to its cap (cap_max)
    cap_max: int | None = None      # None: cap_multiple x the initial number of Gaussians; the run's Gaussian budget replaces it
    cap_multiple: float = 10.0  # cap = this x initial Gaussians when cap_max is None
    opacity_reg: float = 0.01  # weight of mean |opacity| in the loss
    scale_reg: float = 0.01  # weight of mean |scale| in the loss
    noise_lr: float = 5e5  # position noise scale x position LR
    noise_k: float = 100.0  # steepness of the noise gate sigmoid(k((1-o)-x0))
    noise_x0: float = 0.995  # centre of the noise gate
    n_max: int = N_MAX  # largest number of copies in the relocation formula
    seed: int | None = None         # sampling RNG (None: torch's global RNG, seeded by the trainer)

    def __post_init__(self):
        if self.cap_max is not None and self.cap_max < 1:
            raise StringsBenchError(f"MCMC cap_max must be a positive number of Gaussians, got {self.cap_max}",
                                    hint="leave it unset to use cap_multiple x the initial point count")
        if not 1 <= self.n_max <= 200:
            raise StringsBenchError(f"MCMC n_max must be in [1, 200], got {self.n_max}")

    def initialize_state(self, scene_extent: float, cameras=None) -> dict:
        """`Strategy.initialize_state` plus cap (the run's budget, else `cap_max`), generator, n_relocated, n_added."""
        state = super().initialize_state(scene_extent, cameras)
        # The seeded generator is made at first use, on the model's device (a CPU generator cannot
        # drive torch.multinomial / torch.randn on CUDA tensors).
        # The run's Gaussian budget (run --budget) is MCMC's own cap: cap_max := the context's budget.
        state.update(cap=self.cap_max if self.context.budget is None else int(self.context.budget), generator=None,
                     n_relocated=0, n_added=0)
        return state

    def generator(self, state: dict, device: torch.device) -> torch.Generator | None:
        """The sampling generator (seeded, on `device`), or None for torch's global RNG."""
        if self.seed is not None and state.get("generator") is None:
            state["generator"] = torch.Generator(device=device).manual_seed(int(self.seed))
        return state.get("generator")

    def loss_terms(self, model: GaussianModel, info: dict, step: int):
        """opacity_reg x mean |opacity| + scale_reg x mean |scale| over the model's Gaussians (a scalar in the graph)."""
        terms = 0.0
        if self.opacity_reg:
            terms = terms + self.opacity_reg * model.opacities.abs().mean()
        if self.scale_reg:
            terms = terms + self.scale_reg * model.scales.abs().mean()
        return terms

    def step_post_backward(self, model: GaussianModel, optimizer: GaussianAdam, state: dict, step: int,
                           info: dict) -> None:
        """Every `refine_every` inside (refine_start_iter, refine_stop_iter): `relocate`, then `grow`; at every step
        the position noise (`position_noise`), scaled by the step's position LR."""
        if state.get("cap") is None:
            state["cap"] = max(len(model), int(round(self.cap_multiple * len(model))))
        if (self.at(self.refine_start_iter) < step < self.at(self.refine_stop_iter)
                and step % self.every(self.refine_every) == 0):
            state["n_relocated"] += self.relocate(model, optimizer, state)
            state["n_added"] += self.grow(model, optimizer, state)
        lr = optimizer.lrs.get("means", 0.0)
        if lr and self.noise_lr:
            noise = position_noise(model, lr, self.noise_lr, self.noise_k, self.noise_x0,
                                   self.generator(state, model.device))
            model.params["means"].data.add_(noise)

    # ---- pieces -------------------------------------------------------------------------------
    @torch.no_grad()
    def _apply_eq9(self, model: GaussianModel, sources: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Unique sampled sources, their new opacity logits and log-scales (n = times sampled + 1)."""
        uniq, counts = torch.unique(sources, return_counts=True)
        o_new, s_new = relocation_update(model.opacities[uniq], model.scales[uniq], counts + 1, self.n_max,
                                         self.min_opacity)
        return uniq, logit(o_new).to(model.params["opacity_logits"].dtype), torch.log(s_new)

    @torch.no_grad()
    def relocate(self, model: GaussianModel, optimizer: GaussianAdam, state: dict) -> int:
        """Move every dead Gaussian (opacity <= min_opacity) onto a live one sampled by opacity, eq. 9 updating the
        sources' opacity and scale. Returns the number relocated."""
        opacity = model.opacities
        dead = opacity <= self.min_opacity
        n_dead = int(dead.sum())
        alive = (~dead).nonzero().squeeze(1)
        if n_dead == 0 or alive.numel() == 0:
            return 0
        sources = sample_by_opacity(opacity, alive, n_dead, self.generator(state, model.device))
        uniq, new_logit, new_log_scale = self._apply_eq9(model, sources)
        ops.replace_rows(model, optimizer, uniq, {"opacity_logits": new_logit, "log_scales": new_log_scale})
        # every dead row becomes a copy of its (already updated) source
        dead_rows = dead.nonzero().squeeze(1)
        values = {name: p.detach()[sources] for name, p in model.params.items()}
        ops.replace_rows(model, optimizer, dead_rows, values)
        for name, v in model.extras.items():
            v[dead_rows] = v[sources]
        return n_dead

    @torch.no_grad()
    def grow(self, model: GaussianModel, optimizer: GaussianAdam, state: dict) -> int:
        """Add min(cap, N (1 + grow_rate)) - N Gaussians, copies of sources sampled by opacity (eq. 9 on the sources).
        Returns the number added."""
        n = len(model)
        target = min(int(state["cap"]), int(n * (1.0 + self.grow_rate)))
        n_new = max(0, target - n)
        if n_new == 0:
            return 0
        sources = sample_by_opacity(model.opacities, torch.arange(n, device=model.device), n_new,
                                    self.generator(state, model.device))
        uniq, new_logit, new_log_scale = self._apply_eq9(model, sources)
        ops.replace_rows(model, optimizer, uniq, {"opacity_logits": new_logit, "log_scales": new_log_scale})
        # appended rows copy their source (params, extras, state rows) and start with zero moments
        ops.rebuild(model, optimizer, torch.arange(n, device=model.device), parents=sources, state=state)
        return n_new

