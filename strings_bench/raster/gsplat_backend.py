"""gsplat backend (CUDA): the same interface on top of gsplat.rasterization (gsplat >= 1.4).

Not run on a GPU by this version yet. CI runs this code on the CPU with gsplat's CUDA stages routed to
gsplat's PyTorch reference functions (tests/raster/test_gsplat_reference.py, docs/raster.md "The CUDA path on
the CPU"); tests marked `gpu` compare it with the CPU backend when CUDA and gsplat are present.

Mapping: scales = exp(log_scales); opacities = sigmoid(logits); colours are evaluated by our own SH
code (sh.py) and passed as plain RGB (sh_degree=None) so both backends share one colour rule;
render_mode "RGB+D" gives the accumulated depth, divided by alpha here; the background is
composited here (color + (1 - alpha) bg). mip_filter -> rasterize_mode="antialiased", eps2d=0.1
(gsplat's compensation sqrt(det Sigma / det(Sigma + eps2d I)) is the Mip-Splatting 2D filter);
otherwise eps2d=0.3 (3DGS dilation). packed=False.

Differences from the CPU backend (see docs/raster.md; measured in docs/raster.md, "The gsplat backend"): gsplat lets a Gaussian
touch every pixel of the tiles its opacity-aware radius overlaps, i.e. wherever its alpha >= 1/255 (the
CPU backend only pixels in its 3-sigma box), keeps Gaussians exactly on the near plane (culls z < near),
and treats the alpha clamp differently from 3DGS (read in gsplat's CUDA source):
- the forward clamps alpha at 0.999 in the releases v1.3.0 - v1.5.3 (`min(0.999f, opac * vis)`), at
  0.99 (`MAX_ALPHA`) on its main branch since commit c5ff586b (2026-02-04, not in a release tag);
- the backward computes dL/dalpha with the clamped alpha, as 3DGS, but adds the conic, means2d
  (and absgrad) and opacity gradients only `if (opac * vis <= 0.999f)` (main: `<= MAX_ALPHA`): where
  the clamp is active they are zero (torch.clamp's rule; the colour gradient still flows). 3DGS and
  the CPU backend pass them through as if alpha = o G. On this backend opaque splats therefore feed
  neither the densification statistic nor their opacity at their clamped pixels. gsplat's own CUDA
  code cannot be changed from here.

means2d: gsplat returns (C=1, N, 2); we expose an (N, 2) leaf whose .grad is filled by a hook on
gsplat's tensor during backward (retain_grad() on it is harmless), so callers see the same shape
and pixel units as on the CPU. absgrad likewise comes from gsplat's `means2d.absgrad`.
"""

from __future__ import annotations

import weakref

import torch


def gsplat_available() -> bool:
    try:
        import gsplat  # noqa: F401
    except Exception:  # ImportError, or a CUDA extension that fails to load
        return False
    return torch.cuda.is_available()


def expose_means2d(m2d_gs: torch.Tensor, compute_absgrad: bool) -> tuple[torch.Tensor, torch.Tensor | None]:
    """gsplat's (1, N, 2) projected centres as an (N, 2) leaf whose .grad a hook on `m2d_gs` fills
    during backward, and (with compute_absgrad) an (N, 2) buffer the hook fills from `m2d_gs.absgrad`.

    References, so that nothing leaks and nothing is lost:
    - The hook reaches `m2d_gs`, the leaf and the buffer through weak references: a closure holding
      `m2d_gs` itself, stored in `m2d_gs`'s own hooks, is a reference cycle through autograd that
      Python's collector cannot see, and it kept every step's graph (and its GPU memory) alive.
      tests/raster/test_raster.py checks that a step's tensors are freed when the step ends.
    - The leaf and the buffer hold `m2d_gs` (attribute `_gsplat_means2d`): gsplat's backward sets
      `.absgrad` on the Python object that its `ctx.saved_tensors` returns, which is `m2d_gs` only
      while `m2d_gs` is alive. Without this, `m2d_gs` died with gsplat's `meta` when the backend
      returned, and absgrad stayed zero (found by tests/raster/test_gsplat_reference.py; no cycle: the
      hook holds neither strongly).
    """
    n, dt, dev = m2d_gs.shape[1], m2d_gs.dtype, m2d_gs.device
    means2d = m2d_gs.detach()[0].clone().requires_grad_(m2d_gs.requires_grad)
    absgrad = torch.zeros((n, 2), dtype=dt, device=dev) if compute_absgrad else None
    if m2d_gs.requires_grad:
        means2d._gsplat_means2d = m2d_gs
        if absgrad is not None:
            absgrad._gsplat_means2d = m2d_gs
        source, leaf_ref = weakref.ref(m2d_gs), weakref.ref(means2d)
        absgrad_ref = weakref.ref(absgrad) if absgrad is not None else None

        def _hook(grad):
            leaf = leaf_ref()
            if leaf is not None:
                g = grad[0].detach()
                leaf.grad = g.clone() if leaf.grad is None else leaf.grad + g
            src, buf = source(), (absgrad_ref() if absgrad_ref is not None else None)
            if buf is not None and src is not None and getattr(src, "absgrad", None) is not None:
                buf.copy_(src.absgrad[0])
            return grad

        m2d_gs.register_hook(_hook)
    return means2d, absgrad


def require_cuda(means: torch.Tensor) -> None:
    """gsplat's kernels run on CUDA tensors only. (tests/_gsplat_cpu.py replaces this check, together
    with gsplat's CUDA stages, to run this backend on the CPU in CI.)"""
    from strings_bench.raster.types import RasterInputError

    if means.device.type != "cuda":
        raise RasterInputError(f"rasterize: backend 'gsplat' needs CUDA tensors, got {means.device}",
                               hint="move the tensors to a CUDA device, or use backend='cpu'")


def rasterize_gsplat(means, quats, log_scales, opacity_logits, colors, camera, background, mip_filter,
                     compute_absgrad, near, far):
    from strings_bench.raster.types import RasterInputError, RasterOutput

    try:
        from gsplat import rasterization
    except Exception as exc:
        raise RasterInputError(f"rasterize: backend 'gsplat' requested but gsplat does not import ({exc})",
                               hint="pip install 'strings-bench[cuda]' on a CUDA machine, or use backend='cpu'")
    require_cuda(means)
    dev, dt = means.device, means.dtype
    viewmat = torch.as_tensor(camera.viewmat, dtype=dt, device=dev)[None]
    Ks = torch.as_tensor(camera.K, dtype=dt, device=dev)[None]
    # gsplat normalises quaternions without a guard: a zero quaternion becomes the identity here,
    # as on the CPU (where q / max(|q|, 1e-12) = 0 gives the identity rotation).
    qn = quats.norm(dim=-1, keepdim=True)
    ident = torch.tensor([1.0, 0.0, 0.0, 0.0], dtype=dt, device=dev).expand_as(quats)
    quats = torch.where(qn > 1e-12, quats, ident)
    render, alphas, meta = rasterization(
        means, quats, torch.exp(log_scales), torch.sigmoid(opacity_logits), colors, viewmat, Ks,
        int(camera.width), int(camera.height), near_plane=float(near), far_plane=float(far),
        eps2d=0.1 if mip_filter else 0.3, sh_degree=None, packed=False, tile_size=16, backgrounds=None,
        render_mode="RGB+D", absgrad=bool(compute_absgrad),
        rasterize_mode="antialiased" if mip_filter else "classic")
    render, alpha = render[0], alphas[0, ..., 0]
    color = render[..., :3] + (1.0 - alpha)[..., None] * background
    depth = render[..., 3] / alpha.clamp_min(1e-10)
    radii = meta["radii"][0]
    if radii.dim() == 2:  # gsplat >= 1.5 returns per-axis radii (N, 2)
        radii = radii.max(dim=-1).values
    radii = radii.to(torch.int32)
    means2d, absgrad = expose_means2d(meta["means2d"], compute_absgrad)
    return RasterOutput(color=color, alpha=alpha, depth=depth, radii=radii, means2d=means2d,
                        absgrad=absgrad, visible=radii > 0, backend="gsplat")
