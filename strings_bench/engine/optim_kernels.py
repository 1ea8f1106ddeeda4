"""A fused Adam update for float32 CPU tensors: one numba pass over (param, grad, exp_avg, exp_avg_sq)
instead of the nine element-wise torch passes (and three temporaries) of `GaussianAdam`'s reference path.

The arithmetic is the reference path's, operation for operation and in float32, so the result is the
same bit for bit (tests/engine/test_engine.py checks it against that path and against torch.optim.Adam):

    m <- fma(g, 1 - b1, m * b1)              m.mul_(b1).add_(g, alpha=1 - b1)
    v <- fma((1 - b2) * g, g, v * b2)       v.mul_(b2).addcmul_(g, g, value=1 - b2)
    d <- sqrt(v) / sqrt(bc2) + eps           (exact_sqrt(v) / math.sqrt(bc2)).add_(eps)
    u <- m / d  [* row_scale[row]]           m / denom, update.mul_(scale)
    p <- fma(u, -lr / bc1, p)                p.add_(update, alpha=-lr / bc1)

torch's CPU `add` with an alpha is a fused multiply-add (ATen's vectorised `fmadd`), and so is its
scalar remainder loop on this build; `fma32` below is LLVM's fma intrinsic, so the rounding is the
same. Scalars are rounded to float32 first, as torch does with a Python scalar on a float32 tensor.
The square root is the correctly rounded one (IEEE 754: the processor's own square-root instruction, the
same bits on every CPU), not torch's: torch's float32 sqrt on the CPU is MKL's `vsSqrt`, whose rounding
follows MKL's code branch, which MKL picks by the CPU's vendor and instruction set (on an Intel Xeon its
AVX2 branch rounds correctly, its COMPATIBLE and AVX-512 branches do not, and an AMD EPYC's differs again;
docs/reproducibility.md, "Across machines"). With torch's sqrt, Adam's first step already differed between
machines.
"""

from __future__ import annotations

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


# The element loops run over slices indexed from 0 (numba then needs no negative-index wraparound, and LLVM
# puts them on the vector units); vector and scalar code give the same bits here (no reassociation, the fma
# explicit, IEEE division either way).
@njit(cache=True, inline="always")
def _moments(g, m, v, b1, a1, b2, a2):
    for j in range(g.shape[0]):
        gj = g[j]
        m[j] = fma32(gj, a1, m[j] * b1)
        v[j] = fma32(a2 * gj, gj, v[j] * b2)


@njit(cache=True, inline="always")
def _update(p, m, v, scale, first, row_len, s2, eps, alpha):
    """p[j] <- fma(m[j] / (sqrt(v[j]) / s2 + eps) [* scale[(first + j) // row_len]], alpha, p[j]); np.sqrt is LLVM's
    sqrt intrinsic, the processor's correctly rounded square root."""
    if scale.shape[0] > 0:
        for j in range(p.shape[0]):
            u = m[j] / (np.sqrt(v[j]) / s2 + eps)
            p[j] = fma32(u * scale[(first + j) // row_len], alpha, p[j])
    else:
        for j in range(p.shape[0]):
            p[j] = fma32(m[j] / (np.sqrt(v[j]) / s2 + eps), alpha, p[j])


@njit(parallel=True, cache=True)
def adam_moments(g, m, v, b1, a1, b2, a2):
    """m and v in place (flat float32 arrays); a1 = 1 - b1, a2 = 1 - b2 as float32."""
    n = g.shape[0]
    for ch in prange((n + CHUNK - 1) // CHUNK):
        lo = ch * CHUNK
        hi = min(n, lo + CHUNK)
        _moments(g[lo:hi], m[lo:hi], v[lo:hi], b1, a1, b2, a2)


FUSED_CHUNK = 1 << 12  # values per work item: its p, g, m and v stay in the core's cache between the two loops


@njit(parallel=True, cache=True)
def adam_step(p, g, m, v, scale, row_len, b1, a1, b2, a2, s2, eps, alpha):
    """The whole update, chunk by chunk: the moments (`_moments`), then p <- fma(m / (sqrt(v) / s2 + eps)
    [* scale[i // row_len]], alpha, p) with the correctly rounded sqrt. scale is used when its length is > 0;
    a1 = 1 - b1, a2 = 1 - b2, s2 = sqrt(bias correction 2), alpha = -lr / bias correction 1 (float32)."""
    n = p.shape[0]
    for ch in prange((n + FUSED_CHUNK - 1) // FUSED_CHUNK):
        lo = ch * FUSED_CHUNK
        hi = min(n, lo + FUSED_CHUNK)
        _moments(g[lo:hi], m[lo:hi], v[lo:hi], b1, a1, b2, a2)
        _update(p[lo:hi], m[lo:hi], v[lo:hi], scale, lo, row_len, s2, eps, alpha)


def f32(x: float) -> np.float32:
    return np.float32(x)


F32_MAX = float(np.finfo(np.float32).max)
SUM_CHUNK = 1 << 16


@njit(parallel=True, cache=True, fastmath={"reassoc", "nsz"})
def _total_f32(x):
    """Sum of a float32 vector in float64: chunks of SUM_CHUNK in parallel (vectorised inside), then the
    chunk sums in order. The chunking is by index, not by thread: the result is the same at any
    thread count (not at any vector width: `reassoc` lets LLVM sum a chunk in one partial sum per lane, which
    is harmless here, since only whether the sum is finite and in float32's range is used). Each chunk is a
    slice read from index 0: with `x[c * SUM_CHUNK + i]` numba cannot
    prove the index non-negative, every read carries the negative-index wraparound and the loop
    stays scalar (10x slower)."""
    n = x.shape[0]
    nc = (n + SUM_CHUNK - 1) // SUM_CHUNK
    part = np.zeros(nc)
    for c in prange(nc):
        xs = x[c * SUM_CHUNK: min(n, (c + 1) * SUM_CHUNK)]
        s = 0.0
        for i in range(xs.shape[0]):
            s += xs[i]
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
