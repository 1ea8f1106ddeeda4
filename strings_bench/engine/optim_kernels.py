"""A fused Adam update for float32 CPU tensors: two numba passes and torch's sqrt over (param, grad,
exp_avg, exp_avg_sq) instead of the nine element-wise torch passes (and three temporaries) of
`GaussianAdam`'s reference path.

The arithmetic is the torch path's, operation for operation and in float32, so the result is the
same bit for bit (tests/test_engine.py checks it against the torch path and against
torch.optim.Adam):

    m <- fma(g, 1 - b1, m * b1)              m.mul_(b1).add_(g, alpha=1 - b1)
    v <- fma((1 - b2) * g, g, v * b2)       v.mul_(b2).addcmul_(g, g, value=1 - b2)
    d <- sqrt(v) / sqrt(bc2) + eps           (v.sqrt() / math.sqrt(bc2)).add_(eps)
    u <- m / d  [* row_scale[row]]           m / denom, update.mul_(scale)
    p <- fma(u, -lr / bc1, p)                p.add_(update, alpha=-lr / bc1)

torch's CPU `add` with an alpha is a fused multiply-add (ATen's vectorised `fmadd`), and so is its
scalar remainder loop on this build; `fma32` below is LLVM's fma intrinsic, so the rounding is the
same. Scalars are rounded to float32 first, as torch does with a Python scalar on a float32 tensor.
The square root stays torch's own (`torch.sqrt(v, out=...)`, between the two passes): torch's float32
sqrt on this build is not the correctly rounded one (about 20 % of values differ from numpy's by an
ulp), so a numba sqrt would change the result.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from numba import njit, prange
from numba.core import types
from numba.extending import intrinsic

CHUNK = 1 << 14  # elements per parallel work item


@intrinsic
def fma32(typingctx, a, b, c):
    """a * b + c with one rounding (float32)."""
    if not (a == types.float32 and b == types.float32 and c == types.float32):
        return None
    sig = types.float32(types.float32, types.float32, types.float32)

    def codegen(context, builder, signature, args):
        return builder.fma(*args)

    return sig, codegen


@njit(parallel=True, cache=True)
def adam_moments(g, m, v, b1, a1, b2, a2):
    """m and v in place (flat float32 arrays); a1 = 1 - b1, a2 = 1 - b2 as float32."""
    n = g.shape[0]
    for ch in prange((n + CHUNK - 1) // CHUNK):
        for i in range(ch * CHUNK, min(n, (ch + 1) * CHUNK)):
            gi = g[i]
            m[i] = fma32(gi, a1, m[i] * b1)
            v[i] = fma32(a2 * gi, gi, v[i] * b2)


@njit(parallel=True, cache=True)
def adam_param(p, m, sqrt_v, scale, row_len, s2, eps, alpha):
    """p in place: p <- fma(m / (sqrt_v / s2 + eps) [* scale[i // row_len]], alpha, p). scale is used
    when its length is > 0. s2 = sqrt(bias correction 2), alpha = -lr / bias correction 1 (float32)."""
    n = p.shape[0]
    use_scale = scale.shape[0] > 0
    for ch in prange((n + CHUNK - 1) // CHUNK):
        for i in range(ch * CHUNK, min(n, (ch + 1) * CHUNK)):
            u = m[i] / (sqrt_v[i] / s2 + eps)
            if use_scale:
                u = u * scale[i // row_len]
            p[i] = fma32(u, alpha, p[i])


def f32(x: float) -> np.float32:
    return np.float32(x)


F32_MAX = float(np.finfo(np.float32).max)
SUM_CHUNK = 1 << 16


@njit(parallel=True, cache=True, fastmath={"reassoc", "nsz"})
def _total_f32(x):
    """Sum of a float32 vector in float64: chunks of SUM_CHUNK in parallel (vectorised inside), then the
    chunk sums in order. The chunking is by index, not by thread: the result is the same at any
    thread count."""
    n = x.shape[0]
    nc = (n + SUM_CHUNK - 1) // SUM_CHUNK
    part = np.zeros(nc)
    for c in prange(nc):
        s = 0.0
        for i in range(c * SUM_CHUNK, min(n, (c + 1) * SUM_CHUNK)):
            s += x[i]
        part[c] = s
    tot = 0.0
    for c in range(nc):
        tot += part[c]
    return tot


def sums_finite(tensors) -> bool:
    """The trainer's finite check: True when every tensor's sum is finite and at most float32's
    largest value in magnitude, i.e. no element is NaN or infinite and the total has not diverged
    past 3.4e38 (what the float32 torch sum it replaces tested). float32 CPU tensors are summed by
    `_total_f32` on the numba threads (one pass at memory speed, instead of a one-thread torch sum);
    others by torch."""
    for t in tensors:
        t = t.detach()
        if t.dtype == torch.float32 and t.device.type == "cpu" and t.is_contiguous():
            tot = _total_f32(t.reshape(-1).numpy())
            if not abs(tot) <= F32_MAX:
                return False
        elif not bool(torch.isfinite(t.sum())):
            return False
    return True
