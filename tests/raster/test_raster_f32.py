"""The float32 blend kernels (backend "cpu", the default) against the float64 kernels ("cpu-f64", the
reference that tests/raster/test_raster.py holds to the brute-force reference at 1e-5).

Issue 37's tolerances: renders (colour, alpha: values on [0, 1]) max absolute difference <= 1e-4;
every gradient relative error (norm-wise, ||a - b|| / ||b||) <= 1e-3. Checked on the random scenes and
the numerical extremes of tests/raster/test_raster.py, and on blend inputs captured from real training steps
of a small scene (the deterministic, small stand-in for issue 28's nine captured steps, which are
not in the repository; docs/engine.md gives the same check on those). Plus: the vector `exp` against
float64, bit-identical results at any thread count, and the tight boxes still changing no bit."""

from __future__ import annotations

import math
from pathlib import Path

import numba
import numpy as np
import pytest
import torch

from strings_bench.raster import rasterize
from tests.raster.test_raster import (NAMES, make_camera, output_weights, random_scene, weighted_loss, SCENES,
                         _blend_with_boxes)

RENDER_ATOL = 1e-4
GRAD_RTOL = 1e-3


def rel(a, b):
    a, b = a.detach().double(), b.detach().double()
    nb = b.norm().item()
    if nb == 0.0:
        return a.norm().item()  # both must then be (near) zero
    return ((a - b).norm() / nb).item()


def run(params, cam, backend, **kw):
    leaves = [p.clone().float().requires_grad_() for p in params]
    out = rasterize(*leaves[:5], cam, leaves[5], backend=backend, compute_absgrad=True, **kw)
    out.means2d.retain_grad()
    weighted_loss(out.color, out.alpha, out.depth, output_weights(cam.height, cam.width)).backward()
    return out, leaves


def agreement(params, cam, **kw):
    """Errors of "cpu" against "cpu-f64": max abs for colour and alpha, relative for depth and every
    gradient (the inputs', means2d's and absgrad)."""
    new, ln = run(params, cam, "cpu", **kw)
    ref, lr = run(params, cam, "cpu-f64", **kw)
    assert new.backend == "cpu" and ref.backend == "cpu-f64"
    assert torch.equal(new.radii, ref.radii)
    render = {k: (getattr(new, k) - getattr(ref, k)).abs().max().item() if getattr(new, k).numel() else 0.0
              for k in ("color", "alpha")}
    grads = {"depth": rel(new.depth, ref.depth), "grad_means2d": rel(new.means2d.grad, ref.means2d.grad),
             "absgrad": rel(new.absgrad, ref.absgrad)}
    for name, a, b in zip(NAMES, ln, lr):
        assert torch.isfinite(a.grad).all(), name
        grads["grad_" + name] = rel(a.grad, b.grad)
    return render, grads


def check(render, grads):
    bad = {k: v for k, v in render.items() if not v <= RENDER_ATOL}
    bad.update({k: v for k, v in grads.items() if not v <= GRAD_RTOL})
    assert not bad, f"above tolerance: {bad} (all: {render} {grads})"


def test_vector_exp_matches_float64():
    from strings_bench.raster.cpu_kernels_f32 import exp_neg32

    @numba.njit
    def many(x):
        out = np.empty_like(x)
        for i in range(x.shape[0]):
            out[i] = exp_neg32(x[i])
        return out

    x = np.linspace(-10.0, 0.0, 200_001).astype(np.float32)
    got = many(x)
    assert got.dtype == np.float32
    err = np.abs(got.astype(np.float64) / np.exp(x.astype(np.float64)) - 1.0).max()
    assert err <= 3e-7, err  # a few float32 ulp
    assert many(np.array([0.0], np.float32))[0] == 1.0
    # below the clamp: e^-10, small enough that o e^x < 1/255 for every opacity o <= 1
    assert many(np.array([-50.0], np.float32))[0] == pytest.approx(math.exp(-10.0), rel=1e-6)


@pytest.mark.parametrize("scene", list(SCENES))
def test_float32_blend_agrees_with_float64_on_random_scenes(scene):
    render, grads = agreement(random_scene(**SCENES[scene]), make_camera())
    check(render, grads)


def test_float32_blend_agrees_with_mip_filter_and_rotated_camera():
    check(*agreement(random_scene(seed=6, scale=(0.004, 0.05)), make_camera(), mip_filter=True))
    ang = 0.3
    R = np.array([[math.cos(ang), 0, math.sin(ang)], [0, 1, 0], [-math.sin(ang), 0, math.cos(ang)]])
    params = random_scene(seed=5, n=60)
    params[0] = params[0] * torch.tensor([2.5, 2.0, 1.0])
    check(*agreement(params, make_camera(R=R, t=np.array([0.2, -0.1, 0.5]))))


def _extreme(case):
    """The numerical extremes of tests/raster/test_raster.py (same seeds and values)."""
    if case == "tiny_scales":
        params = random_scene(n=10, seed=10)
        params[2] = torch.full((10, 3), math.log(1e-6))
    elif case == "huge_scales":
        params = random_scene(n=6, seed=11)
        params[2] = torch.log(torch.tensor([[2e3, 1e3, 4e3]])).expand(6, 3)
    elif case in ("logit+30", "logit-30"):
        params = random_scene(n=30, seed=12)
        params[3] = torch.full((30,), 30.0 if case == "logit+30" else -30.0)
    elif case == "behind_camera":
        params = random_scene(n=4, seed=13)
        params[0] = torch.tensor([[0.0, 0.0, -2.0], [0.1, 0.0, 0.0], [0.0, 0.1, 0.01], [0.0, 0.0, 3.0]])
    elif case == "zero_quaternions":
        params = random_scene(n=20, seed=14)
        params[1][:10] = 0.0
    elif case == "one_covering":
        params = random_scene(n=1, seed=15)
        params[0] = torch.tensor([[0.0, 0.0, 2.0]])
        params[2] = torch.log(torch.tensor([[3.0, 2.0, 4.0]]))
        params[3] = torch.tensor([4.0])
    else:  # empty
        params = [torch.zeros(0, 3), torch.zeros(0, 4), torch.zeros(0, 3), torch.zeros(0), torch.zeros(0, 16, 3),
                  torch.tensor([0.2, 0.4, 0.6])]
    return params


EXTREMES = ["tiny_scales", "huge_scales", "logit+30", "logit-30", "behind_camera", "zero_quaternions",
            "one_covering", "empty"]


@pytest.mark.parametrize("case", EXTREMES)
def test_float32_blend_agrees_with_float64_at_the_extremes(case):
    render, grads = agreement(_extreme(case), make_camera())
    if case == "tiny_scales":
        # equal tiny scales: the true quaternion gradient is 0; both are rounding noise (test_raster)
        del grads["grad_quats"]
    if case in ("logit-30", "empty"):
        # nothing is blended: every Gaussian gradient is exactly zero in both (rel() gives |a| here)
        assert all(v == 0.0 for k, v in grads.items() if k not in ("grad_background", "depth")), grads
    check(render, grads)


# ---- blend inputs captured from real training steps ------------------------------------------------

class _Capture:
    """Stands in for raster.cpu.RasterizeTiles during training: records each call's inputs and the
    gradients that reach its outputs."""

    def __init__(self, real):
        self.real = real
        self.calls = []

    def apply(self, *args):
        feat, alpha = self.real.apply(*args)
        rec = {"args": [a.detach().clone() if isinstance(a, torch.Tensor) else a for a in args], "grads": [None, None]}
        self.calls.append(rec)

        def keep(i):
            def hook(g):
                rec["grads"][i] = g.detach().clone()
            return hook

        if feat.requires_grad:
            feat.register_hook(keep(0))
            alpha.register_hook(keep(1))
        return feat, alpha


def blend_errors(args, grads):
    """Forward and backward of RasterizeTiles with both precisions on the same inputs and output
    gradients; returns (render errors, gradient errors) as in `agreement`."""
    from strings_bench.raster.cpu import RasterizeTiles

    res = {}
    for prec in ("f32", "f64"):
        ins = [a.clone().requires_grad_() if isinstance(a, torch.Tensor) and i < 4 else a
               for i, a in enumerate(args[:10])]
        n = ins[0].shape[0]
        ins[9] = torch.zeros((n, 2))  # absgrad
        feat, alpha = RasterizeTiles.apply(*ins, prec)
        torch.autograd.backward([feat, alpha], [grads[0], grads[1]])
        res[prec] = (feat.detach(), alpha.detach(), [x.grad for x in ins[:4]], ins[9])
    (f32, a32, g32, ab32), (f64, a64, g64, ab64) = res["f32"], res["f64"]
    render = {"color": (f32[..., :3] - f64[..., :3]).abs().max().item(), "alpha": (a32 - a64).abs().max().item()}
    errs = {"depth_feature": rel(f32[..., 3], f64[..., 3]), "absgrad": rel(ab32, ab64)}
    for name, a, b in zip(("means2d", "conics", "opacities", "features"), g32, g64):
        errs["grad_" + name] = rel(a, b)
    return render, errs


@pytest.fixture(scope="module")
def captured_steps(tmp_path_factory):
    """Blend inputs and output gradients of three training steps of 3DGS (SH degree 3 colours through
    the real loss) on a small scene, at steps 5, 120 and 240, after densification has grown the model."""
    import strings_bench.raster.cpu as cpu
    from _engine_helpers import make_tiny_scene
    from strings_bench.engine.splatting import GaussianSplatting, TrainConfig
    from strings_bench.engine.trainer import seed_everything

    scene = make_tiny_scene(tmp_path_factory.mktemp("f32scene"), n_views=6, width=96, height=72, n_points=400)
    method = GaussianSplatting(TrainConfig(steps_scale=0.02, seed=0))
    seed_everything(0)
    method.setup(scene, device="cpu")
    cap = _Capture(cpu.RasterizeTiles)
    want = {5, 120, 240}
    got = []
    for step in range(1, max(want) + 1):
        if step in want:
            cpu.RasterizeTiles = cap
        try:
            method.train_step(step)
        finally:
            cpu.RasterizeTiles = cap.real
        method.refine(step)
        if step in want:
            got.append((step, method.num_gaussians(), cap.calls[-1]))
    return got


def test_float32_blend_agrees_on_captured_training_steps(captured_steps):
    assert len(captured_steps) == 3
    assert captured_steps[-1][1] > captured_steps[0][1]  # densification ran: the model grew
    for step, n, rec in captured_steps:
        assert rec["grads"][0] is not None and rec["grads"][1] is not None
        render, errs = blend_errors(rec["args"], rec["grads"])
        bad = {k: v for k, v in render.items() if not v <= RENDER_ATOL}
        bad.update({k: v for k, v in errs.items() if not v <= GRAD_RTOL})
        assert not bad, (step, n, render, errs)


def test_float32_blend_is_bit_identical_at_any_thread_count():
    """The same inputs give the same bits with 1 and 2 numba threads and any chunk size (each tile is
    one thread's; the per-Gaussian sums run in a fixed order)."""
    params = random_scene(n=400, seed=21, scale=(0.01, 0.12))
    cam = make_camera(W=96, H=80)
    runs = []
    n0 = numba.get_num_threads()
    try:
        for threads, chunk in ((1, 2), (min(2, numba.config.NUMBA_NUM_THREADS), 1),
                               (min(2, numba.config.NUMBA_NUM_THREADS), 7)):
            numba.set_num_threads(threads)
            with numba.parallel_chunksize(chunk):
                out, leaves = run(params, cam, "cpu")
            runs.append([out.color, out.alpha, out.depth, out.absgrad, out.means2d.grad] + [x.grad for x in leaves])
    finally:
        numba.set_num_threads(n0)
    for other in runs[1:]:
        for a, b in zip(runs[0], other):
            assert torch.equal(a, b)


def test_float32_backward_skipping_the_ended_blocks_gives_the_bits_of_visiting_them(monkeypatch):
    """The float32 backward skips a 16-pixel block whose pixels all ended before the splat (their last contributor
    is in front of it); visiting those blocks (`skip_ended=False`) must give every gradient bit for bit. Opaque,
    overlapping splats, so that most pixels end well before their tile's list does."""
    import strings_bench.raster.cpu as cpu
    from strings_bench.raster import cpu_kernels_f32 as K32

    params = random_scene(n=600, seed=5, opacity_mean=3.0, opacity_std=0.5, scale=(0.03, 0.15))
    cam = make_camera(W=96, H=80)
    seen = {}

    class Kernels:  # cpu_kernels_f32 with the backward's skip switched as asked
        def __init__(self, skip):
            self.skip = skip

        def __getattr__(self, name):
            return getattr(K32, name)

        def backward(self, tile_start, lst, P, BB, W, H, tiles_x, T_final, last_k, *rest):
            seen["ended"] = seen.get("ended") or _ended_share(tile_start, last_k, W, H, tiles_x)
            return K32.backward(tile_start, lst, P, BB, W, H, tiles_x, T_final, last_k, *rest, self.skip)

    runs = []
    for skip in (True, False):
        monkeypatch.setitem(cpu.BLEND_KERNELS, "f32", Kernels(skip))
        out, leaves = run(params, cam, "cpu")
        runs.append([out.absgrad, out.means2d.grad] + [x.grad for x in leaves])
    assert seen["ended"] > 0.5, seen  # the skip has blocks to skip
    for a, b in zip(*runs):
        assert torch.equal(a, b)


def _ended_share(tile_start, last_k, W, H, tiles_x):
    """The share of pixels whose last contributor comes before the end of their tile's list."""
    ended = 0
    for py in range(H):
        for px in range(W):
            t = (py // 16) * tiles_x + px // 16
            ended += int(last_k[py, px]) < int(tile_start[t + 1])
    return ended / (W * H)


_COMPILED_VS_CACHED = r"""
import hashlib, json, sys
import numba
from strings_bench.raster import cpu_kernels_f32
from tests.raster.test_raster_f32 import run
from tests.raster.test_raster import make_camera, random_scene
out, leaves = run(random_scene(n=1500, seed=3), make_camera(W=128, H=96), "cpu")
digest = hashlib.sha256()
for t in [out.color, out.alpha, out.depth, out.absgrad, out.means2d.grad] + [x.grad for x in leaves]:
    digest.update(t.detach().numpy().tobytes())
hits = sum(sum(getattr(cpu_kernels_f32, k).stats.cache_hits.values()) for k in ("forward", "backward", "pack"))
print(json.dumps({"digest": digest.hexdigest(), "cache_hits": hits}))
"""


@pytest.mark.heavy
def test_float32_kernels_compiled_here_and_loaded_from_the_cache_give_the_same_bits(tmp_path):
    """A clean clone's first process compiles the kernels (numba's JIT); every later one loads the object
    code numba cached. Both must give the same bits, or a run depends on whether it came first (the
    reason the kernels have no `contract`: LLVM fused multiply-adds differently on the two paths)."""
    import json
    import os
    import subprocess
    import sys

    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "numba"),
           "PYTHONPATH": os.pathsep.join([str(Path(__file__).parents[2]), os.environ.get("PYTHONPATH", "")])}
    runs = [json.loads(subprocess.run([sys.executable, "-c", _COMPILED_VS_CACHED], env=env, check=True,
                                      capture_output=True, text=True, timeout=600).stdout.splitlines()[-1])
            for _ in range(2)]
    assert runs[0]["cache_hits"] == 0 and runs[1]["cache_hits"] == 3  # compiled, then loaded
    assert runs[0]["digest"] == runs[1]["digest"]


def test_float32_tight_boxes_change_no_pixel():
    """As test_raster's test for the float64 kernels: the float32 blend of tight boxes against the
    blend of the 3-sigma boxes. Every pixel's recursion is the same, so the image and transmittance
    are identical bit for bit; the per-Gaussian gradient sums are vector reductions whose grouping of
    pixels into lanes follows the box, so they may differ in the last bits (here <= 1e-6 relative)."""
    import strings_bench.raster.cpu_kernels_f32 as K32
    from strings_bench.raster.cpu import Preprocess

    W, H = 96, 80
    cam = make_camera(W=W, H=H)
    params = random_scene(n=300, seed=11, opacity_mean=-3.0, opacity_std=2.0, scale=(0.005, 0.25))
    with torch.no_grad():
        means2d, conics, opac, feats, radii, bbox = Preprocess.apply(*params[:5], 3, cam, False, 0.01, 1e10)
    vis = torch.nonzero(radii > 0).flatten()
    order = vis[torch.argsort(feats[vis, 3], stable=True)].numpy()
    P, tight = K32.pack(order, means2d.numpy(), conics.numpy(), opac.numpy(), feats.numpy(), bbox.numpy())
    full = bbox.numpy()[order].astype(np.int64)
    f_t, T_t, g_t, m_t, _ = _blend_with_boxes(P, tight, W, H, kernels=K32)
    f_f, T_f, g_f, m_f, _ = _blend_with_boxes(P, full, W, H, kernels=K32)
    assert m_t < 0.75 * m_f, (m_t, m_f)
    assert np.array_equal(f_t, f_f) and np.array_equal(T_t, T_f)
    for a, b in zip(g_t, g_f):
        assert rel(torch.from_numpy(a), torch.from_numpy(b)) <= 1e-6
    assert np.abs(g_f[0]).sum() > 0 and (T_f < 1).mean() > 0.2


@pytest.mark.parametrize("backend", ["cpu", "cpu-f64"])
@pytest.mark.parametrize("sh_degree", [None, 1, 0])
def test_sh_rest_gives_the_concatenations_bits(backend, sh_degree):
    """rasterize(sh=sh0, sh_rest=shN) (what the model passes: no concatenation) equals rasterize with
    their concatenation bit for bit, gradients of sh0 and shN included."""
    params = random_scene(n=60, seed=22)
    cam = make_camera()
    outs = []
    for split in (False, True):
        leaves = [p.clone().float().requires_grad_() for p in params]
        sh0 = params[4][:, :1].clone().requires_grad_()
        shN = params[4][:, 1:].clone().requires_grad_()
        if split:
            out = rasterize(*leaves[:4], sh0, cam, leaves[5], sh_degree=sh_degree, backend=backend, sh_rest=shN,
                            compute_absgrad=True)
        else:
            out = rasterize(*leaves[:4], torch.cat([sh0, shN], 1), cam, leaves[5], sh_degree=sh_degree,
                            backend=backend, compute_absgrad=True)
        weighted_loss(out.color, out.alpha, out.depth, output_weights(cam.height, cam.width)).backward()
        outs.append([out.color, out.alpha, out.depth, out.absgrad, sh0.grad, shN.grad]
                    + [x.grad for x in leaves[:4]] + [leaves[5].grad])
    for a, b in zip(*outs):
        assert torch.equal(a, b)
    assert outs[1][4].abs().sum() > 0 and (sh_degree == 0 or outs[1][5].abs().sum() > 0)


def test_sh_rest_shape_errors():
    from strings_bench.raster import RasterInputError

    params = random_scene(n=5, seed=23)
    with pytest.raises(RasterInputError, match="sh_rest"):
        rasterize(*params[:4], params[4], make_camera(), params[5], sh_rest=params[4][:, 1:])
    with pytest.raises(RasterInputError, match="coefficients"):
        rasterize(*params[:4], params[4][:, :1], make_camera(), params[5], sh_rest=params[4][:, 1:3])


def test_trainer_finite_check_sums():
    """engine.optim_kernels.sums_finite (the trainer's per-step check, on the numba threads): False for a
    NaN or an infinity anywhere, or a total beyond float32's range; True otherwise; float64 and
    non-contiguous tensors through torch."""
    from strings_bench.engine.optim_kernels import sums_finite

    x = torch.randn(300_001)
    assert sums_finite([x, torch.zeros(0), torch.randn(7, 3)])
    for bad in (float("nan"), float("inf"), -float("inf")):
        y = x.clone()
        y[123_457] = bad
        assert not sums_finite([torch.ones(4), y])
    assert not sums_finite([torch.full((1000,), 3e36)])  # finite elements, total 3e39 > 3.4e38
    assert sums_finite([torch.full((1000,), 3e34)])
    assert not sums_finite([torch.tensor([1.0, float("nan")], dtype=torch.float64)])
    assert not sums_finite([torch.ones(6, 4).t().contiguous().t().clone().fill_(float("nan"))])
    assert sums_finite([torch.ones(6, 4).t()])


def test_a_block_the_ellipse_test_skips_has_no_pixel_that_blends():
    """The float32 blends skip a 2-row x 8-column block of a Gaussian's box where `block_meets_ellipse` says the
    alpha >= 1/255 ellipse misses it. Checked against the exact per-pixel test, written out here in numpy (float32,
    as the kernels compute it): for random Gaussians (elongated, rotated, opacities from 1/255 up, sub-pixel to
    wide), every block that holds a passing pixel is kept."""
    from strings_bench.raster import cpu_kernels as K
    from strings_bench.raster import cpu_kernels_f32 as K32

    rng = np.random.default_rng(7)
    n = 400
    means2d = rng.uniform(-4, 52, (n, 2)).astype(np.float32)
    sx, sy = np.exp(rng.uniform(np.log(0.3), np.log(12.0), (2, n)))
    th = rng.uniform(0, np.pi, n)
    c, s = np.cos(th), np.sin(th)
    cov = np.stack([c * c * sx ** 2 + s * s * sy ** 2, c * s * (sx ** 2 - sy ** 2), s * s * sx ** 2 + c * c * sy ** 2], 1)
    det = cov[:, 0] * cov[:, 2] - cov[:, 1] ** 2
    conics = np.stack([cov[:, 2] / det, -cov[:, 1] / det, cov[:, 0] / det], 1).astype(np.float32)
    opac = np.exp(rng.uniform(np.log(1 / 255), 0, n)).astype(np.float32)
    feats = np.zeros((n, K.NF), np.float32)
    rad = np.ceil(3 * np.sqrt(np.maximum(sx, sy) ** 2)).astype(np.int64)
    bbox = np.stack([means2d[:, 0] - rad, means2d[:, 0] + rad, means2d[:, 1] - rad, means2d[:, 1] + rad], 1)
    bbox = np.clip(np.round(bbox), 0, 47).astype(np.int32)
    P, BB = K32.pack(np.arange(n), means2d, conics, opac, feats, bbox)
    kept = skipped = 0
    for i in range(n):
        xs, xe, ys, ye = (int(v) for v in BB[i])
        if xs > xe or ys > ye:
            continue
        mx, my, ca, cb, cc, op = (np.float32(v) for v in P[i, :6])
        for py0 in range(0, 48, K.TILE):  # the tiles the box touches, each cut into 2 x 8 blocks
            for px0 in range(0, 48, K.TILE):
                bx0, bx1, by0, by1 = max(xs, px0), min(xe, px0 + 15), max(ys, py0), min(ye, py0 + 15)
                if bx0 > bx1 or by0 > by1:
                    continue
                for r in range(0, 16, 2):
                    for h in (0, 1):
                        c_lo = px0 + 8 * h
                        px = np.arange(c_lo, c_lo + 8, dtype=np.float32)
                        py = np.array([py0 + r, py0 + r + 1], np.float32)
                        dx = mx - (px[None, :] + np.float32(0.5))
                        dy = my - (py[:, None] + np.float32(0.5))
                        power = np.float32(-0.5) * (ca * dx * dx + cc * dy * dy) - cb * dx * dy
                        alpha = np.minimum(op * np.exp(np.minimum(power, 0)), np.float32(0.99))
                        inside = ((px[None, :] >= bx0) & (px[None, :] <= bx1) & (py[:, None] >= by0) & (py[:, None] <= by1))
                        passes = inside & (power <= 0) & (alpha >= np.float32(1 / 255))
                        meets = K32.block_meets_ellipse(P, i, py0, r, by0, by1, bx0, bx1, c_lo, c_lo + 7)
                        assert meets or not passes.any(), (i, px0, py0, r, h)
                        kept += meets
                        skipped += not meets
    assert kept > 100 and skipped > 100  # both cases occur
