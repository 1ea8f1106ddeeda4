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
        out = rasterize(*leaves[:5], cam, leaves[5], sh_degree=sh_degree, backend="cpu", mip_filter=mip,
                        compute_absgrad=absgrad)
    else:
        out = _rasterize_cpu(*leaves[:4], leaves[4], deg, cam, leaves[5], mip_filter=mip, compute_absgrad=absgrad,
                             near=0.01, far=1e10, preprocess="torch")
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
out = np.zeros((2, 2))
cpu_kernels.reduce_intersections(np.arange(6.0).reshape(3, 2), np.array([0, 2, 3]), np.array([0, 2, 1]), out)
print(out.tolist())
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
    assert done.stdout.strip().splitlines()[-1] == "[[4.0, 6.0], [2.0, 3.0]]"  # rows 0+2 and row 1 of buf
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
