"""How far training moves the Gaussians: the motion log of a 3DGS-family method.

A schedule shrunk by s shrinks the sum of the position learning rate over a run by s (3DGS' log-linear decay,
scaled in time), so every Gaussian can travel about s times as far as under the paper's schedule. The log
measures it: after every Adam step, the mean over the Gaussians of the length of their position update, summed
over the steps, in units of the scene extent (the position LR's unit: 3DGS' position LR is 1.6e-4 x extent,
Kerbl et al. 2023, Sec. 7.1). Per Gaussian identities change at each densification round, so the log keeps the
mean step, not per-Gaussian paths: `position_path` is the distance a Gaussian that lived through every step
would have moved along its path on average. Text Gaussians (STRinGS' `is_text`) get their own sum.

The log reads the parameters; it never changes them (the training's bits are the same with it).
"""

from __future__ import annotations

import math

import numpy as np
import torch
from numba import njit, prange

CHUNK = 1 << 14  # Gaussians per parallel work item


@njit(parallel=True, cache=True)
def _step_sums(before, after, is_text, has_text):
    """(sum of |after - before| over all rows, over the text rows, text rows) of (N, 3) float32 positions,
    in float64, in chunks of fixed size summed in order (the same at any thread count)."""
    n = before.shape[0]
    nc = (n + CHUNK - 1) // CHUNK
    part = np.zeros((nc, 3))
    for c in prange(nc):
        s_all = 0.0
        s_text = 0.0
        k_text = 0.0
        for i in range(c * CHUNK, min(n, (c + 1) * CHUNK)):
            dx = np.float64(after[i, 0]) - np.float64(before[i, 0])
            dy = np.float64(after[i, 1]) - np.float64(before[i, 1])
            dz = np.float64(after[i, 2]) - np.float64(before[i, 2])
            d = math.sqrt(dx * dx + dy * dy + dz * dz)
            s_all += d
            if has_text and is_text[i]:
                s_text += d
                k_text += 1.0
        part[c, 0] = s_all
        part[c, 1] = s_text
        part[c, 2] = k_text
    out = np.zeros(3)
    for c in range(nc):
        out += part[c]
    return out[0], out[1], out[2]


def new_motion_log(from_step: int = 0) -> dict:
    """An empty log; `from_step` > 0 when it starts on a state saved before logs existed."""
    return {"position_path": 0.0, "text_position_path": 0.0, "steps": 0, "text_steps": 0, "count_changes": 0,
            "from_step": int(from_step)}


@torch.no_grad()
def note_motion(log: dict, before: torch.Tensor, after: torch.Tensor, extent: float,
                is_text: torch.Tensor | None = None) -> None:
    """Add one step's position updates (means (N, 3) before and after Adam) to `log`."""
    n = len(after)
    if before.shape != after.shape or n == 0:
        return
    has_text = is_text is not None and is_text.shape[0] == n
    flags = (is_text.cpu().numpy().astype(np.bool_, copy=False) if has_text else np.zeros(1, np.bool_))
    total, text, n_text = _step_sums(before.detach().cpu().float().contiguous().numpy(),
                                     after.detach().cpu().float().contiguous().numpy(), flags, has_text)
    log["position_path"] += total / n / float(extent)  # the mean step, in extents
    log["steps"] += 1
    if n_text > 0:
        log["text_position_path"] += text / n_text / float(extent)
        log["text_steps"] += 1


def motion_record(log: dict) -> dict:
    """The log's entries for a checkpoint's record (result.json `extra`)."""
    out = {"position_path": log["position_path"], "count_changes": int(log["count_changes"]),
           "motion_steps": int(log["steps"])}
    if log["text_steps"]:
        out["text_position_path"] = log["text_position_path"]
    if log["from_step"]:
        out["motion_from_step"] = int(log["from_step"])  # the log covers only the steps after this one
    return out
