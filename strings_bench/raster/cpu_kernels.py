"""Numba kernels of the CPU rasterizer: tile binning, forward blending, hand-written backward.

Size (~460 lines): the float64 reference blends and the helpers the float32 kernels share with them (binning, the
tight boxes, the per-Gaussian reduction); splitting them would separate a rule from the kernels that must agree on it.

Layout: Gaussians are first sorted front to back; `P` holds their parameters in that order, one row
each: mean2d x, y, conic a, b, c, opacity, then NF features (RGB and camera depth), then
qmin = 2 (log(255 o) + slack), NaN where o < 1/255: a pixel can pass alpha >= 1/255 only where
a dx^2 + 2 b dx dy + c dy^2 <= qmin (`pack` builds P). `BB` holds the pixel boxes (x0, x1, y0, y1),
inclusive, tightened to that ellipse (`tight_box`). Binning gives, per 16x16 tile, a slice of `lst`
(indices into P, front to back); `rows_in_list_order` then copies each intersection's rows of P and BB into
list order, so that the blends read one tile's rows one after the other (`lst` becomes 0, 1, ..., M - 1).
Blending runs tile by tile in parallel (prange); inside a tile the
loop is Gaussian-outer / pixel-inner over the Gaussian's box only, with the per-pixel state
(transmittance, accumulated features, done flag) kept in small per-tile arrays.

The backward pass walks each tile's list back to front (as 3DGS does per pixel), re-deriving the
transmittance by division; at the alpha clamp it follows 3DGS: dL/dalpha is computed with the
clamped alpha of the forward and passed to opacity and G as if alpha = o G (dalpha/do = G,
dalpha/dG = o, no zeroing where o G > 0.99). It writes the gradient summed over the tile's pixels
into the row of a per-intersection buffer; a second parallel pass sums each Gaussian's rows and
scatters them to the input order. No two threads write the same memory, results do not depend on
the thread count, and memory scales with the number of tile-Gaussian intersections.

All per-pixel arithmetic is float64 (the parameters come in as float32 values).

Work skipping that does not change results: a Gaussian with opacity < 1/255 can never reach
alpha >= 1/255 and gets an empty box; its box is cut to the ellipse's bounding box; in each pixel
row of the box only the span of pixels where power >= -log(255 o) - 1e-3 is visited, and a pixel
with power below that bound gets no exp (conservative, widened bounds from the quadratic; the exact
per-pixel tests still decide, so the results are those of visiting every pixel of the 3-sigma box).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

TILE = 16
NF = 4  # blended features: R, G, B, camera depth
ALPHA_MAX = 0.99
ALPHA_MIN = 1.0 / 255.0
T_MIN = 1e-4
N_GRAD = 6 + NF + 2  # mean2d x, y, conic a, b, c, opacity, features, |d mean2d| x, y
N_PARAM = 6 + NF + 1
SPAN_SLACK = 1e-3


@njit(cache=True, inline="always")
def row_span(ca, cb, cc, qmin, inv_ca, mx, dy, xs, xe):
    """Pixel columns [lo, hi] of one row that may pass the alpha threshold, clipped to [xs, xe]
    (inv_ca = 1 / ca: the bound keeps a pixel of slack, so its rounding does not matter)."""
    bq = cb * dy
    disc = bq * bq - ca * (cc * dy * dy - qmin)
    if not disc >= 0.0:  # also catches NaN (opacity below 1/255)
        return 1, 0
    sq = math.sqrt(disc)
    # dx = mx - (px + 0.5) in [(-bq - sq) / ca, (-bq + sq) / ca], one pixel of slack each side
    lo = mx - 0.5 - (-bq + sq) * inv_ca - 1.0
    hi = mx - 0.5 - (-bq - sq) * inv_ca + 1.0
    lo = max(lo, float(xs))
    hi = min(hi, float(xe))
    if lo > hi:
        return 1, 0
    return int(math.ceil(lo)), int(math.floor(hi))


@njit(cache=True, inline="always")
def tight_box(mx, my, ca, cb, cc, qmin, x0, x1, y0, y1):
    """A Gaussian's pixel box (x0, x1, y0, y1) clipped to the bounding box of the ellipse where it can
    reach alpha >= 1/255 (q <= qmin), widened by one pixel each side; empty (x0 > x1) where the
    opacity is below 1/255. The 3-sigma box of the largest axis can be many times larger (low
    opacity, elongated), so fewer tiles and rows are visited; every pixel outside the ellipse fails
    the exact alpha test anyway, so the blend's results do not change."""
    if not qmin >= 0.0:  # NaN: opacity below 1/255, never blended
        return 1, 0, 1, 0
    det = ca * cc - cb * cb
    if det > 0.0:
        # half-extents of {a dx^2 + 2 b dx dy + c dy^2 <= qmin}: sqrt(qmin cov_xx), sqrt(qmin cov_yy)
        ex = math.sqrt(qmin * cc / det)
        ey = math.sqrt(qmin * ca / det)
        if ex < 1e7 and ey < 1e7:
            # pixel centres px + 0.5 within [m - e, m + e]
            x0 = max(x0, int(math.ceil(mx - ex - 1.5)))
            x1 = min(x1, int(math.floor(mx + ex + 0.5)))
            y0 = max(y0, int(math.ceil(my - ey - 1.5)))
            y1 = min(y1, int(math.floor(my + ey + 0.5)))
    return x0, x1, y0, y1


@njit(cache=True, inline="always")
def tile_rect(t, tiles_x, W, H):
    """Tile t's first pixel column and row and its width and height inside the W x H image (both precisions'
    blends; inlined, so the compiled kernels are as if written out)."""
    ty = t // tiles_x
    tx = t - ty * tiles_x
    px0 = tx * TILE
    py0 = ty * TILE
    return px0, py0, min(TILE, W - px0), min(TILE, H - py0)


@njit(cache=True, inline="always")
def box_in_tile(BB, i, px0, py0, pw, ph):
    """Gaussian i's pixel box clipped to the tile: first and last column, first and last row (empty when a
    first exceeds its last)."""
    return (max(BB[i, 0], px0), min(BB[i, 1], px0 + pw - 1), max(BB[i, 2], py0), min(BB[i, 3], py0 + ph - 1))


@njit(cache=True, inline="always")
def splat_params(P, i):
    """Row i of P: mean2d x, y, conic a, b, c, opacity."""
    return P[i, 0], P[i, 1], P[i, 2], P[i, 3], P[i, 4], P[i, 5]


@njit(parallel=True, cache=True)
def pack(order, means2d, conics, opacities, feats, bbox):
    """P (V, N_PARAM) float64 and BB (V, 4) int64 of the Gaussians `order` (front to back): the
    layout of the module docstring, with each box tightened by `tight_box`. The float32 inputs
    convert exactly."""
    V = order.shape[0]
    P = np.empty((V, N_PARAM), np.float64)
    BB = np.empty((V, 4), np.int64)
    for v in prange(V):
        i = order[v]
        P[v, 0] = means2d[i, 0]
        P[v, 1] = means2d[i, 1]
        P[v, 2] = conics[i, 0]
        P[v, 3] = conics[i, 1]
        P[v, 4] = conics[i, 2]
        o = np.float64(opacities[i])
        P[v, 5] = o
        for c in range(NF):
            P[v, 6 + c] = feats[i, c]
        qmin = 2.0 * (math.log(255.0 * o) + SPAN_SLACK) if o >= ALPHA_MIN else np.nan
        P[v, 6 + NF] = qmin
        x0, x1, y0, y1 = tight_box(P[v, 0], P[v, 1], P[v, 2], P[v, 3], P[v, 4], qmin,
                                   bbox[i, 0], bbox[i, 1], bbox[i, 2], bbox[i, 3])
        BB[v, 0] = x0
        BB[v, 1] = x1
        BB[v, 2] = y0
        BB[v, 3] = y1
    return P, BB


@njit(cache=True)
def _depth_keys(radii, depths):
    """The visible Gaussians (radii > 0) and their depths as unsigned keys that order as the floats do:
    IEEE bits with the sign bit set for a positive float, all bits flipped for a negative one (-0.0
    counted as 0.0, so that it ties with it as in a comparison sort; every NaN after +inf, as torch sorts them)."""
    n = 0
    for i in range(radii.shape[0]):
        if radii[i] > 0:
            n += 1
    idx = np.empty(n, np.int64)
    keys = np.empty(n, np.uint32)
    j = 0
    for i in range(radii.shape[0]):
        if radii[i] > 0:
            idx[j] = i
            z = np.float32(depths[i] + np.float32(0.0))  # -0.0 + 0.0 = +0.0
            b = np.uint32(0xFFFFFFFF) if z != z else z.view(np.uint32) | np.uint32(0x80000000)
            keys[j] = b if z != z or z >= 0 else z.view(np.uint32) ^ np.uint32(0xFFFFFFFF)
            j += 1
    return idx, keys


@njit(cache=True)
def depth_order(radii, depths):
    """The indices of the visible Gaussians (radii > 0) front to back: a stable sort by float32 depth, as
    torch.argsort(stable=True) of their depths gives (equal depths keep index order). An LSD radix sort over
    the keys' four bytes: four counting passes, 10x faster than torch's comparison sort at 300k."""
    idx, keys = _depth_keys(radii, depths)
    n = idx.shape[0]
    idx2 = np.empty_like(idx)
    keys2 = np.empty_like(keys)
    count = np.empty(257, np.int64)
    for shift in range(0, 32, 8):
        sh = np.uint32(shift)
        count[:] = 0
        for j in range(n):
            count[((keys[j] >> sh) & np.uint32(255)) + 1] += 1
        if count[1 + ((keys[0] >> sh) & np.uint32(255)) if n else 0] == n:
            continue  # one digit value: this pass moves nothing
        for d in range(256):
            count[d + 1] += count[d]
        for j in range(n):
            d = (keys[j] >> sh) & np.uint32(255)
            k = count[d]
            count[d] = k + 1
            keys2[k] = keys[j]
            idx2[k] = idx[j]
        keys, keys2 = keys2, keys
        idx, idx2 = idx2, idx
    return idx


@njit(cache=True)
def bin_tiles(BB, tiles_x, tiles_y):
    """Counting sort of (tile, depth) keys; BB rows are already front to back.

    Returns tile_start (n_tiles+1), lst (M) of Gaussian rows, g_start (V+1) and isect_pos (M): the
    intersections of Gaussian i are lst positions isect_pos[g_start[i]:g_start[i+1]].
    """
    V = BB.shape[0]
    n_tiles = tiles_x * tiles_y
    g_start = np.empty(V + 1, np.int64)
    tile_start = np.zeros(n_tiles + 1, np.int64)
    g_start[0] = 0
    for i in range(V):
        if BB[i, 0] > BB[i, 1] or BB[i, 2] > BB[i, 3]:  # empty box (tight_box: opacity below 1/255)
            g_start[i + 1] = g_start[i]
            continue
        tx0, tx1 = BB[i, 0] // TILE, BB[i, 1] // TILE
        ty0, ty1 = BB[i, 2] // TILE, BB[i, 3] // TILE
        g_start[i + 1] = g_start[i] + (tx1 - tx0 + 1) * (ty1 - ty0 + 1)
        for ty in range(ty0, ty1 + 1):
            for tx in range(tx0, tx1 + 1):
                tile_start[ty * tiles_x + tx + 1] += 1
    for t in range(n_tiles):
        tile_start[t + 1] += tile_start[t]
    M = g_start[V]
    lst = np.empty(M, np.int32)
    isect_pos = np.empty(M, np.int64)
    fill = tile_start[:n_tiles].copy()
    for i in range(V):
        j = g_start[i]
        if j == g_start[i + 1]:
            continue
        tx0, tx1 = BB[i, 0] // TILE, BB[i, 1] // TILE
        ty0, ty1 = BB[i, 2] // TILE, BB[i, 3] // TILE
        for ty in range(ty0, ty1 + 1):
            for tx in range(tx0, tx1 + 1):
                t = ty * tiles_x + tx
                k = fill[t]
                fill[t] = k + 1
                lst[k] = i
                isect_pos[j] = k
                j += 1
    return tile_start, lst, g_start, isect_pos


@njit(parallel=True, cache=True)
def rows_in_list_order(lst, P, BB):
    """(P[lst], BB[lst], 0..M-1): the rows of every intersection in list order, and the list that reads them.

    The blends read row lst[k] of P and BB for the k-th intersection; a tile's Gaussians are scattered over P
    (front to back over the whole image), so at a few hundred thousand Gaussians each read missed the caches
    and the blends waited on memory. Read in list order they stream, and every value is the same (bit-identical
    results: tests/raster/test_raster.py). Copied in parallel, many reads in flight: M x 80 B once per render."""
    M = lst.shape[0]
    n = P.shape[1]
    PL = np.empty((M, n), P.dtype)
    BL = np.empty((M, 4), BB.dtype)
    listed = np.empty(M, lst.dtype)  # the new list: intersection k reads row k
    for k in prange(M):
        i = lst[k]
        for j in range(n):
            PL[k, j] = P[i, j]
        for j in range(4):
            BL[k, j] = BB[i, j]
        listed[k] = k
    return PL, BL, listed


@njit(parallel=True, cache=True)
def forward(tile_start, lst, P, BB, W, H, tiles_x, out_f, out_T, out_last):
    """out_f (H, W, NF) float32, out_T (H, W) float64 final transmittance, out_last (H, W) int64:
    one past the lst position of the last Gaussian blended into the pixel (0 = none)."""
    n_tiles = tile_start.shape[0] - 1
    for t in prange(n_tiles):
        px0, py0, pw, ph = tile_rect(t, tiles_x, W, H)
        T = np.ones(TILE * TILE, np.float64)
        acc = np.zeros((TILE * TILE, NF), np.float64)
        done = np.zeros(TILE * TILE, np.bool_)
        last = np.zeros(TILE * TILE, np.int64)
        n_done = 0
        n_pix = pw * ph
        for k in range(tile_start[t], tile_start[t + 1]):
            i = lst[k]
            xs, xe, ys, ye = box_in_tile(BB, i, px0, py0, pw, ph)
            mx, my, ca, cb, cc, op = splat_params(P, i)
            qmin = P[i, 6 + NF]
            power_min = -0.5 * qmin  # below it alpha < 1/255 for sure: skip the exp
            inv_ca = 1.0 / ca
            for py in range(ys, ye + 1):
                dy = my - (py + 0.5)
                row = (py - py0) * TILE - px0
                lo, hi = row_span(ca, cb, cc, qmin, inv_ca, mx, dy, xs, xe)
                for px in range(lo, hi + 1):
                    p = row + px
                    if done[p]:
                        continue
                    dx = mx - (px + 0.5)
                    power = -0.5 * (ca * dx * dx + cc * dy * dy) - cb * dx * dy
                    if power > 0.0 or power < power_min:
                        continue
                    alpha = op * math.exp(power)
                    if alpha > ALPHA_MAX:
                        alpha = ALPHA_MAX
                    if alpha < ALPHA_MIN:
                        continue
                    test_T = T[p] * (1.0 - alpha)
                    if test_T < T_MIN:
                        done[p] = True
                        n_done += 1
                        continue
                    w = alpha * T[p]
                    for c in range(NF):
                        acc[p, c] += w * P[i, 6 + c]
                    T[p] = test_T
                    last[p] = k + 1
            if n_done == n_pix:
                break
        for py in range(ph):
            for px in range(pw):
                p = py * TILE + px
                for c in range(NF):
                    out_f[py0 + py, px0 + px, c] = acc[p, c]
                out_T[py0 + py, px0 + px] = T[p]
                out_last[py0 + py, px0 + px] = last[p]


@njit(parallel=True, cache=True)
def backward(tile_start, lst, P, BB, W, H, tiles_x, T_final, last_k, grad_f, grad_alpha, buf):
    """grad_f (H, W, NF), grad_alpha (H, W): dL/d(outputs). buf (M, N_GRAD) float32: per-intersection
    gradient w.r.t. the Gaussian's row of P (summed over the tile's pixels) and the sums of |dL/dmean2d|."""
    n_tiles = tile_start.shape[0] - 1
    for t in prange(n_tiles):
        px0, py0, pw, ph = tile_rect(t, tiles_x, W, H)
        T = np.zeros(TILE * TILE, np.float64)
        Tfin = np.zeros(TILE * TILE, np.float64)
        lastk = np.zeros(TILE * TILE, np.int64)
        gf = np.zeros((TILE * TILE, NF), np.float64)
        ga = np.zeros(TILE * TILE, np.float64)
        accum = np.zeros((TILE * TILE, NF), np.float64)
        last_f = np.zeros((TILE * TILE, NF), np.float64)
        last_a = np.zeros(TILE * TILE, np.float64)
        kmax = tile_start[t]
        for py in range(ph):
            for px in range(pw):
                p = py * TILE + px
                T[p] = T_final[py0 + py, px0 + px]
                Tfin[p] = T[p]
                lastk[p] = last_k[py0 + py, px0 + px]
                kmax = max(kmax, lastk[p])
                ga[p] = grad_alpha[py0 + py, px0 + px]
                for c in range(NF):
                    gf[p, c] = grad_f[py0 + py, px0 + px, c]
        for k in range(kmax, tile_start[t + 1]):
            for j in range(N_GRAD):
                buf[k, j] = 0.0
        feat = np.empty(NF, np.float64)
        g_feat = np.empty(NF, np.float64)
        for k in range(kmax - 1, tile_start[t] - 1, -1):
            i = lst[k]
            xs, xe, ys, ye = box_in_tile(BB, i, px0, py0, pw, ph)
            mx, my, ca, cb, cc, op = splat_params(P, i)
            for c in range(NF):
                feat[c] = P[i, 6 + c]
                g_feat[c] = 0.0
            g_mx = 0.0
            g_my = 0.0
            g_ca = 0.0
            g_cb = 0.0
            g_cc = 0.0
            g_op = 0.0
            abs_x = 0.0
            abs_y = 0.0
            qmin = P[i, 6 + NF]
            power_min = -0.5 * qmin  # below it alpha < 1/255 for sure: skip the exp
            inv_ca = 1.0 / ca
            for py in range(ys, ye + 1):
                dy = my - (py + 0.5)
                row = (py - py0) * TILE - px0
                lo, hi = row_span(ca, cb, cc, qmin, inv_ca, mx, dy, xs, xe)
                for px in range(lo, hi + 1):
                    p = row + px
                    if k >= lastk[p]:
                        continue
                    dx = mx - (px + 0.5)
                    power = -0.5 * (ca * dx * dx + cc * dy * dy) - cb * dx * dy
                    if power > 0.0 or power < power_min:
                        continue
                    G = math.exp(power)
                    alpha = min(op * G, ALPHA_MAX)
                    if alpha < ALPHA_MIN:
                        continue
                    one_m = 1.0 - alpha
                    T[p] = T[p] / one_m
                    w = alpha * T[p]
                    dL_da = 0.0
                    la = last_a[p]
                    for c in range(NF):
                        g = gf[p, c]
                        g_feat[c] += w * g
                        acc_c = la * last_f[p, c] + (1.0 - la) * accum[p, c]
                        accum[p, c] = acc_c
                        last_f[p, c] = feat[c]
                        dL_da += (feat[c] - acc_c) * g
                    dL_da *= T[p]
                    last_a[p] = alpha
                    dL_da += Tfin[p] / one_m * ga[p]
                    # 3DGS: dL/dalpha (built above with the clamped alpha) reaches opacity and G as if
                    # alpha = o G, also where the 0.99 clamp is active (no zeroing there).
                    dL_dG = op * dL_da
                    g_op += G * dL_da
                    gdx = G * dx
                    gdy = G * dy
                    gx = dL_dG * (-gdx * ca - gdy * cb)
                    gy = dL_dG * (-gdy * cc - gdx * cb)
                    g_mx += gx
                    g_my += gy
                    abs_x += abs(gx)
                    abs_y += abs(gy)
                    g_ca += -0.5 * gdx * dx * dL_dG
                    g_cb += -gdx * dy * dL_dG
                    g_cc += -0.5 * gdy * dy * dL_dG
            buf[k, 0] = g_mx
            buf[k, 1] = g_my
            buf[k, 2] = g_ca
            buf[k, 3] = g_cb
            buf[k, 4] = g_cc
            buf[k, 5] = g_op
            for c in range(NF):
                buf[k, 6 + c] = g_feat[c]
            buf[k, 6 + NF] = abs_x
            buf[k, 7 + NF] = abs_y


@njit(parallel=True, cache=True)
def reduce_intersections(buf, g_start, isect_pos, order, g_means2d, g_conics, g_opacities, g_feats, g_abs):
    """Each Gaussian's gradient: the sum (float64, in intersection order) of its rows of buf, written
    to row order[v] of the outputs (N rows; the rest are zero), each value rounded once at the store.
    Each Gaussian's sum is one thread's, so the result does not depend on the thread count. g_abs
    (N, 2) receives the |dL/dmean2d| sums; pass a (0, 2) array to skip them."""
    V = g_start.shape[0] - 1
    N = g_means2d.shape[0]
    n = buf.shape[1]
    with_abs = g_abs.shape[0] > 0
    for i in prange(N):
        g_means2d[i, 0] = 0.0
        g_means2d[i, 1] = 0.0
        for j in range(3):
            g_conics[i, j] = 0.0
        g_opacities[i] = 0.0
        for j in range(NF):
            g_feats[i, j] = 0.0
        if with_abs:
            g_abs[i, 0] = 0.0
            g_abs[i, 1] = 0.0
    # The sums in twelve scalars, not a small array per Gaussian: an array allocated in the loop is a heap
    # allocation per Gaussian, and a loop over buf's columns of unknown length kept them in memory. Each sum
    # still adds its rows in intersection order, so the bits are the same.
    assert n == N_GRAD and NF == 4
    for v in prange(V):
        a0 = a1 = a2 = a3 = a4 = a5 = a6 = a7 = a8 = a9 = a10 = a11 = 0.0
        for s in range(g_start[v], g_start[v + 1]):
            k = isect_pos[s]
            a0 += buf[k, 0]
            a1 += buf[k, 1]
            a2 += buf[k, 2]
            a3 += buf[k, 3]
            a4 += buf[k, 4]
            a5 += buf[k, 5]
            a6 += buf[k, 6]
            a7 += buf[k, 7]
            a8 += buf[k, 8]
            a9 += buf[k, 9]
            a10 += buf[k, 10]
            a11 += buf[k, 11]
        i = order[v]
        g_means2d[i, 0] = a0
        g_means2d[i, 1] = a1
        g_conics[i, 0] = a2
        g_conics[i, 1] = a3
        g_conics[i, 2] = a4
        g_opacities[i] = a5
        g_feats[i, 0] = a6
        g_feats[i, 1] = a7
        g_feats[i, 2] = a8
        g_feats[i, 3] = a9
        if with_abs:
            g_abs[i, 0] = a10
            g_abs[i, 1] = a11
