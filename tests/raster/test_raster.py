"""Rasterizer: CPU backend vs the float64 brute-force reference, reference vs finite differences,
absgrad vs a per-pixel brute force, the mip filter, and the extremes documented in docs/raster.md."""

from __future__ import annotations

import math
import os

import numpy as np
import pytest
import torch

from strings_bench.scene.camera import Camera
from strings_bench.raster import RasterInputError, _rasterize_cpu, rasterize
from strings_bench.raster.reference import rasterize_reference
from strings_bench.raster.sh import sh_basis

TOL = 1e-5
# The accuracy tests below hold the float64 blend kernels to the brute-force reference; the float32
# kernels (backend "cpu", the default) are held to these in tests/raster/test_raster_f32.py.
CPU_REF = "cpu-f64"
NAMES = ("means", "quats", "log_scales", "opacity_logits", "sh", "background")


def rel(a, b):
    a, b = a.detach().double(), b.detach().double()
    return ((a - b).norm() / b.norm().clamp_min(1e-30)).item()


def make_camera(W=40, H=32, R=None, t=None):
    return Camera(fx=38.0, fy=41.0, cx=W / 2 + 0.7, cy=H / 2 - 0.4, width=W, height=H,
                  R=np.eye(3) if R is None else R, t=np.zeros(3) if t is None else t)


def random_scene(n=50, deg=3, seed=0, opacity_mean=0.0, opacity_std=1.0, scale=(0.02, 0.17)):
    g = torch.Generator().manual_seed(seed)
    means = torch.randn(n, 3, generator=g) * torch.tensor([0.6, 0.5, 0.5]) + torch.tensor([0.0, 0.0, 3.0])
    quats = torch.randn(n, 4, generator=g)
    log_scales = torch.log(torch.rand(n, 3, generator=g) * (scale[1] - scale[0]) + scale[0])
    logits = torch.randn(n, generator=g) * opacity_std + opacity_mean
    sh = torch.randn(n, (deg + 1) ** 2, 3, generator=g) * 0.3
    bg = torch.rand(3, generator=g)
    return [means, quats, log_scales, logits, sh, bg]


def output_weights(H, W, seed=1):
    g = torch.Generator().manual_seed(seed)
    return (torch.randn(H, W, 3, generator=g), torch.randn(H, W, generator=g), 0.1 * torch.randn(H, W, generator=g))


def weighted_loss(color, alpha, depth, w):
    wc, wa, wd = (x.to(color.dtype) for x in w)
    return (color * wc).sum() + (alpha * wa).sum() + (depth * wd).sum()


def run_cpu(params, cam, sh_degree=None, mip=False, preprocess="numba", absgrad=False):
    leaves = [p.clone().float().requires_grad_() for p in params]
    deg = {1: 0, 4: 1, 9: 2, 16: 3}[leaves[4].shape[1]] if sh_degree is None else sh_degree
    if preprocess == "numba":
        out = rasterize(*leaves[:5], cam, leaves[5], sh_degree=sh_degree, backend=CPU_REF, mip_filter=mip,
                        compute_absgrad=absgrad)
    else:
        out = _rasterize_cpu(*leaves[:4], leaves[4], deg, cam, leaves[5], mip_filter=mip, compute_absgrad=absgrad,
                             near=0.01, far=1e10, preprocess="torch", backend=CPU_REF)
    out.means2d.retain_grad()
    weighted_loss(out.color, out.alpha, out.depth, output_weights(cam.height, cam.width)).backward()
    return out, leaves


def run_reference(params, cam, sh_degree=None, mip=False):
    leaves = [p.clone().double().requires_grad_() for p in params]
    ref = rasterize_reference(*leaves[:5], cam, leaves[5], sh_degree=sh_degree, mip_filter=mip)
    ref["means2d"].retain_grad()
    weighted_loss(ref["color"], ref["alpha"], ref["depth"], output_weights(cam.height, cam.width)).backward()
    return ref, leaves


def compare(params, cam, **kw):
    preprocess = kw.pop("preprocess", "numba")
    out, leaves = run_cpu(params, cam, preprocess=preprocess, **kw)
    ref, rleaves = run_reference(params, cam, **kw)
    assert torch.equal(out.radii, ref["radii"])
    errs = {k: rel(getattr(out, k), ref[k]) for k in ("color", "alpha", "depth")}
    vis = out.visible  # means2d of culled Gaussians is a placeholder (documented), their grads are 0
    errs["means2d"] = rel(out.means2d[vis], ref["means2d"][vis])
    errs["grad_means2d"] = rel(out.means2d.grad, ref["means2d"].grad)
    for name, a, b in zip(NAMES, leaves, rleaves):
        assert torch.isfinite(a.grad).all(), name
        errs["grad_" + name] = rel(a.grad, b.grad)
    return errs, out, ref


SCENES = {
    "sh3": dict(seed=0),
    "sh1": dict(seed=1, deg=1),
    "opaque": dict(seed=2, n=80, opacity_mean=3.0, opacity_std=2.0),  # early stop and the 0.99 clamp
    "small": dict(seed=3, scale=(0.003, 0.02)),  # mostly the 0.3 px dilation
}


@pytest.mark.parametrize("preprocess", ["numba", "torch"])
@pytest.mark.parametrize("scene", list(SCENES))
def test_cpu_matches_float64_reference(scene, preprocess):
    params = random_scene(**SCENES[scene])
    errs, out, ref = compare(params, make_camera(), preprocess=preprocess)
    assert out.n_visible > 10
    bad = {k: v for k, v in errs.items() if not v <= TOL}
    assert not bad, f"relative errors above {TOL}: {bad}"


def test_sh_degree_restriction_matches_reference():
    params = random_scene(seed=4, deg=3)
    errs, _, _ = compare(params, make_camera(), sh_degree=1)
    assert max(errs.values()) <= TOL, errs
    out, leaves = run_cpu(params, make_camera(), sh_degree=1)
    assert (leaves[4].grad[:, 4:] == 0).all()  # inactive bands get no gradient
    assert (leaves[4].grad[:, :4] != 0).any()


def test_rotated_camera_and_off_screen_gaussians():
    ang = 0.3
    R = np.array([[math.cos(ang), 0, math.sin(ang)], [0, 1, 0], [-math.sin(ang), 0, math.cos(ang)]])
    cam = make_camera(R=R, t=np.array([0.2, -0.1, 0.5]))
    params = random_scene(seed=5, n=60)
    params[0] = params[0] * torch.tensor([2.5, 2.0, 1.0])  # many outside the frustum: Jacobian clamp
    errs, out, _ = compare(params, cam)
    assert max(errs.values()) <= TOL, errs
    assert 0 < out.n_visible < 60


def test_mip_filter_matches_reference_and_changes_the_image():
    params = random_scene(seed=6, scale=(0.004, 0.05))
    errs, out, ref = compare(params, make_camera(), mip=True)
    assert max(errs.values()) <= TOL, errs
    plain, _ = run_cpu(params, make_camera())
    assert rel(out.color, plain.color) > 1e-3  # the filter does something
    # small Gaussians lose opacity to the compensation: the mip image is less opaque overall
    assert out.alpha.sum() < plain.alpha.sum()


def test_mip_filter_torch_preprocess_matches():
    params = random_scene(seed=7, scale=(0.004, 0.05))
    errs, _, _ = compare(params, make_camera(), mip=True, preprocess="torch")
    assert max(errs.values()) <= TOL, errs


def test_reference_agrees_with_finite_differences():
    cam = make_camera(W=9, H=7)
    cam = Camera(fx=6.0, fy=6.5, cx=4.6, cy=3.4, width=9, height=7, R=np.eye(3), t=np.zeros(3))
    params = random_scene(n=4, deg=1, seed=8, scale=(0.15, 0.4))
    params[0] = torch.tensor([[0.1, 0.0, 2.5], [-0.4, 0.3, 3.0], [0.5, -0.2, 3.5], [0.0, 0.2, 2.0]])
    params = [p.double().requires_grad_() for p in params]
    w = [x.double() for x in output_weights(7, 9, seed=3)]

    def f(*xs):
        r = rasterize_reference(*xs[:5], cam, xs[5])
        return weighted_loss(r["color"], r["alpha"], r["depth"], w)

    assert torch.autograd.gradcheck(f, params, eps=1e-6, atol=1e-6, rtol=1e-4)


def test_absgrad_matches_per_pixel_brute_force():
    cam = make_camera(W=20, H=16)
    params = random_scene(n=25, seed=9)
    out, _ = run_cpu(params, cam, absgrad=True)
    leaves = [p.clone().double().requires_grad_() for p in params]
    ref = rasterize_reference(*leaves[:5], cam, leaves[5])
    wc, wa, wd = (x.double() for x in output_weights(cam.height, cam.width))
    per_pixel = (ref["color"] * wc).sum(-1) + ref["alpha"] * wa + ref["depth"] * wd  # (H, W)
    total = torch.zeros(params[0].shape[0], 2, dtype=torch.float64)
    signed = torch.zeros_like(total)
    for lp in per_pixel.reshape(-1):
        (g,) = torch.autograd.grad(lp, ref["means2d"], retain_graph=True)
        total += g.abs()
        signed += g
    assert rel(out.absgrad, total) <= TOL
    assert rel(out.means2d.grad, signed) <= TOL
    # the point of AbsGS: absolute sums exceed the norm of the signed sum
    vis = out.radii > 0
    assert (out.absgrad[vis].norm(dim=-1) >= out.means2d.grad[vis].norm(dim=-1) - 1e-6).all()
    assert (out.absgrad[vis].norm(dim=-1) > 1.5 * out.means2d.grad[vis].norm(dim=-1)).any()


def test_sh_basis_is_orthonormal():
    nt, npz = 400, 800
    theta = (torch.arange(nt, dtype=torch.float64) + 0.5) * math.pi / nt
    phi = (torch.arange(npz, dtype=torch.float64) + 0.5) * 2 * math.pi / npz
    th, ph = torch.meshgrid(theta, phi, indexing="ij")
    dirs = torch.stack([th.sin() * ph.cos(), th.sin() * ph.sin(), th.cos()], -1).reshape(-1, 3)
    wts = (th.sin() * (math.pi / nt) * (2 * math.pi / npz)).reshape(-1)
    Y = sh_basis(dirs, 3)
    gram = (Y * wts[:, None]).T @ Y
    assert torch.allclose(gram, torch.eye(16, dtype=torch.float64), atol=1e-4)


# ---- the alpha clamp: 3DGS' backward (dL/dalpha passes to opacity and shape as if alpha = o G) -------

OPAQUE_LOGIT = math.log(0.999 / 0.001)  # o = 0.999


N_OPAQUE = 7


def clamp_scene(seed=20):
    """N_OPAQUE opaque Gaussians (o = 0.999 and o ~ 1, sigma 4-8 px) on a grid of screen positions,
    at depths in front of and behind 30 random ones of mixed opacity; the first two share a screen
    position (two clamped splats on one pixel: T = 1e-4, then the early stop). Where G > 0.991 (within
    ~0.14 sigma of the centre) o G > 0.99: clamped."""
    cam = make_camera()
    g = torch.Generator().manual_seed(seed)
    uv = torch.tensor([[0.0, 0.0], [0.0, 0.0], [20.0, 9.0], [31.0, 11.0], [8.0, 23.0], [21.0, 22.0], [32.0, 21.0]])
    z = torch.tensor([2.0, 2.1, 4.0, 2.6, 3.8, 2.4, 4.2])
    uv[2:] += torch.rand(N_OPAQUE - 2, 2, generator=g) - 0.5
    uv[:2] = torch.tensor([9.5, 10.5])  # a pixel centre: G = 1 there for both
    means = torch.stack([(uv[:, 0] - cam.cx) * z / cam.fx, (uv[:, 1] - cam.cy) * z / cam.fy, z], dim=1)
    log_scales = torch.log(torch.rand(N_OPAQUE, 3, generator=g) * 0.3 + 0.5)
    quats = torch.randn(N_OPAQUE, 4, generator=g)
    logits = torch.tensor([OPAQUE_LOGIT, 12.0] * 4)[:N_OPAQUE]
    sh = torch.randn(N_OPAQUE, 16, 3, generator=g) * 0.3
    rest = random_scene(n=30, seed=seed + 1, opacity_mean=0.0, opacity_std=1.5)
    return [torch.cat([a, b]) for a, b in zip([means, quats, log_scales, logits, sh], rest[:5])] + [rest[5]]


def test_clamped_splats_match_the_reference_with_the_3dgs_rule():
    params = clamp_scene()
    cam = make_camera()
    errs, out, ref = compare(params, cam)  # reference default: clamp_grad="pass"
    bad = {k: v for k, v in errs.items() if not v <= TOL}
    assert not bad, f"relative errors above {TOL}: {bad}"
    assert out.alpha.max() > 0.9998  # pixels where two clamped splats overlap: 1 - 0.01^2, then the early stop
    # The scene does exercise the clamp: under the torch.clamp rule (zero gradient where clamped,
    # what this backend did before) the opaque Gaussians' gradients differ from the 3DGS rule's by far
    # more than TOL, so the comparison above would fail with the old backward.
    zref, zleaves = run_reference_rule(params, cam, "zero")
    pref, pleaves = run_reference_rule(params, cam, "pass")
    k = N_OPAQUE
    for j in range(4):  # means, quats, log_scales, opacity logits
        assert rel(zleaves[j].grad[:k], pleaves[j].grad[:k]) > 50 * TOL, NAMES[j]
    assert rel(zref["means2d"].grad[:k], pref["means2d"].grad[:k]) > 50 * TOL
    for i in range(k):  # every opaque Gaussian, the second of the stacked pair included
        assert rel(zleaves[3].grad[i], pleaves[3].grad[i]) > 100 * TOL, i
    # colours and the background see only forward values: identical under both rules
    assert rel(zleaves[4].grad, pleaves[4].grad) < 1e-12 and rel(zleaves[5].grad, pleaves[5].grad) < 1e-12


def run_reference_rule(params, cam, rule):
    leaves = [p.clone().double().requires_grad_() for p in params]
    ref = rasterize_reference(*leaves[:5], cam, leaves[5], clamp_grad=rule)
    ref["means2d"].retain_grad()
    weighted_loss(ref["color"], ref["alpha"], ref["depth"], output_weights(cam.height, cam.width)).backward()
    return ref, leaves


def test_clamped_splats_match_the_reference_torch_preprocess_and_mip():
    params = clamp_scene(seed=23)
    for kw in (dict(preprocess="torch"), dict(mip=True)):
        errs, _, _ = compare(params, make_camera(), **kw)
        assert max(errs.values()) <= TOL, (kw, errs)


def test_reference_rejects_unknown_clamp_rule():
    params = random_scene(n=3)
    with pytest.raises(RasterInputError, match="clamp_grad"):
        rasterize_reference(*params[:5], make_camera(), params[5], clamp_grad="straight")


def _one_pixel_hand(gaussians, bg, wts, f=2.0):
    """Hand derivation for a 1x1 image, camera at the origin looking down +z, fx = fy = f,
    principal point at the pixel centre (0.5, 0.5); Gaussians at (x, 0, z), isotropic scale s,
    identity rotation, SH degree 0, listed front to back.

    Projection: u = f x / z + 0.5, so the offset to the pixel centre is d = f x / z (v: 0).
    EWA: J = [[f/z, 0, -f x / z^2], [0, f/z, 0]], Sigma3 = s^2 I, so
        Sigma2 = s^2 (f/z)^2 [[1 + (x/z)^2, 0], [0, 1]] + 0.3 I   (diagonal),
        G = exp(-d^2 / (2 Sigma_xx)),  alpha_i = min(0.99, o_i G_i).
    Colour c_i = 0.28209479 sh_i + 0.5. With L = sum_ch w_ch colour_ch and
        colour = sum_i alpha_i T_i c_i + T_N bg,  T_i = prod_{j<i} (1 - alpha_j),
    3DGS' backward: dL/dalpha_i = T_i w.(c_i - S_i) - T_N / (1 - alpha_i) w.bg, S_i the colour
    blended behind i normalised by T_{i+1} (sum_{j>i} alpha_j T_j c_j / T_{i+1}); every factor uses
    the clamped alpha. Then, as if alpha = o G:
        dL/dlogit_i = dL/dalpha_i G_i o_i (1 - o_i)            (do/dlogit = o (1 - o))
        dL/du_i     = dL/dalpha_i o_i dG/du = dL/dalpha_i o_i G_i (-d_i / Sigma_xx,i)
        dL/dsh_i    = 0.28209479 alpha_i T_i w                   (forward value, clamped)
    Returns per Gaussian (dL/dlogit, dL/du, dL/dsh (3,), o G) and dL/dbg."""
    out = []
    T = 1.0
    rows = []
    for x, z, s, logit, sh in gaussians:
        o = 1.0 / (1.0 + math.exp(-logit))
        d = f * x / z
        sxx = s * s * (f / z) ** 2 * (1 + (x / z) ** 2) + 0.3
        G = math.exp(-d * d / (2 * sxx))
        a = min(0.99, o * G)
        c = [0.28209479177387814 * v + 0.5 for v in sh]
        rows.append((o, d, sxx, G, a, c, T))
        T *= 1 - a
    T_N = T
    wbg = sum(w * b for w, b in zip(wts, bg))
    for i, (o, d, sxx, G, a, c, Ti) in enumerate(rows):
        behind = [0.0, 0.0, 0.0]  # sum_{j>i} alpha_j T_j c_j
        for (_, _, _, _, aj, cj, Tj) in rows[i + 1:]:
            behind = [b + aj * Tj * cv for b, cv in zip(behind, cj)]
        T_next = Ti * (1 - a)
        S = [b / T_next for b in behind]
        dL_da = Ti * sum(w * (cv - sv) for w, cv, sv in zip(wts, c, S)) - T_N / (1 - a) * wbg
        out.append((dL_da * G * o * (1 - o), dL_da * o * G * (-d / sxx),
                    [0.28209479177387814 * a * Ti * w for w in wts], o * G))
    return out, [T_N * w for w in wts]


@pytest.mark.parametrize("case", ["single", "clamped_in_front", "clamped_behind"])
def test_clamped_opacity_gradient_matches_hand_derivation(case):
    # (x, z, s, logit, sh0 rgb), front to back
    clamped = (0.05, 2.0, 1.0, 8.0, (0.9, -0.3, 0.4))  # o = 0.99966, G = 0.99904: o G = 0.9987 > 0.99
    other = (-0.04, 3.0, 1.2, 0.4, (-0.5, 0.7, 0.2))  # o = 0.599: unclamped
    gs = {"single": [clamped], "clamped_in_front": [clamped, other], "clamped_behind": [other, clamped]}[case]
    if case == "clamped_behind":
        gs[1] = (0.05, 3.5, 1.0, 8.0, (0.9, -0.3, 0.4))
    bg, wts = (0.2, 0.6, 0.1), (1.0, -0.7, 0.5)
    hand, hand_bg = _one_pixel_hand(gs, bg, wts)
    assert any(h[3] > 0.99 for h in hand)  # the case has a clamped splat
    cam = Camera(fx=2.0, fy=2.0, cx=0.5, cy=0.5, width=1, height=1, R=np.eye(3), t=np.zeros(3))
    n = len(gs)
    params = [torch.tensor([[x, 0.0, z] for x, z, _, _, _ in gs]), torch.tensor([[1.0, 0, 0, 0]] * n),
              torch.log(torch.tensor([[s] * 3 for _, _, s, _, _ in gs])), torch.tensor([g[3] for g in gs]),
              torch.tensor([[g[4]] for g in gs]), torch.tensor(bg)]
    w = torch.tensor(wts, dtype=torch.float64)
    leaves = [p.clone().float().requires_grad_() for p in params]
    out = rasterize(*leaves[:5], cam, leaves[5], backend="cpu")
    out.means2d.retain_grad()
    (out.color[0, 0].double() * w).sum().backward()
    rleaves = [p.clone().double().requires_grad_() for p in params]
    ref = rasterize_reference(*rleaves[:5], cam, rleaves[5])
    ref["means2d"].retain_grad()
    (ref["color"][0, 0] * w).sum().backward()
    exp_logit = torch.tensor([h[0] for h in hand], dtype=torch.float64)
    exp_u = torch.tensor([h[1] for h in hand], dtype=torch.float64)
    exp_sh = torch.tensor([h[2] for h in hand], dtype=torch.float64)
    for name, got_logit, got_m2d, got_sh, got_bg in (
            ("cpu", leaves[3].grad, out.means2d.grad, leaves[4].grad, leaves[5].grad),
            ("reference", rleaves[3].grad, ref["means2d"].grad, rleaves[4].grad, rleaves[5].grad)):
        assert rel(got_logit, exp_logit) <= TOL, (name, got_logit, exp_logit)
        assert rel(got_m2d[:, 0], exp_u) <= TOL, (name, got_m2d, exp_u)
        assert got_m2d[:, 1].abs().max() <= 1e-6 * exp_u.abs().max()  # v offset 0 and a diagonal conic
        assert rel(got_sh[:, 0], exp_sh) <= TOL, name
        assert rel(got_bg, torch.tensor(hand_bg, dtype=torch.float64)) <= TOL, name
    # the clamped splat's own opacity gradient is far from 0 (the old backward gave exactly 0)
    for i, h in enumerate(hand):
        if h[3] > 0.99:
            assert abs(leaves[3].grad[i].item()) > 0.5 * abs(h[0]) > 0
            assert abs(out.means2d.grad[i, 0].item()) > 0.5 * abs(h[1]) > 0


# ---- extremes ------------------------------------------------------------------------------

def _finite_render(params, cam, **kw):
    leaves = [p.clone().float().requires_grad_() for p in params]
    out = rasterize(*leaves[:5], cam, leaves[5], backend="cpu", compute_absgrad=True, **kw)
    out.means2d.retain_grad()
    weighted_loss(out.color, out.alpha, out.depth, output_weights(cam.height, cam.width)).backward()
    for k in ("color", "alpha", "depth"):
        assert torch.isfinite(getattr(out, k)).all(), k
    for name, leaf in zip(NAMES, leaves):
        assert leaf.grad is not None and torch.isfinite(leaf.grad).all(), name
    assert torch.isfinite(out.means2d.grad).all() and torch.isfinite(out.absgrad).all()
    return out, leaves


def test_extreme_tiny_scales_render_as_the_dilation_footprint():
    params = random_scene(n=10, seed=10)
    params[2] = torch.full((10, 3), math.log(1e-6))
    out, leaves = _finite_render(params, make_camera())
    vis = out.radii > 0
    assert vis.sum() >= 5
    # cov2d ~ 0.3 I: lambda_max = 0.3 + sqrt(0.1) -> radius ceil(3 sqrt(0.616)) = 3
    assert (out.radii[vis] == 3).all()
    errs, _, _ = compare(params, make_camera())
    # equal tiny scales: the rotation does not matter, the quaternion gradient is rounding noise (~1e-25)
    assert leaves[1].grad.abs().max() < 1e-20
    del errs["grad_quats"]
    assert max(errs.values()) <= TOL, errs


def test_extreme_huge_scales_cover_the_image():
    params = random_scene(n=6, seed=11)
    params[2] = torch.log(torch.tensor([[2e3, 1e3, 4e3]])).expand(6, 3)  # ~1000 x the ~2-unit scene
    out, _ = _finite_render(params, make_camera())
    vis = out.radii > 0
    assert vis.all()
    assert (out.alpha > 0.0).all()  # every pixel is covered
    errs, _, _ = compare(params, make_camera())
    assert max(errs.values()) <= 1e-4, errs


@pytest.mark.parametrize("logit", [30.0, -30.0])
def test_extreme_opacity_logits(logit):
    params = random_scene(n=30, seed=12)
    params[3] = torch.full((30,), logit)
    out, leaves = _finite_render(params, make_camera())
    if logit > 0:
        assert out.alpha.max() > 0.99  # saturated pixels, alpha of each splat clamped at 0.99
        errs, _, _ = compare(params, make_camera())
        assert max(errs.values()) <= TOL, errs
    else:
        # o = 9e-14 < 1/255: every splat is skipped, the image is the background
        assert (out.alpha == 0).all()
        assert torch.allclose(out.color, params[5].expand_as(out.color))
        assert (leaves[0].grad == 0).all()


def test_extreme_behind_camera_and_on_near_plane_are_culled():
    params = random_scene(n=4, seed=13)
    params[0] = torch.tensor([[0.0, 0.0, -2.0], [0.1, 0.0, 0.0], [0.0, 0.1, 0.01], [0.0, 0.0, 3.0]])
    out, leaves = _finite_render(params, make_camera(), near=0.01)
    assert out.radii[:3].tolist() == [0, 0, 0] and out.radii[3] > 0
    assert (leaves[0].grad[:3] == 0).all() and (leaves[0].grad[3] != 0).any()
    errs, _, _ = compare(params, make_camera())
    assert max(errs.values()) <= TOL, errs


def test_extreme_zero_norm_quaternions_are_identity():
    params = random_scene(n=20, seed=14)
    params[1][:10] = 0.0
    out, leaves = _finite_render(params, make_camera())
    assert (leaves[1].grad[:10] == 0).all()
    ident = [p.clone() for p in params]
    ident[1][:10] = torch.tensor([1.0, 0.0, 0.0, 0.0])
    out2, _ = _finite_render(ident, make_camera())
    assert torch.allclose(out.color, out2.color, atol=1e-6)


def test_extreme_one_gaussian_covering_the_image():
    params = random_scene(n=1, seed=15)
    params[0] = torch.tensor([[0.0, 0.0, 2.0]])
    params[2] = torch.log(torch.tensor([[3.0, 2.0, 4.0]]))
    params[3] = torch.tensor([4.0])
    out, _ = _finite_render(params, make_camera())
    assert out.n_visible == 1 and (out.alpha > 0.5).all()  # every pixel covered
    errs, _, _ = compare(params, make_camera())
    assert max(errs.values()) <= TOL, errs


def test_extreme_empty_scene_is_background():
    params = [torch.zeros(0, 3), torch.zeros(0, 4), torch.zeros(0, 3), torch.zeros(0), torch.zeros(0, 16, 3),
              torch.tensor([0.2, 0.4, 0.6])]
    out, leaves = _finite_render(params, make_camera())
    assert torch.allclose(out.color, params[5].expand(32, 40, 3))
    assert (out.alpha == 0).all() and (out.depth == 0).all()
    assert out.radii.shape == (0,) and out.means2d.shape == (0, 2)
    assert torch.allclose(leaves[5].grad, output_weights(32, 40)[0].sum((0, 1)))


# ---- interface ------------------------------------------------------------------------------

def test_bad_inputs_raise_clear_errors():
    params = random_scene(n=5)
    cam = make_camera()
    with pytest.raises(RasterInputError, match="shapes"):
        rasterize(params[0], params[1][:, :3], *params[2:5], cam, params[5])
    with pytest.raises(RasterInputError, match="sh_degree"):
        rasterize(*params[:4], params[4][:, :4], cam, params[5], sh_degree=2)
    with pytest.raises(RasterInputError, match="coefficients"):
        rasterize(*params[:4], params[4][:, :5], cam, params[5])
    with pytest.raises(RasterInputError, match="backend"):
        rasterize(*params[:5], cam, params[5], backend="opengl")
    with pytest.raises(RasterInputError, match="background"):
        rasterize(*params[:5], cam, torch.zeros(4))


def test_opacity_logits_column_shape_and_outputs():
    params = random_scene(n=12, seed=16)
    cam = make_camera()
    a = rasterize(*params[:3], params[3][:, None], params[4], cam, params[5])
    b = rasterize(*params[:5], cam, params[5])
    assert torch.equal(a.color, b.color)
    assert a.color.shape == (32, 40, 3) and a.alpha.shape == (32, 40) and a.depth.shape == (32, 40)
    assert a.radii.dtype == torch.int32 and a.means2d.shape == (12, 2) and a.absgrad is None
    assert a.backend == "cpu" and a.visible.dtype == torch.bool


_CACHE_PROBE = """
import numba  # imported first: the package must still redirect numba's cache (config read at import)
import numpy as np
import strings_bench.raster.cpu_kernels as cpu_kernels
buf = np.arange(36.0, dtype=np.float32).reshape(3, 12)
outs = [np.full(shape, 9.0, np.float32) for shape in ((3, 2), (3, 3), (3,), (3, 4), (3, 2))]
# two Gaussians, drawn in the order [1, 0]; the first has intersections 0 and 2 (buf rows 0 and 2)
cpu_kernels.reduce_intersections(buf, np.array([0, 2, 3]), np.array([0, 2, 1]), np.array([1, 0]), *outs)
print(outs[0].tolist())
"""


def test_compiled_kernels_are_cached_under_the_suite_cache(tmp_path):
    """In a fresh interpreter without NUMBA_CACHE_DIR, kernels compile into STRINGS_BENCH_CACHE/numba
    (conftest sets NUMBA_CACHE_DIR for this session, so only a subprocess sees the package's default)."""
    import subprocess
    import sys

    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
    env["STRINGS_BENCH_CACHE"] = str(tmp_path / "suite")
    done = subprocess.run([sys.executable, "-c", _CACHE_PROBE], env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    # input row 1: buf rows 0 + 2; input row 0: buf row 1; input row 2 (not drawn): zero
    assert done.stdout.strip().splitlines()[-1] == "[[12.0, 13.0], [24.0, 26.0], [0.0, 0.0]]"
    names = {p.suffix for p in (tmp_path / "suite" / "numba").rglob("*reduce_intersections*")}
    assert {".nbi", ".nbc"} <= names, sorted(p.name for p in tmp_path.rglob("*"))


@pytest.mark.gpu
def test_gsplat_backend_agrees_with_cpu():
    if not torch.cuda.is_available():
        pytest.skip("no CUDA")
    pytest.importorskip("gsplat")
    params = random_scene(n=50, seed=17, scale=(0.01, 0.05))
    cam = make_camera(W=64, H=48)
    cpu = rasterize(*params[:5], cam, params[5], backend="cpu")
    # leaves that require grad: gsplat's means2d (and so ours) only requires grad when its inputs do
    leaves = [p.detach().cuda().requires_grad_() for p in params[:5]]
    gpu = rasterize(*leaves, cam, params[5].cuda(), backend="gsplat", compute_absgrad=True)
    # tile-level vs box-level support and alpha clamp differ slightly between the two
    assert rel(gpu.color.detach().cpu(), cpu.color.detach()) < 1e-2
    assert gpu.means2d.requires_grad
    gpu.means2d.retain_grad()  # harmless on our leaf (its .grad is filled by the backend's hook)
    gpu.color.sum().backward()
    assert gpu.means2d.grad is not None and gpu.means2d.grad.shape == (50, 2)
    assert gpu.absgrad is not None and gpu.absgrad.abs().sum() > 0


def test_gsplat_means2d_hook_frees_each_steps_graph():
    """200 steps through the gsplat backend's hook wiring (expose_means2d) with a stand-in for gsplat's
    (1, N, 2) output: a step's tensors must be freed when the step ends, by reference counting alone
    (the collector is off). The closure that held gsplat's tensor made a cycle that kept every
    step's graph alive (70 GiB at 3K steps of 1280x960 on an H100)."""
    import gc
    import weakref

    from strings_bench.raster.gsplat_backend import expose_means2d

    n = 64
    leaf = torch.randn(n, 2, dtype=torch.float64, requires_grad=True)
    previous: list[weakref.ref] = []
    was_enabled = gc.isenabled()
    gc.disable()
    try:
        for step in range(200):
            m2d_gs = (leaf * (1.0 + step))[None]  # non-leaf, part of a graph, as gsplat's meta["means2d"]
            m2d_gs.absgrad = torch.full((1, n, 2), float(step), dtype=torch.float64)  # gsplat sets it in backward
            means2d, absgrad = expose_means2d(m2d_gs, compute_absgrad=True)
            loss = (m2d_gs ** 2).sum()
            loss.backward()
            # the hook delivered the gradient and the absolute gradient (d/dm of m^2 = 2m)
            assert torch.allclose(means2d.grad, 2 * m2d_gs.detach()[0])
            assert torch.equal(absgrad, torch.full((n, 2), float(step), dtype=torch.float64))
            leaf.grad = None
            assert all(r() is None for r in previous), f"step {step - 1}'s tensors are still alive at step {step}"
            previous = [weakref.ref(m2d_gs), weakref.ref(means2d), weakref.ref(loss)]
            del m2d_gs, means2d, absgrad, loss
    finally:
        if was_enabled:
            gc.enable()
    assert all(r() is None for r in previous)


def _blend_with_boxes(P, BB, W, H, seed=5, kernels=None, list_order=False):
    """Forward and backward blend of P with pixel boxes BB; per-Gaussian gradients (input order = P's).
    kernels: the blend kernels' module (default cpu_kernels, float64; or cpu_kernels_f32). list_order: the rows
    copied into list order first (`rows_in_list_order`, as the rasterizer does), else read where they are."""
    import strings_bench.raster.cpu_kernels as K

    KB = K if kernels is None else kernels
    f32 = P.dtype == np.float32

    tiles_x, tiles_y = (W + K.TILE - 1) // K.TILE, (H + K.TILE - 1) // K.TILE
    tile_start, lst, g_start, isect_pos = K.bin_tiles(BB, tiles_x, tiles_y)
    if list_order:
        P, BB, lst = K.rows_in_list_order(lst, P, BB)
    out_f = np.empty((H, W, K.NF), np.float32)
    out_T = np.empty((H, W), np.float32 if f32 else np.float64)
    out_last = np.empty((H, W), np.int32 if f32 else np.int64)
    KB.forward(tile_start, lst, P, BB, W, H, tiles_x, out_f, out_T, out_last)
    rng = np.random.default_rng(seed)
    gF = rng.standard_normal((H, W, K.NF)).astype(np.float32)
    gA = rng.standard_normal((H, W)).astype(np.float32)
    buf = np.empty((lst.shape[0], K.N_GRAD), np.float32)
    KB.backward(tile_start, lst, P, BB, W, H, tiles_x, out_T, out_last, gF, gA, buf)
    V = g_start.shape[0] - 1
    grads = [np.empty(shape, np.float32) for shape in ((V, 2), (V, 3), (V,), (V, K.NF), (V, 2))]
    K.reduce_intersections(buf, g_start, isect_pos, np.arange(V), *grads)
    return out_f, out_T, grads, lst.shape[0], out_last


@pytest.mark.parametrize("precision", ["f64", "f32"])
def test_rows_copied_into_list_order_blend_to_the_same_bits(precision):
    """The rasterizer copies each intersection's rows of P and BB into list order before the blends (so that a
    tile's rows are read one after the other): the image, the transmittance, the last contributor and every
    gradient must be what the blends give reading the rows where they are, bit for bit."""
    import strings_bench.raster.cpu_kernels as K
    import strings_bench.raster.cpu_kernels_f32 as K32
    from strings_bench.raster.cpu import Preprocess

    KB = K32 if precision == "f32" else K
    W, H = 96, 80
    cam = make_camera(W=W, H=H)
    params = random_scene(n=400, seed=13, opacity_mean=0.0, opacity_std=1.5, scale=(0.005, 0.2))
    with torch.no_grad():
        means2d, conics, opac, feats, radii, bbox = Preprocess.apply(*params[:5], 3, cam, False, 0.01, 1e10)
    vis = torch.nonzero(radii > 0).flatten()
    order = vis[torch.argsort(feats[vis, 3], stable=True)].numpy()
    P, BB = KB.pack(order, means2d.numpy(), conics.numpy(), opac.numpy(), feats.numpy(), bbox.numpy())
    tiles_x, tiles_y = (W + K.TILE - 1) // K.TILE, (H + K.TILE - 1) // K.TILE
    lst = K.bin_tiles(BB, tiles_x, tiles_y)[1]
    PL, BL, ident = K.rows_in_list_order(lst, P, BB)
    assert np.array_equal(PL, P[lst], equal_nan=True) and np.array_equal(BL, BB[lst])
    assert np.array_equal(ident, np.arange(lst.shape[0]))
    assert len(np.unique(lst)) < lst.shape[0]  # Gaussians on several tiles: rows copied more than once
    where = _blend_with_boxes(P, BB, W, H, kernels=KB)
    listed = _blend_with_boxes(P, BB, W, H, kernels=KB, list_order=True)
    for a, b in zip(where[:2] + (where[4],), listed[:2] + (listed[4],)):
        assert np.array_equal(a, b)
    for a, b in zip(where[2], listed[2]):
        assert np.array_equal(a, b)
    assert np.abs(where[2][0]).sum() > 0 and (where[1] < 1).mean() > 0.2  # something was drawn and differentiated


def test_tight_boxes_skip_work_without_changing_a_bit():
    """The blend visits each Gaussian only inside the bounding box of the ellipse where it can reach
    alpha >= 1/255 (cpu_kernels.tight_box), not its whole 3-sigma box: faint, elongated Gaussians then
    touch far fewer tiles, and the image and every gradient must be the same bit for bit."""
    import strings_bench.raster.cpu_kernels as K
    from strings_bench.raster.cpu import Preprocess

    W, H = 96, 80
    cam = make_camera(W=W, H=H)
    params = random_scene(n=300, seed=11, opacity_mean=-3.0, opacity_std=2.0, scale=(0.005, 0.25))
    with torch.no_grad():
        means2d, conics, opac, feats, radii, bbox = Preprocess.apply(*params[:5], 3, cam, False, 0.01, 1e10)
    vis = torch.nonzero(radii > 0).flatten()
    order = vis[torch.argsort(feats[vis, 3], stable=True)].numpy()
    P, tight = K.pack(order, means2d.numpy(), conics.numpy(), opac.numpy(), feats.numpy(), bbox.numpy())
    full = bbox.numpy()[order].astype(np.int64)
    assert (opac.numpy()[order] < K.ALPHA_MIN).any()  # some are never blended: empty tight boxes
    f_t, T_t, g_t, m_t, _ = _blend_with_boxes(P, tight, W, H)
    f_f, T_f, g_f, m_f, _ = _blend_with_boxes(P, full, W, H)
    assert m_t < 0.75 * m_f, (m_t, m_f)  # the test scene exercises the skipping
    assert np.array_equal(f_t, f_f) and np.array_equal(T_t, T_f)
    for a, b in zip(g_t, g_f):
        assert np.array_equal(a, b)
    assert np.abs(g_f[0]).sum() > 0 and (T_f < 1).mean() > 0.2  # something was drawn and differentiated


def test_depth_order_is_torchs_stable_argsort_of_the_visible_depths():
    """The rasterizer's front-to-back order (a radix sort of the float32 depths' bits) against torch's stable
    comparison sort: equal depths, -0.0 against 0.0, negative depths, infinities and NaNs of either sign."""
    import numpy as np
    import torch

    from strings_bench.raster.cpu_kernels import depth_order

    rng = np.random.default_rng(3)
    for n in (0, 1, 2, 7, 1000, 50_000):
        d = rng.normal(2.0, 3.0, n).astype(np.float32)
        if n >= 7:
            d[::5] = d[1]  # ties
            d[::11] = 0.0
            d[::13] = -0.0
            d[2], d[3], d[4] = np.inf, -np.inf, np.nan
            d[5] = -np.float32(np.nan)
            d[6] = np.float32(1e-38)  # a subnormal's neighbour
        radii = (rng.random(n) > 0.2).astype(np.int32)
        radii[: min(n, 7)] = 1
        t = torch.from_numpy(d)
        vis = torch.nonzero(torch.from_numpy(radii) > 0).flatten()
        want = vis[torch.argsort(t[vis], stable=True)].numpy()
        assert np.array_equal(depth_order(radii, d), want), n
