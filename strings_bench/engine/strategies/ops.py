"""Operations that change the set of Gaussians while keeping everything in step.

Every op updates, together: the model's parameters (new `nn.Parameter`s in `model.params`), the
optimizer's Adam moments (kept rows move with their Gaussian, new rows start at zero), the model's
`extras` (new rows copy their parent, or are given), and any tensor in a strategy `state` dict whose
first dimension is the number of Gaussians (new rows copy their parent; appended rows are zero).

Row order after an op: the kept rows in their old order, then the new rows.
"""

from __future__ import annotations

from typing import Mapping

import torch

from strings_bench.core.errors import StringsBenchError
from strings_bench.engine.gaussians import PARAM_NAMES, GaussianModel, quat_to_rotmat
from strings_bench.engine.optim import GaussianAdam, rows_then


def _as_mask(mask, n: int, device) -> torch.Tensor:
    mask = torch.as_tensor(mask, device=device)
    if mask.dtype != torch.bool:
        m = torch.zeros(n, dtype=torch.bool, device=device)
        m[mask.long()] = True
        return m
    if mask.shape != (n,):
        raise StringsBenchError(f"mask has shape {tuple(mask.shape)}, expected ({n},)")
    return mask


@torch.no_grad()
def rebuild(model: GaussianModel, optimizer: GaussianAdam | None, keep: torch.Tensor,
            new_params: Mapping[str, torch.Tensor] | None = None, parents: torch.Tensor | None = None,
            new_extras: Mapping[str, torch.Tensor] | None = None, state: dict | None = None) -> None:
    """The primitive behind every op: rows become old[keep] followed by K new rows.

    New parameter rows come from `new_params[name]` or, where not given, copy `parents` (K,).
    New extras and state rows copy `parents`, or come from `new_extras`, or are zero.
    """
    n = len(model)
    device = model.device
    keep = torch.as_tensor(keep, dtype=torch.long, device=device)
    new_params = dict(new_params or {})
    if parents is not None:
        parents = torch.as_tensor(parents, dtype=torch.long, device=device)
        k = int(parents.shape[0])
    elif new_params:
        k = int(next(iter(new_params.values())).shape[0])
    else:
        k = 0
    for name in PARAM_NAMES:
        old = model.params[name]
        if name in new_params:
            add = new_params[name].to(dtype=old.dtype, device=device)
            if add.shape[0] != k or tuple(add.shape[1:]) != tuple(old.shape[1:]):
                raise StringsBenchError(f"new rows for {name} have shape {tuple(add.shape)}, expected "
                                        f"({k}, {', '.join(map(str, old.shape[1:]))})")
        elif parents is not None:
            add = old.detach()[parents]
        elif k:
            raise StringsBenchError(f"new rows for {name} are missing and have no parents to copy")
        else:
            add = old.detach()[:0]
        model.params[name] = torch.nn.Parameter(rows_then(old.detach(), keep, add), requires_grad=old.requires_grad)
        if optimizer is not None:
            optimizer.params[name] = model.params[name]
            optimizer.gather_rows(name, keep, k)

    def _resize(v: torch.Tensor, given: torch.Tensor | None) -> torch.Tensor:
        if given is not None:
            add = torch.as_tensor(given, dtype=v.dtype, device=v.device)
        elif parents is not None:
            add = v[parents]
        else:
            return rows_then(v, keep, n_zero=k)
        return rows_then(v, keep, add)

    given_extras = dict(new_extras or {})
    for name, v in list(model.extras.items()):
        model.extras[name] = _resize(v, given_extras.pop(name, None))
    if given_extras:  # extras named only for the new rows: old rows get zeros
        for name, add in given_extras.items():
            add = torch.as_tensor(add, device=device)
            model.extras[name] = torch.cat([add.new_zeros((len(keep),) + tuple(add.shape[1:])), add])
    if state is not None:
        for key, v in list(state.items()):
            if torch.is_tensor(v) and v.ndim >= 1 and v.shape[0] == n:
                state[key] = _resize(v, None)
    model.check()


def duplicate(model: GaussianModel, optimizer: GaussianAdam | None, mask, state: dict | None = None) -> None:
    """Clone the selected Gaussians (3DGS clone: an identical copy, fresh Adam moments)."""
    mask = _as_mask(mask, len(model), model.device)
    rebuild(model, optimizer, torch.arange(len(model), device=model.device), parents=mask.nonzero().squeeze(1),
            state=state)


@torch.no_grad()
def sample_children(model: GaussianModel, parents: torch.Tensor, n_children: int | torch.Tensor,
                    scale_divisor: float | torch.Tensor | None = None,
                    generator: torch.Generator | None = None) -> tuple[dict[str, torch.Tensor], torch.Tensor]:
    """Children of `parents`: positions drawn from N(mean, R diag(s^2) R^T) of the parent, log-scales
    reduced by log(scale_divisor) (default 0.8 * n), everything else copied.

    `n_children` may be an int or a per-parent tensor. Returns (new param rows, parent index per child).
    """
    parents = torch.as_tensor(parents, dtype=torch.long, device=model.device)
    counts = torch.as_tensor(n_children, device=model.device).long().expand(parents.shape[0])
    child_parent = parents.repeat_interleave(counts)
    if scale_divisor is None:
        div = 0.8 * counts.to(torch.float32)
    else:
        div = torch.as_tensor(scale_divisor, dtype=torch.float32, device=model.device).expand(parents.shape[0])
    div = div.repeat_interleave(counts)
    p = {k: v.detach() for k, v in model.params.items()}
    scales = torch.exp(p["log_scales"][child_parent])
    noise = torch.randn(scales.shape, generator=generator, device=model.device, dtype=scales.dtype) if generator \
        else torch.randn_like(scales)
    R = quat_to_rotmat(p["quats"][child_parent])
    offsets = torch.einsum("nij,nj->ni", R, noise * scales)
    new = {k: v[child_parent].clone() for k, v in p.items()}
    new["means"] = p["means"][child_parent] + offsets
    new["log_scales"] = p["log_scales"][child_parent] - torch.log(div)[:, None]
    return new, child_parent


def split(model: GaussianModel, optimizer: GaussianAdam | None, mask, n_children: int = 2,
          scale_divisor: float | None = None, state: dict | None = None,
          generator: torch.Generator | None = None) -> None:
    """Replace each selected Gaussian by `n_children` samples of itself (3DGS split: n = 2, scales / 1.6)."""
    mask = _as_mask(mask, len(model), model.device)
    new, child_parent = sample_children(model, mask.nonzero().squeeze(1), n_children, scale_divisor, generator)
    rebuild(model, optimizer, (~mask).nonzero().squeeze(1), new_params=new, parents=child_parent, state=state)


def remove(model: GaussianModel, optimizer: GaussianAdam | None, mask, state: dict | None = None) -> None:
    """Delete the selected Gaussians."""
    mask = _as_mask(mask, len(model), model.device)
    rebuild(model, optimizer, (~mask).nonzero().squeeze(1), state=state)


def append(model: GaussianModel, optimizer: GaussianAdam | None, new_params: Mapping[str, torch.Tensor],
           new_extras: Mapping[str, torch.Tensor] | None = None, state: dict | None = None) -> None:
    """Add Gaussians with the given parameters (all groups); extras not given are zero."""
    missing = [k for k in PARAM_NAMES if k not in new_params]
    if missing:
        raise StringsBenchError(f"append needs every parameter group; missing {missing}")
    rebuild(model, optimizer, torch.arange(len(model), device=model.device), new_params=new_params,
            new_extras=new_extras, state=state)


@torch.no_grad()
def replace_rows(model: GaussianModel, optimizer: GaussianAdam | None, rows, values: Mapping[str, torch.Tensor],
                 reset_state: bool = True) -> None:
    """Overwrite some rows in place (e.g. MCMC relocation) and zero their Adam moments in every group."""
    rows = torch.as_tensor(rows, device=model.device)
    for name, v in values.items():
        model.params[name].data[rows] = v.to(model.params[name].dtype)
    if optimizer is not None and reset_state:
        for name in model.params:
            optimizer.zero_rows(name, rows)


@torch.no_grad()
def reset_opacity(model: GaussianModel, optimizer: GaussianAdam | None, value: float = 0.01) -> None:
    """3DGS opacity reset: opacity <- min(opacity, value); the opacity group's moments are zeroed."""
    cap = torch.logit(torch.tensor(value, dtype=model.params["opacity_logits"].dtype, device="cpu")).item()  # a host scalar
    old = model.params["opacity_logits"]
    model.params["opacity_logits"] = torch.nn.Parameter(old.detach().clamp_max(cap), requires_grad=old.requires_grad)
    if optimizer is not None:
        optimizer.params["opacity_logits"] = model.params["opacity_logits"]
        st = optimizer.state["opacity_logits"]
        st["exp_avg"].zero_()
        st["exp_avg_sq"].zero_()
