"""The 3DGS loss on the CPU in one numba pass each way: (1 - lambda) L1 + lambda (1 - SSIM) of a float32
(H, W, C) render against its target, and its gradient with respect to the render.

The same loss as `losses.gs_loss` through torch (SSIM of `eval.image_quality`: an 11x11 Gaussian
window, sigma 1.5, zero padding, C1 = 0.01^2, C2 = 0.03^2; Kerbl et al. 2023, section 7.1 and their
release's utils/loss_utils.py), computed without torch's temporaries and convolutions:

- the five local statistics (means of x, y, x^2, y^2, xy) by the separable window, rows then columns,
  each tap in order, in float32 as torch's float32 path computes them;
- the SSIM map and |x - y| summed per image row in float64, the rows then added in order;
- backward: with m = A1 A2 / (B1 B2), A1 = 2 mu_x mu_y + C1, A2 = 2 s_xy + C2, B1 = mu_x^2 + mu_y^2 + C1,
  B2 = s_xx + s_yy + C2 (s_xx = E[x^2] - mu_x^2, s_xy = E[xy] - mu_x mu_y), the map's derivatives with
  respect to the statistics are
      dm/dmu_x = 2 mu_y (A2 - A1) / (B1 B2) - 2 mu_x m (1 / B1 - 1 / B2),
      dm/dE[x^2] = -m / B2,   dm/dE[xy] = 2 A1 / (B1 B2),
  and dL/dx = W * (w dm/dmu_x) + 2 x W * (w dm/dE[x^2]) + y W * (w dm/dE[xy]) + (1 - lambda) sign(x - y) / n,
  W * the same zero-padded window (it is symmetric, so the filter is its own adjoint), w = -lambda / n.

Every sum is in an order the code writes (no fastmath flags), so the result is the same at any thread
count and vector width. tests/engine/test_losses.py holds it to the float64 torch reference.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from strings_bench.eval.image_quality import SSIM_C1, SSIM_C2, SSIM_SIGMA, SSIM_WINDOW


def gaussian_window(size: int = SSIM_WINDOW, sigma: float = SSIM_SIGMA) -> np.ndarray:
    """The normalised 1-D Gaussian of the SSIM window (float32), as `eval.image_quality` builds it."""
    x = np.arange(size, dtype=np.float64) - (size - 1) / 2
    g = np.exp(-(x ** 2) / (2 * sigma ** 2))
    return (g / g.sum()).astype(np.float32)


@njit(cache=True, inline="always")
def _filter_rows(src, dst, g, H, W):
    """dst[c] = sum_k g[k] src[c + k - R] over the taps inside the row (zero padding), k ascending: one
    pass over the row per tap, so that the columns run on the vector units and each output still adds
    its taps in the same order. Each tap runs over two slices indexed from 0: an index numba cannot prove
    non-negative (c + off) gets its wraparound check, which keeps the loop off the vector units (12x slower)."""
    R = g.shape[0] // 2
    for c in range(W):
        dst[c] = 0.0
    for k in range(g.shape[0]):
        gk = g[k]
        off = k - R
        lo = max(0, -off)
        hi = min(W, W - off)
        d = dst[lo:hi]
        s = src[lo + off:hi + off]
        for i in range(hi - lo):
            d[i] += gk * s[i]


@njit(parallel=True, cache=True)
def _stats(x, y, g, out):
    """out (C, 5, H, W) float32: the window means of x, y, x^2, y^2, xy per channel; x, y (H, W, C)."""
    H, W, C = x.shape
    R = g.shape[0] // 2
    K = g.shape[0]
    tmp = np.empty((C, 5, H, W), np.float32)
    # rows: per image row, each channel's five products, then the row filter
    for r in prange(H):
        row = np.empty((5, W), np.float32)
        for ch in range(C):
            for c in range(W):
                a = x[r, c, ch]
                b = y[r, c, ch]
                row[0, c] = a
                row[1, c] = b
                row[2, c] = a * a
                row[3, c] = b * b
                row[4, c] = a * b
            for s in range(5):
                _filter_rows(row[s], tmp[ch, s, r], g, H, W)
    # columns: per image row, each (channel, statistic) row summed over the taps in order
    for r in prange(H):
        for ch in range(C):
            for s in range(5):
                dst = out[ch, s, r]
                for c in range(W):
                    dst[c] = 0.0
                for k in range(K):
                    rr = r + k - R
                    if 0 <= rr < H:
                        gk = g[k]
                        src = tmp[ch, s, rr]
                        for c in range(W):
                            dst[c] += gk * src[c]


@njit(parallel=True, cache=True)
def _map_terms(x, y, st, c1, c2, lam, want_grad, partial, row_sums):
    """Per (channel, row): the SSIM map's and |x - y|'s row sums (float64) into row_sums (C, H, 2); with
    want_grad, the map's derivatives by the statistics (dm/dmu_x, dm/dE[x^2], dm/dE[xy]) into partial
    (C, 3, H, W)."""
    H, W, C = x.shape
    for job in prange(C * H):
        ch = job // H
        r = job - ch * H
        s_map = 0.0
        s_l1 = 0.0
        for c in range(W):
            mx = st[ch, 0, r, c]
            my = st[ch, 1, r, c]
            sxx = st[ch, 2, r, c] - mx * mx
            syy = st[ch, 3, r, c] - my * my
            sxy = st[ch, 4, r, c] - mx * my
            a1 = np.float32(2.0) * mx * my + c1
            a2 = np.float32(2.0) * sxy + c2
            b1 = mx * mx + my * my + c1
            b2 = sxx + syy + c2
            m = (a1 * a2) / (b1 * b2)
            s_map += m
            s_l1 += abs(x[r, c, ch] - y[r, c, ch])
            if want_grad:
                d = b1 * b2
                partial[ch, 0, r, c] = (np.float32(2.0) * my * (a2 - a1)) / d \
                    - np.float32(2.0) * mx * m * (np.float32(1.0) / b1 - np.float32(1.0) / b2)
                partial[ch, 1, r, c] = -m / b2
                partial[ch, 2, r, c] = (np.float32(2.0) * a1) / d
        row_sums[ch, r, 0] = s_map
        row_sums[ch, r, 1] = s_l1


@njit(parallel=True, cache=True)
def _grad(x, y, partial, g, w_ssim, w_l1, out):
    """out (H, W, C) float32: dL/dx from the map's partial derivatives (filtered by the window, rows then
    columns) and the L1 term."""
    H, W, C = x.shape
    R = g.shape[0] // 2
    K = g.shape[0]
    tmp = np.empty((C, 3, H, W), np.float32)
    for job in prange(C * 3 * H):
        ch = job // (3 * H)
        rest = job - ch * 3 * H
        s = rest // H
        r = rest - s * H
        _filter_rows(partial[ch, s, r], tmp[ch, s, r], g, H, W)
    for job in prange(C * H):
        ch = job // H
        r = job - ch * H
        f = np.zeros((3, W), np.float32)
        for k in range(K):
            rr = r + k - R
            if 0 <= rr < H:
                gk = g[k]
                for s in range(3):
                    src = tmp[ch, s, rr]
                    for c in range(W):
                        f[s, c] += gk * src[c]
        for c in range(W):
            xv = x[r, c, ch]
            yv = y[r, c, ch]
            d = xv - yv
            sign = np.float32(1.0) if d > 0 else (np.float32(-1.0) if d < 0 else np.float32(0.0))
            out[r, c, ch] = w_ssim * (f[0, c] + np.float32(2.0) * xv * f[1, c] + yv * f[2, c]) + w_l1 * sign


@njit(cache=True)
def _ordered_sums(row_sums):
    """The (map, L1) sums of row_sums (C, H, 2) float64: rows in order, then channels (a fixed order)."""
    a = 0.0
    b = 0.0
    for ch in range(row_sums.shape[0]):
        for r in range(row_sums.shape[1]):
            a += row_sums[ch, r, 0]
            b += row_sums[ch, r, 1]
    return a, b


def gs_loss_forward(x: np.ndarray, y: np.ndarray, lam: float, want_grad: bool):
    """(loss as a Python float, (L1, SSIM) means, the state `gs_loss_backward` needs or None) for float32
    (H, W, C) C-contiguous arrays."""
    H, W, C = x.shape
    g = _WINDOW
    st = np.empty((C, 5, H, W), np.float32)
    _stats(x, y, g, st)
    partial = np.empty((C, 3, H, W) if want_grad else (1, 3, 1, 1), np.float32)
    row_sums = np.empty((C, H, 2), np.float64)
    _map_terms(x, y, st, np.float32(SSIM_C1), np.float32(SSIM_C2), np.float32(lam), want_grad, partial, row_sums)
    n = H * W * C
    map_sum, l1_sum = _ordered_sums(row_sums)
    ssim_mean = map_sum / n
    l1_mean = l1_sum / n
    loss = (1.0 - lam) * l1_mean + lam * (1.0 - ssim_mean)
    return loss, (l1_mean, ssim_mean), (partial if want_grad else None)


def gs_loss_backward(x: np.ndarray, y: np.ndarray, partial: np.ndarray, lam: float, grad_out: float) -> np.ndarray:
    """dL/dx (H, W, C) float32, scaled by the loss's incoming gradient `grad_out`."""
    H, W, C = x.shape
    n = H * W * C
    out = np.empty_like(x)
    _grad(x, y, partial, _WINDOW, np.float32(-lam * grad_out / n), np.float32((1.0 - lam) * grad_out / n), out)
    return out


_WINDOW = gaussian_window()
assert math.isclose(float(_WINDOW.sum()), 1.0, rel_tol=1e-6)
