"""`--executor slurm`, against a real Slurm: the single-node Slurm of scripts/slurm_local.sh on this machine.

- a grid of 2 methods x 2 synthetic scenes submitted with --detach as one job array, followed by a second run
  (which submits nothing), gives the local executor's results.csv in every non-time column;
- a task cancelled mid-training (scancel) is reported with its cell and log path; the same command then
  resubmits only that job, which continues from the training state it saved before it was cancelled;
- a job failing on its node (a corrupt scene) is reported with its cells, its own message and its log;
- Ctrl-C cancels the tasks, waits until they have left the queue and leaves only complete cells.

The Slurm tests need `sinfo`, `sbatch`, ... and a node that goes idle: the fixture runs scripts/slurm_local.sh
(apt-get install and start, as root) and skips with its reason where that fails. They are slow (each Slurm task
imports torch on a 2-core machine): `pytest -m slow tests/integration/test_slurm.py`, run by .ci/run in a step of its own.
The grid is test_ray.py's: the tiny schedule shortened to 6 and 14 steps on 96x72 scenes of 12 views, with the
test suite's deterministic OCR.
"""

from __future__ import annotations

import csv
import json
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

submitit = pytest.importorskip("submitit")

REPO = Path(__file__).resolve().parents[2]

import runner_fakes as rf  # noqa: E402
from _ray_helpers import PausingRunner, is_time_column  # noqa: E402  (not Ray-specific: a Runner that pauses mid-job)
from strings_bench.bench import runner  # noqa: E402
from strings_bench.bench.plan import plan_run  # noqa: E402
from strings_bench.bench.slurm_executor import JOBS_FILE, WORKER_FILE, SlurmExecutor  # noqa: E402
from strings_bench.core.errors import StringsBenchError  # noqa: E402
from strings_bench.core.results import RESULT_FILE, CellKey  # noqa: E402

METHODS = ["strings", "3dgs"]
SCHEDULE = dict(schedule="tiny", steps_scale=0.002, checkpoints=[3000, 7000])  # trained as 6 and 14 steps
CHECKPOINTS = [6, 14]
PAUSE_STEP = 10  # between the state saved at step 8 (--save-every 4steps) and checkpoint 14


SETUP = REPO / "scripts" / "slurm_local.sh"


def _slurm_ready() -> str | None:
    """None when a Slurm node is idle here, else why not."""
    if not shutil.which("sinfo"):
        return "no sinfo"
    try:
        out = subprocess.run(["sinfo", "-h", "-N", "-o", "%T"], capture_output=True, text=True, timeout=30)
    except subprocess.TimeoutExpired:
        return "sinfo gave no answer in 30 s"
    states = out.stdout.split()
    return None if "idle" in states or "mixed" in states else f"sinfo: {(out.stderr or out.stdout).strip() or 'no node'}"


@pytest.fixture(scope="module")
def slurm(worker_pythonpath):
    """A Slurm with an idle node: the one here, or the single-node one scripts/slurm_local.sh installs and starts."""
    why = _slurm_ready()
    if why is not None:
        if os.geteuid() != 0:
            pytest.skip(f"no Slurm here ({why}) and not root, so scripts/slurm_local.sh cannot install one")
        proc = subprocess.run(["bash", str(SETUP)], capture_output=True, text=True, timeout=900)
        why = _slurm_ready()
        if proc.returncode != 0 or why is not None:
            lines = (proc.stderr or proc.stdout).strip().splitlines()
            pytest.skip(f"could not install or start a local Slurm (scripts/slurm_local.sh: "
                        f"{lines[-1] if lines else why})")
    yield  # sbatch exports the environment, worker_pythonpath's PYTHONPATH included, to the tasks


def _plan(out: Path, scenes, methods=METHODS):
    return plan_run(list(methods), [str(s) for s in scenes], run_dir=out, ocr="fake", ocr_backend=rf.FakeOCR(),
                    with_lpips=False, save_every="4steps", **SCHEDULE)


def _rows(out: Path) -> dict[tuple, dict]:
    with open(out / "results.csv", newline="") as f:
        return {(r["method"], r["scene"], r["iteration"]): r for r in csv.DictReader(f)}


def _cell(out: Path, method: str, scene: Path, iteration: int) -> dict:
    return json.loads((CellKey(method, scene.name, scene.name, iteration).path(out) / RESULT_FILE).read_text())


def _records(out: Path) -> dict:
    return json.loads((out / "slurm" / JOBS_FILE).read_text())


def _runner(out: Path, **pause) -> runner.Runner:
    cls = PausingRunner if pause else runner.Runner
    return cls(out, ocr=rf.FakeOCR(), progress=False, results_csv=False, **pause)


def _execute(plan, job_runner, **options):
    # lost_after: the run folder is local here, a task's result file is seen at once (on NFS it may take 60 s)
    return runner.execute(plan, executor=SlurmExecutor(job_runner, poll_seconds=1, lost_after=3, **options),
                          progress=False, write_report=False)


@pytest.mark.slow
def test_a_detached_array_followed_by_a_second_run_equals_the_local_run(slurm, scenes, tmp_path):
    local_out, slurm_out = tmp_path / "local", tmp_path / "slurm"
    runner.execute(_plan(local_out, scenes), ocr=rf.FakeOCR(), executor="local", progress=False,
                   write_report=False)

    plan = _plan(slurm_out, scenes)
    ex = SlurmExecutor(_runner(slurm_out), poll_seconds=1, detach=True)
    runner.execute(plan, executor=ex, progress=False, write_report=False)
    # One array of 4 tasks, recorded in the run folder; the command returned at once.
    assert len(ex.submitted) == 4 and len({s.split("_")[0] for s in ex.submitted}) == 1
    first = _records(slurm_out)
    assert sorted(r["job_id"] for r in first.values()) == sorted(ex.submitted)

    # The same command again follows the array (nothing submitted) and waits for it.
    follower = SlurmExecutor(_runner(slurm_out), poll_seconds=1)
    runner.execute(plan, executor=follower, progress=False, write_report=False)
    assert follower.submitted == [] and sorted(follower.followed) == sorted(ex.submitted)
    assert _records(slurm_out) == first

    want, got = _rows(local_out), _rows(slurm_out)
    assert sorted(got) == sorted(want) and len(got) == len(METHODS) * len(scenes) * len(CHECKPOINTS)
    for key, row in want.items():
        columns = {c for c in row if not is_time_column(c)}
        assert {c: got[key][c] for c in columns} == {c: row[c] for c in columns}, key
    # Each task ran as a Slurm task (its worker.json names its array task) and its log is where jobs.json says.
    for key, rec in first.items():
        method, dataset, scene = key.split("/")
        worker = json.loads((slurm_out / "state" / method / dataset / scene / WORKER_FILE).read_text())
        assert worker["slurm_job_id"] == rec["job_id"]
        assert Path(rec["log_err"]).is_file()
    # A third run finds every cell written: nothing to submit.
    third = SlurmExecutor(_runner(slurm_out), poll_seconds=1)
    runner.execute(plan, executor=third, progress=False, write_report=False)
    assert third.submitted == [] and third.followed == []


@pytest.mark.slow
def test_a_task_cancelled_mid_training_is_reported_and_resumed_from_its_checkpoint(slurm, scenes, tmp_path):
    out, pause = tmp_path / "run", tmp_path / "pause"
    pause.mkdir()
    target = scenes[0]
    plan = _plan(out, scenes, methods=["3dgs"])
    state_dir = out / "state" / "3dgs" / target.name / target.name
    cancelled: dict = {}

    def scancel_the_paused_task():
        end = time.monotonic() + 300
        while not list(pause.glob("paused-*")) and time.monotonic() < end:
            time.sleep(0.2)
        worker = json.loads((state_dir / WORKER_FILE).read_text())
        cancelled["job_id"] = worker["slurm_job_id"]
        cancelled["state_step"] = __import__("torch").load(state_dir / "training_state.pt", weights_only=False)["step"]
        subprocess.run(["scancel", worker["slurm_job_id"]], check=True)

    killer = threading.Thread(target=scancel_the_paused_task, daemon=True)
    killer.start()
    # The 3dgs job on the first scene stops at step 10 (its state saved at step 8) and is cancelled there.
    with pytest.raises(StringsBenchError) as caught:
        _execute(plan, _runner(out, pause_dir=str(pause), pause_step=PAUSE_STEP, only=("3dgs", target.name)))
    killer.join(timeout=5)
    message = str(caught.value)
    records = _records(out)
    rec = records[f"3dgs/{target.name}/{target.name}"]
    assert rec["job_id"] == cancelled["job_id"] and cancelled["state_step"] == 8
    assert "1 of 2 job(s) failed; 1 cell(s) not written" in message
    assert f"3dgs {target.name}/{target.name} @14 (7K): Slurm job {rec['job_id']}" in message
    assert "CANCELLED" in message and rec["log_err"] in message
    assert (CellKey("3dgs", target.name, target.name, 6).path(out) / RESULT_FILE).is_file()  # written before

    # The same command resubmits only the cancelled job, which continues from step 8.
    (pause / "released").touch()
    again = SlurmExecutor(_runner(out), poll_seconds=1)
    runner.execute(plan, executor=again, progress=False, write_report=False)
    assert len(again.submitted) == 1 and again.submitted[0] != rec["job_id"] and again.followed == []
    assert _records(out)[f"3dgs/{target.name}/{target.name}"]["job_id"] == again.submitted[0]
    assert _records(out)[f"3dgs/{scenes[1].name}/{scenes[1].name}"] == records[f"3dgs/{scenes[1].name}/{scenes[1].name}"]
    assert _cell(out, "3dgs", target, 6)["resumed_from_step"] == 0
    assert _cell(out, "3dgs", target, 14)["resumed_from_step"] == 8
    assert not (state_dir / "training_state.pt").exists()
    assert sorted(_rows(out)) == sorted(("3dgs", s.name, str(it)) for s in scenes for it in CHECKPOINTS)


@pytest.mark.slow
def test_a_job_that_fails_on_its_node_is_reported_with_its_cell_and_log(slurm, scenes, tmp_path):
    broken = tmp_path / "scenes" / "broken"
    shutil.copytree(scenes[1], broken)
    images_bin = broken / "sparse" / "0" / "images.bin"
    images_bin.write_bytes(images_bin.read_bytes()[:40])  # a truncated COLMAP file: the job fails loading it
    out = tmp_path / "run"
    plan = plan_run(["3dgs"], [str(broken)], run_dir=out, ocr="fake", ocr_backend=rf.FakeOCR(), with_lpips=False,
                    save_every="4steps", **SCHEDULE)
    with pytest.raises(StringsBenchError) as caught:
        _execute(plan, _runner(out))
    message = str(caught.value)
    rec = _records(out)["3dgs/broken/broken"]
    assert "1 of 1 job(s) failed; 2 cell(s) not written" in message
    assert "3dgs broken/broken @6 (3K), @14 (7K): " in message and "images.bin" in message
    assert f"Slurm job {rec['job_id']} on " in message and rec["log_err"] in message
    assert "images.bin" in Path(rec["log_err"]).read_text()  # the traceback is in the log the message names


@pytest.mark.slow
def test_ctrl_c_cancels_the_tasks_and_leaves_only_complete_cells(slurm, scenes, tmp_path, sigint_raises):
    out, pause = tmp_path / "run", tmp_path / "pause"
    pause.mkdir()
    plan = _plan(out, scenes[:1], methods=["3dgs"])
    # The job stops when its last cell's renders are written but not its result.json.
    job_runner = _runner(out, pause_dir=str(pause), pause_cell=CHECKPOINTS[-1])

    def interrupt_when_paused():
        end = time.monotonic() + 300
        while not list(pause.glob("paused-*")) and time.monotonic() < end:
            time.sleep(0.2)
        os.kill(os.getpid(), signal.SIGINT)  # as Ctrl-C in the driver's terminal

    threading.Thread(target=interrupt_when_paused, daemon=True).start()
    with pytest.raises(KeyboardInterrupt):
        _execute(plan, job_runner)
    job_id = _records(out)[f"3dgs/{scenes[0].name}/{scenes[0].name}"]["job_id"]
    queued = subprocess.run(["squeue", "-h", "-j", job_id], capture_output=True, text=True).stdout.strip()
    assert queued == ""  # cancelled, and gone from the queue before execute returned
    assert not [p for p in out.glob("cells/*/*/*/*") if not (p / RESULT_FILE).exists()]  # half-written cell removed
    assert sorted(p.parent.name for p in out.glob("cells/**/result.json")) == ["6"]
    assert len(list(out.glob("state/**/training_state.pt"))) == 1  # kept: the same command continues from it


# ---- without a Slurm: options and errors ------------------------------------------------------------
def test_slurm_options_are_checked_before_anything_is_planned(monkeypatch, capsys, tmp_path):
    from strings_bench.cli import main

    out = str(tmp_path / "run")
    assert main(["run", "--slurm-partition", "gpu", "--detach", "--out", out]) == 1
    assert "--slurm-partition, --detach apply to --executor slurm only" in capsys.readouterr().err
    assert main(["run", "--executor", "ray", "--slurm-gpus-per-task", "1", "--out", out]) == 1
    assert "--slurm-gpus-per-task applies to --executor slurm only" in capsys.readouterr().err
    assert main(["run", "--executor", "slurm", "--max-retries", "1", "--out", out]) == 1
    assert "--max-retries applies to --executor ray only" in capsys.readouterr().err
    assert main(["run", "--executor", "slurm", "--device", "cuda:1", "--out", out]) == 1
    assert "the GPU Slurm assigns" in capsys.readouterr().err
    assert main(["run", "--executor", "slurm", "--device", "cuda", "--slurm-gpus-per-task", "0", "--out", out]) == 1
    assert "ask Slurm for no GPU" in capsys.readouterr().err
    assert main(["run", "--executor", "slurm", "--cpus-per-job", "1.5", "--out", out]) == 1
    assert "--cpus-per-job must be an integer >= 1" in capsys.readouterr().err
    assert main(["run", "--executor", "slurm", "--slurm-resources", "strings=gpu:1", "--out", out]) == 1
    assert "KEY one of gpus, cpus, mem, time" in capsys.readouterr().err
    assert main(["run", "--executor", "slurm", "--slurm-option", "account", "--out", out]) == 1
    assert "is not KEY=VALUE" in capsys.readouterr().err
    monkeypatch.setitem(sys.modules, "submitit", None)  # as if submitit were not installed
    assert main(["run", "--executor", "slurm", "--out", out]) == 1
    assert "pip install -e '.[slurm]'" in capsys.readouterr().err
    assert not (tmp_path / "run").exists()  # refused before anything was planned or written


def test_resources_per_method_group_the_jobs_into_arrays(tmp_path):
    from strings_bench.bench.executors import Job
    from strings_bench.bench.slurm_executor import Resources

    def job(method, device="auto"):
        return Job(run_dir=str(tmp_path), method=method, dataset="d", scene="s", scene_path=str(tmp_path),
                   scene_settings={}, checkpoints=(1,), labels={}, schedule="tiny", downscale=1, ocr="fake",
                   steps_scale=1, device=device)

    ex = SlurmExecutor(lambda j: [], cpus_per_job=2, mem="8G", method_resources=["strings=gpus:1,time:90", "3dgs=cpus:4"])
    assert ex.resources(job("strings")) == Resources(gpus=1, cpus=2, mem="8G", time=90)
    assert ex.resources(job("3dgs")) == Resources(gpus=0, cpus=4, mem="8G", time=24 * 60)
    assert ex.resources(job("mcmc")) == Resources(gpus=0, cpus=2, mem="8G", time=24 * 60)
    assert ex.resources(job("mcmc", device="cuda")).gpus == 1  # --device cuda: one GPU unless told otherwise
    assert SlurmExecutor(lambda j: [], gpus_per_task=2).resources(job("mcmc", device="cuda")).gpus == 2
    assert Resources(gpus=1, cpus=2, mem="8G", time=90).sbatch() == {"cpus_per_task": 2, "time": 90,
                                                                     "gpus_per_task": 1, "mem": "8G"}


def test_without_slurm_commands_the_error_says_where_to_run(monkeypatch, tmp_path):
    monkeypatch.setenv("PATH", str(tmp_path))  # no sinfo, sbatch, squeue here
    ex = SlurmExecutor(lambda j: [])
    with pytest.raises(StringsBenchError, match="the Slurm command 'sinfo' is not installed here") as caught:
        ex.start(tmp_path, [])
    assert "login node" in caught.value.hint
