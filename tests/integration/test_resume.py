"""Resumable training: a run killed with SIGKILL at a random step continues from its last saved state
and ends with the same parameters as an uninterrupted run under the same seed."""

from __future__ import annotations

import strings_bench.bench as bench

import json
import os
import random
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
import torch

from _engine_helpers import make_tiny_text_scene, train  # noqa: E402
from strings_bench.core.errors import StringsBenchError  # noqa: E402
from strings_bench.engine.trainer import SaveEvery, Trainer  # noqa: E402
from strings_bench.methods.registry import get_method  # noqa: E402
from strings_bench.scene.scene import Scene  # noqa: E402

REPO = Path(__file__).resolve().parents[2]
CHECKPOINTS = [12, 30]
# strings: T1 = 6 steps at this scale, so a kill after step 6 resumes inside phase 2
SETTINGS = {"3dgs": dict(steps_scale=0.002, sh_degree=1),
            "strings": dict(steps_scale=0.002, sh_degree=1, mask_dilation_fraction=0.0, n_max=3),
            "mcmc": dict(steps_scale=0.01, sh_degree=0, refine_every=1)}


@pytest.fixture(scope="module")
def text_scene(tmp_path_factory) -> Path:
    return make_tiny_text_scene(tmp_path_factory.mktemp("resume") / "scene")


pytestmark = pytest.mark.usefixtures("private_cache")  # tests/conftest.py


def _params(method) -> dict[str, np.ndarray]:
    return {k: v.detach().cpu().numpy().copy() for k, v in method.model.params.items()}


KILLED_RUN = textwrap.dedent("""
    import os, signal, sys
    sys.path.insert(0, {tests!r})
    from strings_bench.engine.splatting import GaussianSplatting
    from strings_bench.engine.trainer import SaveEvery, Trainer
    from strings_bench.methods.registry import get_method
    from strings_bench.scene.scene import Scene

    kill_at = {kill_at}
    real = GaussianSplatting.train_step

    def train_step(self, step):
        if step == kill_at:
            os.kill(os.getpid(), signal.SIGKILL)  # no clean-up of any kind, as kill -9
        return real(self, step)

    GaussianSplatting.train_step = train_step
    method = get_method({name!r}).build(None, **{settings!r})
    trainer = Trainer(method, Scene.load({scene!r}), {checkpoints!r}, device="cpu", progress=False,
                      state_path={state!r}, save_every=SaveEvery(minutes=None, steps=5))
    for result in trainer.train():
        print("checkpoint", result.iteration, flush=True)
""")


@pytest.mark.parametrize("name", ["3dgs", "strings", "mcmc"])
def test_kill_9_at_a_random_step_resumes_to_the_same_parameters(name, text_scene, tmp_path):
    scene = Scene.load(text_scene)
    settings = SETTINGS[name]
    whole = get_method(name).build(None, **settings)
    uninterrupted = train(whole, scene, CHECKPOINTS)
    kill_at = random.Random(f"{name}-kill").randint(8, CHECKPOINTS[-1] - 1)
    state = tmp_path / "state.pt"
    script = KILLED_RUN.format(tests=str(Path(__file__).parents[1]), kill_at=kill_at, name=name, settings=settings,
                               scene=str(text_scene), checkpoints=CHECKPOINTS, state=str(state))
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, env=env, timeout=300)
    assert proc.returncode == -signal.SIGKILL, proc.stderr[-2000:]
    assert state.is_file()
    saved_at = torch.load(state, map_location="cpu", weights_only=False)["step"]
    assert 0 < saved_at < kill_at  # the last save before the kill (every 5 steps and at checkpoint 12)

    resumed = get_method(name).build(None, **settings)
    trainer = Trainer(resumed, scene, CHECKPOINTS, device="cpu", progress=False, state_path=state,
                      save_every=SaveEvery(minutes=None, steps=5))
    results = list(trainer.train())
    assert trainer.resumed_from_step == saved_at and all(r.resumed_from_step == saved_at for r in results)
    assert [r.iteration for r in results] == [c for c in CHECKPOINTS if c > saved_at]
    want, got = _params(whole), _params(resumed)
    assert want.keys() == got.keys()
    for k in want:
        assert want[k].shape == got[k].shape, k
        np.testing.assert_allclose(got[k], want[k], rtol=0, atol=1e-6, err_msg=k)
    last = uninterrupted[-1]
    for view, img in results[-1].renders.items():
        np.testing.assert_allclose(img, last.renders[view], atol=1e-6)
    assert results[-1].gaussians == last.gaussians


def test_state_from_other_settings_is_refused(text_scene, tmp_path):
    scene = Scene.load(text_scene)
    state = tmp_path / "state.pt"
    first = Trainer(get_method("3dgs").build(None, **SETTINGS["3dgs"]), scene, [6], progress=False, device="cpu",
                    state_path=state, fingerprint={"settings": {"sh_degree": 1}})
    list(first.train())
    assert state.is_file()
    other = Trainer(get_method("3dgs").build(None, **SETTINGS["3dgs"]), scene, [6], progress=False, device="cpu",
                    state_path=state, fingerprint={"settings": {"sh_degree": 2}})
    with pytest.raises(StringsBenchError, match="other settings"):
        list(other.train())
    state.write_bytes(b"not a torch file")
    with pytest.raises(StringsBenchError, match="unreadable"):
        list(Trainer(get_method("3dgs").build(None, **SETTINGS["3dgs"]), scene, [6], progress=False,
                     state_path=state).train())


def test_save_every_parses_minutes_steps_and_off():
    assert SaveEvery.parse("10") == SaveEvery(minutes=10.0)
    assert SaveEvery.parse("2.5min") == SaveEvery(minutes=2.5)
    assert SaveEvery.parse("20steps") == SaveEvery(minutes=None, steps=20)
    assert SaveEvery.parse("off") == SaveEvery(minutes=None, steps=None)
    assert SaveEvery(minutes=None, steps=20).due(40, 0.0) and not SaveEvery(minutes=None, steps=20).due(41, 1e9)
    assert SaveEvery(minutes=1.0).due(3, 61.0) and not SaveEvery(minutes=1.0).due(3, 59.0)
    for bad in ("-1", "ten", "0steps", "5 parsecs"):
        with pytest.raises(StringsBenchError, match="save-every"):
            SaveEvery.parse(bad)


def test_run_killed_mid_training_resumes_and_records_it(text_scene, tmp_path):
    """`strings-bench run` killed with SIGKILL mid-training: the re-run continues from the saved state
    (result.json records resumed_from_step) and writes the metrics of an uninterrupted run."""
    import runner_fakes as rf

    def run_cli(out: Path, kill_at: int | None, keep_models: bool = False) -> subprocess.CompletedProcess:
        code = textwrap.dedent(f"""
            import os, signal, sys
            sys.path.insert(0, {str(Path(__file__).parents[1])!r})
            import runner_fakes as rf
            import strings_bench.bench as bench
            from strings_bench.engine.splatting import GaussianSplatting
            real = GaussianSplatting.train_step

            def train_step(self, step):
                if step == {kill_at!r}:
                    os.kill(os.getpid(), signal.SIGKILL)
                return real(self, step)

            GaussianSplatting.train_step = train_step
            bench.run(["3dgs"], [{str(text_scene)!r}], run_dir={str(out)!r}, schedule="tiny", ocr_backend=rf.FakeOCR(),
                       with_lpips=False, progress=False, write_report=False, save_every="4steps",
                       keep_models={keep_models!r},
                       method_overrides={{"3dgs": {{"sh_degree": 0}}}})
        """)
        env = {**os.environ, "PYTHONPATH": str(REPO)}
        return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=600)

    killed = tmp_path / "killed"
    proc = run_cli(killed, kill_at=23)  # tiny preset: checkpoints 15, 35 and 150 steps
    assert proc.returncode == -signal.SIGKILL, proc.stderr[-2000:]
    assert list(killed.glob("state/**/training_state.pt"))
    assert run_cli(killed, kill_at=None).returncode == 0
    assert not list(killed.glob("state/**/training_state.pt"))  # removed once every cell is written
    whole = tmp_path / "whole"
    assert run_cli(whole, kill_at=None, keep_models=True).returncode == 0
    recs = {p.parent.name: json.loads(p.read_text()) for p in killed.glob("cells/**/result.json")}
    refs = {p.parent.name: json.loads(p.read_text()) for p in whole.glob("cells/**/result.json")}
    assert sorted(recs) == sorted(refs) == ["15", "150", "35"]  # tiny preset: 3K, 30K, 7K
    for it in recs:
        # 15 was written before the kill at 23; the state saved at step 20 carried the rest
        assert recs[it]["resumed_from_step"] == (0 if it == "15" else 20) and refs[it]["resumed_from_step"] == 0
        assert recs[it]["metrics"]["psnr"] == pytest.approx(refs[it]["metrics"]["psnr"], abs=1e-5)
        assert recs[it]["gaussians"] == refs[it]["gaussians"]
    # --keep-models: each cell of the uninterrupted run holds its model, which reads back at that size
    from strings_bench.engine.ply import read_ply

    for it, rec in refs.items():
        ply = next(whole.glob(f"cells/**/{it}/model.ply"))
        assert len(read_ply(ply)) == rec["gaussians"] and rec["extra"]["ply"] == str(ply)
    assert not list(killed.glob("cells/**/model.ply"))  # not asked for there
    assert rf  # the fake OCR came from the test helpers
