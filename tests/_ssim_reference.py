"""An independent SSIM for tests: the zero-padded ("same") 11x11 Gaussian-window map written as plain
float64 loops over windows, from the formula (Wang et al. 2004; the 3DGS training/evaluation convention).
Slow: for small images only."""

import numpy as np


def brute_ssim_same(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """SSIM map (H, W, C) of two (H, W, C) float images in [0, 1], window zero-padded at the border."""
    x = np.arange(11) - 5
    g = np.exp(-x ** 2 / (2 * 1.5 ** 2))
    w = np.outer(g, g) / np.outer(g, g).sum()
    c1, c2 = 0.01 ** 2, 0.03 ** 2
    H, W, C = a.shape
    pa = np.pad(np.asarray(a, np.float64), ((5, 5), (5, 5), (0, 0)))
    pb = np.pad(np.asarray(b, np.float64), ((5, 5), (5, 5), (0, 0)))
    out = np.zeros((H, W, C))
    for i in range(H):
        for j in range(W):
            wa, wb = pa[i:i + 11, j:j + 11], pb[i:i + 11, j:j + 11]
            for c in range(C):
                mx, my = (w * wa[..., c]).sum(), (w * wb[..., c]).sum()
                sxx = (w * wa[..., c] ** 2).sum() - mx ** 2
                syy = (w * wb[..., c] ** 2).sum() - my ** 2
                sxy = (w * wa[..., c] * wb[..., c]).sum() - mx * my
                out[i, j, c] = ((2 * mx * my + c1) * (2 * sxy + c2)) / ((mx ** 2 + my ** 2 + c1) * (sxx + syy + c2))
    return out
