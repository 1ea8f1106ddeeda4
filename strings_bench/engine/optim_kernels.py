"""A fused Adam update for float32 CPU tensors: one numba pass (or two around torch's sqrt) over (param,
grad, exp_avg, exp_avg_sq) instead of the nine element-wise torch passes (and three temporaries) of
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
The square root must be torch's own: torch's float32 sqrt on the CPU is MKL's vector square root
`vsSqrt` (ATen's VML path), which is not the correctly rounded one (about 20 % of values differ from
numpy's by an ulp), so a numba sqrt would change the result. Where libtorch exports `vsSqrt` and it
gives torch.sqrt's bits on a probe (`vs_sqrt_available`, checked once per process), `adam_fused` calls
it on each chunk of 4 096 values between the moments and the update, and the whole step is one pass
over memory (7 arrays' worth of bytes instead of 11). Elsewhere the step is two numba passes with
torch.sqrt between them (`adam_moments`, `adam_param`). Both give the same bits.
"""

from __future__ import annotations

import ctypes
import math
import os

import numpy as np
import torch
from llvmlite import binding as llvm_binding
from llvmlite import ir as llvm_ir
from numba import njit, prange
from numba.core import cgutils, types
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
def _update(p, m, sq, scale, first, row_len, s2, eps, alpha):
    """p[j] <- fma(m[j] / (sq[j] / s2 + eps) [* scale[(first + j) // row_len]], alpha, p[j])."""
    if scale.shape[0] > 0:
        for j in range(p.shape[0]):
            u = m[j] / (sq[j] / s2 + eps)
            p[j] = fma32(u * scale[(first + j) // row_len], alpha, p[j])
    else:
        for j in range(p.shape[0]):
            p[j] = fma32(m[j] / (sq[j] / s2 + eps), alpha, p[j])


@njit(parallel=True, cache=True)
def adam_moments(g, m, v, b1, a1, b2, a2):
    """m and v in place (flat float32 arrays); a1 = 1 - b1, a2 = 1 - b2 as float32."""
    n = g.shape[0]
    for ch in prange((n + CHUNK - 1) // CHUNK):
        lo = ch * CHUNK
        hi = min(n, lo + CHUNK)
        _moments(g[lo:hi], m[lo:hi], v[lo:hi], b1, a1, b2, a2)


@njit(parallel=True, cache=True)
def adam_param(p, m, sqrt_v, scale, row_len, s2, eps, alpha):
    """p in place: p <- fma(m / (sqrt_v / s2 + eps) [* scale[i // row_len]], alpha, p). scale is used
    when its length is > 0. s2 = sqrt(bias correction 2), alpha = -lr / bias correction 1 (float32)."""
    n = p.shape[0]
    for ch in prange((n + CHUNK - 1) // CHUNK):
        lo = ch * CHUNK
        hi = min(n, lo + CHUNK)
        _update(p[lo:hi], m[lo:hi], sqrt_v[lo:hi], scale, lo, row_len, s2, eps, alpha)


# ---- one pass with MKL's square root ------------------------------------------------------------
VS_SQRT_SYMBOL = "strings_bench_vsSqrt"  # the name the compiled kernel calls; bound to libtorch's vsSqrt
# MKL's per-thread thread count: called from a numba worker, vsSqrt would otherwise start its own team of
# OpenMP threads on every chunk (measured: the one-pass step 58 ms against 35 ms at 330k Gaussians)
MKL_THREADS_SYMBOL = "strings_bench_mkl_set_num_threads_local"
FUSED_CHUNK = 1 << 12  # values per chunk: the chunk's p, g, m, v and square roots stay in the core's cache
_vs_sqrt_state: list = []  # [bool] once checked


def _probe_values() -> np.ndarray:
    """Square-root inputs of every kind an Adam step meets: second moments from 1e-38 to 1e3, exact zeros,
    subnormals, and the special values."""
    rng = np.random.default_rng(0)
    parts = [rng.random(20000, dtype=np.float32) * np.float32(10.0) ** rng.integers(-38, 4, 20000).astype(np.float32),
             np.zeros(300, np.float32), rng.random(300, dtype=np.float32) * np.float32(1e-38),
             np.array([np.inf, np.nan, -0.0, 1e-45, 3.4e38, 1.0, 2.0, -1.0], np.float32)]
    x = np.concatenate(parts).astype(np.float32)
    rng.shuffle(x)
    return x


def vs_sqrt_available() -> bool:
    """Whether the one-pass step applies: libtorch exports MKL's `vsSqrt`, and on a probe cut into uneven
    chunks it gives torch.sqrt's bits (so torch's sqrt is that function on this build and CPU). Checked once
    per process; the symbol is then bound for the compiled kernel."""
    if _vs_sqrt_state:
        return _vs_sqrt_state[0]
    ok = False
    try:
        lib = ctypes.CDLL(os.path.join(os.path.dirname(torch.__file__), "lib", "libtorch_cpu.so"))
        fn = lib.vsSqrt
        threads_local = lib.MKL_Set_Num_Threads_Local  # the C function (the lower-case symbol is the Fortran one)
        fn.restype = None
        fn.argtypes = [ctypes.c_int, ctypes.c_void_p, ctypes.c_void_p]
        x = _probe_values()
        out = np.empty_like(x)
        pos, sizes = 0, (7, 4096, 1, 333, 5000)
        while pos < x.shape[0]:
            n = min(sizes[pos % len(sizes)], x.shape[0] - pos)
            fn(n, x[pos:].ctypes.data, out[pos:].ctypes.data)
            pos += n
        ok = bool(np.array_equal(out.view(np.int32), torch.sqrt(torch.from_numpy(x)).numpy().view(np.int32)))
        if ok:
            llvm_binding.add_symbol(VS_SQRT_SYMBOL, ctypes.cast(fn, ctypes.c_void_p).value)
            llvm_binding.add_symbol(MKL_THREADS_SYMBOL, ctypes.cast(threads_local, ctypes.c_void_p).value)
    except (OSError, AttributeError):
        ok = False
    _vs_sqrt_state.append(ok)
    return ok


@intrinsic
def _vs_sqrt(typingctx, n, src, start, dst):
    """dst[:n] = vsSqrt(src[start:start + n]) (float32 1-D arrays; n < 2^31), on the calling thread alone (MKL's
    thread count of this thread set to 1 for the call and restored after it)."""
    if not (isinstance(src, types.Array) and isinstance(dst, types.Array) and src.dtype == types.float32
            and dst.dtype == types.float32):
        return None
    sig = types.void(types.int64, src, types.int64, dst)

    def codegen(context, builder, signature, args):
        n_, src_, start_, dst_ = args
        fp = llvm_ir.FloatType().as_pointer()
        fnty = llvm_ir.FunctionType(llvm_ir.VoidType(), [llvm_ir.IntType(32), fp, fp])
        fn = cgutils.get_or_insert_function(builder.module, fnty, VS_SQRT_SYMBOL)
        a = context.make_array(signature.args[1])(context, builder, src_)
        r = context.make_array(signature.args[3])(context, builder, dst_)
        i32 = llvm_ir.IntType(32)
        set_local = cgutils.get_or_insert_function(builder.module, llvm_ir.FunctionType(i32, [i32]), MKL_THREADS_SYMBOL)
        before = builder.call(set_local, [llvm_ir.Constant(i32, 1)])
        builder.call(fn, [builder.trunc(n_, i32), builder.gep(a.data, [start_]), r.data])
        builder.call(set_local, [before])
        return context.get_dummy_value()

    return sig, codegen


@njit(parallel=True, cache=True)
def adam_fused(p, g, m, v, scale, row_len, b1, a1, b2, a2, s2, eps, alpha):
    """`adam_moments` then `adam_param` with the square roots from `vsSqrt`, chunk by chunk: the same
    operations on every value, in one pass over memory. Call only where `vs_sqrt_available()`."""
    n = p.shape[0]
    for ch in prange((n + FUSED_CHUNK - 1) // FUSED_CHUNK):
        lo = ch * FUSED_CHUNK
        hi = min(n, lo + FUSED_CHUNK)
        sq = np.empty(hi - lo, np.float32)
        _moments(g[lo:hi], m[lo:hi], v[lo:hi], b1, a1, b2, a2)
        _vs_sqrt(hi - lo, v, lo, sq)
        _update(p[lo:hi], m[lo:hi], sq, scale, lo, row_len, s2, eps, alpha)


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
