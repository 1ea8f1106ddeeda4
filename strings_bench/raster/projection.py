"""Per-Gaussian EWA projection in torch (autograd): camera transform, 2D covariance, conic, radius.

Rules (3DGS, with gsplat's handling of an off-centre principal point):
- p = R @ mean + t; a Gaussian with z <= near or z >= far is culled (radius 0).
- means2d = (fx x / z + cx, fy y / z + cy) in pixels; pixel (i, j) has its centre at (i + 0.5, j + 0.5).
- Jacobian of the perspective map evaluated with x/z, y/z clamped to the frustum widened by
  0.3 x tan(fov/2) on each side (= 1.3 x tan(fov/2) for a centred principal point, as in 3DGS).
- Sigma2D = J R Sigma R^T J^T + eps I, eps = 0.3 px^2 (3DGS dilation) or 0.1 with the Mip-Splatting
  2D filter, which also scales opacity by sqrt(det Sigma2D_raw / det(Sigma2D_raw + 0.1 I)).
- radius = ceil(3 sqrt(lambda_max)), lambda_max = mid + sqrt(max(0.1, mid^2 - det)).
- A Gaussian contributes to a pixel only inside its square pixel box |centre - mean2d| <= radius
  (per axis); it is culled when that box holds no pixel of the image.

det(Sigma2D_raw) is computed as the sum of the squared 2x2 minors of M = J R Rq S (Cauchy-Binet),
which is never negative, so huge or needle-thin Gaussians do not get a negative determinant from
float32 cancellation.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

DILATION = 0.3
MIP_FILTER = 0.1
MAX_RADIUS = 1 << 24  # radii are clamped here so they fit int32; the pixel box is clipped anyway


def quat_to_rotmat(quats: torch.Tensor) -> torch.Tensor:
    """(N, 4) wxyz quaternions of any norm -> (N, 3, 3). A zero quaternion gives the identity
    (its normalised value is 0, and R is 1 - 2(...) on the diagonal), with zero gradient."""
    q = quats / quats.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    w, x, y, z = q.unbind(-1)
    return torch.stack([
        1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
        2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
        2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
    ], dim=-1).reshape(-1, 3, 3)


@dataclass
class Projected:
    means2d: torch.Tensor  # (N, 2) pixels
    conics: torch.Tensor  # (N, 3) inverse 2D covariance (a, b, c): power = -0.5 (a dx^2 + c dy^2) - b dx dy
    opacities: torch.Tensor  # (N,) after sigmoid (and mip compensation)
    depths: torch.Tensor  # (N,) camera-space z
    radii: torch.Tensor  # (N,) int32, 0 = culled
    bbox: torch.Tensor  # (N, 4) int32 pixel box x0, x1, y0, y1 (inclusive), valid where radii > 0


def camera_tensors(camera, dtype, device):
    R = torch.as_tensor(camera.R, dtype=dtype, device=device)
    t = torch.as_tensor(camera.t, dtype=dtype, device=device)
    return R, t


def project(means, quats, log_scales, opacity_logits, camera, mip_filter=False, near=0.01, far=1e10) -> Projected:
    dtype, device = means.dtype, means.device
    R, t = camera_tensors(camera, dtype, device)
    W, H = int(camera.width), int(camera.height)
    fx, fy, cx, cy = float(camera.fx), float(camera.fy), float(camera.cx), float(camera.cy)

    p = means @ R.T + t
    x, y, z = p.unbind(-1)
    in_depth = (z > near) & (z < far)
    # Culled Gaussians get harmless stand-in values so that no inf/NaN enters the backward pass.
    zs = torch.where(in_depth, z, torch.ones_like(z))
    xs = torch.where(in_depth, x, torch.zeros_like(x))
    ys = torch.where(in_depth, y, torch.zeros_like(y))
    u = fx * xs / zs + cx
    v = fy * ys / zs + cy

    tan_x, tan_y = 0.5 * W / fx, 0.5 * H / fy
    lim_xp, lim_xn = (W - cx) / fx + 0.3 * tan_x, cx / fx + 0.3 * tan_x
    lim_yp, lim_yn = (H - cy) / fy + 0.3 * tan_y, cy / fy + 0.3 * tan_y
    tx = zs * torch.clamp(xs / zs, -lim_xn, lim_xp)
    ty = zs * torch.clamp(ys / zs, -lim_yn, lim_yp)

    # M = J R Rq S (2 x 3): rows of J are (fx/z, 0, -fx tx/z^2) and (0, fy/z, -fy ty/z^2).
    RS = (R @ quat_to_rotmat(quats)) * torch.exp(log_scales)[:, None, :]
    inv_z = 1.0 / zs
    m0 = (fx * inv_z)[:, None] * RS[:, 0, :] - (fx * tx * inv_z * inv_z)[:, None] * RS[:, 2, :]
    m1 = (fy * inv_z)[:, None] * RS[:, 1, :] - (fy * ty * inv_z * inv_z)[:, None] * RS[:, 2, :]
    a = (m0 * m0).sum(-1)
    b = (m0 * m1).sum(-1)
    c = (m1 * m1).sum(-1)
    minors = torch.stack([m0[:, 0] * m1[:, 1] - m0[:, 1] * m1[:, 0],
                          m0[:, 0] * m1[:, 2] - m0[:, 2] * m1[:, 0],
                          m0[:, 1] * m1[:, 2] - m0[:, 2] * m1[:, 1]], dim=-1)
    det_raw = (minors * minors).sum(-1)
    eps = MIP_FILTER if mip_filter else DILATION
    a2, c2 = a + eps, c + eps
    det = det_raw + eps * (a + c) + eps * eps
    conics = torch.stack([c2 / det, -b / det, a2 / det], dim=-1)

    opac = torch.sigmoid(opacity_logits.reshape(-1))
    if mip_filter:
        opac = opac * torch.sqrt(torch.clamp_min(det_raw / det, 1e-12))

    with torch.no_grad():
        a64, c64, det64 = a2.double(), c2.double(), det.double()
        mid = 0.5 * (a64 + c64)
        lam = mid + torch.sqrt(torch.clamp_min(mid * mid - det64, 0.1))
        r = torch.ceil(3.0 * torch.sqrt(lam)).clamp(max=MAX_RADIUS)
        u64, v64 = u.double(), v.double()
        x0 = torch.ceil(u64 - r - 0.5).clamp(0, W)
        x1 = torch.floor(u64 + r - 0.5).clamp(-1, W - 1)
        y0 = torch.ceil(v64 - r - 0.5).clamp(0, H)
        y1 = torch.floor(v64 + r - 0.5).clamp(-1, H - 1)
        visible = in_depth & (x0 <= x1) & (y0 <= y1) & torch.isfinite(r) & (r > 0)
        visible &= torch.isfinite(u64) & torch.isfinite(v64) & torch.isfinite(conics).all(-1)
        radii = torch.where(visible, r, torch.zeros_like(r)).to(torch.int32)
        bbox = torch.stack([x0, x1, y0, y1], dim=-1).nan_to_num(0.0).to(torch.int32)
    return Projected(torch.stack([u, v], dim=-1), conics, opac, z, radii, bbox)
