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

import torch


def new_motion_log(from_step: int = 0) -> dict:
    """An empty log; `from_step` > 0 when it starts on a state saved before logs existed."""
    return {"position_path": 0.0, "text_position_path": 0.0, "steps": 0, "text_steps": 0, "count_changes": 0,
            "from_step": int(from_step)}


@torch.no_grad()
def note_motion(log: dict, before: torch.Tensor, after: torch.Tensor, extent: float,
                is_text: torch.Tensor | None = None) -> None:
    """Add one step's position updates (means (N, 3) before and after Adam) to `log`."""
    if before.shape != after.shape or len(after) == 0:
        return
    step = (after.double() - before.double()).norm(dim=1) / float(extent)  # (N,) in extents
    log["position_path"] += float(step.mean())
    log["steps"] += 1
    if is_text is not None and is_text.shape[0] == step.shape[0] and bool(is_text.any()):
        log["text_position_path"] += float(step[is_text].mean())
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
