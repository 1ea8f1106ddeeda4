from strings_bench.core.schedules import get_schedule
"""Engine: Gaussian init, Adam (vs torch.optim.Adam), LR schedule, densification ops (state, extras,
children statistics), the vanilla 3DGS strategy, and the trainer (end to end, repeatability, NaN)."""

import math
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from _engine_helpers import make_tiny_scene, train  # noqa: E402

from strings_bench.core.errors import StringsBenchError, TrainingError  # noqa: E402
from strings_bench.engine.gaussians import GaussianModel  # noqa: E402
from strings_bench.engine.optim import GaussianAdam, LearningRates, exponential_lr  # noqa: E402
from strings_bench.engine.strategies import DefaultStrategy, Strategy, ops  # noqa: E402
from strings_bench.engine.splatting import GaussianSplatting, TrainConfig  # noqa: E402
from strings_bench.engine.trainer import Trainer  # noqa: E402


@pytest.fixture(autouse=True)
def one_thread():
    # Tiny tensors: thread start-up costs more than the work, badly so on a busy 2-core machine.
    n = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(n)


@pytest.fixture(scope="module")
def tiny_scene(tmp_path_factory):
    return make_tiny_scene(tmp_path_factory.mktemp("tiny"))


def _random_model(n=40, seed=0, degree=1):
    rng = np.random.default_rng(seed)
    m = GaussianModel.from_points(rng.normal(size=(n, 3)), rng.integers(0, 256, (n, 3)).astype(np.uint8),
                                  sh_degree=degree, extras={"is_text": torch.from_numpy(rng.random(n) < 0.5),
                                                            "tag": torch.arange(n)})
    g = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for p in m.params.values():
            p.add_(0.1 * torch.randn(p.shape, generator=g))
    return m


# ---- model ------------------------------------------------------------------------------------
def test_from_points_matches_3dgs_init():
    rng = np.random.default_rng(1)
    xyz = rng.normal(size=(30, 3))
    rgb = rng.integers(0, 256, (30, 3)).astype(np.uint8)
    m = GaussianModel.from_points(xyz, rgb, sh_degree=3)
    d2 = ((xyz[:, None] - xyz[None]) ** 2).sum(-1)
    np.fill_diagonal(d2, np.inf)
    expected = np.log(np.sqrt(np.sort(d2, axis=1)[:, :3].mean(1)))
    np.testing.assert_allclose(m.params["log_scales"].detach().numpy(), np.repeat(expected[:, None], 3, 1), rtol=1e-5)
    np.testing.assert_allclose(m.opacities.detach().numpy(), 0.1, rtol=1e-5)
    np.testing.assert_array_equal(m.params["quats"].detach().numpy(), np.tile([1, 0, 0, 0], (30, 1)))
    np.testing.assert_allclose(m.params["sh0"].detach().numpy()[:, 0], (rgb / 255 - 0.5) * 2 * math.sqrt(math.pi), rtol=1e-5, atol=1e-6)
    assert m.params["shN"].shape == (30, 15, 3) and not m.params["shN"].detach().any()
    assert len(m) == 30 and m.sh.shape == (30, 16, 3)


def test_concat_and_subset_keep_extras():
    a, b = _random_model(5, 1), _random_model(7, 2)
    del b.extras["tag"]
    c = GaussianModel.concat([a, b])
    assert len(c) == 12 and c.extras["tag"][5:].eq(0).all() and c.extras["is_text"].dtype == torch.bool
    s = c.subset(c.extras["is_text"])
    assert len(s) == int(c.extras["is_text"].sum())
    torch.testing.assert_close(s.params["means"], c.params["means"][c.extras["is_text"]])


# ---- optimizer -------------------------------------------------------------------------------
@pytest.mark.parametrize("fused", [True, False])
def test_adam_matches_torch_adam(fused):
    m1, m2 = _random_model(seed=3), _random_model(seed=3)
    lrs = {"means": 1e-2, "quats": 1e-3, "log_scales": 5e-3, "opacity_logits": 0.05, "sh0": 2.5e-3, "shN": 1e-4}
    ours = GaussianAdam(m1.params, lrs, fused=fused)
    ref = torch.optim.Adam([{"params": [m2.params[k]], "lr": v} for k, v in lrs.items()], eps=1e-15)
    for it in range(5):
        for m in (m1, m2):
            loss = sum(((p - 0.3 * it) ** 2 * (1 + i)).sum() for i, p in enumerate(m.params.values()))
            loss.backward()
        ours.step()
        ref.step()
        ours.zero_grad()
        ref.zero_grad()
    for k in lrs:
        torch.testing.assert_close(m1.params[k], m2.params[k], rtol=1e-6, atol=1e-7)


@pytest.mark.parametrize("n", [1, 7, 33, 4099, 9000])
def test_fused_adam_is_bit_identical_to_the_torch_path(n):
    """The numba Adam (engine/optim_kernels.py) must give the torch element-wise path's float32 results
    bit for bit: parameters and both moments, over steps with gradients from 1e-9 to 10, exact zeros,
    a per-row scale on some steps, a zero learning rate, and state resized by gather_rows (9000 values span
    three of its chunks)."""
    ma, mb = _random_model(n, seed=5, degree=3), _random_model(n, seed=5, degree=3)
    lrs = {"means": 1.6e-4 * 3.7, "quats": 1e-3, "log_scales": 5e-3, "opacity_logits": 0.05, "sh0": 2.5e-3,
           "shN": 0.0}
    fused, ref = GaussianAdam(ma.params, lrs, fused=True), GaussianAdam(mb.params, lrs, fused=False)
    gen = torch.Generator().manual_seed(n)
    for it in range(7):
        for k, p in ma.params.items():
            grad = torch.randn(p.shape, generator=gen) * 10.0 ** float(torch.empty(()).uniform_(-9, 1, generator=gen))
            if it == 2:
                grad[: max(1, n // 2)] = 0.0
            ma.params[k].grad = grad.clone()
            mb.params[k].grad = grad.clone()
        rs = {"means": torch.rand(n, generator=gen) * 2} if it % 2 else None
        fused.step(rs)
        ref.step(rs)
        if it == 4:  # densification reorders the moments
            idx = torch.arange(n - 1, -1, -1)
            for opt, m in ((fused, ma), (ref, mb)):
                for k in m.params:
                    m.params[k] = torch.nn.Parameter(torch.cat([m.params[k].detach()[idx], m.params[k].detach()[:1]]))
                    opt.gather_rows(k, idx, n_new=1)
            n += 1
    for k in ma.params:
        assert torch.equal(ma.params[k], mb.params[k]), k
        for key in ("exp_avg", "exp_avg_sq"):
            assert torch.equal(fused.state[k][key], ref.state[k][key]), (k, key)
    assert fused.state["means"]["step"] == ref.state["means"]["step"] == 7


def test_adams_square_root_is_the_correctly_rounded_one_on_every_path():
    """Adam's sqrt(v) is IEEE's correctly rounded square root (numpy's, float64's rounded once), not torch's CPU sqrt
    (MKL's, whose rounding follows MKL's code branch, i.e. the CPU: docs/reproducibility.md). One step from zero
    moments with gradient g gives m = 0.1 g, v = 0.001 g^2: the update divides by sqrt(v) exactly as the reference
    computes it."""
    from strings_bench.engine.optim import exact_sqrt

    rng = np.random.default_rng(0)
    x = (rng.random(50000) * 10.0 ** rng.integers(-38, 4, 50000)).astype(np.float32)
    want = np.sqrt(x.astype(np.float64)).astype(np.float32)  # exact: float64 holds the float32 root's rounding
    assert np.array_equal(exact_sqrt(torch.from_numpy(x)).numpy(), want)
    for fused in (True, False):
        g = torch.from_numpy(rng.standard_normal(9000).astype(np.float32) * 1e-3)
        p = torch.nn.Parameter(torch.zeros(9000))
        opt = GaussianAdam({"means": p}, {"means": 0.5}, fused=fused)
        p.grad = g.clone()
        opt.step()
        v = np.float32(1 - 0.999) * g.numpy()  # fma(a2 g, g, 0): a2 g rounded, then one rounding
        v = (v.astype(np.float64) * g.numpy().astype(np.float64)).astype(np.float32)
        d = (np.sqrt(v.astype(np.float64)).astype(np.float32) / np.float32(np.sqrt(1 - 0.999))) + np.float32(1e-15)
        m = (np.float32(1 - 0.9) * g.numpy()).astype(np.float32)
        u = m / d
        want_p = (u.astype(np.float64) * np.float64(np.float32(-0.5 / (1 - 0.9)))).astype(np.float32)
        assert np.array_equal(p.detach().numpy(), want_p), fused


def test_row_scale_scales_the_update_not_the_gradient():
    m = _random_model(10, seed=4)
    before = m.params["means"].detach().clone()
    opt = GaussianAdam(m.params, {"means": 0.1})
    (m.params["means"] * torch.arange(1.0, 31.0).reshape(10, 3)).sum().backward()
    scale = torch.tensor([0.0, 0.5, 1.0, 2.0] + [1.0] * 6)
    opt.step({"means": scale})
    step = m.params["means"].detach() - before
    # First Adam step moves every coordinate by lr * sign(grad), whatever the gradient's size.
    torch.testing.assert_close(step, -0.1 * scale[:, None].expand(10, 3), rtol=1e-5, atol=1e-7)


def test_exponential_lr_schedule():
    assert exponential_lr(0, 1.6e-4, 1.6e-6, 30000) == pytest.approx(1.6e-4)
    assert exponential_lr(30000, 1.6e-4, 1.6e-6, 30000) == pytest.approx(1.6e-6)
    assert exponential_lr(15000, 1.6e-4, 1.6e-6, 30000) == pytest.approx(math.sqrt(1.6e-4 * 1.6e-6))
    assert exponential_lr(60000, 1.6e-4, 1.6e-6, 30000) == pytest.approx(1.6e-6)
    lrs = LearningRates().group_lrs(extent=2.0)
    assert lrs["means"] == pytest.approx(3.2e-4) and lrs["opacity_logits"] == 0.05 and lrs["shN"] == pytest.approx(1.25e-4)


# ---- ops ------------------------------------------------------------------------------------------
def _adam_with_state(m):
    opt = GaussianAdam(m.params, {k: 1e-3 for k in m.params})
    for k, p in m.params.items():  # distinct, recognisable moments per row
        rows = torch.arange(len(m), dtype=torch.float32).reshape((-1,) + (1,) * (p.ndim - 1))
        opt.state[k]["exp_avg"] = (rows + 1).expand(p.shape).clone()
        opt.state[k]["exp_avg_sq"] = (rows + 1000).expand(p.shape).clone()
    return opt


def test_ops_move_optimizer_state_extras_and_strategy_state():
    m = _random_model(10, seed=5)
    opt = _adam_with_state(m)
    state = {"grad2d": torch.arange(10.0), "scalar": 3}
    old_means = m.params["means"].detach().clone()
    clone = torch.zeros(10, dtype=torch.bool)
    clone[[2, 7]] = True
    ops.duplicate(m, opt, clone, state=state)
    assert len(m) == 12 and m.extras["tag"].tolist() == list(range(10)) + [2, 7]
    torch.testing.assert_close(m.params["means"][10:], old_means[[2, 7]])
    ea = opt.state["means"]["exp_avg"]
    assert ea[:10, 0].tolist() == [float(i + 1) for i in range(10)] and ea[10:].eq(0).all()
    assert opt.state["means"]["exp_avg_sq"][10:].eq(0).all()
    assert state["grad2d"].tolist() == list(map(float, range(10))) + [2.0, 7.0] and state["scalar"] == 3
    assert opt.params["means"] is m.params["means"]

    split = torch.zeros(12, dtype=torch.bool)
    split[[0, 11]] = True
    ops.split(m, opt, split, n_children=3, state=state)
    assert len(m) == 12 - 2 + 6 and m.extras["tag"].tolist() == [1, 2, 3, 4, 5, 6, 7, 8, 9, 2, 0, 0, 0, 7, 7, 7]
    assert opt.state["quats"]["exp_avg"][:10, 0].tolist() == [2.0, 3, 4, 5, 6, 7, 8, 9, 10, 0]
    assert opt.state["quats"]["exp_avg"][10:].eq(0).all() and opt.state["sh0"]["exp_avg_sq"][10:].eq(0).all()
    assert m.extras["is_text"].dtype == torch.bool and len(m.extras["is_text"]) == 16

    remove = m.extras["tag"] == 7
    kept_sq = opt.state["log_scales"]["exp_avg_sq"][~remove].clone()
    ops.remove(m, opt, remove, state=state)
    assert len(m) == 12 and 7 not in m.extras["tag"].tolist()
    torch.testing.assert_close(opt.state["log_scales"]["exp_avg_sq"], kept_sq)
    assert state["grad2d"].shape == (12,)
    for k, p in m.params.items():
        assert isinstance(p, torch.nn.Parameter) and opt.state[k]["exp_avg"].shape == p.shape

    new = {k: v.detach()[:2].clone() for k, v in m.params.items()}
    ops.append(m, opt, new, new_extras={"tag": torch.tensor([100, 101])})
    assert len(m) == 14 and m.extras["tag"][-2:].tolist() == [100, 101] and not m.extras["is_text"][-2:].any()


def test_split_children_sample_the_parent_gaussian():
    m = _random_model(1, seed=6)
    with torch.no_grad():
        m.params["log_scales"].copy_(torch.log(torch.tensor([[0.5, 0.2, 0.05]])))
        m.params["quats"].copy_(torch.tensor([[0.9, 0.3, -0.2, 0.25]]))
    cov = m.covariances()[0].double()
    mean = m.params["means"].detach()[0].double()
    parent_log_scales = m.params["log_scales"].detach().clone()
    torch.manual_seed(0)
    n = 40000
    ops.split(m, None, torch.tensor([True]), n_children=n, scale_divisor=1.6)
    x = m.params["means"].detach().double()
    assert len(m) == n
    torch.testing.assert_close(x.mean(0), mean, atol=0.01, rtol=0)
    torch.testing.assert_close(torch.cov(x.T), cov, atol=0.004, rtol=0.03)
    torch.testing.assert_close(m.params["log_scales"].detach(), (parent_log_scales - math.log(1.6)).expand(n, 3))

    # default divisor 0.8 * n: 3DGS split (n = 2) divides scales by 1.6
    m2 = _random_model(4, seed=7)
    before = m2.scales.detach().clone()
    ops.split(m2, None, torch.tensor([True, False, False, False]))
    torch.testing.assert_close(m2.scales.detach()[3:], (before[0] / 1.6).expand(2, 3))


def test_reset_opacity_caps_and_zeroes_state():
    m = _random_model(6, seed=8)
    with torch.no_grad():
        m.params["opacity_logits"].copy_(torch.logit(torch.tensor([0.001, 0.005, 0.01, 0.2, 0.5, 0.9])))
    opt = _adam_with_state(m)
    ops.reset_opacity(m, opt, 0.01)
    np.testing.assert_allclose(m.opacities.detach().numpy(), [0.001, 0.005, 0.01, 0.01, 0.01, 0.01], rtol=1e-5)
    assert opt.state["opacity_logits"]["exp_avg"].eq(0).all() and opt.state["means"]["exp_avg"].ne(0).all()
    assert opt.params["opacity_logits"] is m.params["opacity_logits"]


# ---- strategy ----------------------------------------------------------------------------------
def test_default_strategy_clone_split_prune():
    m = _random_model(6, seed=9)
    with torch.no_grad():
        m.params["log_scales"].copy_(torch.log(torch.tensor([0.005, 0.005, 0.05, 0.05, 0.005, 0.005])).unsqueeze(1).expand(6, 3))
        m.params["opacity_logits"].copy_(torch.logit(torch.tensor([0.5, 0.5, 0.5, 0.5, 0.001, 0.5])))
    opt = GaussianAdam(m.params, {})
    strat = DefaultStrategy()
    state = strat.initialize_state(scene_extent=1.0)
    # NDC gradient norms: 3e-4 (high) for Gaussians 0 and 2, 1e-4 (low) otherwise; all visible.
    px = torch.tensor([3e-4, 1e-4, 3e-4, 1e-4, 1e-4, 1e-4])
    means2d = torch.zeros(6, 2, requires_grad=True)
    means2d.grad = torch.stack([px / (64 / 2), torch.zeros(6)], 1)
    info = {"means2d": means2d, "radii": torch.ones(6, dtype=torch.long), "width": 64, "height": 48}
    strat._update_state(m, state, info)
    torch.testing.assert_close(state["grad2d"], px)
    strat.step_post_backward(m, opt, state, step=600, info=info)  # 600: refine step, grads counted twice
    # 0 cloned (small), 2 split into 2 (large), 4 pruned (opacity 0.001)
    assert state["last_clone"] == 1 and state["last_split"] == 1 and state["last_prune"] == 1
    assert m.extras["tag"].tolist() == [0, 1, 3, 5, 0, 2, 2]
    assert state["grad2d"] is None


@pytest.mark.parametrize("scale", [1e-20, 1e-8, 1e-4, 1.0, 1e18])
def test_fused_densification_statistics_match_torch_bit_for_bit(scale, monkeypatch):
    """The one-pass numba statistics (int32 radii on the CPU) against the strategy's torch ops (taken for other
    radii dtypes): torch's norm, where, add and maximum, over three steps, tiny and huge gradients (squares that
    underflow or overflow), invisible Gaussians with NaN gradients, negative zeros."""
    import strings_bench.engine.strategies.stats_kernels as SK

    calls = []
    real = SK.accumulate_screen_stats
    monkeypatch.setattr(SK, "accumulate_screen_stats", lambda *a: calls.append(1) or real(*a))
    n = 50_000
    gen = torch.Generator().manual_seed(3)
    m = _random_model(n, seed=4)
    strat = DefaultStrategy()
    fused, ref = strat.initialize_state(1.0), strat.initialize_state(1.0)
    for step in range(3):
        grad = torch.randn(n, 2, generator=gen) * scale
        grad[::7, 0] = 0.0
        grad[::11, 1] = -0.0
        radii = torch.randint(0, 40, (n,), generator=gen, dtype=torch.int32)
        grad[radii == 0] = float("nan")  # culled: the gradient must not reach the statistics
        means2d = torch.zeros(n, 2, requires_grad=True)
        means2d.grad = grad
        info = {"means2d": means2d, "radii": radii, "width": 320, "height": 240, "n_cameras": 1}
        strat._update_state(m, fused, info)
        strat._update_state(m, ref, {**info, "radii": radii.long()})
    assert len(calls) == 3, "the fused path was not taken"
    for key in ("grad2d", "count", "max_radii"):
        assert torch.equal(fused[key].view(torch.int32), ref[key].view(torch.int32)), key
    assert torch.isfinite(ref["grad2d"]).all() == (scale < 1e18)  # the overflow case really overflowed


def test_default_strategy_schedule_scales_with_steps():
    from strings_bench.engine.strategies import StrategyContext

    strat = DefaultStrategy(context=StrategyContext(steps_scale=0.1))
    # intervals shorter than MIN_SCALED_INTERVAL (50) are held at 50 in scaled runs; starts/stops scale freely
    assert strat.at(strat.refine_start_iter) == 50 and strat.every(strat.refine_every) == 50
    assert strat.every(strat.reset_every) == 300 and strat.at(strat.refine_stop_iter) == 1500
    assert strat.every(20) == 20  # a nominal interval below the floor is kept as given
    # opacity resets: at least MIN_SCALED_RESET_INTERVAL (200) steps apart in scaled runs
    assert strat.reset_interval(strat.reset_every) == 300
    quick = DefaultStrategy(context=StrategyContext(steps_scale=0.01))
    assert quick.reset_interval(quick.reset_every) == 200 and quick.every(quick.reset_every) == 50
    full = DefaultStrategy(context=StrategyContext(steps_scale=1.0))
    assert full.every(full.refine_every) == 100 and full.every(1) == 1


# ---- trainer -----------------------------------------------------------------------------------
def test_checkpoint_is_taken_before_that_steps_opacity_reset(tiny_scene):
    """A reset due on a checkpoint step runs after the checkpoint (the reference saves, then densifies)."""
    strategy = DefaultStrategy(refine_start_iter=1000, reset_every=10, refine_stop_iter=1000)
    tr = GaussianSplatting(TrainConfig(sh_degree=0), strategy)
    seen = {}
    for result in Trainer(tr, tiny_scene, (10, 12), progress=False).train():
        seen[result.iteration] = float(tr.model.opacities.detach().max())
    assert seen[10] > 0.05            # initial opacity 0.1, not reset yet when the checkpoint renders
    assert seen[12] < 0.02            # reset to 0.01 right after the checkpoint, two Adam steps since


def test_trainer_end_to_end_loss_decreases(tiny_scene, tmp_path):
    cfg = TrainConfig(steps_scale=0.05, sh_degree=1)
    tr = GaussianSplatting(cfg)
    losses = []
    orig = tr.train_step

    def record(step, **kw):
        losses.append(orig(step, **kw))
        return losses[-1]

    tr.train_step = record
    results = train(tr, tiny_scene, (50, 350), model_path=lambda step: tmp_path / "ply" / f"iteration_{step}.ply")
    assert [r.iteration for r in results] == [50, 350]
    assert [r.extra["paper_iteration"] for r in results] == [1000, 7000]
    assert results[0].train_seconds < results[1].train_seconds
    assert all(r.gaussians > 0 and r.peak_memory_mb > 0 for r in results)
    names = [tiny_scene.names[i] for i in tiny_scene.test_idx]
    for r in results:
        assert sorted(r.renders) == sorted(names)
        for img in r.renders.values():
            assert img.shape == (24, 32, 3) and img.dtype == np.float32 and 0 <= img.min() and img.max() <= 1
    assert np.mean(losses[-30:]) < 0.6 * np.mean(losses[:10])
    assert results[1].gaussians != 120  # densification ran (clones/splits/prunes at scaled steps)
    assert Path(results[1].extra["ply"]).exists()
    # held-out views are reproduced much better than by the initial point cloud
    gt = {tiny_scene.names[i]: tiny_scene.load_image(i) for i in tiny_scene.test_idx}
    tr.set_model(tr.initial_model(tiny_scene))
    err0 = np.mean([np.abs(tr.render(i) - gt[tiny_scene.names[i]]).mean() for i in tiny_scene.test_idx])
    err = np.mean([np.abs(results[1].renders[k] - gt[k]).mean() for k in gt])
    assert err < 0.5 * err0, (err, err0)


def test_trainer_is_repeatable(tiny_scene):
    def run(seed):
        cfg = TrainConfig(steps_scale=0.02, sh_degree=0, seed=seed)
        return train(GaussianSplatting(cfg), tiny_scene, (20,))[0]

    a, b, c = run(0), run(0), run(1)
    for k in a.renders:
        np.testing.assert_array_equal(a.renders[k], b.renders[k])
    assert any(not np.array_equal(a.renders[k], c.renders[k]) for k in a.renders)


def test_trainer_schedules_scale():
    class FakeScene:
        extent = 2.0
        name = "fake"

    tr = GaussianSplatting(TrainConfig(steps_scale=0.1))
    tr.scene, tr.extent = FakeScene(), FakeScene.extent
    assert Trainer(tr, FakeScene(), [3000, 700, 700]).checkpoints == [700, 3000]
    with pytest.raises(StringsBenchError, match="positive"):
        Trainer(tr, FakeScene(), [0, 10])
    assert tr.sh_degree_for_step(99) == 0 and tr.sh_degree_for_step(100) == 1 and tr.sh_degree_for_step(2000) == 3
    assert tr.position_lr(1500) == pytest.approx(2 * math.sqrt(1.6e-4 * 1.6e-6))
    assert tr.position_lr(3000) == pytest.approx(1.6e-6 * 2)


def test_nan_parameter_stops_training_naming_group(tiny_scene):
    class Poison(GaussianSplatting):
        def on_step_start(self, step):
            if step == 7:
                with torch.no_grad():
                    self.model.params["log_scales"][3, 0] = float("nan")

    with pytest.raises(TrainingError, match=r"iteration 7.*log_scales"):
        train(Poison(TrainConfig(sh_degree=0), Strategy()), tiny_scene, (20,))


def test_nan_gradient_stops_training_naming_group(tiny_scene):
    class BadGrad(GaussianSplatting):
        def loss(self, out, gt, view_idx, step):
            base = super().loss(out, gt, view_idx, step)
            if step == 4:  # finite value, infinite derivative: sqrt at 0
                base = base + 0 * torch.sqrt(self.model.params["quats"][:, 1] * 0).sum()
            return base

    with pytest.raises(TrainingError, match=r"iteration 4.*quats"):
        train(BadGrad(TrainConfig(sh_degree=0), Strategy()), tiny_scene, (10,))


def test_per_row_position_lr_scale(tiny_scene):
    class Frozen(GaussianSplatting):
        def initial_model(self, scene):
            m = super().initial_model(scene)
            m.extras["is_text"] = torch.arange(len(m)) % 2 == 0
            self.start = m.params["means"].detach().clone()
            return m

        def position_lr_scale(self, step):
            return (~self.model.extras["is_text"]).float()  # text rows get position LR 0

    tr = Frozen(TrainConfig(sh_degree=0), Strategy())
    train(tr, tiny_scene, (15,))
    moved = (tr.model.params["means"].detach() - tr.start).abs().sum(1) > 0
    is_text = tr.model.extras["is_text"]
    assert not moved[is_text].any() and moved[~is_text].float().mean() > 0.5


def test_motion_log_sums_adams_position_steps(tiny_scene):
    """The log's first step against Adam's first update worked out by hand: each coordinate with a non-zero
    gradient moves by the LR (m/sqrt(v) = sign(g)), so a Gaussian moves lr x sqrt(its non-zero coordinates)."""
    class TextHalf(GaussianSplatting):
        def initial_model(self, scene):
            m = super().initial_model(scene)
            m.extras["is_text"] = torch.arange(len(m)) % 2 == 0
            return m

        def position_lr_scale(self, step):
            return (~self.model.extras["is_text"]).float()  # text rows locked: they must log no motion

    method = TextHalf(TrainConfig(sh_degree=0), Strategy())
    method.setup(tiny_scene, device="cpu")
    method.train_step(1)
    grad = method.model.params["means"].grad
    lr = method.optimizer.lrs["means"]
    moving = ~method.model.extras["is_text"]
    nonzero = ((grad != 0) & moving[:, None]).sum(1).double()
    expected = float((lr * nonzero.sqrt()).mean()) / method.extent
    log = method.motion_log
    assert expected > 0 and log["steps"] == 1
    assert log["position_path"] == pytest.approx(expected, rel=1e-5)
    assert log["text_position_path"] == 0.0
    method.refine(1)
    for step in range(2, 6):
        method.train_step(step)
        method.refine(step)
    record = method.checkpoint_extra(5)
    assert record["motion_steps"] == 5 and record["position_path"] > expected
    assert "motion_from_step" not in record


def test_gs3d_method_registered_and_trains(tiny_scene):
    from strings_bench.bench.plan import takes_steps_scale
    from strings_bench.core.errors import StringsBenchError
    from strings_bench.methods.registry import get_method

    spec = get_method("3dgs")
    assert takes_steps_scale(spec) and not spec.presets  # the run's schedule scales it (build(steps_scale=...))
    method = spec.build(steps_scale=get_schedule("quick").steps_scale, sh_degree=0, lr_opacity_logits=0.025, grow_grad2d=3e-4)
    assert method.config.lrs.opacity_logits == 0.025 and method.strategy.grow_grad2d == 3e-4
    assert method.config.steps_scale == 0.01
    results = train(method, tiny_scene, [10, 20])
    assert [r.iteration for r in results] == [10, 20]
    with pytest.raises(StringsBenchError, match=r"(?s)no setting.*grow_grad_2d.*valid settings:.*grow_grad2d"):
        spec.build(grow_grad_2d=1)


@pytest.mark.slow
def test_vanilla_3dgs_on_synthetic_books_reaches_25db():
    """Standard schedule (1 500 steps = 30K x 0.05) on synthetic/books at its default 320x240."""
    from strings_bench.datasets import resolve_scenes
    from strings_bench.engine.losses import psnr
    from strings_bench.scene.scene import Scene

    ref = resolve_scenes(["synthetic/books"])[0]
    scene = Scene.load(ref.path, settings=ref.settings)
    result = train(GaussianSplatting(TrainConfig(steps_scale=0.05)), scene, (1500,))[0]
    scores = [psnr(torch.from_numpy(result.renders[scene.names[i]]), torch.from_numpy(np.asarray(scene.load_image(i))))
              for i in scene.test_idx]
    assert np.mean(scores) >= 25.0, scores


def test_setup_preloads_training_images_outside_the_timed_steps(tiny_scene):
    # Decoding happens in setup (preprocess_seconds): after it every training view's target is cached,
    # equal to the decoded file, and a step reads no image.
    from PIL import Image

    import strings_bench.scene.scene as scene_mod

    method = GaussianSplatting(TrainConfig(sh_degree=0), Strategy())
    method.setup(tiny_scene)
    assert sorted(method._targets) == sorted(tiny_scene.train_idx)
    i = tiny_scene.train_idx[1]
    with Image.open(tiny_scene.image_path(i)) as im:
        expected = np.asarray(im.convert("RGB"), dtype=np.float32) / 255.0
    assert torch.equal(method.target(i), torch.from_numpy(expected))
    calls = []
    orig = scene_mod._load_rgb
    scene_mod._load_rgb = lambda *a: calls.append(a) or orig(*a)
    try:
        for step in range(1, 4):
            method.train_step(step)
            method.refine(step)
    finally:
        scene_mod._load_rgb = orig
    assert calls == []


def test_corrupt_training_image_fails_in_setup(tiny_scene, tmp_path):
    import shutil

    from strings_bench.core.errors import DatasetError
    from strings_bench.scene.scene import Scene

    root = tmp_path / "scene"
    shutil.copytree(tiny_scene.root, root)
    scene = Scene.load(root)
    scene.image_path(scene.train_idx[-1]).write_bytes(b"not an image")
    with pytest.raises(DatasetError, match="cannot read image"):
        GaussianSplatting(TrainConfig(sh_degree=0), Strategy()).setup(scene)


def test_cpu_threads_sets_and_restores_torch_threads():
    from strings_bench.engine.trainer import CPU_TORCH_THREADS, cpu_threads

    before = torch.get_num_threads()
    with cpu_threads(1):
        assert torch.get_num_threads() == 1
    assert torch.get_num_threads() == before
    with cpu_threads(None):
        assert torch.get_num_threads() == before
    with pytest.raises(RuntimeError):
        with cpu_threads(1):
            raise RuntimeError("the body failed")
    assert torch.get_num_threads() == before and CPU_TORCH_THREADS == 1


_MALLOC_PROBE = """
import ctypes, sys
import numpy as np
if sys.argv[1] == "keep":
    from strings_bench.engine.trainer import keep_freed_memory
    assert keep_freed_memory() and keep_freed_memory()  # once per process; the second call is a no-op
elif sys.argv[1] == "switched-off":  # STRINGS_BENCH_KEEP_FREED_MEMORY=0 in the environment
    from strings_bench.engine.trainer import keep_freed_memory
    assert keep_freed_memory() is False
class MallInfo2(ctypes.Structure):
    _fields_ = [(name, ctypes.c_size_t) for name in
                ("arena", "ordblks", "smblks", "hblks", "hblkhd", "usmblks", "fsmblks", "uordblks", "fordblks", "keepcost")]
libc = ctypes.CDLL("libc.so.6")
libc.mallinfo2.restype = MallInfo2
a = np.empty(64 << 20, np.uint8)
a[::4096] = 1
mapped = libc.mallinfo2().hblkhd  # bytes in blocks mmap'ed on their own (handed back when freed)
del a
print(mapped >> 20, libc.mallinfo2().fordblks >> 20)  # MiB mmap'ed while alive; MiB free in the heap after
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's malloc")
def test_keep_freed_memory_serves_large_blocks_from_the_heap():
    """With the default malloc a 64 MB block is mmap'ed on its own and handed back to the kernel when
    freed (its pages are faulted in again next time); after keep_freed_memory (the Trainer's CPU
    setting) it comes from the heap and stays there for the next step; STRINGS_BENCH_KEEP_FREED_MEMORY=0
    leaves malloc as it was."""
    import os
    import subprocess

    got = {}
    for mode in ("default", "keep", "switched-off"):
        env = {k: v for k, v in os.environ.items() if not k.startswith("MALLOC_")}
        env["STRINGS_BENCH_KEEP_FREED_MEMORY"] = "0" if mode == "switched-off" else "1"
        done = subprocess.run([sys.executable, "-c", _MALLOC_PROBE, mode], env=env, capture_output=True, text=True,
                              timeout=120)
        assert done.returncode == 0, done.stderr
        got[mode] = [int(x) for x in done.stdout.split()[-2:]]
    assert got["default"][0] >= 64 and got["default"][1] < 64, got  # mmap'ed, then returned
    assert got["keep"][0] < 64 and got["keep"][1] >= 64, got  # from the heap, kept after the free
    assert got["switched-off"][0] >= 64 and got["switched-off"][1] < 64, got  # as the default


@pytest.mark.skipif(not Path("/proc/self/clear_refs").exists(), reason="Linux's resident high-water mark reset")
def test_peak_memory_is_the_trainings_own_not_the_process_peak(tiny_scene):
    """After a 400 MB allocation is freed, the reset peak is far below the process's lifetime peak
    (ru_maxrss, which the reset does not touch), and a training reports its figure with scope `training`."""
    import resource

    from strings_bench.engine.trainer import peak_memory_mb, reset_peak_memory

    import mmap

    big = mmap.mmap(-1, 400 * 2 ** 20)  # an anonymous mapping, unmapped on close (a freed numpy array can stay
    for offset in range(0, len(big), mmap.PAGESIZE):  # with the allocator, still resident)
        big[offset] = 1  # touched: resident
    big.close()
    lifetime_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2 ** 10
    assert reset_peak_memory("cpu") == "training"
    assert 0 < peak_memory_mb("cpu") < lifetime_mb - 300, (peak_memory_mb("cpu"), lifetime_mb)
    (result,) = list(Trainer(GaussianSplatting(TrainConfig(steps_scale=0.005)), tiny_scene, (5,), progress=False).train())
    assert result.extra["peak_memory_scope"] == "training" and 0 < result.peak_memory_mb <= lifetime_mb + 1


@pytest.mark.parametrize("shape,dtype", [((50,), torch.float32), ((50, 15, 3), torch.float32), ((50, 2), torch.bool),
                                         ((50, 4), torch.int64)])
def test_rows_then_is_indexing_then_concatenation(shape, dtype):
    """Densification's row copies (`optim.rows_then`): old[index] then the added or zero rows, as torch.cat gives."""
    from strings_bench.engine.optim import rows_then

    g = torch.Generator().manual_seed(1)
    old = (torch.randn(shape, generator=g) * 5).to(dtype)
    for index in (torch.randperm(50, generator=g)[:31], torch.arange(0), torch.tensor([3, 3, 49, 0])):
        add = (torch.randn((7,) + shape[1:], generator=g) * 5).to(dtype)
        assert torch.equal(rows_then(old, index, add), torch.cat([old[index], add]))
        assert torch.equal(rows_then(old, index, n_zero=5), torch.cat([old[index], torch.zeros((5,) + shape[1:], dtype=dtype)]))
        assert torch.equal(rows_then(old, index), old[index])


# ---- a strategy's context: given once, never in its state --------------------------------------------------------
SETTING_KEYS = {"steps_scale", "interval_floor", "budget", "budget_reserved", "budget_dropped", "gaussian_budget",
                "max_gaussians", "cap"}


def _strategy_classes():
    from strings_bench.engine.strategies.absgs import AbsGSStrategy
    from strings_bench.engine.strategies.edc import EDCStrategy
    from strings_bench.engine.strategies.improved import ImprovedGSStrategy
    from strings_bench.engine.strategies.mcmc import MCMCStrategy
    from strings_bench.engine.strategies.mip import MipStrategy
    from strings_bench.engine.strategies.perceptual import PerceptualGSStrategy

    return [DefaultStrategy, AbsGSStrategy, EDCStrategy, MCMCStrategy, MipStrategy, ImprovedGSStrategy,
            PerceptualGSStrategy]


@pytest.mark.parametrize("cls", _strategy_classes(), ids=lambda c: c.__name__)
def test_a_strategys_state_holds_no_settings(cls):
    """The run's steps scale, interval floor and cap reach a strategy in its StrategyContext; its fresh state
    holds none of them, nor any of its own settings (MCMC's "cap" is its own, from cap_max or the context, and
    is only allowed there)."""
    import dataclasses

    from strings_bench.engine.strategies import StrategyContext
    from strings_bench.scene.camera import Camera

    context = StrategyContext(steps_scale=0.05, interval_floor=7, budget=1234, budget_reserved=lambda: 34)
    strategy = cls(context=context)
    cams = [Camera(fx=40.0, fy=40.0, cx=24.0, cy=16.0, width=48, height=32, R=np.eye(3), t=np.zeros(3))]
    state = strategy.initialize_state(2.0, cams)
    fields = {f.name for f in dataclasses.fields(strategy)}
    leaked = (set(state) & (SETTING_KEYS | fields)) - ({"cap"} if cls.__name__ == "MCMCStrategy" else set())
    assert not leaked, leaked
    assert "context" in fields and strategy.context is context
    assert strategy.at(1000) == 50 and strategy.every(1000) == 50 and strategy.every(100) == 7
    assert context.budget_now() == 1200


def test_the_method_and_its_strategy_share_one_context():
    """A method built with a steps scale, a floor and a cap tells its strategy once; both scale alike, and a
    strategy built for another context is refused."""
    from strings_bench.core.errors import StringsBenchError
    from strings_bench.engine.splatting import GaussianSplatting, TrainConfig
    from strings_bench.engine.strategies import StrategyContext

    method = GaussianSplatting(TrainConfig(steps_scale=0.05, interval_floor=10, gaussian_budget=50_000))
    assert method.strategy.context is method.context and method.context.budget == 50_000
    for nominal in (100, 1000, 3000, 15_000):
        assert method.at(nominal) == method.strategy.at(nominal)
    assert method.every(1000) == method.strategy.every(1000) == 50
    given = DefaultStrategy()
    assert GaussianSplatting(TrainConfig(steps_scale=0.05), given).strategy is given and given.context.steps_scale == 0.05
    with pytest.raises(StringsBenchError, match="scale alike|built for"):
        GaussianSplatting(TrainConfig(steps_scale=0.05), DefaultStrategy(context=StrategyContext(steps_scale=0.5)))
