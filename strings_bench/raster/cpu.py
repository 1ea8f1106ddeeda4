"""CPU backend: torch projection + numba tile rasterizer with a hand-written backward."""

from __future__ import annotations

import numba
import numpy as np
import torch

from strings_bench.core.instrument import active, note, stage, timed
import strings_bench.raster.cpu_kernels as K
import strings_bench.raster.cpu_kernels_f32 as K32


CHUNK = 2  # tiles per work item: tiles differ a lot in cost, so hand them out in small chunks


def _np(x: torch.Tensor, dtype) -> np.ndarray:
    return np.ascontiguousarray(x.detach().cpu().numpy(), dtype=dtype)


def _np_in(x: torch.Tensor) -> np.ndarray:
    """A float32 or float64 tensor as an array without a copy (the preprocessing kernels read both and
    compute in float64); other dtypes as a float64 copy."""
    if x.dtype in (torch.float32, torch.float64):
        return x.detach().contiguous().numpy()
    return _np(x, np.float64)


# blend kernels by precision: "f32" (default: float32, vectorised) and "f64" (the float64 reference)
BLEND_KERNELS = {"f32": K32, "f64": K}


class RasterizeTiles(torch.autograd.Function):
    """Blend (means2d, conics, opacities, features) over an H x W image.

    Returns features (H, W, NF) = sum_i w_i f_i and alpha (H, W) = 1 - prod_i (1 - alpha_i).
    `absgrad_out` (N, 2), if given, is filled in backward with sum over pixels of |dL/dmean2d|.
    `precision`: "f32" (cpu_kernels_f32) or "f64" (cpu_kernels, the reference).
    """

    @staticmethod
    @stage("tiles.forward")
    def forward(ctx, means2d, conics, opacities, feats, radii, bbox, depths, width, height, absgrad_out,
                precision="f32"):
        KB = BLEND_KERNELS[precision]
        N = means2d.shape[0]
        H, W = int(height), int(width)
        tiles_x, tiles_y = (W + K.TILE - 1) // K.TILE, (H + K.TILE - 1) // K.TILE
        with torch.no_grad():
            if depths.dtype == torch.float32 and radii.dtype == torch.int32:  # the same order, 4-5x faster
                order = torch.from_numpy(K.depth_order(radii.contiguous().numpy(), depths.detach().contiguous().numpy()))
            else:
                vis = torch.nonzero(radii > 0).flatten()
                order = vis[torch.argsort(depths.detach()[vis], stable=True)]
        P, BB = KB.pack(order.numpy(), *(_np_in(x) for x in (means2d, conics, opacities, feats)),
                       bbox.contiguous().numpy())
        tile_start, lst, g_start, isect_pos = K.bin_tiles(BB, tiles_x, tiles_y)
        P, BB, lst = K.rows_in_list_order(lst, P, BB)  # each tile's rows one after the other (same results)
        out_f = np.empty((H, W, K.NF), np.float32)
        out_T = np.empty((H, W), np.float32 if precision == "f32" else np.float64)
        out_last = np.empty((H, W), np.int32 if precision == "f32" else np.int64)
        with numba.parallel_chunksize(CHUNK), timed("blend.forward"):
            KB.forward(tile_start, lst, P, BB, W, H, tiles_x, out_f, out_T, out_last)
        if active():  # the blend's inputs, for a profiling tool that counts its work
            note("blend.forward", tile_start=tile_start, lst=lst, P=P, BB=BB, W=W, H=H, tiles_x=tiles_x,
                 out_last=out_last, visible=int(order.shape[0]))
        ctx.saved = (tile_start, lst, g_start, isect_pos, P, BB, out_T, out_last, tiles_x)
        ctx.kernels = KB
        ctx.order = order
        ctx.N = N
        ctx.size = (W, H)
        ctx.absgrad_out = absgrad_out
        ctx.dtypes = (means2d.dtype, conics.dtype, opacities.dtype, feats.dtype)
        feat_img = torch.from_numpy(out_f).to(feats.dtype)
        alpha = torch.from_numpy((1.0 - out_T).astype(np.float32)).to(feats.dtype)
        return feat_img, alpha

    @staticmethod
    @stage("tiles.backward")
    def backward(ctx, grad_f, grad_alpha):
        tile_start, lst, g_start, isect_pos, P, BB, out_T, out_last, tiles_x = ctx.saved
        W, H = ctx.size
        N = ctx.N
        if grad_f is None:
            grad_f = torch.zeros((H, W, K.NF), device="cpu")
        if grad_alpha is None:
            grad_alpha = torch.zeros((H, W), device="cpu")
        gF = _np(grad_f, np.float32)
        gA = _np(grad_alpha, np.float32)
        M = lst.shape[0]
        buf = np.empty((M, K.N_GRAD), np.float32)
        with numba.parallel_chunksize(CHUNK):
            ctx.kernels.backward(tile_start, lst, P, BB, W, H, tiles_x, out_T, out_last, gF, gA, buf)
        # Each gradient in its input's dtype (a float32 is rounded once from the float64 sum).
        # (device given: a caller's default device, e.g. meta, must not reach these host buffers)
        d_m, d_c, d_o, d_f = (torch.empty(shape, dtype=dt, device="cpu") for shape, dt in
                              zip(((N, 2), (N, 3), (N,), (N, K.NF)), ctx.dtypes))
        # absgrad_out is _rasterize_cpu's fresh (N, 2) zeros on the CPU: the kernel fills it in place
        g_abs = ctx.absgrad_out.numpy() if ctx.absgrad_out is not None else np.empty((0, 2))
        K.reduce_intersections(buf, g_start, isect_pos, ctx.order.numpy(), d_m.numpy(), d_c.numpy(), d_o.numpy(),
                               d_f.numpy(), g_abs)
        return d_m, d_c, d_o, d_f, None, None, None, None, None, None, None


def camera_array(camera) -> np.ndarray:
    """R (9), t (3), fx, fy, cx, cy, Jacobian clamp limits (x-, x+, y-, y+), camera centre (3)."""
    W, H = camera.width, camera.height
    fx, fy, cx, cy = float(camera.fx), float(camera.fy), float(camera.cx), float(camera.cy)
    tan_x, tan_y = 0.5 * W / fx, 0.5 * H / fy
    lims = [cx / fx + 0.3 * tan_x, (W - cx) / fx + 0.3 * tan_x, cy / fy + 0.3 * tan_y, (H - cy) / fy + 0.3 * tan_y]
    return np.concatenate([np.asarray(camera.R, np.float64).ravel(), np.asarray(camera.t, np.float64),
                           [fx, fy, cx, cy], lims, np.asarray(camera.center, np.float64)])


class Preprocess(torch.autograd.Function):
    """Numba per-Gaussian projection + SH colour (see cpu_preprocess). Returns means2d (N,2),
    conics (N,3), opacities (N,), feats (N,4) = RGB and camera depth, radii (N,) int32, bbox (N,4)."""

    @staticmethod
    @stage("preprocess.forward")
    def forward(ctx, means, quats, log_scales, opacity_logits, sh, deg, camera, mip, near, far, sh_rest=None):
        """sh (N, K, 3), or with `sh_rest`: sh (N, 1, 3) the DC band and sh_rest (N, K - 1, 3) the
        others (the model's sh0 and shN, read where they are: no concatenation, no split of the
        gradient)."""
        from strings_bench.raster.cpu_preprocess import preprocess_forward
        from strings_bench.raster.projection import DILATION, MIP_FILTER

        N = means.shape[0]
        cam = camera_array(camera)
        eps = MIP_FILTER if mip else DILATION
        arrs = [_np_in(x) for x in (means, quats, log_scales, opacity_logits, sh)]
        split = sh_rest is not None
        rest = _np_in(sh_rest) if split else arrs[4]
        means2d = np.empty((N, 2), np.float32)
        conics = np.empty((N, 3), np.float32)
        opac = np.empty(N, np.float32)
        feats = np.empty((N, K.NF), np.float32)
        radii = np.empty(N, np.int32)
        bbox = np.empty((N, 4), np.int32)
        preprocess_forward(*arrs, rest, 0 if split else 1, int(deg), cam, int(camera.width), int(camera.height),
                           float(near), float(far), eps, bool(mip), means2d, conics, opac, feats, radii, bbox)
        # The kernels read the parameters' own memory: saved for backward (torch's version check
        # refuses a backward after an in-place change), converted again there.
        if split:
            ctx.save_for_backward(means, quats, log_scales, opacity_logits, sh, sh_rest)
        else:
            ctx.save_for_backward(means, quats, log_scales, opacity_logits, sh)
        ctx.setup = (int(deg), cam, eps, bool(mip), radii)
        ctx.dtypes = [x.dtype for x in (means, quats, log_scales, opacity_logits, sh)] + (
            [sh_rest.dtype] if split else [])
        dt = means.dtype
        radii_t, bbox_t = torch.from_numpy(radii), torch.from_numpy(bbox)
        ctx.mark_non_differentiable(radii_t, bbox_t)
        return (torch.from_numpy(means2d).to(dt), torch.from_numpy(conics).to(dt), torch.from_numpy(opac).to(dt),
                torch.from_numpy(feats).to(dt), radii_t, bbox_t)

    @staticmethod
    @stage("preprocess.backward")
    def backward(ctx, g_means2d, g_conics, g_opac, g_feats, _g_radii, _g_bbox):
        from strings_bench.raster.cpu_preprocess import preprocess_backward

        saved = [_np_in(x) for x in ctx.saved_tensors]
        split = len(saved) == 6
        means, quats, log_scales, logits, sh = saved[:5]
        rest = saved[5] if split else sh
        deg, cam, eps, mip, radii = ctx.setup
        N = means.shape[0]
        grads_in = [(_np_in(g) if g is not None else np.zeros(shape))
                    for g, shape in ((g_means2d, (N, 2)), (g_conics, (N, 3)), (g_opac, (N,)), (g_feats, (N, K.NF)))]
        # Gradients are written in the inputs' dtype (float32: rounded once at the store, as the
        # float64 result's conversion did).
        outs = [np.empty_like(x) for x in (means, quats, log_scales, logits, sh)]
        d_rest = np.empty_like(rest) if split else outs[4]
        preprocess_backward(means, quats, log_scales, logits, sh, rest, 0 if split else 1, deg, cam, eps, mip, radii,
                            *grads_in, *outs, d_rest)
        res = [torch.from_numpy(o).to(dt) for o, dt in zip(outs + ([d_rest] if split else []), ctx.dtypes)]
        return (*res[:5], None, None, None, None, None, res[5] if split else None)
