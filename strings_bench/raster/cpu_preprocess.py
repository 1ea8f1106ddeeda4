"""Numba per-Gaussian preprocessing of the CPU backend, with its hand-written backward.

Forward, per Gaussian (same rules as `projection.py`, which is the torch-autograd version used as
an independent check in the tests): camera transform, culling, means2d, EWA 2D covariance with the
clamped Jacobian, dilation or mip filter (+ opacity compensation), conic, radius, pixel box,
sigmoid opacity and, for a Gaussian on the image (radius > 0; 0 for the others), the SH colour seen from the
camera centre. All arithmetic is float64: inputs may be float32 or float64 arrays and every value read is
converted to float64 first (exact; with `np.float64(x)`: numba types `float(x)` of a float32 as float32), so a
float32 parameter gives the same result as its float64 copy did; gradient outputs take the inputs' dtype and are
rounded once, at the store.

Backward: the chain rule through the same steps, written out (conic = inverse 2D covariance:
dL/dSigma = -Q G Q; quaternion -> rotation derivatives; clamped-Jacobian and normalisation cases
as torch autograd treats them: clamp boundaries count as inside, a norm below 1e-12 is a constant).
Culled Gaussians get zero gradients.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from strings_bench.raster.sh import SH_C0, SH_C1, SH_C2, SH_C3

CHUNK = 256
MAX_RADIUS = float(1 << 24)
C20, C21, C22, C23, C24 = SH_C2
C30, C31, C32, C33, C34, C35, C36 = SH_C3


@njit(cache=True, inline="always")
def _sh_basis(x, y, z, deg, Y):
    Y[0] = SH_C0
    if deg >= 1:
        Y[1] = -SH_C1 * y
        Y[2] = SH_C1 * z
        Y[3] = -SH_C1 * x
    if deg >= 2:
        xx, yy, zz = x * x, y * y, z * z
        Y[4] = C20 * x * y
        Y[5] = C21 * y * z
        Y[6] = C22 * (2 * zz - xx - yy)
        Y[7] = C23 * x * z
        Y[8] = C24 * (xx - yy)
        if deg >= 3:
            Y[9] = C30 * y * (3 * xx - yy)
            Y[10] = C31 * x * y * z
            Y[11] = C32 * y * (4 * zz - xx - yy)
            Y[12] = C33 * z * (2 * zz - 3 * xx - 3 * yy)
            Y[13] = C34 * x * (4 * zz - xx - yy)
            Y[14] = C35 * z * (xx - yy)
            Y[15] = C36 * x * (xx - 3 * yy)


@njit(cache=True, inline="always")
def _sh_basis_grad(x, y, z, deg, dY):
    """dY[k, j] = d Y_k / d dir_j."""
    for k in range(dY.shape[0]):
        dY[k, 0] = 0.0
        dY[k, 1] = 0.0
        dY[k, 2] = 0.0
    if deg >= 1:
        dY[1, 1] = -SH_C1
        dY[2, 2] = SH_C1
        dY[3, 0] = -SH_C1
    if deg >= 2:
        xx, yy, zz = x * x, y * y, z * z
        dY[4, 0] = C20 * y
        dY[4, 1] = C20 * x
        dY[5, 1] = C21 * z
        dY[5, 2] = C21 * y
        dY[6, 0] = -2 * C22 * x
        dY[6, 1] = -2 * C22 * y
        dY[6, 2] = 4 * C22 * z
        dY[7, 0] = C23 * z
        dY[7, 2] = C23 * x
        dY[8, 0] = 2 * C24 * x
        dY[8, 1] = -2 * C24 * y
        if deg >= 3:
            dY[9, 0] = C30 * 6 * x * y
            dY[9, 1] = C30 * (3 * xx - 3 * yy)
            dY[10, 0] = C31 * y * z
            dY[10, 1] = C31 * x * z
            dY[10, 2] = C31 * x * y
            dY[11, 0] = C32 * -2 * x * y
            dY[11, 1] = C32 * (4 * zz - xx - 3 * yy)
            dY[11, 2] = C32 * 8 * y * z
            dY[12, 0] = C33 * -6 * x * z
            dY[12, 1] = C33 * -6 * y * z
            dY[12, 2] = C33 * (6 * zz - 3 * xx - 3 * yy)
            dY[13, 0] = C34 * (4 * zz - 3 * xx - yy)
            dY[13, 1] = C34 * -2 * x * y
            dY[13, 2] = C34 * 8 * x * z
            dY[14, 0] = C35 * 2 * x * z
            dY[14, 1] = C35 * -2 * y * z
            dY[14, 2] = C35 * (xx - yy)
            dY[15, 0] = C36 * (3 * xx - 3 * yy)
            dY[15, 1] = C36 * -6 * x * y


@njit(cache=True, inline="always")
def _quat_rot(qw, qx, qy, qz, Rq):
    n = math.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
    inv = 1.0 / max(n, 1e-12)
    w, x, y, z = qw * inv, qx * inv, qy * inv, qz * inv
    Rq[0, 0] = 1 - 2 * (y * y + z * z)
    Rq[0, 1] = 2 * (x * y - w * z)
    Rq[0, 2] = 2 * (x * z + w * y)
    Rq[1, 0] = 2 * (x * y + w * z)
    Rq[1, 1] = 1 - 2 * (x * x + z * z)
    Rq[1, 2] = 2 * (y * z - w * x)
    Rq[2, 0] = 2 * (x * z - w * y)
    Rq[2, 1] = 2 * (y * z + w * x)
    Rq[2, 2] = 1 - 2 * (x * x + y * y)
    return w, x, y, z, n


@njit(cache=True, inline="always")
def _geometry(g, means, quats, log_scales, cam, Rq, RS, M):
    """Shared forward steps up to M = J R Rq S. Returns (x, y, z, u, v, j00, j02, j11, j12, txc, tyc,
    qw, qx, qy, qz, qn, s0, s1, s2); txc/tyc = 1 if x/z (y/z) was inside its clamp range."""
    R = cam[0:9]
    fx, fy, cx, cy = cam[12], cam[13], cam[14], cam[15]
    lxn, lxp, lyn, lyp = cam[16], cam[17], cam[18], cam[19]
    mx, my, mz = np.float64(means[g, 0]), np.float64(means[g, 1]), np.float64(means[g, 2])
    x = R[0] * mx + R[1] * my + R[2] * mz + cam[9]
    y = R[3] * mx + R[4] * my + R[5] * mz + cam[10]
    z = R[6] * mx + R[7] * my + R[8] * mz + cam[11]
    u = fx * x / z + cx
    v = fy * y / z + cy
    rx, ry = x / z, y / z
    txc, tyc = 1.0, 1.0
    if rx < -lxn:
        rx, txc = -lxn, 0.0
    elif rx > lxp:
        rx, txc = lxp, 0.0
    if ry < -lyn:
        ry, tyc = -lyn, 0.0
    elif ry > lyp:
        ry, tyc = lyp, 0.0
    tx, ty = z * rx, z * ry
    j00 = fx / z
    j02 = -fx * tx / (z * z)
    j11 = fy / z
    j12 = -fy * ty / (z * z)
    qw, qx, qy, qz, qn = _quat_rot(np.float64(quats[g, 0]), np.float64(quats[g, 1]), np.float64(quats[g, 2]), np.float64(quats[g, 3]), Rq)
    s0 = math.exp(np.float64(log_scales[g, 0]))
    s1 = math.exp(np.float64(log_scales[g, 1]))
    s2 = math.exp(np.float64(log_scales[g, 2]))
    for i in range(3):
        for k in range(3):
            RS[i, k] = R[3 * i] * Rq[0, k] + R[3 * i + 1] * Rq[1, k] + R[3 * i + 2] * Rq[2, k]
        RS[i, 0] *= s0
        RS[i, 1] *= s1
        RS[i, 2] *= s2
    for k in range(3):
        M[0, k] = j00 * RS[0, k] + j02 * RS[2, k]
        M[1, k] = j11 * RS[1, k] + j12 * RS[2, k]
    return x, y, z, u, v, j00, j02, j11, j12, txc, tyc, qw, qx, qy, qz, qn, s0, s1, s2


@njit(cache=True, inline="always")
def _cov2d(M, eps):
    a = M[0, 0] * M[0, 0] + M[0, 1] * M[0, 1] + M[0, 2] * M[0, 2]
    b = M[0, 0] * M[1, 0] + M[0, 1] * M[1, 1] + M[0, 2] * M[1, 2]
    c = M[1, 0] * M[1, 0] + M[1, 1] * M[1, 1] + M[1, 2] * M[1, 2]
    m01 = M[0, 0] * M[1, 1] - M[0, 1] * M[1, 0]
    m02 = M[0, 0] * M[1, 2] - M[0, 2] * M[1, 0]
    m12 = M[0, 1] * M[1, 2] - M[0, 2] * M[1, 1]
    det_raw = m01 * m01 + m02 * m02 + m12 * m12
    det = det_raw + eps * (a + c) + eps * eps
    return a, b, c, det_raw, det


@njit(parallel=True, cache=True)
def preprocess_forward(means, quats, log_scales, opacity_logits, sh0, shN, off, deg, cam, W, H, near, far, eps, mip,
                       means2d, conics, opac, feats, radii, bbox):
    """cam: R (9), t (3), fx, fy, cx, cy, clamp limits (4), camera centre (3).
    SH coefficient k of Gaussian g: sh0[g, 0] for k = 0, shN[g, k - 1 + off] above (the model's
    sh0 / shN with off = 0, or one (N, K, 3) array passed as both with off = 1: no concatenation).
    Outputs float32 except radii / bbox (int32). feats = (r, g, b, z)."""
    N = means.shape[0]
    n_chunks = (N + CHUNK - 1) // CHUNK
    nk = (deg + 1) * (deg + 1)
    for ch in prange(n_chunks):
        Rq = np.empty((3, 3))
        RS = np.empty((3, 3))
        M = np.empty((2, 3))
        Y = np.empty(16)
        for g in range(ch * CHUNK, min(N, (ch + 1) * CHUNK)):
            radii[g] = 0
            for j in range(4):
                bbox[g, j] = 0
            z = cam[6] * np.float64(means[g, 0]) + cam[7] * np.float64(means[g, 1]) + cam[8] * np.float64(means[g, 2]) + cam[11]
            if not (z > near and z < far):
                means2d[g, 0] = 0.0
                means2d[g, 1] = 0.0
                for j in range(3):
                    conics[g, j] = 0.0
                opac[g] = 0.0
                for j in range(4):
                    feats[g, j] = 0.0
                continue
            x, y, z, u, v, j00, j02, j11, j12, txc, tyc, qw, qx, qy, qz, qn, s0, s1, s2 = _geometry(
                g, means, quats, log_scales, cam, Rq, RS, M)
            a, b, c, det_raw, det = _cov2d(M, eps)
            A, C = a + eps, c + eps
            means2d[g, 0] = u
            means2d[g, 1] = v
            conics[g, 0] = C / det
            conics[g, 1] = -b / det
            conics[g, 2] = A / det
            sig = 1.0 / (1.0 + math.exp(-np.float64(opacity_logits[g])))
            if mip:
                r = det_raw / det
                sig *= math.sqrt(max(r, 1e-12))
            opac[g] = sig
            feats[g, 3] = z
            # radius and pixel box
            mid = 0.5 * (A + C)
            lam = mid + math.sqrt(max(mid * mid - det, 0.1))
            rad = min(math.ceil(3.0 * math.sqrt(lam)), MAX_RADIUS)
            x0 = max(math.ceil(u - rad - 0.5), 0.0)
            x1 = min(math.floor(u + rad - 0.5), W - 1.0)
            y0 = max(math.ceil(v - rad - 0.5), 0.0)
            y1 = min(math.floor(v + rad - 0.5), H - 1.0)
            ok = x0 <= x1 and y0 <= y1 and rad > 0 and math.isfinite(u) and math.isfinite(v)
            ok = ok and math.isfinite(C / det) and math.isfinite(b / det) and math.isfinite(A / det)
            if not ok:  # culled: no colour (nothing blends it; the backward gives it no gradient)
                feats[g, 0] = feats[g, 1] = feats[g, 2] = 0.0
                continue
            radii[g] = int(rad)
            bbox[g, 0] = int(x0)
            bbox[g, 1] = int(x1)
            bbox[g, 2] = int(y0)
            bbox[g, 3] = int(y1)
            # colour, of the Gaussians on the image only (97k of 236k in front of the camera at 335k: 21 -> 13 ms)
            dx = np.float64(means[g, 0]) - cam[20]
            dy = np.float64(means[g, 1]) - cam[21]
            dz = np.float64(means[g, 2]) - cam[22]
            dn = max(math.sqrt(dx * dx + dy * dy + dz * dz), 1e-12)
            _sh_basis(dx / dn, dy / dn, dz / dn, deg, Y)
            for ci in range(3):
                acc = Y[0] * np.float64(sh0[g, 0, ci])
                for k in range(1, nk):
                    acc += Y[k] * np.float64(shN[g, k - 1 + off, ci])
                feats[g, ci] = max(acc + 0.5, 0.0)


@njit(parallel=True, cache=True)
def preprocess_backward(means, quats, log_scales, opacity_logits, sh0, shN, off, deg, cam, eps, mip, radii,
                        g_means2d, g_conics, g_opac, g_feats,
                        d_means, d_quats, d_log_scales, d_logits, d_sh0, d_shN):
    """The chain rule of preprocess_forward; d_sh0 / d_shN laid out as sh0 / shN (the same array
    twice with off = 1 for an unsplit sh)."""
    N = means.shape[0]
    n_chunks = (N + CHUNK - 1) // CHUNK
    nk = (deg + 1) * (deg + 1)
    fx, fy = cam[12], cam[13]
    for ch in prange(n_chunks):
        Rq = np.empty((3, 3))
        RS = np.empty((3, 3))
        M = np.empty((2, 3))
        Y = np.empty(16)
        dY = np.empty((16, 3))
        gM = np.empty((2, 3))
        gT = np.empty((3, 3))
        gR = np.empty((3, 3))
        for g in range(ch * CHUNK, min(N, (ch + 1) * CHUNK)):
            for j in range(3):
                d_means[g, j] = 0.0
                d_log_scales[g, j] = 0.0
            for j in range(4):
                d_quats[g, j] = 0.0
            d_logits[g] = 0.0
            for ci in range(3):
                d_sh0[g, 0, ci] = 0.0
            for k in range(off, shN.shape[1]):
                for ci in range(3):
                    d_shN[g, k, ci] = 0.0
            if radii[g] <= 0:
                continue
            x, y, z, u, v, j00, j02, j11, j12, txc, tyc, qw, qx, qy, qz, qn, s0, s1, s2 = _geometry(
                g, means, quats, log_scales, cam, Rq, RS, M)
            a, b, c, det_raw, det = _cov2d(M, eps)
            A, C = a + eps, c + eps

            # ---- opacity (sigmoid, mip compensation)
            sig = 1.0 / (1.0 + math.exp(-np.float64(opacity_logits[g])))
            go = np.float64(g_opac[g])
            ga = 0.0
            gb = 0.0
            gc = 0.0
            if mip:
                r = det_raw / det
                comp = math.sqrt(max(r, 1e-12))
                d_logits[g] = go * comp * sig * (1.0 - sig)
                if r > 1e-12:
                    g_r = go * sig * 0.5 / comp
                    det2 = det * det
                    ga += g_r * (c * det - det_raw * C) / det2
                    gc += g_r * (a * det - det_raw * A) / det2
                    gb += g_r * (-2.0 * b * (det - det_raw)) / det2
            else:
                d_logits[g] = go * sig * (1.0 - sig)

            # ---- conic = inverse of [[A, b], [b, C]]: dL/dSigma = -Q G Q
            inv_det = 1.0 / det
            q00, q01, q11 = C * inv_det, -b * inv_det, A * inv_det
            g00, g01, g11 = np.float64(g_conics[g, 0]), 0.5 * np.float64(g_conics[g, 1]), np.float64(g_conics[g, 2])
            # QG
            t00 = q00 * g00 + q01 * g01
            t01 = q00 * g01 + q01 * g11
            t10 = q01 * g00 + q11 * g01
            t11 = q01 * g01 + q11 * g11
            ga += -(t00 * q00 + t01 * q01)
            gb += -2.0 * (t00 * q01 + t01 * q11)
            gc += -(t10 * q01 + t11 * q11)

            # ---- a = M0.M0, b = M0.M1, c = M1.M1
            for k in range(3):
                gM[0, k] = 2.0 * ga * M[0, k] + gb * M[1, k]
                gM[1, k] = gb * M[0, k] + 2.0 * gc * M[1, k]
            # M0 = j00 RS0 + j02 RS2 ; M1 = j11 RS1 + j12 RS2
            gj00 = gM[0, 0] * RS[0, 0] + gM[0, 1] * RS[0, 1] + gM[0, 2] * RS[0, 2]
            gj02 = gM[0, 0] * RS[2, 0] + gM[0, 1] * RS[2, 1] + gM[0, 2] * RS[2, 2]
            gj11 = gM[1, 0] * RS[1, 0] + gM[1, 1] * RS[1, 1] + gM[1, 2] * RS[1, 2]
            gj12 = gM[1, 0] * RS[2, 0] + gM[1, 1] * RS[2, 1] + gM[1, 2] * RS[2, 2]
            # RS = T diag(s), T = R Rq
            sc = (s0, s1, s2)
            gs0 = 0.0
            gs1 = 0.0
            gs2 = 0.0
            for k in range(3):
                g_rs0 = j00 * gM[0, k]
                g_rs1 = j11 * gM[1, k]
                g_rs2 = j02 * gM[0, k] + j12 * gM[1, k]
                s = sc[k]
                # T[i, k] = RS[i, k] / s
                gsum = (g_rs0 * RS[0, k] + g_rs1 * RS[1, k] + g_rs2 * RS[2, k]) / s
                if k == 0:
                    gs0 = gsum
                elif k == 1:
                    gs1 = gsum
                else:
                    gs2 = gsum
                gT[0, k] = g_rs0 * s
                gT[1, k] = g_rs1 * s
                gT[2, k] = g_rs2 * s
            d_log_scales[g, 0] = gs0 * s0
            d_log_scales[g, 1] = gs1 * s1
            d_log_scales[g, 2] = gs2 * s2
            # gRq = R^T gT
            for i in range(3):
                for k in range(3):
                    gR[i, k] = cam[i] * gT[0, k] + cam[3 + i] * gT[1, k] + cam[6 + i] * gT[2, k]
            w, qxx, qyy, qzz = qw, qx, qy, qz
            gw = 2 * (-qzz * gR[0, 1] + qyy * gR[0, 2] + qzz * gR[1, 0] - qxx * gR[1, 2] - qyy * gR[2, 0] + qxx * gR[2, 1])
            gx = 2 * (qyy * gR[0, 1] + qzz * gR[0, 2] + qyy * gR[1, 0] - 2 * qxx * gR[1, 1] - w * gR[1, 2]
                      + qzz * gR[2, 0] + w * gR[2, 1] - 2 * qxx * gR[2, 2])
            gy = 2 * (-2 * qyy * gR[0, 0] + qxx * gR[0, 1] + w * gR[0, 2] + qxx * gR[1, 0] + qzz * gR[1, 2]
                      - w * gR[2, 0] + qzz * gR[2, 1] - 2 * qyy * gR[2, 2])
            gz = 2 * (-2 * qzz * gR[0, 0] - w * gR[0, 1] + qxx * gR[0, 2] + w * gR[1, 0] - 2 * qzz * gR[1, 1]
                      + qyy * gR[1, 2] + qxx * gR[2, 0] + qyy * gR[2, 1])
            if qn > 1e-12:
                dot = gw * w + gx * qxx + gy * qyy + gz * qzz
                d_quats[g, 0] = (gw - w * dot) / qn
                d_quats[g, 1] = (gx - qxx * dot) / qn
                d_quats[g, 2] = (gy - qyy * dot) / qn
                d_quats[g, 3] = (gz - qzz * dot) / qn
            else:
                d_quats[g, 0] = gw / 1e-12
                d_quats[g, 1] = gx / 1e-12
                d_quats[g, 2] = gy / 1e-12
                d_quats[g, 3] = gz / 1e-12

            # ---- Jacobian entries and means2d -> camera point
            gu, gv = np.float64(g_means2d[g, 0]), np.float64(g_means2d[g, 1])
            iz = 1.0 / z
            iz2 = iz * iz
            tx = x if txc > 0 else -j02 * z * z / fx
            ty = y if tyc > 0 else -j12 * z * z / fy
            g_x = gu * fx * iz
            g_y = gv * fy * iz
            g_z = -gu * fx * x * iz2 - gv * fy * y * iz2 + np.float64(g_feats[g, 3])
            g_z += -gj00 * fx * iz2 - gj11 * fy * iz2 + gj02 * 2 * fx * tx * iz2 * iz + gj12 * 2 * fy * ty * iz2 * iz
            g_tx = -gj02 * fx * iz2
            g_ty = -gj12 * fy * iz2
            if txc > 0:
                g_x += g_tx
            else:
                g_z += g_tx * tx * iz  # tx = z * limit
            if tyc > 0:
                g_y += g_ty
            else:
                g_z += g_ty * ty * iz
            # float64 until the one store: the outputs may be float32 arrays (rounded once, as a
            # float64 result converted afterwards would be)
            dm0 = cam[0] * g_x + cam[3] * g_y + cam[6] * g_z
            dm1 = cam[1] * g_x + cam[4] * g_y + cam[7] * g_z
            dm2 = cam[2] * g_x + cam[5] * g_y + cam[8] * g_z

            # ---- colour
            dx = np.float64(means[g, 0]) - cam[20]
            dy = np.float64(means[g, 1]) - cam[21]
            dz = np.float64(means[g, 2]) - cam[22]
            dnr = math.sqrt(dx * dx + dy * dy + dz * dz)
            dn = max(dnr, 1e-12)
            ux, uy, uz = dx / dn, dy / dn, dz / dn
            _sh_basis(ux, uy, uz, deg, Y)
            gdir0 = 0.0
            gdir1 = 0.0
            gdir2 = 0.0
            if deg > 0:
                _sh_basis_grad(ux, uy, uz, deg, dY)
            for ci in range(3):
                acc = Y[0] * np.float64(sh0[g, 0, ci])
                for k in range(1, nk):
                    acc += Y[k] * np.float64(shN[g, k - 1 + off, ci])
                gcol = np.float64(g_feats[g, ci]) if acc + 0.5 >= 0.0 else 0.0
                if gcol == 0.0:
                    continue
                d_sh0[g, 0, ci] = Y[0] * gcol
                if deg > 0:
                    w_k = np.float64(sh0[g, 0, ci]) * gcol
                    gdir0 += w_k * dY[0, 0]
                    gdir1 += w_k * dY[0, 1]
                    gdir2 += w_k * dY[0, 2]
                for k in range(1, nk):
                    d_shN[g, k - 1 + off, ci] = Y[k] * gcol
                    if deg > 0:
                        w_k = np.float64(shN[g, k - 1 + off, ci]) * gcol
                        gdir0 += w_k * dY[k, 0]
                        gdir1 += w_k * dY[k, 1]
                        gdir2 += w_k * dY[k, 2]
            if deg > 0:
                if dnr > 1e-12:
                    dot = gdir0 * ux + gdir1 * uy + gdir2 * uz
                    dm0 += (gdir0 - ux * dot) / dn
                    dm1 += (gdir1 - uy * dot) / dn
                    dm2 += (gdir2 - uz * dot) / dn
                else:
                    dm0 += gdir0 / dn
                    dm1 += gdir1 / dn
                    dm2 += gdir2 / dn
            d_means[g, 0] = dm0
            d_means[g, 1] = dm1
            d_means[g, 2] = dm2
