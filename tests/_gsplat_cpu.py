"""Test-only: the suite's gsplat backend on CPU tensors, gsplat's CUDA stages routed to gsplat's own
pure-PyTorch reference implementations (`gsplat/cuda/_torch_impl.py`).

    with gsplat_on_cpu():
        out = rasterize(..., backend="gsplat")        # CPU tensors, strings_bench/raster/gsplat_backend.py

What runs is gsplat's real `rasterization` (its Python: colours, "RGB+D", the antialiased
compensation, absgrad plumbing, tiles) and the backend's real code. Only the five calls that would
launch CUDA kernels are replaced, each by gsplat's reference function of that stage:

- `fully_fused_projection` -> `_quat_scale_to_covar_preci` + `_fully_fused_projection`. The reference
  returns radii of 3.33 sigma and keeps its own near/far test (z > near); the CUDA kernel of 1.5.3
  (`ProjectionEWA3DGSFused.cu`, read) computes opacity-aware radii `ceil(min(3.33, sqrt(2 ln(255 o)))
  sqrt(Sigma_ii))`, culls o (x compensation) < 1/255, z < near, z > far, det <= 0 and boxes off the
  image, and leaves culled entries' outputs at zero. `_cuda_radii` below is that kernel's rule, so the
  backend's `radii` and `means2d` are what a GPU returns; renders do not depend on it (a Gaussian is
  drawn where alpha >= 1/255, which both boxes contain).
- `isect_tiles`, `isect_offset_encode` -> `_isect_tiles`, `_isect_offset_encode` as they are.
- `rasterize_to_pixels` -> `_rasterize_to_pixels` as it is. It needs two things that are not pure
  PyTorch: the CUDA `rasterize_to_indices_in_range` (which Gaussian-pixel pairs are blended) and
  nerfacc's segmented transmittance. `_indices_in_range` is the CUDA kernel
  `RasterizeToIndices3DGS.cu` written in torch (same rules: pixel centres at +0.5, sigma < 0 or
  alpha = min(0.999, o exp(-sigma)) < 1/255 skipped, the pixel stops before the splat that takes T
  to <= 1e-4; arithmetic in the input dtype); `_NerfaccStandIn` gives `render_weight_from_alpha` and
  `accumulate_along_rays` in torch.
- absgrad: the CUDA backward sums |dL_pixel / d means2d| over pixels into `means2d.absgrad`. Here the
  per-pair copy of means2d inside gsplat's `accumulate` gets a hook that adds |grad| per Gaussian.

Backward is torch autograd through gsplat's reference code, so at the 0.999 clamp it is torch.clamp's
rule, which is the rule of gsplat's CUDA backward (`if (opac * vis <= 0.999f)`, read).

No CUDA code is compiled or loaded: `assert_no_cuda_backend()` checks that gsplat's JIT loader
(`gsplat.cuda._backend`) was never imported.
"""

from __future__ import annotations

import contextlib
import sys
import types

import torch

ALPHA_THRESHOLD = 1.0 / 255.0


def _cuda_radii(means, covars, viewmats, Ks, width, height, eps2d, near, far, radius_clip, opacities,
                compensations):
    """(C, N, 2) int32 radii by the rule of gsplat 1.5.3's `projection_ewa_3dgs_fused_fwd_kernel`."""
    from gsplat.cuda._torch_impl import _persp_proj, _world_to_cam

    with torch.no_grad():
        means_c, covars_c = _world_to_cam(means, covars, viewmats)
        means2d, cov2d = _persp_proj(means_c, covars_c, Ks, width, height)
        a, b, c = cov2d[..., 0, 0] + eps2d, cov2d[..., 0, 1], cov2d[..., 1, 1] + eps2d
        det = a * c - b * cov2d[..., 1, 0]
        z = means_c[..., 2]
        opacity = torch.broadcast_to(opacities[..., None, :], z.shape)
        if compensations is not None:
            opacity = opacity * compensations
        extend = torch.clamp(torch.sqrt(2.0 * torch.log(opacity.clamp_min(ALPHA_THRESHOLD) / ALPHA_THRESHOLD)),
                             max=3.33)
        rx = torch.ceil(extend * torch.sqrt(a.clamp_min(0)))
        ry = torch.ceil(extend * torch.sqrt(c.clamp_min(0)))
        keep = (z >= near) & (z <= far) & (det > 0) & (opacity >= ALPHA_THRESHOLD)
        keep &= ~((rx <= radius_clip) & (ry <= radius_clip))
        u, v = means2d.unbind(-1)
        keep &= ~((u + rx <= 0) | (u - rx >= width) | (v + ry <= 0) | (v - ry >= height))
        radii = torch.where(keep[..., None], torch.stack([rx, ry], -1), torch.zeros_like(a)[..., None])
    return radii.to(torch.int32), keep


def fully_fused_projection(means, covars, quats, scales, viewmats, Ks, width, height, eps2d=0.3, packed=False,
                           near_plane=0.01, far_plane=1e10, radius_clip=0.0, sparse_grad=False,
                           calc_compensations=False, camera_model="pinhole", opacities=None):
    from gsplat.cuda._torch_impl import _fully_fused_projection, _quat_scale_to_covar_preci

    assert not packed and covars is None and camera_model == "pinhole", "the backend's settings only"
    covars, _ = _quat_scale_to_covar_preci(quats, scales, compute_covar=True, compute_preci=False)
    # The kernel returns before touching a Gaussian culled by depth (and its backward skips it); the
    # reference would still project it, and z = 0 gives inf and then NaN gradients through
    # torch.where. Such rows get a stand-in point 1 unit in front of the camera instead.
    assert viewmats.shape[0] == 1, "one camera: the backend's call"
    with torch.no_grad():
        R, t = viewmats[0, :3, :3], viewmats[0, :3, 3]
        z = means @ R[2] + t[2]
        in_depth = (z >= near_plane) & (z <= far_plane)
        ahead = R.T @ (torch.tensor([0.0, 0.0, 1.0], dtype=means.dtype) - t)
    means_in = torch.where(in_depth[:, None], means, ahead.expand_as(means))
    _, means2d, depths, conics, compensations = _fully_fused_projection(
        means_in, covars, viewmats, Ks, width, height, eps2d=eps2d, near_plane=near_plane, far_plane=far_plane,
        calc_compensations=calc_compensations)
    radii, keep = _cuda_radii(means_in, covars, viewmats, Ks, width, height, eps2d, near_plane, far_plane,
                              radius_clip, opacities, compensations)
    keep &= in_depth
    radii = radii * keep[..., None]
    # the kernel writes outputs of kept Gaussians only (the buffers start at zero)
    means2d = torch.where(keep[..., None], means2d, torch.zeros_like(means2d))
    depths = torch.where(keep, depths, torch.zeros_like(depths))
    conics = torch.where(keep[..., None], conics, torch.zeros_like(conics))
    return radii, means2d, depths, conics, compensations


def isect_tiles(means2d, radii, depths, tile_size, tile_width, tile_height, sort=True, segmented=False,
                packed=False, n_images=None, image_ids=None, gaussian_ids=None):
    from gsplat.cuda._torch_impl import _isect_tiles

    assert not packed
    return _isect_tiles(means2d, radii, depths, tile_size, tile_width, tile_height, sort=sort)


def isect_offset_encode(isect_ids, n_images, tile_width, tile_height):
    from gsplat.cuda._torch_impl import _isect_offset_encode

    return _isect_offset_encode(isect_ids, n_images, tile_width, tile_height)


class _AbsgradSink:
    """Where `accumulate` sends |per-pair means2d gradient| while a render with absgrad is in flight."""

    buffer: torch.Tensor | None = None


def rasterize_to_pixels(means2d, conics, colors, opacities, image_width, image_height, tile_size, isect_offsets,
                        flatten_ids, backgrounds=None, masks=None, packed=False, absgrad=False):
    from gsplat.cuda._torch_impl import _rasterize_to_pixels

    assert not packed and masks is None and means2d.shape[0] == 1, "one image, unpacked: the backend's call"
    if absgrad:
        means2d.absgrad = torch.zeros_like(means2d)  # filled during backward, as the CUDA backward does
        _AbsgradSink.buffer = means2d.absgrad
    try:
        return _rasterize_to_pixels(means2d, conics, colors, opacities, image_width, image_height, tile_size,
                                    isect_offsets, flatten_ids, backgrounds=backgrounds)
    finally:
        _AbsgradSink.buffer = None


def _accumulate_with_absgrad(original):
    """gsplat's `accumulate`, given per-pair copies of the Gaussians' values, so that the gradient of
    each (Gaussian, pixel) pair's means2d can be read (its |.| summed per Gaussian is AbsGS' statistic)."""

    def accumulate(means2d, conics, opacities, colors, gaussian_ids, pixel_ids, image_ids, image_width,
                   image_height):
        sink = _AbsgradSink.buffer
        if sink is None or not means2d.requires_grad:
            return original(means2d, conics, opacities, colors, gaussian_ids, pixel_ids, image_ids, image_width,
                            image_height)
        pair_means = means2d[image_ids, gaussian_ids]  # (M, 2)
        ids = gaussian_ids.clone()

        def add_abs(grad):
            sink[0].index_add_(0, ids, grad.abs())

        pair_means.register_hook(add_abs)
        m = pair_means.shape[0]
        pick = lambda x: x[image_ids, gaussian_ids][None]  # noqa: E731
        return original(pair_means[None], pick(conics), pick(opacities), pick(colors),
                        torch.arange(m, device=means2d.device), pixel_ids,
                        torch.zeros_like(image_ids), image_width, image_height)

    return accumulate


@torch.no_grad()
def _indices_in_range(range_start, range_end, transmittances, means2d, conics, opacities, image_width,
                      image_height, tile_size, isect_offsets, flatten_ids):
    """gsplat 1.5.3's `rasterize_to_indices_3dgs` kernel in torch: the (Gaussian, pixel, image) pairs
    that the batches [range_start, range_end) of each tile blend, grouped by pixel, front to back."""
    I, N = means2d.shape[0], means2d.shape[1]
    tile_h, tile_w = isect_offsets.shape[-2:]
    n_isects = flatten_ids.shape[0]
    offsets = torch.cat([isect_offsets.reshape(-1).long(), torch.tensor([n_isects])])
    block = tile_size * tile_size
    dt = means2d.dtype
    m2 = means2d.reshape(I * N, 2)
    cn = conics.reshape(I * N, 3)
    op = opacities.reshape(I * N)
    g_out, p_out, key_out = [], [], []
    for t in range(I * tile_h * tile_w):
        image_id, tile_id = divmod(t, tile_h * tile_w)
        ty, tx = divmod(tile_id, tile_w)
        lo = int(offsets[t]) + block * range_start
        hi = min(int(offsets[t + 1]), int(offsets[t]) + block * range_end)
        if lo >= hi:
            continue
        ys = torch.arange(ty * tile_size, min((ty + 1) * tile_size, image_height))
        xs = torch.arange(tx * tile_size, min((tx + 1) * tile_size, image_width))
        if len(ys) == 0 or len(xs) == 0:
            continue
        py, px = torch.meshgrid(ys, xs, indexing="ij")
        py, px = py.reshape(-1), px.reshape(-1)
        g = flatten_ids[lo:hi].long()  # (G,) in depth order
        dx = m2[g, 0][:, None] - (px.to(dt) + 0.5)[None]
        dy = m2[g, 1][:, None] - (py.to(dt) + 0.5)[None]
        c = cn[g]
        sigma = 0.5 * (c[:, 0:1] * dx * dx + c[:, 2:3] * dy * dy) + c[:, 1:2] * dx * dy
        alpha = torch.clamp_max(op[g][:, None] * torch.exp(-sigma), 0.999)
        valid = (sigma >= 0) & (alpha >= ALPHA_THRESHOLD)
        a = torch.where(valid, alpha, torch.zeros_like(alpha))
        T0 = transmittances[image_id][py, px].to(dt)
        # sequential products T0 (1 - a_1) (1 - a_2) ... as the kernel multiplies
        next_T = torch.cumprod(torch.cat([T0[None], 1.0 - a]), dim=0)[1:]
        stops = valid & (next_T <= 1e-4)
        first_stop = torch.where(stops.any(0), stops.float().argmax(0), torch.full_like(px, len(g)))
        order = torch.arange(len(g))[:, None]
        take = valid & (order < first_stop[None])
        gi, pi = torch.nonzero(take, as_tuple=True)
        pix = py[pi] * image_width + px[pi] + image_id * image_height * image_width
        g_out.append(g[gi] % N)
        p_out.append(pix)
        key_out.append(pix * (n_isects + 1) + (lo + gi))  # pixel, then front to back
    if not g_out:
        empty = torch.zeros(0, dtype=torch.long)
        return empty, empty, empty
    gids, pids, keys = torch.cat(g_out), torch.cat(p_out), torch.cat(key_out)
    order = torch.argsort(keys)
    gids, pids = gids[order], pids[order]
    return gids, pids % (image_width * image_height), pids // (image_width * image_height)


class _NerfaccStandIn(types.ModuleType):
    """nerfacc's two functions that gsplat's `accumulate` imports, in torch (pairs grouped by ray,
    front to back, as `_indices_in_range` returns them)."""

    def __init__(self):
        super().__init__("nerfacc")
        self.render_weight_from_alpha = self._render_weight_from_alpha
        self.accumulate_along_rays = self._accumulate_along_rays

    @staticmethod
    def _render_weight_from_alpha(alphas, packed_info=None, ray_indices=None, n_rays=None, prefix_trans=None):
        assert packed_info is None and prefix_trans is None and ray_indices is not None
        m = alphas.shape[0]
        if m == 0:
            return alphas.clone(), torch.ones_like(alphas)
        rays, inverse, counts = torch.unique_consecutive(ray_indices, return_inverse=True, return_counts=True)
        starts = torch.cumsum(counts, 0) - counts
        pos = torch.arange(m) - starts[inverse]
        dense = torch.ones(len(rays), int(counts.max()) + 1, dtype=alphas.dtype)
        dense = dense.index_put((inverse, pos + 1), 1.0 - alphas)
        trans = torch.cumprod(dense, dim=1)[inverse, pos]  # exclusive: prod of the earlier pairs
        return alphas * trans, trans

    @staticmethod
    def _accumulate_along_rays(weights, values=None, ray_indices=None, n_rays=None):
        src = weights[..., None] if values is None else weights[..., None] * values
        out = torch.zeros((n_rays, src.shape[-1]), dtype=src.dtype, device=src.device)
        return out.index_add(0, ray_indices, src)


@contextlib.contextmanager
def gsplat_on_cpu():
    """Within the block, `rasterize(..., backend="gsplat")` runs on CPU tensors through gsplat's
    reference functions (module docstring). Everything is restored afterwards."""
    import gsplat.cuda._torch_impl as torch_impl
    import gsplat.cuda._wrapper as wrapper
    import gsplat.rendering as rendering

    import strings_bench.raster.gsplat_backend as backend

    patches = [(rendering, "fully_fused_projection", fully_fused_projection),
               (rendering, "isect_tiles", isect_tiles),
               (rendering, "isect_offset_encode", isect_offset_encode),
               (rendering, "rasterize_to_pixels", rasterize_to_pixels),
               (wrapper, "rasterize_to_indices_in_range", _indices_in_range),
               (torch_impl, "accumulate", _accumulate_with_absgrad(torch_impl.accumulate)),
               (backend, "require_cuda", lambda means: None)]
    saved = [(mod, name, getattr(mod, name)) for mod, name, _ in patches]
    had_nerfacc = sys.modules.get("nerfacc")
    try:
        for mod, name, new in patches:
            setattr(mod, name, new)
        sys.modules["nerfacc"] = _NerfaccStandIn()
        yield
    finally:
        for mod, name, old in saved:
            setattr(mod, name, old)
        if had_nerfacc is None:
            sys.modules.pop("nerfacc", None)
        else:
            sys.modules["nerfacc"] = had_nerfacc


def assert_no_cuda_backend():
    """gsplat compiles its CUDA extension when `gsplat.cuda._backend` is first imported."""
    assert "gsplat.cuda._backend" not in sys.modules, "a gsplat CUDA wrapper was called: its JIT loader ran"


__all__ = ["gsplat_on_cpu", "assert_no_cuda_backend"]
