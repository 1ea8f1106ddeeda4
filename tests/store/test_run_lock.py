"""One run at a time in a run folder (store/lock.py), and the training's CPU seconds (engine/trainer.py)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

import runner_fakes as rf
import strings_bench.bench as bench
from strings_bench.core.errors import StringsBenchError
from strings_bench.store import run_folder_busy, run_folder_lock

REPO = Path(__file__).resolve().parents[2]
pytestmark = pytest.mark.skipif(sys.platform == "win32", reason="runs are not locked where flock is missing")


def test_the_lock_is_held_once_and_names_its_holder(tmp_path):
    assert not run_folder_busy(tmp_path)  # no lock file yet
    with run_folder_lock(tmp_path):
        assert run_folder_busy(tmp_path)
        # a second open of the file is another holder (flock locks belong to the open file, not the process)
        with pytest.raises(StringsBenchError, match=rf"in use by another run \(process {os.getpid()} on "):
            with run_folder_lock(tmp_path):
                pass
    assert not run_folder_busy(tmp_path)
    with run_folder_lock(tmp_path):  # free again
        assert run_folder_busy(tmp_path)


def test_a_killed_run_leaves_its_folder_free(tmp_path):
    code = textwrap.dedent(f"""
        import sys, time
        from strings_bench.store import run_folder_lock
        with run_folder_lock({str(tmp_path)!r}):
            print("locked", flush=True)
            time.sleep(600)
    """)
    child = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True,
                             env={**os.environ, "PYTHONPATH": str(REPO)})
    try:
        assert child.stdout.readline().strip() == "locked"
        assert run_folder_busy(tmp_path)
        with pytest.raises(StringsBenchError, match=rf"process {child.pid} "):
            with run_folder_lock(tmp_path):
                pass
    finally:
        child.kill()  # SIGKILL: no clean-up of any kind
        child.wait()
    assert not run_folder_busy(tmp_path)


def test_a_second_run_in_a_busy_folder_stops_before_writing(tmp_path, scene_dir):
    out = tmp_path / "run"
    out.mkdir()
    with run_folder_lock(out):
        with pytest.raises(StringsBenchError, match="in use by another run"):
            bench.run(["fake-a"], [str(scene_dir)], run_dir=out, schedule="tiny", ocr="fake",
                      ocr_backend=rf.FakeOCR(), with_lpips=False, progress=False, write_report=False)
    assert sorted(p.name for p in out.iterdir()) == [".run.lock"]  # nothing of the refused run
    bench.run(["fake-a"], [str(scene_dir)], run_dir=out, schedule="tiny", ocr="fake", ocr_backend=rf.FakeOCR(),
              with_lpips=False, progress=False, write_report=False)
    assert (out / "results.csv").is_file() and not run_folder_busy(out)


def test_cpu_seconds_count_work_not_waiting(tmp_path):
    """A training whose steps sleep: its wall clock counts the sleep, its CPU time does not; both accumulate over
    the checkpoints; a resumed training continues the CPU count from its saved state, and one resumed from a state
    saved before the count was kept reports it unknown (None), not a part."""
    import torch

    from _engine_helpers import make_tiny_scene
    from strings_bench.engine.splatting import GaussianSplatting
    from strings_bench.engine.trainer import SaveEvery, Trainer
    from strings_bench.methods.registry import get_method

    scene = make_tiny_scene(tmp_path / "scene", n_views=9, n_points=60)
    real = GaussianSplatting.train_step
    # Long enough that a sleep is most of a step: the CPU count holds the kernels' two threads, up to twice the wall
    # time of the work itself (0.02 s failed once: 0.143 s of CPU against 0.232 s of wall clock, 0.2 of it asleep).
    nap = 0.05

    def slow_step(self, step):
        time.sleep(nap)
        return real(self, step)

    def train(state_path=None, stop_at=None):
        method = get_method("3dgs").build(None, steps_scale=0.002, sh_degree=0)
        trainer = Trainer(method, scene, [10, 20], device="cpu", progress=False, state_path=state_path,
                          save_every=SaveEvery(minutes=None, steps=5))
        out = []
        for r in trainer.train():
            out.append(r)
            if r.iteration == stop_at:
                break  # closed at the checkpoint, before step 10's state is saved: step 5's is the last
        return out

    GaussianSplatting.train_step = slow_step
    try:
        a, b = train()
        first = train(tmp_path / "state.pt", stop_at=10)
        resumed = train(tmp_path / "state.pt")
        train(tmp_path / "old.pt", stop_at=10)
        old = torch.load(tmp_path / "old.pt", weights_only=False)
        del old["train_cpu_seconds"]  # as a state saved before the count existed
        torch.save(old, tmp_path / "old.pt")
        from_old = train(tmp_path / "old.pt")
    finally:
        GaussianSplatting.train_step = real
    assert a.train_seconds >= 10 * nap and b.train_seconds >= 20 * nap  # the sleeps are wall time...
    assert 0 < a.train_cpu_seconds < a.train_seconds - 5 * nap  # ...and not CPU time
    assert a.train_cpu_seconds < b.train_cpu_seconds < b.train_seconds - 10 * nap
    assert first[0].iteration == 10 and [r.iteration for r in resumed] == [10, 20]
    assert resumed[0].resumed_from_step == 5
    assert resumed[1].train_cpu_seconds > resumed[0].train_cpu_seconds > 0
    assert [r.train_cpu_seconds for r in from_old] == [None, None]
    assert from_old[1].train_seconds >= 15 * nap  # the wall clock still continues from the state


def test_results_csv_and_result_json_hold_the_cpu_seconds(tmp_path, scene_dir):
    out = tmp_path / "run"
    bench.run(["fake-a"], [str(scene_dir)], run_dir=out, schedule="tiny", ocr="fake", ocr_backend=rf.FakeOCR(),
              with_lpips=False, progress=False, write_report=False)
    recs = [json.loads(p.read_text()) for p in out.glob("cells/**/result.json")]
    assert recs and all("train_cpu_seconds" in r["timings"] for r in recs)
    header = (out / "results.csv").read_text().splitlines()[0].split(",")
    assert "train_cpu_seconds" in header


def test_a_file_system_without_flock_runs_unlocked_with_a_warning(tmp_path, monkeypatch, caplog):
    import errno

    import strings_bench.store.lock as lock

    def refuse(fd, op):
        raise OSError(errno.ENOLCK, "No locks available")

    monkeypatch.setattr(lock.fcntl, "flock", refuse)
    with caplog.at_level("WARNING", logger="strings_bench.store.lock"):
        with run_folder_lock(tmp_path):
            with run_folder_lock(tmp_path):  # nothing can stop the second one there
                assert not run_folder_busy(tmp_path)
    assert "cannot be locked (" in caplog.text and "No locks available" in caplog.text
