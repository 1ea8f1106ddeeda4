"""Float64 brute-force reference rasterizer: every Gaussian against every pixel, pure torch autograd.

Written independently of the fast path (full 3x3 matrix products, plain 2x2 determinant and inverse,
per-pixel box test, cumulative products instead of a sequential loop) but with the same rules:
EWA projection with the clamped Jacobian, +0.3 dilation (or the 0.1 mip filter with opacity
compensation), alpha = min(0.99, o exp(power)), skip alpha < 1/255 and power > 0, stop before the
splat that would take transmittance below 1e-4, and a Gaussian touches only the pixels whose centres
lie in its square box |centre - mean2d| <= radius, radius = ceil(3 sqrt(lambda_max)). Tiles do not
appear: in the fast path they only organise the work.

Gradient at the alpha clamp (`clamp_grad`): "pass" (default, the 3DGS backward) is a straight-through
clamp: the value is min(0.99, o G) but the gradient flows as if alpha = o G, so a clamped splat still
passes dL/dalpha (built with the clamped value) to opacity and shape. "zero" is torch.clamp's own
autograd (no gradient where clamped): the true derivative of the forward, kept for gradcheck-style
tests and for comparing with backends that zero there (gsplat, see docs/raster.md).

Memory is O(pixels x Gaussians); use it on small images only.
"""

from __future__ import annotations

import torch

from strings_bench.raster.sh import sh_to_color
from strings_bench.raster.types import RasterInputError

CLAMP_GRAD_RULES = ("pass", "zero")


def _rotmat(q):
    q = q / q.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    w, x, y, z = q.unbind(-1)
    rows = [[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]]
    return torch.stack([torch.stack(r, dim=-1) for r in rows], dim=-2)


def _clamp_alpha(a, rule):
    if rule == "zero":
        return torch.clamp(a, max=0.99)
    # value exactly min(0.99, a) (a - a.detach() is exactly 0), gradient d/da = 1 everywhere (3DGS)
    return torch.where(a > 0.99, a - a.detach() + 0.99, a)


def rasterize_reference(means, quats, log_scales, opacity_logits, sh, camera, background, sh_degree=None,
                        mip_filter=False, near=0.01, far=1e10, clamp_grad="pass"):
    """Returns dict(color (H,W,3), alpha (H,W), depth (H,W), means2d (N,2), radii (N,)) in float64.

    clamp_grad: "pass" (3DGS, default) or "zero" (torch.clamp autograd); see the module docstring."""
    if clamp_grad not in CLAMP_GRAD_RULES:
        raise RasterInputError(f"rasterize_reference: unknown clamp_grad {clamp_grad!r}",
                               hint=f"use one of {', '.join(CLAMP_GRAD_RULES)}")
    dt = torch.float64
    means, quats, log_scales = means.to(dt), quats.to(dt), log_scales.to(dt)
    opacity_logits, sh, background = opacity_logits.to(dt).reshape(-1), sh.to(dt), torch.as_tensor(background).to(dt)
    n = means.shape[0]
    W, H = camera.width, camera.height
    fx, fy, cx, cy = camera.fx, camera.fy, camera.cx, camera.cy
    deg = {1: 0, 4: 1, 9: 2, 16: 3}[sh.shape[1]] if sh_degree is None else sh_degree
    Rc = torch.tensor(camera.R, dtype=dt)
    tc = torch.tensor(camera.t, dtype=dt)

    pc = (Rc[None] @ means[:, :, None])[:, :, 0] + tc
    z = pc[:, 2]
    ok = ((z > near) & (z < far)).detach()
    zs = torch.where(ok, z, torch.ones_like(z))
    xs = torch.where(ok, pc[:, 0], torch.zeros_like(z))
    ys = torch.where(ok, pc[:, 1], torch.zeros_like(z))
    mean2d = torch.stack([fx * xs / zs + cx, fy * ys / zs + cy], dim=-1)

    tan_x, tan_y = W / (2 * fx), H / (2 * fy)
    tx = zs * torch.minimum(torch.maximum(xs / zs, torch.full_like(z, -(cx / fx + 0.3 * tan_x))),
                            torch.full_like(z, (W - cx) / fx + 0.3 * tan_x))
    ty = zs * torch.minimum(torch.maximum(ys / zs, torch.full_like(z, -(cy / fy + 0.3 * tan_y))),
                            torch.full_like(z, (H - cy) / fy + 0.3 * tan_y))
    zero = torch.zeros_like(z)
    J = torch.stack([torch.stack([fx / zs, zero, -fx * tx / zs ** 2], -1),
                     torch.stack([zero, fy / zs, -fy * ty / zs ** 2], -1)], dim=-2)  # (N, 2, 3)
    S = torch.diag_embed(torch.exp(log_scales))
    Rq = _rotmat(quats)
    cov3 = Rq @ S @ S @ Rq.transpose(1, 2)
    JW = J @ Rc[None]
    cov2_raw = JW @ cov3 @ JW.transpose(1, 2)
    eps = 0.1 if mip_filter else 0.3
    cov2 = cov2_raw + eps * torch.eye(2, dtype=dt)
    det = cov2[:, 0, 0] * cov2[:, 1, 1] - cov2[:, 0, 1] * cov2[:, 1, 0]
    inv = torch.linalg.inv(cov2)
    opac = torch.sigmoid(opacity_logits)
    if mip_filter:
        det_raw = cov2_raw[:, 0, 0] * cov2_raw[:, 1, 1] - cov2_raw[:, 0, 1] * cov2_raw[:, 1, 0]
        opac = opac * torch.sqrt(torch.clamp_min(det_raw / det, 1e-12))

    with torch.no_grad():
        mid = 0.5 * (cov2[:, 0, 0] + cov2[:, 1, 1])
        lam = mid + torch.sqrt(torch.clamp_min(mid * mid - det, 0.1))
        radius = torch.ceil(3 * torch.sqrt(lam))

    cam_center = torch.tensor(camera.center, dtype=dt)
    color = sh_to_color(sh, means, cam_center, deg)

    jj, ii = torch.meshgrid(torch.arange(H, dtype=dt) + 0.5, torch.arange(W, dtype=dt) + 0.5, indexing="ij")
    pix = torch.stack([ii.reshape(-1), jj.reshape(-1)], dim=-1)  # (P, 2) pixel centres
    d = mean2d[None] - pix[:, None]  # (P, N, 2)
    with torch.no_grad():
        in_box = (d.abs() <= radius[None, :, None]).all(-1) & ok[None]
        visible = in_box.any(0)
    power = -0.5 * (inv[None, :, 0, 0] * d[..., 0] ** 2 + inv[None, :, 1, 1] * d[..., 1] ** 2) \
        - inv[None, :, 0, 1] * d[..., 0] * d[..., 1]
    alpha = _clamp_alpha(opac[None] * torch.exp(power), clamp_grad)
    use = in_box & (power <= 0) & (alpha >= 1 / 255)
    alpha = torch.where(use, alpha, torch.zeros_like(alpha))

    order = torch.argsort(torch.where(visible, z, torch.full_like(z, float("inf"))).detach(), stable=True)
    alpha = alpha[:, order]
    with torch.no_grad():
        keep = torch.cumprod(1 - alpha, dim=1) >= 1e-4  # stop before the splat that crosses 1e-4
    alpha = alpha * keep
    t_incl = torch.cumprod(1 - alpha, dim=1)
    t_excl = torch.cat([torch.ones_like(t_incl[:, :1]), t_incl[:, :-1]], dim=1)
    w = alpha * t_excl  # (P, N)
    t_final = t_incl[:, -1] if n else torch.ones(pix.shape[0], dtype=dt)
    rgb = w @ color[order] + t_final[:, None] * background
    acc = 1 - t_final
    dsum = w @ z[order]
    depth = dsum / acc.clamp_min(1e-10)
    return {"color": rgb.reshape(H, W, 3), "alpha": acc.reshape(H, W), "depth": depth.reshape(H, W),
            "means2d": mean2d, "radii": torch.where(visible, radius, torch.zeros_like(radius)).to(torch.int32)}
