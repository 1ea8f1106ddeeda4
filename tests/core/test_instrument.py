"""strings_bench/core/instrument.py: the stage marks of the trainer and the CPU rasterizer, and the profiling tools
that read them (tools/engine_profile.py) without replacing any function of the package."""

from __future__ import annotations


import pytest
import torch

from _engine_helpers import make_tiny_scene
from _scripts import load_tool

from strings_bench.core import instrument
from strings_bench.core.instrument import StageTimes, recording
from strings_bench.engine.splatting import GaussianSplatting, TrainConfig

STEP_STAGES = ("preprocess.forward", "preprocess.backward", "tiles.forward", "blend.forward", "tiles.backward",
               "loss", "backward", "adam")


@pytest.fixture(scope="module")
def tiny_scene(tmp_path_factory):
    return make_tiny_scene(tmp_path_factory.mktemp("tiny"))


def trained(scene, steps: int, recorder=None) -> GaussianSplatting:
    method = GaussianSplatting(TrainConfig(steps_scale=0.01))
    method.setup(scene, device="cpu")
    for step in range(1, steps + 1):
        if recorder is None:
            method.train_step(step)
        else:
            with recording(recorder):
                method.train_step(step)
        method.refine(step)
    return method


def test_without_a_recorder_a_mark_does_nothing():
    assert not instrument.active()
    assert instrument.timed("loss") is instrument.timed("adam")  # the one shared no-op context
    with instrument.timed("loss"):
        pass
    instrument.note("render", color=None)

    @instrument.stage("x")
    def f(a, b=2):
        return a + b
    assert f(1, b=3) == 4 and f.__name__ == "f"


def test_a_recorder_is_installed_for_its_block_only_and_the_previous_one_comes_back():
    outer, inner = StageTimes(), StageTimes()
    with recording(outer):
        with instrument.timed("a"):
            with recording(inner):
                with instrument.timed("b"):
                    pass
                instrument.note("n", v=1)
            with instrument.timed("c"):
                pass
    assert not instrument.active()
    assert set(outer.calls) == {"a", "c"} and set(inner.calls) == {"b"}
    assert inner.notes == {"n": {"v": 1}} and outer.notes == {}
    with pytest.raises(RuntimeError), recording(outer):
        raise RuntimeError("the block fails")
    assert not instrument.active()


def test_a_recorded_step_gives_the_same_bits_and_every_stage_once_per_step(tiny_scene):
    steps = 4
    times = StageTimes()
    plain, recorded = trained(tiny_scene, steps), trained(tiny_scene, steps, times)
    for name, p in plain.model.params.items():
        assert torch.equal(p, recorded.model.params[name]), name
    assert {s: times.calls.get(s) for s in STEP_STAGES} == {s: steps for s in STEP_STAGES}
    # Nesting: the blend kernel runs inside tiles.forward; the backward stages inside backward.
    assert 0 < times.seconds["blend.forward"] <= times.seconds["tiles.forward"]
    inside = sum(times.seconds[s] for s in ("preprocess.backward", "tiles.backward"))
    assert 0 < inside <= times.seconds["backward"]
    assert all(times.cpu_seconds[s] >= 0 for s in STEP_STAGES)
    assert times.notes["render"]["color"].shape[-1] == 3
    assert set(times.notes["blend.forward"]) == {"tile_start", "lst", "P", "BB", "W", "H", "tiles_x", "out_last",
                                                   "visible"}


def test_engine_profile_splits_a_step_into_its_stages_from_the_marks(tiny_scene):
    profile = load_tool("engine_profile")
    method = trained(tiny_scene, 2)
    prof = profile.profile_steps(method, 3, 3)
    st = prof["stages"]
    assert set(st) == {*profile.STAGES}
    for name in ("projection+SH", "forward blend", "backward blend", "backward projection", "loss+SSIM", "Adam"):
        assert st[name] > 0, name
    assert sum(st.values()) == pytest.approx(prof["step_ms"])
    v, m, pairs_f, pairs_b = profile.count_pairs(method, method.views_for_step(6))
    assert 0 < v <= method.num_gaussians() and m >= v and pairs_f > 0 and pairs_b > 0


def test_engine_profile_reads_the_strategy_interval_it_divides_a_densification_round_by(tiny_scene):
    profile = load_tool("engine_profile")
    method = trained(tiny_scene, 2)
    assert profile.refine_interval(method) == method.strategy.every(method.strategy.refine_every) >= 1
