"""`--executor ray` (issue 17): a local Ray with 2 CPUs runs a grid of 2 methods x 2 synthetic scenes.

- a worker SIGKILLed mid-job: Ray retries the job, which resumes from its saved training state, and
  results.csv's metric columns equal the local executor's at the same seed;
- a job failing by itself (a corrupt scene) is not retried and is reported per cell; the others finish;
- Ctrl-C cancels the running tasks and leaves only complete cells;
- a worker that cannot see a scene folder or the run folder fails with a clear message.

One Ray session serves the whole module (starting Ray costs seconds on 2 cores). The schedule is the
tiny preset shortened with --steps-scale / --checkpoints (6 and 14 steps) on 96x72 scenes of 12 views,
with the test suite's deterministic OCR, so that both executors run the grid in well under a minute.
"""

from __future__ import annotations

import strings_bench.bench as bench
from strings_bench.bench.plan import plan_run
from strings_bench.core.results import CellKey
from strings_bench.core.results import RESULT_FILE

import csv
import dataclasses
import json
import os
import shutil
import signal
import sys
import threading
import time
from pathlib import Path

import pytest

ray = pytest.importorskip("ray")


import runner_fakes as rf  # noqa: E402
from _ray_helpers import PausingRunner, is_time_column  # noqa: E402
from strings_bench.bench import runner  # noqa: E402
from strings_bench.bench.ray_executor import WORKER_FILE, RayExecutor, run_job_on_worker  # noqa: E402
from strings_bench.core.errors import StringsBenchError  # noqa: E402

METHODS = ["strings", "3dgs"]
SCHEDULE = dict(schedule="tiny", steps_scale=0.002, checkpoints=[3000, 7000])  # trained as 6 and 14 steps
CHECKPOINTS = [6, 14]
PAUSE_STEP = 10  # between the state saved at step 8 (--save-every 4steps) and checkpoint 14


@pytest.fixture(scope="module")
def ray_session(worker_pythonpath):
    """A local Ray with 2 CPUs whose workers can import the tests' helpers (FakeOCR, PausingRunner)."""
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("RAY_USAGE_STATS_ENABLED", "0")
        # Ray's own memory monitor kills workers when the machine as a whole passes 95 % of its memory: other
        # work on the machine (training runs beside the tests) then failed these tests with a message about Ray,
        # not about the code under test. The tests' jobs are small; the monitor is off for them.
        mp.setenv("RAY_memory_monitor_refresh_ms", "0")
        ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False, object_store_memory=100 * 2**20,
                 logging_level="WARNING")
        try:
            yield ray
        finally:
            ray.shutdown()


def _plan(out: Path, scenes, methods=METHODS):
    return plan_run(list(methods), [str(s) for s in scenes], run_dir=out, ocr="fake", ocr_backend=rf.FakeOCR(), save_every="4steps",
                    with_lpips=False, **SCHEDULE)


def _rows(out: Path) -> dict[tuple, dict]:
    with open(out / "results.csv", newline="") as f:
        return {(r["method"], r["scene"], r["iteration"]): r for r in csv.DictReader(f)}


def _cell(out: Path, method: str, scene: Path, iteration: int) -> dict:
    key = CellKey(method, scene.name, scene.name, iteration)
    return json.loads((key.path(out) / RESULT_FILE).read_text())


def _incomplete(out: Path) -> list[Path]:
    """Cell folders without result.json, and leftovers of atomic writes."""
    cells = [p for p in out.glob("cells/*/*/*/*") if not (p / RESULT_FILE).exists()]
    return cells + list(out.rglob(".*.tmp"))


def _wait_for(pattern: str, folder: Path, count: int = 1, timeout: float = 240) -> list[Path]:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        found = sorted(folder.glob(pattern))
        if len(found) >= count:
            return found
        time.sleep(0.05)
    raise AssertionError(f"no {pattern} in {folder} after {timeout} s")


# The heaviest test of the suite (about 3 minutes loaded): opt-in, `pytest -m slow tests/integration/test_ray.py`.
@pytest.mark.slow
def test_killed_worker_is_retried_and_the_grid_equals_the_local_run(ray_session, scenes, tmp_path):
    local_out, ray_out, pause = tmp_path / "local", tmp_path / "ray", tmp_path / "pause"
    pause.mkdir()
    runner.execute(_plan(local_out, scenes), ocr=rf.FakeOCR(), executor="local", progress=False,
                   write_report=False)

    # The strings job on the first scene stops at step 10 until released; it is SIGKILLed there.
    target = scenes[0]
    state_dir = ray_out / "state" / "strings" / target.name / target.name
    killed: dict = {}

    def kill_the_paused_worker():
        paused = _wait_for("paused-*", pause)[0]
        pid = int(paused.name.split("-")[1])
        killed["record"] = json.loads((state_dir / WORKER_FILE).read_text())  # what the executor wrote
        killed["pid"] = pid
        killed["state_step"] = __import__("torch").load(state_dir / "training_state.pt", weights_only=False)["step"]
        os.kill(pid, signal.SIGKILL)
        (pause / "released").touch()

    killer = threading.Thread(target=kill_the_paused_worker, daemon=True)
    killer.start()
    plan = _plan(ray_out, scenes)
    job_runner = PausingRunner(ray_out, ocr=rf.FakeOCR(), progress=False, results_csv=False,
                               pause_dir=str(pause), pause_step=PAUSE_STEP, only=("strings", target.name))
    runner.execute(plan, executor=RayExecutor(job_runner, max_retries=2), progress=False,
                   write_report=False)
    killer.join(timeout=5)

    # The executor's record named the killed worker; Ray ran the job again, in another process.
    assert killed["record"]["pid"] == killed["pid"] and killed["record"]["attempt"] == 1
    assert killed["state_step"] == 8
    again = json.loads((state_dir / WORKER_FILE).read_text())
    assert again["attempt"] == 2 and again["pid"] != killed["pid"]
    # The retry resumed from the state saved at step 8: checkpoint 6 was written before the kill.
    assert _cell(ray_out, "strings", target, 6)["resumed_from_step"] == 0
    assert _cell(ray_out, "strings", target, 14)["resumed_from_step"] == 8
    assert not (state_dir / "training_state.pt").exists()  # the job finished
    # Same grid, same metrics as the local executor (timings and memory aside).
    want, got = _rows(local_out), _rows(ray_out)
    assert sorted(got) == sorted(want) and len(got) == len(METHODS) * len(scenes) * len(CHECKPOINTS)
    for key, row in want.items():
        metric_columns = {c for c in row if not is_time_column(c)}  # timings and memory differ
        assert {c: got[key][c] for c in metric_columns} == {c: row[c] for c in metric_columns}, key
    assert not _incomplete(ray_out)


def test_a_job_that_fails_by_itself_is_not_retried_and_is_reported_per_cell(ray_session, scenes, tmp_path):
    broken = tmp_path / "scenes" / "broken"
    shutil.copytree(scenes[1], broken)
    images_bin = broken / "sparse" / "0" / "images.bin"
    images_bin.write_bytes(images_bin.read_bytes()[:40])  # a truncated COLMAP file: the job fails loading it
    out = tmp_path / "run"
    with pytest.raises(StringsBenchError) as caught:
        bench.run(["3dgs"], [str(scenes[0]), str(broken)], run_dir=out, ocr="fake", ocr_backend=rf.FakeOCR(),
                   with_lpips=False, progress=False, write_report=False, save_every="4steps", executor="ray",
                   executor_options={"max_retries": 3}, **SCHEDULE)
    message = str(caught.value)
    assert "1 of 2 job(s) failed; 2 cell(s) not written" in message
    assert "3dgs broken/broken @6 (3K), @14 (7K): " in message and "images.bin" in message
    record = json.loads((out / "state" / "3dgs" / "broken" / "broken" / WORKER_FILE).read_text())
    assert record["attempt"] == 1  # a job's own error is not retried (3 retries were allowed)
    assert set(_rows(out)) == {("3dgs", scenes[0].name, str(it)) for it in CHECKPOINTS}  # the other job finished
    assert ray.is_initialized()  # the executor used this session and left it running


def test_ctrl_c_cancels_the_tasks_and_leaves_only_complete_cells(ray_session, scenes, tmp_path, sigint_raises):
    out, pause = tmp_path / "run", tmp_path / "pause"
    pause.mkdir()
    plan = _plan(out, scenes, methods=["3dgs"])
    # Both jobs stop when their last cell's renders are written but not its result.json.
    job_runner = PausingRunner(out, ocr=rf.FakeOCR(), progress=False, results_csv=False,
                               pause_dir=str(pause), pause_cell=CHECKPOINTS[-1])
    paused: list[Path] = []

    def interrupt_when_both_jobs_are_paused():
        paused.extend(_wait_for("paused-*", pause, count=2))
        os.kill(os.getpid(), signal.SIGINT)  # as Ctrl-C in the driver's terminal

    threading.Thread(target=interrupt_when_both_jobs_are_paused, daemon=True).start()
    with pytest.raises(KeyboardInterrupt):
        runner.execute(plan, executor=RayExecutor(job_runner, max_retries=2), progress=False,
                       write_report=False)
    pids = [int(p.name.split("-")[1]) for p in paused]
    time.sleep(0.5)
    for pid in pids:  # the tasks were force-cancelled: their workers are gone
        with pytest.raises(ProcessLookupError):
            os.kill(pid, 0)
    assert not _incomplete(out)  # the half-written cells are gone
    finished = sorted(p.parent.name for p in out.glob("cells/**/result.json"))
    assert finished == ["6", "6"]  # each job wrote checkpoint 6 before it was stopped in cell 14
    # Their training states (saved at step 14) are kept, so the same command continues from them.
    assert len(list(out.glob("state/**/training_state.pt"))) == 2
    with open(out / "results.csv", newline="") as f:
        assert sorted(r["iteration"] for r in csv.DictReader(f)) == ["6", "6"]  # rebuilt on the driver
    assert not list(out.glob(".ray-run-*"))  # the run's token file is gone with the run


def test_workers_that_cannot_see_a_folder_fail_clearly(ray_session, scenes, tmp_path):
    plan = _plan(tmp_path / "run", scenes[:1], methods=["3dgs"])
    job = dataclasses.replace(plan.jobs[0], scene_path=str(tmp_path / "elsewhere" / "books"))
    ex = RayExecutor(runner.Runner(plan.run_dir, ocr=rf.FakeOCR()))
    with pytest.raises(StringsBenchError, match=r"cannot see the scene folder\(s\) .*elsewhere/books") as caught:
        ex.start(plan.run_dir, [job])
    assert "same path" in str(caught.value)
    # A job on a worker that does not see the run folder (its token file) stops before any work.
    with pytest.raises(StringsBenchError, match="cannot see the run folder"):
        run_job_on_worker(lambda j: pytest.fail("ran"), plan.jobs[0], str(tmp_path / "run" / ".ray-run-none"), {})


def test_ray_missing_and_misplaced_options_are_clear(monkeypatch, capsys, tmp_path):
    from strings_bench.cli import main

    assert main(["run", "--max-retries", "2", "--ray-address", "auto"]) == 1
    assert "--ray-address, --max-retries apply to --executor ray only" in capsys.readouterr().err
    assert main(["run", "--executor", "ray", "--device", "cuda:1"]) == 1
    assert "the GPU Ray assigns" in capsys.readouterr().err
    assert main(["run", "--executor", "ray", "--max-retries", "-1"]) == 1
    assert "--max-retries must be an integer >= 0" in capsys.readouterr().err
    monkeypatch.setitem(sys.modules, "ray", None)  # as if Ray were not installed
    assert main(["run", "--executor", "ray", "--out", str(tmp_path / "run")]) == 1
    assert "pip install -e '.[ray]'" in capsys.readouterr().err
    assert not (tmp_path / "run").exists()  # refused before anything was planned or written
