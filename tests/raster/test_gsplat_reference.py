"""The gsplat backend (strings_bench/raster/gsplat_backend.py) run on the CPU through gsplat's own
pure-PyTorch reference stages (tests/_gsplat_cpu.py), against the CPU rasterizer.

What agrees and what differs, with the measurements, is in docs/raster.md ("The CUDA path on the CPU").
Tolerance TOL = 1e-5 (relative L2 norm, as tests/raster/test_raster.py): gsplat's reference path in float32
differs from itself in float64 by at most 5e-6 on these scenes, so the bound is the level of gsplat's
own float32 rounding, and each comparison also checks that.
"""

from __future__ import annotations

import contextlib
import math
import subprocess
import sys

import numpy as np
import pytest
import torch


pytest.importorskip("gsplat")

from _gsplat_cpu import assert_no_cuda_backend, gsplat_on_cpu  # noqa: E402
from tests.raster.test_raster import (NAMES, clamp_scene, make_camera, output_weights, random_scene, rel,  # noqa: E402
                         weighted_loss)

from strings_bench.raster import rasterize  # noqa: E402

TOL = 1e-5
LOW_LOGIT = math.log(0.35 / 0.65)  # o <= 0.35: the CPU's 3-sigma box holds every pixel with alpha >= 1/255


def render(params, cam, backend, dtype=torch.float32, **kw):
    leaves = [p.clone().to(dtype).requires_grad_() for p in params]
    if backend == "gsplat":
        with gsplat_on_cpu():
            out = rasterize(*leaves[:5], cam, leaves[5], backend="gsplat", compute_absgrad=True, **kw)
            out.means2d.retain_grad()
            weighted_loss(out.color, out.alpha, out.depth, output_weights(cam.height, cam.width)).backward()
    else:
        # the float64 CPU kernels: the reference the tolerance was measured against (issue 37 made the
        # float32 kernels the default "cpu"; they agree with these to ~5e-5, tests/raster/test_raster_f32.py)
        out = rasterize(*leaves[:5], cam, leaves[5], backend="cpu-f64", compute_absgrad=True, **kw)
        out.means2d.retain_grad()
        weighted_loss(out.color, out.alpha, out.depth, output_weights(cam.height, cam.width)).backward()
    return out, leaves


def _grad(t):
    # the reference path leaves .grad None where nothing was drawn (the CUDA backward returns zeros)
    return t.grad if t.grad is not None else torch.zeros_like(t)


def errors(a, a_leaves, b, b_leaves):
    errs = {k: rel(getattr(a, k), getattr(b, k)) for k in ("color", "alpha", "depth")}
    for name, x, y in zip(NAMES, a_leaves, b_leaves):
        errs["grad_" + name] = rel(_grad(x), _grad(y))
    errs["grad_means2d"] = rel(_grad(a.means2d), _grad(b.means2d))
    errs["absgrad"] = rel(a.absgrad, b.absgrad)
    return errs


def low(params):
    params = [p.clone() for p in params]
    params[3] = params[3].clamp(max=LOW_LOGIT)
    return params


def _rotated_offscreen():
    ang = 0.3
    R = np.array([[math.cos(ang), 0, math.sin(ang)], [0, 1, 0], [-math.sin(ang), 0, math.cos(ang)]])
    params = low(random_scene(seed=5, n=60))
    params[0] = params[0] * torch.tensor([2.5, 2.0, 1.0])  # many outside the frustum: Jacobian clamp
    return params, make_camera(R=R, t=np.array([0.2, -0.1, 0.5])), {}


def _with(params, index, value):
    params = [p.clone() for p in params]
    params[index] = value
    return params


def _zero_quats():
    params = low(random_scene(n=20, seed=14))
    params[1][:10] = 0.0
    return params


def _stacked():
    """Six wide splats of opacity 0.95 (no clamp) stacked in depth over a small image: T = 0.05^k, so
    every pixel stops before the fourth (T would reach 6e-6 <= 1e-4) on both paths."""
    params = random_scene(n=6, seed=16)
    params[0] = torch.tensor([[0.02 * i, -0.01 * i, 2.0 + 0.3 * i] for i in range(6)])
    params[2] = torch.log(torch.full((6, 3), 3.0))
    params[3] = torch.full((6,), math.log(0.95 / 0.05))
    return params, make_camera(W=12, H=10), {}


AGREE = {
    **{f"sh{d}": lambda d=d: (low(random_scene(seed=10 + d, deg=d)), make_camera(), {}) for d in range(4)},
    "sh1_restricted_to_0": lambda: (low(random_scene(seed=4, deg=1)), make_camera(), dict(sh_degree=0)),
    "mip": lambda: (low(random_scene(seed=6, scale=(0.004, 0.05))), make_camera(), dict(mip_filter=True)),
    "small_dilation": lambda: (low(random_scene(seed=3, scale=(0.003, 0.02))), make_camera(), {}),
    "black_background": lambda: (_with(low(random_scene(seed=7)), 5, torch.zeros(3)), make_camera(), {}),
    "white_background": lambda: (_with(low(random_scene(seed=8)), 5, torch.ones(3)), make_camera(), {}),
    "rotated_offscreen": _rotated_offscreen,
    "zero_quats": lambda: (_zero_quats(), make_camera(), {}),
    "tiny_scales": lambda: (_with(random_scene(n=10, seed=10), 2, torch.full((10, 3), math.log(1e-6))),
                            make_camera(), {}),
    "huge_scales": lambda: (_with(random_scene(n=6, seed=11), 2, torch.log(torch.tensor([[2e3, 1e3, 4e3]])).expand(6, 3)),
                            make_camera(), {}),
    "one_covering": lambda: ([torch.tensor([[0.0, 0.0, 2.0]]), *random_scene(n=1, seed=15)[1:2],
                              torch.log(torch.tensor([[3.0, 2.0, 4.0]])), torch.tensor([4.0]),
                              *random_scene(n=1, seed=15)[4:]], make_camera(), {}),
    "stacked_to_the_transmittance_stop": lambda: _stacked(),
    "behind_camera": lambda: (_with(low(random_scene(n=4, seed=13)), 0, torch.tensor(
        [[0.0, 0.0, -2.0], [0.1, 0.0, 0.0], [0.0, 0.1, 0.02], [0.0, 0.0, 3.0]])), make_camera(), {}),
    "invisible_logit_-30": lambda: (_with(random_scene(n=30, seed=12), 3, torch.full((30,), -30.0)), make_camera(), {}),
    "empty": lambda: ([torch.zeros(0, 3), torch.zeros(0, 4), torch.zeros(0, 3), torch.zeros(0), torch.zeros(0, 16, 3),
                       torch.tensor([0.2, 0.4, 0.6])], make_camera(), {}),
}


# Left out, with why: quats' gradient of isotropic Gaussians is truly 0 (rounding noise only). The
# background's weight at alpha = 0.99975 is 1 - alpha in float32 on both backends (the CPU one too,
# though its T is float64 inside): cancellation, measured 8.6e-5 relative against gsplat's float64
# path (2.5e-5 for gsplat's float32). The background is not trained in the suite.
SKIP = {"tiny_scales": ("grad_quats",), "stacked_to_the_transmittance_stop": ("grad_quats", "grad_background")}


@pytest.mark.parametrize("case", list(AGREE))
def test_gsplat_path_matches_cpu_where_conventions_agree(case):
    """Renders, every gradient, means2d and absgrad of the backend through gsplat's reference stages
    equal the CPU rasterizer's to TOL, in float32, on scenes where the two conventions coincide
    (every opacity <= 0.35 or the Gaussians cover the image; no alpha at the clamp)."""
    params, cam, kw = AGREE[case]()
    cpu, cpu_leaves = render(params, cam, "cpu", **kw)
    g32, g32_leaves = render(params, cam, "gsplat", **kw)
    g64, g64_leaves = render(params, cam, "gsplat", torch.float64, **kw)
    assert_no_cuda_backend()
    skip = set(SKIP.get(case, ()))
    for label, errs in (("gsplat f32 vs cpu", errors(g32, g32_leaves, cpu, cpu_leaves)),
                        ("gsplat f64 vs cpu", errors(g64, g64_leaves, cpu, cpu_leaves)),
                        ("gsplat f32 vs f64", errors(g32, g32_leaves, g64, g64_leaves))):
        bad = {k: v for k, v in errs.items() if k not in skip and not v <= TOL}
        assert not bad, f"{label}: relative errors above {TOL}: {bad}"
    # radii > 0 differ (docs/raster.md: opacity-aware boxes, o < 1/255 culled, box-vs-image test), but
    # only for Gaussians that neither path draws: their gradients are zero on both
    differ = g32.visible ^ cpu.visible
    for leaves in (cpu_leaves, g32_leaves):
        assert (_grad(leaves[0])[differ] == 0).all() and (_grad(leaves[3])[differ] == 0).all(), case
    if case == "invisible_logit_-30":
        assert cpu.visible.all() and not g32.visible.any()
    if case == "mip":
        plain, _ = render(params, cam, "gsplat")
        assert rel(plain.color, g32.color) > 1e-3  # the antialiased mode does something
    if case == "sh1_restricted_to_0":
        assert (g32_leaves[4].grad[:, 1:] == 0).all() and (g32_leaves[4].grad[:, :1] != 0).any()
    drawn = g32.visible.any()
    assert (g32.absgrad.abs().sum() > 0) == bool(drawn)


def _tail_pixels(params, cam):
    """Pixels where some Gaussian has alpha >= 1/255 outside its 3-sigma pixel box: drawn by gsplat
    (tile support, opacity-aware radius), not by the CPU rasterizer (box support)."""
    from strings_bench.raster.projection import project

    with torch.no_grad():
        p = project(*[x.double() for x in params[:4]], cam)
        ys, xs = torch.meshgrid(torch.arange(cam.height, dtype=torch.float64) + 0.5,
                                torch.arange(cam.width, dtype=torch.float64) + 0.5, indexing="ij")
        dx = xs.reshape(1, -1) - p.means2d[:, :1]
        dy = ys.reshape(1, -1) - p.means2d[:, 1:]
        a, b, c = p.conics.unbind(-1)
        power = -0.5 * (a[:, None] * dx * dx + c[:, None] * dy * dy) - b[:, None] * dx * dy
        alpha = p.opacities[:, None] * torch.exp(power)
        outside = (dx.abs() > p.radii[:, None]) | (dy.abs() > p.radii[:, None])
        tail = (outside & (alpha >= 1 / 255) & (p.radii[:, None] > 0)).any(0)
    return tail.reshape(cam.height, cam.width)


def test_support_tails_are_the_whole_difference_without_the_clamp():
    """Opacities up to 0.96 (no splat reaches the 0.99 clamp): the images differ only on pixels where a
    Gaussian's alpha >= 1/255 lies outside its 3-sigma box (gsplat draws them, the CPU does not)."""
    params = random_scene(seed=0)
    assert float(torch.sigmoid(params[3]).max()) < 0.99
    cam = make_camera()
    cpu, _ = render(params, cam, "cpu")
    g32, _ = render(params, cam, "gsplat")
    tail = _tail_pixels(params, cam)
    diff = (g32.color - cpu.color).abs().amax(-1).detach()
    assert tail.any() and diff[tail].max() > 1e-4  # the scene has tails, and they show
    assert diff[~tail].max() <= 2e-6, float(diff[~tail].max())  # float32 rounding elsewhere


def _one_pixel(logit):
    cam = make_camera(W=1, H=1)
    cam = type(cam)(fx=2.0, fy=2.0, cx=0.5, cy=0.5, width=1, height=1, R=np.eye(3), t=np.zeros(3))
    params = [torch.tensor([[0.0, 0.0, 2.0]]), torch.tensor([[1.0, 0.0, 0.0, 0.0]]), torch.log(torch.full((1, 3), 0.5)),
              torch.tensor([logit]), torch.tensor([[[0.4, -0.2, 0.1]]]), torch.tensor([0.3, 0.6, 0.9])]
    return params, cam


def test_alpha_clamp_convention_measured():
    """gsplat 1.5.3 clamps alpha at 0.999 and gives zero opacity and means2d gradient where the clamp
    is active; the CPU rasterizer (3DGS) clamps at 0.99 and passes those gradients through."""
    params, cam = _one_pixel(12.0)  # o G = 0.99999 at the pixel centre
    cpu, cl = render(params, cam, "cpu")
    g, gl = render(params, cam, "gsplat")
    assert abs(float(cpu.alpha.detach()) - 0.99) < 1e-6 and abs(float(g.alpha.detach()) - 0.999) < 1e-6
    assert float(gl[3].grad.abs()) == 0 and float(g.means2d.grad.abs().sum()) == 0 and float(g.absgrad.sum()) == 0
    assert float(cl[3].grad.abs()) > 0
    # the colour gradient flows on both, scaled by the clamped alpha
    assert torch.allclose(gl[4].grad / 0.999, cl[4].grad / 0.99, rtol=1e-5)
    # below the clamp both agree
    params, cam = _one_pixel(1.0)
    cpu, cl = render(params, cam, "cpu")
    g, gl = render(params, cam, "gsplat")
    assert max(errors(g, gl, cpu, cl).values()) <= TOL


# measured on this machine (docs/raster.md); the bounds are these x ~2: they catch a change, not noise
DIFFER = {
    "sh3_default_opacity": (lambda: random_scene(seed=0), dict(color=2e-4, grads=6e-3)),
    "opaque": (lambda: random_scene(seed=2, n=80, opacity_mean=3.0, opacity_std=2.0), dict(color=1e-3, grads=3e-2)),
    "clamp_scene": (clamp_scene, dict(color=3e-3, grads=8e-2)),
    "logit_+30": (lambda: _with(random_scene(n=30, seed=12), 3, torch.full((30,), 30.0)), dict(color=3e-3, grads=3e-2)),
}


@pytest.mark.parametrize("case", list(DIFFER))
def test_documented_differences_stay_measured(case):
    """Scenes with opacities above 0.35 or at the clamp differ by the two documented conventions
    (support tails, the 0.999 clamp and its zero gradient). The difference is the same in float64
    (a convention, not rounding) and stays within twice what was measured."""
    make, bound = DIFFER[case]
    params, cam = make(), make_camera()
    cpu, cl = render(params, cam, "cpu")
    g32, gl32 = render(params, cam, "gsplat")
    g64, gl64 = render(params, cam, "gsplat", torch.float64)
    e32, e64 = errors(g32, gl32, cpu, cl), errors(g64, gl64, cpu, cl)
    assert e32["color"] <= bound["color"], e32
    logit = {"grad_opacity_logits"} if case in ("logit_+30", "clamp_scene") else set()  # 0 vs ~1e-13 o(1-o)
    assert max(v for k, v in e32.items() if k.startswith("grad") and k not in logit) <= bound["grads"], e32
    assert max(e32.values()) > 10 * TOL  # it is a real difference ...
    for k in ("color", "alpha", "grad_means", "grad_sh"):  # ... and not float32 rounding
        assert abs(e32[k] - e64[k]) <= 0.05 * e32[k] + TOL, (k, e32[k], e64[k])


def test_gaussian_on_the_near_plane_is_kept_by_gsplat():
    """gsplat culls z < near, the CPU rasterizer (3DGS) z <= near: a Gaussian exactly on the plane
    (float32) is drawn by gsplat only, very large."""
    params = _with(low(random_scene(n=2, seed=13)), 0, torch.tensor([[0.0, 0.1, 0.01], [0.0, 0.0, 3.0]]))
    cam = make_camera()
    cpu, _ = render(params, cam, "cpu", near=0.01)
    g, gl = render(params, cam, "gsplat", near=0.01)
    assert cpu.radii[0] == 0 and g.radii[0] > 100
    assert all(torch.isfinite(_grad(x)).all() for x in gl)


def test_sh_layout_matches_gsplat():
    """Our SH colour (raster/sh.py, which the backend passes to gsplat as RGB) is gsplat's
    `spherical_harmonics` + 0.5 clamped at 0 for every degree: the coefficient layout and signs agree,
    so passing SH to gsplat (sh_degree=d) would give the same colours."""
    from gsplat.cuda._torch_impl import _spherical_harmonics

    from strings_bench.raster.sh import sh_to_color

    g = torch.Generator().manual_seed(3)
    means = torch.randn(200, 3, generator=g, dtype=torch.float64)
    centre = torch.tensor([0.3, -0.2, -2.0], dtype=torch.float64)
    sh = torch.randn(200, 16, 3, generator=g, dtype=torch.float64) * 0.5
    for deg in range(4):
        ours = sh_to_color(sh, means, centre, deg)
        theirs = torch.clamp_min(_spherical_harmonics(deg, means - centre, sh) + 0.5, 0.0)
        assert torch.allclose(ours, theirs, atol=1e-12), deg


def test_absgrad_survives_when_gsplats_means2d_is_dropped():
    """gsplat's backward sets `.absgrad` on the Python object its ctx.saved_tensors returns
    (`_RasterizeToPixels.backward`, gsplat 1.5.3). The backend drops gsplat's `meta` when it returns;
    before the fix the object died with it and absgrad stayed zero on the GPU. Stand-in for gsplat's
    autograd function, with the backend's own `expose_means2d`."""
    from strings_bench.raster.gsplat_backend import expose_means2d

    class SavesMeans2d(torch.autograd.Function):
        @staticmethod
        def forward(ctx, m2d):
            ctx.save_for_backward(m2d)
            return (m2d * m2d).sum()

        @staticmethod
        def backward(ctx, grad):
            (m2d,) = ctx.saved_tensors
            m2d.absgrad = torch.full_like(m2d, 7.0)
            return 2 * m2d * grad

    leaf = torch.randn(5, 2, requires_grad=True)

    def backend_call():
        meta = {"means2d": (leaf * 2.0)[None]}
        means2d, absgrad = expose_means2d(meta["means2d"], compute_absgrad=True)
        return SavesMeans2d.apply(meta["means2d"]), means2d, absgrad  # meta dies here

    loss, means2d, absgrad = backend_call()
    loss.backward()
    assert torch.equal(absgrad, torch.full((5, 2), 7.0))
    assert torch.allclose(means2d.grad, 2 * (leaf * 2.0).detach())


def test_importing_gsplat_compiles_nothing():
    """gsplat 1.5.3 is a py3-none-any wheel that JIT-compiles its CUDA code at the first CUDA call
    (`gsplat.cuda._backend`); importing it and the backend must not load that module."""
    code = ("import sys, gsplat, strings_bench.raster.gsplat_backend as b; "
            "print(gsplat.__version__, 'gsplat.cuda._backend' in sys.modules, b.gsplat_available())")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    version, loaded, available = done.stdout.split()
    assert loaded == "False"
    assert available == str(torch.cuda.is_available())


# ---- training through the path -------------------------------------------------------------------

@pytest.fixture(scope="module")
def text_scene(tmp_path_factory):
    from _engine_helpers import make_tiny_scene
    from tests.methods.test_strings import TEXT_BOX, _write_masks

    from strings_bench.scene.scene import Scene

    root = tmp_path_factory.mktemp("gsplat_ref") / "scene"
    scene = make_tiny_scene(root, n_views=9, n_points=60)
    _write_masks(root, scene, TEXT_BOX, empty_views=(3,))
    return Scene.load(root)


DENSIFY_EARLY = dict(sh_degree=1, refine_start_iter=5, refine_every=10)  # refinements at steps 10, 20, 30
TRAIN = {
    "3dgs": DENSIFY_EARLY,
    "absgs": DENSIFY_EARLY,  # densifies on absgrad
    "mip-splatting": DENSIFY_EARLY,  # the antialiased mode
    "strings": dict(steps_scale=0.002, mask_dilation_fraction=0.0, n_max=3, sh_degree=1),  # phase 2 from step 6
}


@pytest.mark.parametrize("method", list(TRAIN))
def test_30_training_steps_through_the_gsplat_path_match_the_cpu_engine(method, text_scene, monkeypatch, tmp_path):
    """30 steps of the suite's trainer with backend=gsplat (reference stages) and backend=cpu: the
    same losses to 1e-3 relative per step (measured <= 3e-4), the same number of Gaussians after the
    densifications, renders within 0.03 (measured <= 0.016)."""
    from _engine_helpers import train

    from strings_bench.methods.registry import get_method

    monkeypatch.setenv("STRINGS_BENCH_CACHE", str(tmp_path / "cache"))
    runs = {}
    for backend in ("cpu-f64", "gsplat"):
        m = get_method(method).build(backend=backend, **TRAIN[method])
        losses, step = [], m.train_step

        def record(s, _step=step, _losses=losses, **kw):
            _losses.append(_step(s, **kw))
            return _losses[-1]

        m.train_step = record
        with gsplat_on_cpu() if backend == "gsplat" else contextlib.nullcontext():
            (result,) = train(m, text_scene, [30])
        runs[backend] = (np.array(losses), result)
    assert_no_cuda_backend()
    (lc, rc), (lg, rg) = runs["cpu-f64"], runs["gsplat"]
    assert len(lc) == len(lg) == 30
    assert np.all(np.abs(lg - lc) <= 1e-3 * np.abs(lc)), np.abs(lg - lc) / np.abs(lc)
    assert rg.gaussians == rc.gaussians and rc.gaussians > 60  # densification ran, identically
    for name, img in rc.renders.items():
        assert np.abs(img - rg.renders[name]).max() <= 0.03, name
