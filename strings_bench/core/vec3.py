"""3-vector and 3x3-matrix arithmetic in a written order, for everything that builds a scene.

numpy's `@`, `dot`, `einsum` and `linalg.norm` of a vector hand the sums to BLAS (OpenBLAS in numpy's wheels),
whose kernels are chosen by the CPU model (or OPENBLAS_CORETYPE) and add, or fuse a multiply into an add, in
another order on each: the same synthetic room gave other pixels and points on an AVX-512 CPU than on an AVX2
one. Here every result is products and sums of numpy's element-wise operations in the order written, which
IEEE 754 rounds the same way on every CPU. Arrays broadcast like numpy's; the last axis holds the 3
components (rows of a matrix for `matvec`, columns for `vecmat`).
"""

from __future__ import annotations

import numpy as np


def dot(a, b) -> np.ndarray:
    """a . b over the last axis: (a0 b0 + a1 b1) + a2 b2; shapes (..., 3), (..., 3) -> (...)."""
    a, b = np.asarray(a), np.asarray(b)
    return a[..., 0] * b[..., 0] + a[..., 1] * b[..., 1] + a[..., 2] * b[..., 2]


def norm(a) -> np.ndarray:
    """Euclidean length over the last axis: sqrt(dot(a, a)) (the square root is correctly rounded)."""
    return np.sqrt(dot(a, a))


def unit(a) -> np.ndarray:
    """a / norm(a) over the last axis."""
    a = np.asarray(a, np.float64)
    return a / norm(a)[..., None]


def matvec(m, x) -> np.ndarray:
    """m x for a (3, 3) matrix and points x (..., 3) -> (..., 3): component i is dot(row i of m, x)."""
    m = np.asarray(m)
    return np.stack([dot(m[i], x) for i in range(3)], axis=-1)


def vecmat(x, m) -> np.ndarray:
    """x m (the row vectors x (..., 3) times a (3, 3) matrix) -> (..., 3): component j is dot(x, column j)."""
    m = np.asarray(m)
    return np.stack([dot(x, m[:, j]) for j in range(3)], axis=-1)


def matmul(a, b) -> np.ndarray:
    """The (3, 3) product a b: entry (i, j) is dot(row i of a, column j of b)."""
    a, b = np.asarray(a), np.asarray(b)
    return np.stack([vecmat(a[i], b) for i in range(3)], axis=0)


def norm_2d(a) -> np.ndarray:
    """Euclidean length of 2-vectors (pixel offsets) over the last axis: sqrt(a0 a0 + a1 a1)."""
    a = np.asarray(a)
    return np.sqrt(a[..., 0] * a[..., 0] + a[..., 1] * a[..., 1])
