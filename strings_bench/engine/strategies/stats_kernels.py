"""The densification statistics of one step in one numba pass, with the same bits as the torch ops they replace.

`DefaultStrategy._update_state` adds, for each Gaussian with radius > 0, the norm of its screen-space gradient in
NDC units to `grad2d`, one to `count`, and takes the running maximum of its radius in `max_radii`. In torch that is
a dozen element-wise passes over N at one thread (clone, two scalings, norm, where, add, ...); here it is one pass.
Each operation is torch's, in float32, in torch's order:

    x = g0 * f32(W / 2 * n_cameras);  y = g1 * f32(H / 2 * n_cameras)     g[..., 0] *= ...  (scalar rounded to float32)
    norm = sqrt(fma(y, y, x * x))                                         g.norm(dim=-1) of an (N, 2) float32 tensor
    grad2d += norm if radius > 0 else 0                                  grad2d.add_(torch.where(visible, norm, 0))
    count += 1 if radius > 0 else 0                                      count.add_(visible.float())
    max_radii = maximum(max_radii, float(radius) if radius > 0 else 0)   torch.maximum (NaN propagates)

torch's float32 norm over a last dimension of 2 is `sqrt(fma(y, y, x * x))` on its AVX2 kernels (the set
strings_bench pins, core/cpus.py); tests/engine/test_engine.py holds this kernel to torch's ops bit for bit on
gradients from 1e-20 to 1e18 (squares that underflow and overflow included). `fma32` is LLVM's fma (one rounding)
and `np.sqrt` the correctly rounded square root, as torch's vector code uses.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from strings_bench.engine.optim_kernels import fma32

CHUNK = 1 << 14  # Gaussians per parallel work item


@njit(cache=True, inline="always")
def _chunk(g, radii, sx, sy, grad2d, count, max_radii):
    zero = np.float32(0.0)
    one = np.float32(1.0)
    for i in range(radii.shape[0]):
        x = g[i, 0] * sx
        y = g[i, 1] * sy
        norm = np.sqrt(fma32(y, y, x * x))
        visible = radii[i] > 0
        grad2d[i] = grad2d[i] + (norm if visible else zero)
        count[i] = count[i] + (one if visible else zero)
        r = np.float32(radii[i]) if visible else zero
        m = max_radii[i]
        if not (m != m) and r > m:  # torch.maximum: a NaN stays; otherwise the larger
            max_radii[i] = r


@njit(parallel=True, cache=True)
def accumulate_screen_stats(grad, radii, sx, sy, grad2d, count, max_radii):
    """grad (N, 2) float32 screen-space gradient in pixels, radii (N,) int32, sx / sy the float32 NDC factors;
    grad2d, count, max_radii (N,) float32, updated in place. Chunks by index: the same at any thread count."""
    n = radii.shape[0]
    for c in prange((n + CHUNK - 1) // CHUNK):
        lo = c * CHUNK
        hi = min(n, lo + CHUNK)
        _chunk(grad[lo:hi], radii[lo:hi], sx, sy, grad2d[lo:hi], count[lo:hi], max_radii[lo:hi])
