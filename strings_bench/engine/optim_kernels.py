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
