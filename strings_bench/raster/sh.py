"""Real spherical harmonics (degrees 0..3) in the 3DGS / gsplat convention, evaluated in torch.

colour = clamp_min(sum_k sh[k] * Y_k(dir) + 0.5, 0), dir = unit vector from the camera centre to
the Gaussian's mean. The basis ordering and signs are those of the 3DGS release; the constants are
the orthonormal real-SH normalisations (tests check orthonormality on the sphere).
"""

from __future__ import annotations

import torch

SH_C0 = 0.28209479177387814  # Y_0^0 = 1 / (2 sqrt(pi)); the one definition (engine.gaussians imports it)
SH_C1 = 0.4886025119029199
SH_C2 = (1.0925484305920792, -1.0925484305920792, 0.31539156525252005, -1.0925484305920792,
         0.5462742152960396)
SH_C3 = (-0.5900435899266435, 2.890611442640554, -0.4570457994644658, 0.3731763325901154,
         -0.4570457994644658, 1.445305721320277, -0.5900435899266435)


def sh_basis(dirs: torch.Tensor, degree: int) -> torch.Tensor:
    """(N, 3) unit directions -> (N, (degree+1)^2) basis values."""
    x, y, z = dirs.unbind(-1)
    out = [torch.full_like(x, SH_C0)]
    if degree >= 1:
        out += [-SH_C1 * y, SH_C1 * z, -SH_C1 * x]
    if degree >= 2:
        xx, yy, zz, xy, yz, xz = x * x, y * y, z * z, x * y, y * z, x * z
        out += [SH_C2[0] * xy, SH_C2[1] * yz, SH_C2[2] * (2 * zz - xx - yy), SH_C2[3] * xz,
                SH_C2[4] * (xx - yy)]
    if degree >= 3:
        out += [SH_C3[0] * y * (3 * xx - yy), SH_C3[1] * xy * z, SH_C3[2] * y * (4 * zz - xx - yy),
                SH_C3[3] * z * (2 * zz - 3 * xx - 3 * yy), SH_C3[4] * x * (4 * zz - xx - yy),
                SH_C3[5] * z * (xx - yy), SH_C3[6] * x * (xx - 3 * yy)]
    return torch.stack(out, dim=-1)


def sh_to_color(sh: torch.Tensor, means: torch.Tensor, cam_center: torch.Tensor, degree: int) -> torch.Tensor:
    """(N, K, 3) coefficients -> (N, 3) colours seen from cam_center, using bands 0..degree."""
    k = (degree + 1) ** 2
    d = means - cam_center
    # A Gaussian exactly at the camera centre is culled anyway; the clamp only keeps it finite.
    dirs = d / d.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    if degree == 0:
        rgb = SH_C0 * sh[:, 0, :]
    else:
        rgb = (sh_basis(dirs, degree)[:, :, None] * sh[:, :k, :]).sum(dim=1)
    return torch.clamp_min(rgb + 0.5, 0.0)
