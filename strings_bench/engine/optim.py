"""Adam for Gaussian parameters: one learning rate per parameter group, an optional per-row scale
of the update, state that densification ops can resize, and the 3DGS position-LR schedule.

Why a custom Adam rather than torch.optim.Adam: densification changes the number of rows of every
parameter and its moments together, and STRinGS needs a different position step per Gaussian.
Scaling a gradient does not scale an Adam step (Adam normalises the gradient away), so the per-row
factor multiplies the update itself. The update is the same as torch.optim.Adam (bias-corrected,
eps added to sqrt(v_hat)), which tests/engine/test_engine.py checks.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Mapping

import numpy as np
import torch

from strings_bench.core.errors import StringsBenchError
from strings_bench.core.instrument import stage

ADAM_EPS = 1e-15  # 3DGS


@dataclass
class LearningRates:
    """3DGS learning rates (docs/sources.md §1). `means` is the initial position LR before x extent.

    opacity: 0.05 in the 3DGS paper (default here); the 2024 3DGS release that STRinGS forks uses
    0.025 — pass `opacity_logits=0.025` to match it.
    """

    means: float = 1.6e-4  # initial position LR (x scene extent)
    means_final: float = 1.6e-6  # final position LR at position_lr_steps (x extent)
    sh0: float = 2.5e-3  # SH degree-0 colour
    shN: float = 2.5e-3 / 20  # higher SH orders
    opacity_logits: float = 0.05  # opacity (3DGS paper 0.05; the 2024 release 0.025)
    log_scales: float = 5e-3  # log scales
    quats: float = 1e-3  # rotations
    def group_lrs(self, extent: float) -> dict[str, float]:
        d = asdict(self)
        d.pop("means_final")
        d["means"] = self.means * extent
        return d


def exponential_lr(step: float, lr_init: float, lr_final: float, max_steps: float) -> float:
    """3DGS position schedule: log-linear from lr_init at step 0 to lr_final at max_steps, then flat.

    With t = clip(step / max_steps, 0, 1) the value is lr_init^(1-t) * lr_final^t. A zero end point
    takes the limit of that product (as 3DGS' get_expon_lr_func does through exp(log(0)) = 0):
    lr_final = 0 gives lr_init at t = 0 and 0 for every t > 0; lr_init = 0 gives 0 for t < 1 and
    lr_final at t = 1; both 0 give 0. (At the one point where 3DGS' numpy expression is 0 * -inf =
    NaN, t = 0 resp. t = 1, the limit is used.) For a smooth decay towards 0 give a small positive
    lr_final. Negative rates are an error.
    """
    if lr_init < 0 or lr_final < 0 or math.isnan(lr_init) or math.isnan(lr_final):
        raise StringsBenchError(f"learning rates must be >= 0, got lr_init={lr_init}, lr_final={lr_final}",
                                hint="check lr_means / lr_means_final")
    t = min(max(step / max(max_steps, 1e-12), 0.0), 1.0)
    if lr_final == 0.0:
        return lr_init if t == 0.0 else 0.0
    if lr_init == 0.0:
        return lr_final if t == 1.0 else 0.0
    return math.exp(math.log(lr_init) * (1 - t) + math.log(lr_final) * t)


def rows_then(old: torch.Tensor, index: torch.Tensor, add: torch.Tensor | None = None, n_zero: int = 0) -> torch.Tensor:
    """torch.cat([old[index], add]) (or n_zero zero rows after old[index]) in one allocation, the rows copied by
    index_select into it: the same values, 3-4x faster than indexing and concatenating at 330k rows (one torch
    thread), which three rebuilds of every parameter and moment per densification round add up."""
    k = int(index.shape[0])
    tail = int(add.shape[0]) if add is not None else n_zero
    out = old.new_empty((k + tail,) + tuple(old.shape[1:]))
    torch.index_select(old, 0, index, out=out[:k])
    if add is not None:
        out[k:] = add
    elif tail:
        out[k:] = 0
    return out


def exact_sqrt(t: torch.Tensor) -> torch.Tensor:
    """The correctly rounded square root of each element, the same bits on every machine. On the CPU torch's own is
    MKL's vector square root, whose rounding follows the code branch MKL picks by the CPU's vendor and instruction
    set (engine/optim_kernels.py); numpy's is the processor's square-root instruction, correctly rounded (IEEE 754).
    Elsewhere (CUDA) torch's sqrt is already the correctly rounded one."""
    if t.device.type == "cpu" and t.dtype in (torch.float32, torch.float64):
        return torch.from_numpy(np.sqrt(t.detach().numpy()))
    return t.sqrt()


class GaussianAdam:
    """Adam over a dict of parameters (shared with the model: ops replace entries in place).

    state[name] = {"step": int, "exp_avg": Tensor, "exp_avg_sq": Tensor}
    """

    def __init__(self, params: dict[str, torch.nn.Parameter], lrs: Mapping[str, float], eps: float = ADAM_EPS,
                 betas: tuple[float, float] = (0.9, 0.999), fused: bool | None = None):
        unknown = [k for k in lrs if k not in params]
        if unknown:
            raise StringsBenchError(f"learning rates given for unknown parameter groups {unknown}",
                                    hint=f"groups: {', '.join(params)}")
        self.params = params
        self.lrs = {k: float(lrs.get(k, 0.0)) for k in params}
        self.eps = eps
        self.betas = betas
        # fused: one numba pass per group on contiguous float32 CPU tensors (bit-identical to the torch
        # path, engine/optim_kernels.py); None = wherever it applies, False = always the torch path.
        self.fused = fused
        self.state: dict[str, dict] = {}
        for k, p in params.items():
            self.reset_state(k)

    # ---- stepping -------------------------------------------------------------------------
    def zero_grad(self) -> None:
        for p in self.params.values():
            p.grad = None

    def set_lr(self, name: str, lr: float) -> None:
        self.lrs[name] = float(lr)

    @torch.no_grad()
    @stage("adam")
    def step(self, row_scale: Mapping[str, torch.Tensor] | None = None) -> None:
        """One Adam step on every group with a gradient. `row_scale[name]` (N,) multiplies the update
        of each row of that group (e.g. text vs non-text position LR)."""
        b1, b2 = self.betas
        row_scale = row_scale or {}
        for name, p in self.params.items():
            g = p.grad
            if g is None:
                continue
            st = self.state[name]
            if st["exp_avg"].shape != p.shape:
                raise StringsBenchError(f"optimizer state of {name} has shape {tuple(st['exp_avg'].shape)} but the "
                                        f"parameter has {tuple(p.shape)}",
                                        hint="change the number of Gaussians only through strategies.ops")
            st["step"] += 1
            m, v = st["exp_avg"], st["exp_avg_sq"]
            if self.fused is not False and self._fused_step(name, p, g, m, v, st["step"], row_scale.get(name)):
                continue
            m.mul_(b1).add_(g, alpha=1 - b1)
            v.mul_(b2).addcmul_(g, g, value=1 - b2)
            lr = self.lrs[name]
            if lr == 0.0:
                continue
            bc1 = 1 - b1 ** st["step"]
            bc2 = 1 - b2 ** st["step"]
            denom = (exact_sqrt(v) / math.sqrt(bc2)).add_(self.eps)
            update = m / denom
            scale = row_scale.get(name)
            if scale is not None:
                scale = torch.as_tensor(scale, dtype=update.dtype, device=update.device)
                if scale.ndim == 1:
                    if scale.shape[0] != p.shape[0]:
                        raise StringsBenchError(f"row LR scale for {name} has {scale.shape[0]} rows, parameter {p.shape[0]}")
                    scale = scale.reshape((-1,) + (1,) * (p.ndim - 1))
                update.mul_(scale)
            p.add_(update, alpha=-lr / bc1)

    def _fused_step(self, name: str, p, g, m, v, step: int, scale) -> bool:
        """The same update as the torch path in one numba pass; False (nothing done) where it does not
        apply: other dtypes or devices, non-contiguous tensors."""
        tensors = (p, g, m, v)
        if not all(t.dtype == torch.float32 and t.device.type == "cpu" and t.is_contiguous() for t in tensors):
            return False
        from strings_bench.engine.optim_kernels import adam_moments, adam_step, f32

        b1, b2 = self.betas
        lr = self.lrs[name]
        bc1 = 1 - b1 ** step
        bc2 = 1 - b2 ** step
        n = p.numel()
        rows = p.shape[0] if p.ndim else 1
        if scale is not None:
            scale = torch.as_tensor(scale, dtype=torch.float32, device=p.device)
            if scale.ndim == 1:
                if scale.shape[0] != rows:
                    raise StringsBenchError(f"row LR scale for {name} has {scale.shape[0]} rows, parameter {rows}")
                scale_arr = scale.contiguous().numpy()
            else:  # a 0-d factor on every element
                scale_arr = np.full(max(rows, 1), float(scale), np.float32)
        else:
            scale_arr = np.empty(0, np.float32)
        row_len = max(n // max(rows, 1), 1)
        g_flat, m_flat, v_flat = g.view(-1), m.view(-1), v.view(-1)
        if lr == 0.0:  # the moments move, the parameters do not
            adam_moments(g_flat.numpy(), m_flat.numpy(), v_flat.numpy(), f32(b1), f32(1 - b1), f32(b2), f32(1 - b2))
            return True
        adam_step(p.detach().view(-1).numpy(), g_flat.numpy(), m_flat.numpy(), v_flat.numpy(), scale_arr, row_len,
                  f32(b1), f32(1 - b1), f32(b2), f32(1 - b2), f32(math.sqrt(bc2)), f32(self.eps), f32(-lr / bc1))
        return True

    # ---- state resizing (used by strategies.ops) -------------------------------------------
    def reset_state(self, name: str) -> None:
        p = self.params[name]
        self.state[name] = {"step": 0, "exp_avg": torch.zeros_like(p, memory_format=torch.preserve_format).detach(),
                            "exp_avg_sq": torch.zeros_like(p).detach()}

    @torch.no_grad()
    def gather_rows(self, name: str, index: torch.Tensor, n_new: int = 0) -> None:
        """Moments become old[index] followed by n_new zero rows (the step count is kept, as gsplat does)."""
        st = self.state[name]
        index = torch.as_tensor(index, device=st["exp_avg"].device)
        index = index.nonzero().squeeze(1) if index.dtype == torch.bool else index.long()
        for key in ("exp_avg", "exp_avg_sq"):
            st[key] = rows_then(st[key], index, n_zero=n_new)

    @torch.no_grad()
    def zero_rows(self, name: str, rows: torch.Tensor) -> None:
        for key in ("exp_avg", "exp_avg_sq"):
            self.state[name][key][rows] = 0

    def state_dict(self) -> dict:
        return {"lrs": dict(self.lrs), "state": {k: {kk: (vv.clone() if torch.is_tensor(vv) else vv)
                                                     for kk, vv in s.items()} for k, s in self.state.items()}}

    def load_state_dict(self, state: dict) -> None:
        """Restore `state_dict()` (learning rates, moments, step counts) onto the current parameters."""
        missing = set(self.params) - set(state["state"])
        if missing:
            raise StringsBenchError(f"optimizer state lacks parameter group(s) {sorted(missing)}")
        self.lrs = {k: float(state["lrs"].get(k, self.lrs[k])) for k in self.params}
        self.state = {}
        for k, p in self.params.items():
            st = state["state"][k]
            if st["exp_avg"].shape != p.shape:
                raise StringsBenchError(f"optimizer state of {k} has shape {tuple(st['exp_avg'].shape)}, "
                                        f"the parameter {tuple(p.shape)}")
            self.state[k] = {"step": st["step"], "exp_avg": st["exp_avg"].to(p.device).clone(),
                             "exp_avg_sq": st["exp_avg_sq"].to(p.device).clone()}
