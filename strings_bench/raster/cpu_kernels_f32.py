"""Float32 blend kernels of the CPU rasterizer (the default; `cpu_kernels` keeps the float64 reference).

Size (~480 lines): the forward and backward blends with the inlined helpers they share (the tile's
layout, the block skip, exp, the lane trees); each helper's cost is read in the compiled kernels, so they stay in
one module.

Same rules, layout and binning as `cpu_kernels` (its docstring): P rows are (mean2d x, y, conic a, b,
c, opacity, NF features, qmin), here in float32; BB the tight pixel boxes; per 16x16 tile a slice of
`lst` front to back. What differs is the arithmetic and the loop shape, so that LLVM puts the pixel
loop on the vector units:

- the per-pixel state of a tile (transmittance, accumulated features, the done mask; in the backward
  the transmittance, T_final x dL/dalpha, dL/dfeatures and the features blended behind) is float32,
  one row of 256 per quantity in one buffer at constant offsets, indexed with unsigned integers: LLVM
  then needs no alias checks between the rows and no negative-index wraparound;
- the tile is stored as two halves of 8 columns (16 rows x 8, contiguous): for each Gaussian and each
  half its box touches, one flat loop runs over the box's rows x 8 columns, two rows per 16-lane
  AVX-512 vector (an odd row count gets one more row, masked), with no branch: every test of the
  float64 kernels (the box's columns and rows, power > 0, alpha < 1/255, the transmittance stop, a
  pixel already done or, in the backward, behind its last contributor) is a per-pixel mask that
  selects between the updated and the old value. Pixels outside the alpha >= 1/255 ellipse fail the
  alpha test; a block of two rows x 8 columns that the ellipse misses altogether (`block_meets`, from the
  region row by row that `ellipse_rows` solves once per Gaussian and tile) is skipped, as it would only add zeros,
  and so, in the backward, is a block whose pixels all ended before the splat (each pixel's last contributor, highest
  over its two half-rows). A tile stops when all of its pixels are done, as before;
- `exp` is `exp_neg32`: Cephes' expf polynomial with range reduction and 2^k from an exponent bitcast
  (`pow2_f32`), inlined, branch-free;
- the backward updates the colour behind each splat eagerly (alpha f + (1 - alpha) S, the expression
  3DGS evaluates lazily from the previous splat) and keeps each Gaussian's gradient sums in LANES (16)
  partial sums, pixel q of its loop adding into sum q % 16, the 16 added in a fixed tree at the end.

Every addition's order is written in the code (no fastmath flags; the forward counts the pixels done in
LANES partial counts too, which keeps its pixel loop on the vector units): the kernels give the same bits at any vector width and thread count, on any CPU.
Each tile is one thread's, and the per-Gaussian sums over tiles are `cpu_kernels.reduce_intersections`
(float64, in intersection order).
"""

from __future__ import annotations

import math

import numpy as np
from llvmlite import ir as llvm_ir
from numba import njit, prange
from numba.core import types
from numba.extending import intrinsic

from strings_bench.raster.cpu_kernels import (ALPHA_MAX, ALPHA_MIN, N_GRAD, N_PARAM, NF, SPAN_SLACK, T_MIN,
                                              TILE, box_in_tile, splat_params, tight_box, tile_rect)

F32 = np.float32
ZERO = F32(0.0)
ONE = F32(1.0)
HALF = F32(0.5)
AMAX = F32(ALPHA_MAX)
AMIN = F32(ALPHA_MIN)
TMIN = F32(T_MIN)
# exp: e^x = 2^k e^r, k = round(x / ln 2), r = x - k ln 2 in [-ln2/2, ln2/2] (ln 2 in two parts, Cody-Waite)
EXP_LO = F32(-10.0)  # o e^-10 <= 4.5e-5 < 1/255: anything below gives a skipped alpha anyway
LOG2E = F32(1.44269504088896341)
LN2_HI = F32(0.693359375)
LN2_LO = F32(-2.12194440e-4)
# Cephes expf (S. L. Moshier): e^r = 1 + r + r^2 (E5 + r (E4 + ...)), relative error ~1 ulp on the range
E0 = F32(1.9875691500e-4)
E1 = F32(1.3981999507e-3)
E2 = F32(8.3334519073e-3)
E3 = F32(4.1665795894e-2)
E4 = F32(1.6666665459e-1)
E5 = F32(5.0000001201e-1)
# No fastmath flag at all: every float operation is done in the order the code writes it, so the kernels
# give the same bits at every vector width (SSE, AVX2, AVX-512) and target CPU, i.e. on every machine.
# `reassoc` let LLVM sum a Gaussian's gradients in one partial sum per vector lane, so the sums depended
# on the host's vector width (16 lanes on AVX-512, 8 on AVX2: other bits, hence other models after
# densification); the backward now keeps LANES partial sums itself. `contract` (fused multiply-adds),
# `arcp` and `nsz` made LLVM compile the JIT path and numba's cached object code differently (a kernel
# compiled in the process and the same kernel loaded from the cache gave other bits).
FASTMATH: set = set()


@intrinsic
def pow2_f32(typingctx, k):
    """2^k as float32 for an integral float32 k in [-126, 127]: the exponent field built from k's
    integer value and the bits taken as a float (LLVM fptosi, add, shl, bitcast: vectorises)."""
    if k != types.float32:
        return None

    def codegen(context, builder, signature, args):
        i32 = llvm_ir.IntType(32)
        ki = builder.fptosi(args[0], i32)
        bits = builder.shl(builder.add(ki, llvm_ir.Constant(i32, 127)), llvm_ir.Constant(i32, 23))
        return builder.bitcast(bits, llvm_ir.FloatType())

    return types.float32(types.float32), codegen


@njit(cache=True, inline="always", fastmath=FASTMATH)
def exp_neg32(x):
    """e^x in float32 for x <= 0, without a branch or a call (vectorises). x is clamped at -10
    (e^-10 = 4.5e-5: the caller's alpha = o e^x is below 1/255 there anyway). Relative error
    about 1e-7 (checked against float64 in the tests)."""
    x = max(x, EXP_LO)
    fk = np.floor(x * LOG2E + HALF)  # k in [-15, 0]
    r = x - fk * LN2_HI
    r = r - fk * LN2_LO
    z = r * r
    e = (((((E0 * r + E1) * r + E2) * r + E3) * r + E4) * r + E5) * z + r + ONE
    return e * pow2_f32(fk)


@njit(parallel=True, cache=True)
def pack(order, means2d, conics, opacities, feats, bbox):
    """P (V, N_PARAM) float32 and BB (V, 4) int64 of the Gaussians `order` (front to back), as
    `cpu_kernels.pack` (same tight boxes, computed in float64 from the same float32 values)."""
    V = order.shape[0]
    P = np.empty((V, N_PARAM), np.float32)
    BB = np.empty((V, 4), np.int64)
    for v in prange(V):
        i = order[v]
        mx = np.float64(means2d[i, 0])
        my = np.float64(means2d[i, 1])
        ca = np.float64(conics[i, 0])
        cb = np.float64(conics[i, 1])
        cc = np.float64(conics[i, 2])
        o = np.float64(opacities[i])
        P[v, 0] = mx
        P[v, 1] = my
        P[v, 2] = ca
        P[v, 3] = cb
        P[v, 4] = cc
        P[v, 5] = o
        for c in range(NF):
            P[v, 6 + c] = feats[i, c]
        qmin = 2.0 * (math.log(255.0 * o) + SPAN_SLACK) if o >= ALPHA_MIN else np.nan
        P[v, 6 + NF] = qmin
        x0, x1, y0, y1 = tight_box(mx, my, ca, cb, cc, qmin, bbox[i, 0], bbox[i, 1], bbox[i, 2], bbox[i, 3])
        BB[v, 0] = x0
        BB[v, 1] = x1
        BB[v, 2] = y0
        BB[v, 3] = y1
    return P, BB


# Per-tile pixel state: one float32 buffer, one row of TILE*TILE per quantity at a constant offset,
# indexed with unsigned integers. LLVM then sees that the rows never overlap (no runtime alias
# checks, which it gives up on past a few arrays) and needs no negative-index wraparound.
NPIX = TILE * TILE
# Pixel (row, col) of a tile is stored at pix_index(row, col): the tile as two halves of 8 columns,
# each 16 rows x 8 contiguous. A Gaussian whose box lies in one half (most) then runs over 8-pixel
# row pieces, two rows per 16-lane vector, instead of whole 16-pixel rows.
HW = 8  # columns per half
HSZ = TILE * HW  # pixels per half
# forward rows: transmittance, accumulated features (4), done (1 = stopped or outside the image)
F_T, F_A0, F_A1, F_A2, F_A3, F_DONE, F_ROWS = (np.uint64(r * NPIX) for r in range(7))
# backward rows: transmittance, final transmittance x dL/dalpha, dL/dfeatures (4), the features
# blended behind the current splat (4)
B_T, B_TGA, B_G0, B_G1, B_G2, B_G3, B_S0, B_S1, B_S2, B_S3, B_ROWS = (np.uint64(r * NPIX) for r in range(11))
# The backward's per-Gaussian sums, in their own buffer (one buffer apart from S: LLVM then vectorises
# the pixel loop with one alias check): N_GRAD rows of LANES partial sums; pixel q of a box's flat loop
# adds into lane q % LANES, and the lanes are added in one fixed tree at the end. The order of every
# addition is thus the code's, not the compiler's choice for the host's vector width.
LANES = 16
L1, L2, L3, L4, L5, L6, L7, L8, L9, L10, L11 = (np.uint64(j * LANES) for j in range(1, 12))
# Lane ln of a block (q = q0 + ln, q0 a multiple of LANES) is the pixel at column ln & 7 and row q0 / 8 + ln / 8 of
# its half: the two as float32 constants, so the backward's pixel loop converts no integer per lane. The values are
# the same small whole numbers as float32(q & 7) and float32(q >> 3), so the same bits; but AVX2 has no vector
# conversion from 64-bit integers, and LLVM converted each lane's q in scalar code (16 conversions a block). The
# forward keeps the conversions: with the constants LLVM unrolled its loop and spilled more, and it ran slower
# (docs/results/engine-speed.md, "Kernels compiled in the process; the backward's lane constants").
LANE_COL = np.array([ln & (HW - 1) for ln in range(LANES)], np.float32)
LANE_ROW = np.array([ln >> 3 for ln in range(LANES)], np.float32)


@njit(cache=True, inline="always")
def lane_tree(A, b):
    """A[b] <- the LANES (16) partial sums A[b:b + 16] added in one fixed tree: lane l += lane l + w for w = 8,
    4, 2, 1. Each level's additions are independent, and written with constant trip counts LLVM does each
    level in a few vector operations (a loop over w left them scalar, one dependent store and load each)."""
    for ln in range(8):
        A[b + np.uint64(ln)] += A[b + np.uint64(ln + 8)]
    for ln in range(4):
        A[b + np.uint64(ln)] += A[b + np.uint64(ln + 4)]
    for ln in range(2):
        A[b + np.uint64(ln)] += A[b + np.uint64(ln + 2)]
    A[b] += A[b + np.uint64(1)]


@njit(cache=True, inline="always")
def even_rows(ys, ye, py0):
    """The box's first and last row in the tile, widened by one row (down, else up) to an even count: two
    rows a 16-lane vector, a whole number of LANES pixels per half."""
    r0 = ys - py0
    r1 = ye - py0
    if (r1 - r0) % 2 == 0:  # odd row count
        if r1 < TILE - 1:
            r1 += 1
        else:
            r0 -= 1
    return r0, r1


@njit(cache=True, inline="always")
def ellipse_rows(P, i):
    """Gaussian i's alpha >= 1/255 region (q <= qmin) row by row, in float64: the row at dy = my - (py + 0.5)
    holds it at the columns px with |px - c| <= w, c = cx + slope dy, w^2 = k0 + k2 dy^2 (`cpu_kernels.row_span`'s
    quadratic, solved once per Gaussian and tile instead of once per block and row). Returns (cx, slope, k0, k2,
    my); a conic with a <= 0 (not an ellipse) gives w = inf, so no block is ever skipped for it."""
    ca = np.float64(P[i, 2])
    cb = np.float64(P[i, 3])
    if not ca > 0.0:
        return 0.0, 0.0, np.inf, 0.0, 0.0
    inv = 1.0 / ca
    return (np.float64(P[i, 0]) - 0.5, cb * inv, np.float64(P[i, 6 + NF]) * inv,
            (cb * cb - ca * np.float64(P[i, 4])) * inv * inv, np.float64(P[i, 1]))


@njit(cache=True, inline="always")
def block_meets(E, py0, r, ys, ye, lo_col, hi_col):
    """Whether tile rows r and r + 1 (image row py0 + r on), within the box rows ys..ye, hold a pixel of columns
    lo_col..hi_col (floats) within one pixel of the region `ellipse_rows` gives as E. The pixel of slack is far
    larger than the float64 rounding, and a NaN (opacity below 1/255) skips."""
    cx, slope, k0, k2, my = E
    for py in range(max(py0 + r, ys), min(py0 + r + 1, ye) + 1):
        dy = my - (py + 0.5)
        w2 = k0 + k2 * dy * dy
        c = cx + slope * dy
        d = max(lo_col - c, c - hi_col) - 1.0  # the distance from c to the columns, less the slack
        if w2 >= 0.0 and (d <= 0.0 or d * d <= w2):
            return True
    return False


@njit(cache=True, inline="always")
def block_meets_ellipse(P, i, py0, r, ys, ye, xs, xe, c_lo, c_hi):
    """Whether tile rows r and r + 1 (image row py0 + r on), columns c_lo..c_hi, meet the box (rows ys..ye,
    columns xs..xe) where Gaussian i can reach alpha >= 1/255, with a pixel of slack (`ellipse_rows`,
    `block_meets`). A 16-pixel block it misses has no pixel that passes the exact tests, so skipping it adds
    nothing but zeros: the blends give the same bits with or without the test (the partial sums start at +0 and
    never become -0)."""
    return block_meets(ellipse_rows(P, i), py0, r, ys, ye, float(max(xs, c_lo)), float(min(xe, c_hi)))


@njit(parallel=True, cache=True, fastmath=FASTMATH)
def forward(tile_start, lst, P, BB, W, H, tiles_x, out_f, out_T, out_last):
    """out_f (H, W, NF) float32, out_T (H, W) float32 final transmittance, out_last (H, W) int32: one
    past the lst position of the last Gaussian blended into the pixel (0 = none)."""
    n_tiles = tile_start.shape[0] - 1
    for t in prange(n_tiles):
        px0, py0, pw, ph = tile_rect(t, tiles_x, W, H)
        S = np.zeros(F_ROWS, np.float32)
        last = np.zeros(NPIX, np.int32)
        for q in range(NPIX):
            S[F_T + np.uint64(q)] = ONE
            if (q // HSZ) * HW + q % HW >= pw:  # columns outside the image: done from the start
                S[F_DONE + np.uint64(q)] = ONE
        n_pix = F32(pw * ph)
        n_done = ZERO
        D = np.zeros(LANES, np.float32)  # the pixels stopped by the current Gaussian, per lane
        cx0 = F32(px0) + HALF  # pixel-centre x of the tile's column 0
        for k in range(tile_start[t], tile_start[t + 1]):
            i = lst[k]
            xs, xe, ys, ye = box_in_tile(BB, i, px0, py0, pw, ph)
            mx, my, ca, cb, cc, op = splat_params(P, i)
            f0 = P[i, 6]
            f1 = P[i, 7]
            f2 = P[i, 8]
            f3 = P[i, 9]
            k1 = np.int32(k + 1)
            if xs > xe or ys > ye:
                continue
            # the box's rows in the tile as flat loops over (row, column) of each half it touches, 8
            # lanes a row, an even number of rows (two rows a 16-lane vector; a row outside the box is
            # added and masked when needed); the mask keeps the box's columns and rows
            r0, r1 = even_rows(ys, ye, py0)
            E = ellipse_rows(P, i)
            j_lo = F32(xs - px0) - HALF
            j_hi = F32(xe - px0) + HALF
            i_lo = F32(ys - py0 - r0) - HALF  # box rows, relative to r0
            i_hi = F32(ye - py0 - r0) + HALF
            cy0 = F32(py0 + r0) + HALF
            for ln in range(LANES):
                D[ln] = ZERO
            for h in range((xs - px0) // HW, (xe - px0) // HW + 1):
                base = np.uint64(h * HSZ + r0 * HW)
                cxh = cx0 + F32(h * HW)
                fjh = F32(h * HW)
                lo_col = float(max(xs, px0 + h * HW))
                hi_col = float(min(xe, px0 + h * HW + HW - 1))
                for q0 in range(0, (r1 - r0 + 1) * HW, LANES):
                    if not block_meets(E, py0, r0 + q0 // HW, ys, ye, lo_col, hi_col):
                        continue
                    for ln in range(LANES):
                        q = q0 + ln
                        p = base + np.uint64(q)
                        fc = F32(q & (HW - 1))
                        fr = F32(q >> 3)
                        fj = fjh + fc
                        dx = mx - (cxh + fc)
                        dy = my - (cy0 + fr)
                        power = -HALF * (ca * dx * dx + cc * dy * dy) - cb * dx * dy
                        alpha = min(op * exp_neg32(min(power, ZERO)), AMAX)
                        Tp = S[F_T + p]
                        test_T = Tp * (ONE - alpha)
                        ok = ((S[F_DONE + p] == ZERO) & (fj > j_lo) & (fj < j_hi) & (fr > i_lo) & (fr < i_hi)
                              & (power <= ZERO) & (alpha >= AMIN))
                        stop = ok & (test_T < TMIN)
                        blend = ok & (test_T >= TMIN)
                        w = alpha * Tp if blend else ZERO
                        S[F_A0 + p] += w * f0
                        S[F_A1 + p] += w * f1
                        S[F_A2 + p] += w * f2
                        S[F_A3 + p] += w * f3
                        S[F_T + p] = test_T if blend else Tp
                        last[p] = k1 if blend else last[p]
                        S[F_DONE + p] = ONE if stop else S[F_DONE + p]
                        D[ln] += ONE if stop else ZERO  # pixels stopped, per lane (whole numbers: exact)
            # the lanes' counts added in a tree (whole numbers: exact in any order; a chain of 16 additions
            # would wait on each one)
            lane_tree(D, np.uint64(0))
            n_done += D[0]
            if n_done == n_pix:
                break
        for py in range(ph):
            for px in range(pw):
                p = np.uint64((px // HW) * HSZ + py * HW + px % HW)
                out_f[py0 + py, px0 + px, 0] = S[F_A0 + p]
                out_f[py0 + py, px0 + px, 1] = S[F_A1 + p]
                out_f[py0 + py, px0 + px, 2] = S[F_A2 + p]
                out_f[py0 + py, px0 + px, 3] = S[F_A3 + p]
                out_T[py0 + py, px0 + px] = S[F_T + p]
                out_last[py0 + py, px0 + px] = last[p]


@njit(parallel=True, cache=True, fastmath=FASTMATH)
def backward(tile_start, lst, P, BB, W, H, tiles_x, T_final, last_k, grad_f, grad_alpha, buf, skip_ended=True):
    """grad_f (H, W, NF), grad_alpha (H, W): dL/d(outputs). T_final float32 and last_k int32 from
    `forward`. buf (M, N_GRAD) float32: per-intersection gradient w.r.t. the Gaussian's row of P
    (summed over the tile's pixels) and the sums of |dL/dmean2d|. Each pixel's recursion is
    `cpu_kernels.backward`'s (3DGS, back to front, transmittance recovered by division, the 0.99
    clamp passed through), in float32 with masks. `skip_ended` False visits the blocks whose pixels all ended before
    the splat, too (the same bits: tests/raster/test_raster_f32.py)."""
    n_tiles = tile_start.shape[0] - 1
    for t in prange(n_tiles):
        px0, py0, pw, ph = tile_rect(t, tiles_x, W, H)
        S = np.zeros(B_ROWS, np.float32)
        A = np.zeros(N_GRAD * LANES, np.float32)  # the per-Gaussian partial sums (row j: lanes of sum j)
        lastk = np.zeros(NPIX, np.int32)
        # the last contributor of each half-row (8 pixels), highest over them: a 16-pixel block whose two half-rows
        # end before splat k has no pixel where k is active, so it adds only zeros and is skipped
        row_last = np.zeros(2 * TILE, np.int32)
        kmax = tile_start[t]
        for py in range(ph):
            for px in range(pw):
                p = np.uint64((px // HW) * HSZ + py * HW + px % HW)
                S[B_T + p] = T_final[py0 + py, px0 + px]
                S[B_TGA + p] = T_final[py0 + py, px0 + px] * grad_alpha[py0 + py, px0 + px]
                lastk[p] = last_k[py0 + py, px0 + px]
                kmax = max(kmax, np.int64(lastk[p]))
                row_last[(px // HW) * TILE + py] = max(row_last[(px // HW) * TILE + py], lastk[p])
                S[B_G0 + p] = grad_f[py0 + py, px0 + px, 0]
                S[B_G1 + p] = grad_f[py0 + py, px0 + px, 1]
                S[B_G2 + p] = grad_f[py0 + py, px0 + px, 2]
                S[B_G3 + p] = grad_f[py0 + py, px0 + px, 3]
        for k in range(kmax, tile_start[t + 1]):
            for j in range(N_GRAD):
                buf[k, j] = 0.0
        cx0 = F32(px0) + HALF
        for k in range(kmax - 1, tile_start[t] - 1, -1):
            i = lst[k]
            xs, xe, ys, ye = box_in_tile(BB, i, px0, py0, pw, ph)
            mx, my, ca, cb, cc, op = splat_params(P, i)
            f0 = P[i, 6]
            f1 = P[i, 7]
            f2 = P[i, 8]
            f3 = P[i, 9]
            k32 = np.int32(k)
            for j in range(N_GRAD * LANES):
                A[j] = ZERO
            if xs <= xe and ys <= ye:
                r0, r1 = even_rows(ys, ye, py0)
                E = ellipse_rows(P, i)
                j_lo = F32(xs - px0) - HALF
                j_hi = F32(xe - px0) + HALF
                i_lo = F32(ys - py0 - r0) - HALF
                i_hi = F32(ye - py0 - r0) + HALF
                cy0 = F32(py0 + r0) + HALF
                # as the forward: each half the box touches as flat loops over its pixels (two rows a
                # vector: an even row count is a whole number of LANES), each pixel's terms added into
                # its lane's partial sums
                for h in range((xs - px0) // HW, (xe - px0) // HW + 1):
                    base = np.uint64(h * HSZ + r0 * HW)
                    cxh = cx0 + F32(h * HW)
                    fjh = F32(h * HW)
                    lo_col = float(max(xs, px0 + h * HW))
                    hi_col = float(min(xe, px0 + h * HW + HW - 1))
                    for q0 in range(0, (r1 - r0 + 1) * HW, LANES):
                        rr = h * TILE + r0 + q0 // HW
                        if skip_ended and k32 >= max(row_last[rr], row_last[rr + 1]):
                            continue
                        if not block_meets(E, py0, r0 + q0 // HW, ys, ye, lo_col, hi_col):
                            continue
                        fr0 = F32(q0 >> 3)  # the block's first row (q0 is a multiple of LANES)
                        for ln in range(LANES):
                            q = q0 + ln
                            p = base + np.uint64(q)
                            a = np.uint64(ln)
                            fc = LANE_COL[ln]
                            fr = fr0 + LANE_ROW[ln]
                            fj = fjh + fc
                            dx = mx - (cxh + fc)
                            dy = my - (cy0 + fr)
                            power = -HALF * (ca * dx * dx + cc * dy * dy) - cb * dx * dy
                            G = exp_neg32(min(power, ZERO))
                            alpha = min(op * G, AMAX)
                            act = ((k32 < lastk[p]) & (fj > j_lo) & (fj < j_hi) & (fr > i_lo) & (fr < i_hi)
                                   & (power <= ZERO) & (alpha >= AMIN))
                            one_m = ONE - alpha
                            inv_one_m = ONE / one_m
                            Tp = S[B_T + p]
                            Tn = Tp * inv_one_m
                            # S: the features blended behind this splat (3DGS's accum_rec, updated eagerly:
                            # the same expression alpha_b f_b + (1 - alpha_b) S that 3DGS evaluates lazily)
                            c0 = S[B_S0 + p]
                            c1 = S[B_S1 + p]
                            c2 = S[B_S2 + p]
                            c3 = S[B_S3 + p]
                            g0 = S[B_G0 + p]
                            g1 = S[B_G1 + p]
                            g2 = S[B_G2 + p]
                            g3 = S[B_G3 + p]
                            dL_da = ((f0 - c0) * g0 + (f1 - c1) * g1 + (f2 - c2) * g2 + (f3 - c3) * g3) * Tn
                            dL_da += S[B_TGA + p] * inv_one_m
                            dL_da = dL_da if act else ZERO
                            wa = alpha * Tn if act else ZERO
                            S[B_T + p] = Tn if act else Tp
                            S[B_S0 + p] = alpha * f0 + one_m * c0 if act else c0
                            S[B_S1 + p] = alpha * f1 + one_m * c1 if act else c1
                            S[B_S2 + p] = alpha * f2 + one_m * c2 if act else c2
                            S[B_S3 + p] = alpha * f3 + one_m * c3 if act else c3
                            # 3DGS: dL/dalpha (with the clamped alpha) reaches opacity and G as if alpha = o G;
                            # dL/dG = o dL/dalpha, and qg = G dL/dG carries it to the conic and the mean
                            qg = op * G * dL_da
                            gx = -qg * (ca * dx + cb * dy)
                            gy = -qg * (cc * dy + cb * dx)
                            A[a] += gx
                            A[a + L1] += gy
                            A[a + L2] += qg * dx * dx
                            A[a + L3] += qg * dx * dy
                            A[a + L4] += qg * dy * dy
                            A[a + L5] += G * dL_da
                            A[a + L6] += wa * g0
                            A[a + L7] += wa * g1
                            A[a + L8] += wa * g2
                            A[a + L9] += wa * g3
                            A[a + L10] += abs(gx)
                            A[a + L11] += abs(gy)
            # the lanes of every sum in one fixed tree: lane l += lane l + w for w = 8, 4, 2, 1
            for j in range(N_GRAD):
                lane_tree(A, np.uint64(j * LANES))
            g_mx = A[0]
            g_my = A[L1]
            g_ca = A[L2]
            g_cb = A[L3]
            g_cc = A[L4]
            g_op = A[L5]
            gf0 = A[L6]
            gf1 = A[L7]
            gf2 = A[L8]
            gf3 = A[L9]
            abs_x = A[L10]
            abs_y = A[L11]
            buf[k, 0] = g_mx
            buf[k, 1] = g_my
            buf[k, 2] = -HALF * g_ca
            buf[k, 3] = -g_cb
            buf[k, 4] = -HALF * g_cc
            buf[k, 5] = g_op
            buf[k, 6] = gf0
            buf[k, 7] = gf1
            buf[k, 8] = gf2
            buf[k, 9] = gf3
            buf[k, 6 + NF] = abs_x
            buf[k, 7 + NF] = abs_y
