"""Run a benchmark's jobs on Slurm through submitit: `strings-bench run --executor slurm` (docs/guide/cluster.md, "Slurm").

One job, a (method, scene) with all its checkpoints, is one Slurm task; the jobs of one stage that ask for the same
resources go to Slurm as one job array (submitit's `executor.batch()`). The run folder is the one source of truth:

    RUN_DIR/slurm/
      jobs.json                 (method, dataset, scene) -> its latest Slurm job id, log paths, resources; written
                                by the driver after every sbatch
      <job id>/                 submitit's folder of one task: <id>_submission.sh, the pickled job, <id>_0_log.out /
                                <id>_0_log.err (the task's output), <id>_0_result.pkl (its return value or traceback)

Cells are written by the tasks into the run folder, as a local run writes them; the driver follows them there (the
progress bar, results.csv) and rebuilds the report. A second `run` on the same folder reads jobs.json: a job still in
Slurm's queue is followed, not resubmitted; a job with unfinished cells and no live Slurm task is submitted again
and continues from its saved training state. Jobs whose cells are all written are never submitted.

Ending. A task's result pickle says it finished (or raised: the exception's last line, its node and its log path
come back to the driver). A task that leaves the queue without one (scancel, a node failure, a time limit or a
preemption not requeued) is reported with its final Slurm state and log path; re-running the command resubmits it.
A task that Slurm requeues (preemption with PreemptMode=REQUEUE, or submitit's own requeue at the time limit) stays
in the queue and is followed; it continues from the job's saved training state.

Slurm is followed with `squeue` and `scontrol` only (no accounting database is needed: submitit's own job states
come from `sacct`, which many clusters and the single-node Slurm of scripts/slurm_local.sh do not have).
submitit is an optional dependency (`pip install -e '.[slurm]'`), imported only when this executor is used.

Size (~570 lines): one executor read top to bottom: its options and their checks, the callable a task runs, the
submission of arrays, and the following of tasks through squeue, scontrol and their result files.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import os
import socket
import subprocess
import threading
import time
from concurrent.futures import Future
from pathlib import Path
from typing import Any, Callable, Iterable

from strings_bench.bench.executors import Executor
from strings_bench.core.errors import StringsBenchError
from strings_bench.core.io import atomic_write_json
from strings_bench.core.results import safe_name

log = logging.getLogger(__name__)

INSTALL_HINT = "install the Slurm extra: pip install -e '.[slurm]' (or pip install submitit)"
SHARED_FS_HINT = ("the run folder (--out) and the scene folders must be on a file system that every Slurm node mounts "
                  "at the same path (docs/guide/cluster.md, 'Slurm'); synthetic scenes live in STRINGS_BENCH_CACHE")
SLURM_FOLDER = "slurm"  # in the run folder
JOB_NAME = "strings-bench"  # every task's Slurm job name (squeue's NAME)
JOBS_FILE = "jobs.json"  # in RUN_DIR/slurm: the Slurm job of every submitted (method, scene)
WORKER_FILE = "worker.json"  # in a job's state folder: the host, pid and Slurm job of the task that ran it last
ERROR_FILE = "error.json"  # beside it: the error of the task that failed last (its message and hint)
FORWARDED_ENV = ("STRINGS_BENCH_CACHE", "NUMBA_CACHE_DIR")  # made absolute for the tasks (sbatch exports the rest)
DEFAULT_TIME_MIN = 24 * 60
RESOURCE_KEYS = ("gpus", "cpus", "mem", "time")  # --slurm-resources METHOD=gpus:1,cpus:8,mem:32G,time:600
POLL_SECONDS = 5.0  # how often squeue is asked (one call for every job of the run)
# A task absent from the queue with no result file for this long has ended without one. Not at once: on NFS a
# new file in a folder may stay unseen for up to the client's attribute cache time (acdirmax, 60 s by default).
LOST_AFTER_SECONDS = 60.0


def import_submitit():
    """The `submitit` module, or a StringsBenchError with the install hint when it is not installed."""
    try:
        import submitit
    except ImportError as exc:
        raise StringsBenchError(f"--executor slurm needs submitit, which is not installed ({exc})",
                                hint=INSTALL_HINT) from exc
    return submitit


@dataclasses.dataclass(frozen=True)
class Resources:
    """What one task asks Slurm for: GPUs (--gpus-per-task), CPUs (--cpus-per-task), memory (--mem, None: the
    partition's default) and a time limit in minutes."""

    gpus: int = 0
    cpus: int = 1
    mem: str | None = None
    time: int = DEFAULT_TIME_MIN

    def sbatch(self) -> dict:
        """submitit.SlurmExecutor parameters."""
        out: dict[str, Any] = {"cpus_per_task": self.cpus, "time": self.time}
        if self.gpus:
            out["gpus_per_task"] = self.gpus
        if self.mem:
            out["mem"] = self.mem
        return out

    def describe(self) -> str:
        return (f"{self.cpus} CPU(s), {self.gpus} GPU(s)" + (f", {self.mem}" if self.mem else "")
                + f", {self.time} min")


def _positive_int(name: str, value, minimum: int = 1) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, float, str)):
        ok = False
    else:
        try:
            ok = float(value) == int(float(value)) and int(float(value)) >= minimum
        except ValueError:
            ok = False
    if not ok:
        raise StringsBenchError(f"{name} must be an integer >= {minimum}, got {value!r}", hint=f"e.g. {name} {max(minimum, 1)}")
    return int(float(value))


def parse_method_resources(items: Iterable[str] | dict | None) -> dict[str, dict]:
    """`--slurm-resources` values -> {method: {key: value}}: 'strings=gpus:1,cpus:8,mem:32G,time:600' (repeatable)."""
    if not items:
        return {}
    if isinstance(items, dict):
        items = [f"{m}=" + ",".join(f"{k}:{v}" for k, v in kv.items()) for m, kv in items.items()]
    out: dict[str, dict] = {}
    for item in items:
        method, eq, rest = str(item).partition("=")
        pairs = [p.strip() for p in rest.split(",") if p.strip()]
        if not eq or not method.strip() or not pairs:
            raise StringsBenchError(f"--slurm-resources {item!r} is not METHOD=KEY:VALUE[,KEY:VALUE]",
                                    hint="e.g. --slurm-resources strings=gpus:1,cpus:8,mem:32G,time:600")
        mine = out.setdefault(method.strip(), {})
        for pair in pairs:
            key, colon, value = pair.partition(":")
            key = key.strip()
            if not colon or key not in RESOURCE_KEYS or not value.strip():
                raise StringsBenchError(f"--slurm-resources {item!r}: {pair!r} is not KEY:VALUE with KEY one of "
                                        f"{', '.join(RESOURCE_KEYS)}", hint="e.g. --slurm-resources strings=gpus:1,cpus:8")
            value = value.strip()
            if key == "gpus":
                value = _positive_int(f"--slurm-resources {method}=gpus", value, minimum=0)
            elif key in ("cpus", "time"):
                value = _positive_int(f"--slurm-resources {method}={key}", value)
            mine[key] = value
    return out


def parse_sbatch_options(items: Iterable[str] | dict | None) -> dict[str, str]:
    """`--slurm-option` values ('account=proj42', 'qos=high', 'constraint=a100') -> {sbatch option: value}."""
    if not items:
        return {}
    if isinstance(items, dict):
        return {str(k): str(v) for k, v in items.items()}
    out = {}
    for item in items:
        key, eq, value = str(item).partition("=")
        key = key.strip().lstrip("-")
        if not eq or not key:
            raise StringsBenchError(f"--slurm-option {item!r} is not KEY=VALUE (an sbatch option without its --)",
                                    hint="e.g. --slurm-option account=proj42 --slurm-option qos=high")
        out[key] = value.strip()
    return out


def slurm_device(device: str, gpus: int) -> str:
    """The device a task trains on: `cuda` (the GPU(s) Slurm gave it) when it asks for GPUs, else `cpu`.
    `cuda:N` is refused (Slurm chooses the GPU); `cuda` without GPUs asked for is refused."""
    device = str(device)
    if device.startswith("cuda:"):
        raise StringsBenchError(f"--device {device} names a GPU, but on Slurm each job gets the GPU Slurm assigns it",
                                hint="use --device cuda (or auto) with --executor slurm, and --slurm-gpus-per-task 1")
    if device == "cpu":
        return "cpu"
    if device == "cuda" and gpus == 0:
        raise StringsBenchError("--device cuda, but the jobs ask Slurm for no GPU",
                                hint="add --slurm-gpus-per-task 1 (or --slurm-resources METHOD=gpus:1)")
    return "cuda" if gpus > 0 else "cpu"


# ---- what runs on the nodes ----------------------------------------------------------------------
class RunOnNode:
    """The callable a Slurm task runs (pickled by submitit into the run folder): check the run folder is visible
    here, record this task in the job's worker.json, run the job.

    `checkpoint` makes it requeueable: at the time limit (submitit's USR2, 90 s before it) submitit calls it and
    requeues the task, which runs `run_job` again and continues from the job's saved training state."""

    def __init__(self, runner: Callable, env: dict):
        self.runner = runner
        self.env = env

    def __call__(self, job) -> Any:
        os.environ.update(self.env)
        if not (Path(job.run_dir) / "run.json").is_file():
            raise StringsBenchError(f"the Slurm task on {socket.gethostname()} cannot see the run folder {job.run_dir} "
                                    "(no run.json there)", hint=SHARED_FS_HINT)
        record = Path(job.state_path()).parent / WORKER_FILE
        slurm_id = os.environ.get("SLURM_ARRAY_JOB_ID")
        slurm_id = f"{slurm_id}_{os.environ['SLURM_ARRAY_TASK_ID']}" if slurm_id else os.environ.get("SLURM_JOB_ID")
        atomic_write_json(record, {"host": socket.gethostname(), "pid": os.getpid(), "slurm_job_id": slurm_id,
                                   "restarts": int(os.environ.get("SLURM_RESTART_COUNT", 0) or 0),
                                   "started": time.time()})
        try:
            return self.runner(job)
        except Exception as exc:
            # submitit keeps only the traceback's text: the error itself, for the driver's report, goes beside the
            # worker record; the exception is raised on, so the task ends FAILED with its traceback in its log
            message, hint = (exc.message, exc.hint) if isinstance(exc, StringsBenchError) else (
                f"{type(exc).__name__}: {exc}", None)
            atomic_write_json(record.with_name(ERROR_FILE), {"slurm_job_id": slurm_id, "host": socket.gethostname(),
                                                             "message": message, "hint": hint})
            raise

    def checkpoint(self, job):
        import submitit

        return submitit.helpers.DelayedSubmission(self, job)


# ---- the driver side ------------------------------------------------------------------------------
@dataclasses.dataclass
class _Task:
    job: Any
    slurm_id: str
    folder: Path
    future: Future
    absent_since: float | None = None  # since when the task is neither in the queue nor has a result

    def paths(self):
        from submitit.core.utils import JobPaths

        return JobPaths(self.folder, job_id=self.slurm_id, task_id=0)


def job_key(job) -> str:
    return "/".join(safe_name(x) for x in (job.method, job.dataset, job.scene))


class SlurmExecutor(Executor):
    """Runs each job as a Slurm task, the jobs of a stage as job arrays (one per distinct resources).

    partition: the partition (None: the cluster's default). gpus_per_task: GPUs each task asks for (default 1 with
    --device cuda, else 0: the jobs train on the CPU). cpus_per_job: CPUs per task (torch uses that many threads).
    mem: memory per task ("16G"; None: the partition's default). time_min: each task's time limit.
    array_parallelism: at most this many tasks of an array at once (None: Slurm's limits). sbatch_options: any other
    sbatch options ({"account": "proj42"}). method_resources: per method, what differs from the above
    ({"strings": {"gpus": 1, "mem": "32G"}}). detach: submit and return; a later `run` follows the jobs.
    """

    in_process = False

    def __init__(self, runner: Callable, partition: str | None = None, gpus_per_task: int | None = None,
                 cpus_per_job: float = 1, mem: str | None = None, time_min: int = DEFAULT_TIME_MIN,
                 array_parallelism: int | None = None, sbatch_options: dict | list | None = None,
                 method_resources: dict | list | None = None, detach: bool = False, poll_seconds: float = POLL_SECONDS,
                 lost_after: float = LOST_AFTER_SECONDS):
        self.check_options(partition=partition, gpus_per_task=gpus_per_task, cpus_per_job=cpus_per_job,
                           time_min=time_min, array_parallelism=array_parallelism, sbatch_options=sbatch_options,
                           method_resources=method_resources)
        self.submitit = import_submitit()
        self.runner = runner
        self.partition = partition
        self.gpus_per_task = None if gpus_per_task is None else int(gpus_per_task)
        self.default = Resources(gpus=self.gpus_per_task or 0, cpus=_positive_int("--cpus-per-job", cpus_per_job), mem=mem,
                                 time=_positive_int("--slurm-time", time_min))
        self.array_parallelism = array_parallelism
        self.sbatch_options = parse_sbatch_options(sbatch_options)
        self.method_resources = parse_method_resources(method_resources)
        self.detach = bool(detach)
        self.poll_seconds = poll_seconds
        self.lost_after = lost_after
        self._env = {k: os.path.abspath(os.environ[k]) for k in FORWARDED_ENV if os.environ.get(k)}
        self._run_dir: Path | None = None
        self._tasks: dict[str, _Task] = {}  # slurm id -> task, until it has ended
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._monitor: threading.Thread | None = None
        self._queue: dict[str, str] = {}  # the latest squeue: slurm id -> state
        self.submitted: list[str] = []  # the Slurm ids this executor submitted (not those it followed)
        self.followed: list[str] = []  # the Slurm ids of earlier runs it followed

    @staticmethod
    def check_options(device: str = "auto", partition: str | None = None, gpus_per_task: int | None = None,
                      cpus_per_job: float = 1, time_min: int = DEFAULT_TIME_MIN, array_parallelism: int | None = None,
                      sbatch_options=None, method_resources=None, **_ignored) -> None:
        """Refuse what cannot work before any scene is built: submitit missing, a bad number or option, `cuda:N`."""
        import_submitit()
        if gpus_per_task is not None:
            _positive_int("--slurm-gpus-per-task", gpus_per_task, minimum=0)
        _positive_int("--cpus-per-job", cpus_per_job)
        _positive_int("--slurm-time", time_min)
        if array_parallelism is not None:
            _positive_int("--slurm-array-parallelism", array_parallelism)
        parse_sbatch_options(sbatch_options)
        per_method = parse_method_resources(method_resources)
        default_gpus = int(gpus_per_task) if gpus_per_task is not None else (1 if device == "cuda" else 0)
        for gpus in {default_gpus, *(r.get("gpus", default_gpus) for r in per_method.values())}:
            slurm_device(device, gpus)
        if partition is not None and not str(partition).strip():
            raise StringsBenchError("--slurm-partition is empty", hint="`sinfo -s` lists the partitions")

    def resources(self, job) -> Resources:
        """The job's resources: the run's defaults (1 GPU for a --device cuda job unless --slurm-gpus-per-task
        says otherwise), with the method's --slurm-resources over them."""
        default = self.default
        if self.gpus_per_task is None and str(job.device) == "cuda":
            default = dataclasses.replace(default, gpus=1)
        return dataclasses.replace(default, **self.method_resources.get(job.method, {}))

    # -- starting -------------------------------------------------------------------------------
    def start(self, run_dir: Path, jobs: list) -> None:
        """Check that Slurm answers (sinfo), that the partition exists, and say what each job asks for."""
        self._run_dir = Path(os.path.abspath(run_dir))
        unknown = sorted(set(self.method_resources) - {j.method for j in jobs})
        if unknown and jobs:
            log.warning("--slurm-resources names method(s) with no unfinished job in this run: %s", ", ".join(unknown))
        # a clear error when the Slurm commands are missing, the controller is down or the partition unknown
        partitions = self._slurm(["sinfo", "-h", "-o", "%R"]).split()
        if self.partition and self.partition not in partitions:
            raise StringsBenchError(f"--slurm-partition {self.partition}: Slurm has no such partition",
                                    hint=f"partitions: {', '.join(partitions) or '(none)'} (`sinfo -s`)")
        for res in sorted({self.resources(j) for j in jobs}, key=str):
            n = sum(self.resources(j) == res for j in jobs)
            log.info("Slurm: %d job(s) with %s each%s", n, res.describe(),
                     f" on partition {self.partition}" if self.partition else "")

    def _slurm(self, args: list[str], check: bool = True) -> str:
        try:
            proc = subprocess.run(args, capture_output=True, text=True, timeout=120)
        except FileNotFoundError as exc:
            raise StringsBenchError(f"--executor slurm: the Slurm command {args[0]!r} is not installed here",
                                    hint="run strings-bench on a machine of the cluster (a login node) where sbatch, "
                                         "squeue and scontrol work") from exc
        except subprocess.TimeoutExpired as exc:
            raise StringsBenchError(f"{' '.join(args[:2])} gave no answer in 120 s (is slurmctld up?)") from exc
        if check and proc.returncode != 0:
            raise StringsBenchError(f"{' '.join(args[:2])} failed: {(proc.stderr or proc.stdout).strip()}",
                                    hint="is the Slurm controller up? (`sinfo`)")
        return proc.stdout

    def _squeue(self, ids: Iterable[str]) -> dict[str, str]:
        """Slurm id ("123" or "123_4") -> state, for the given jobs still in the queue (one squeue call)."""
        bases = sorted({str(i).split("_")[0] for i in ids})
        args = ["squeue", "-h", "-r", "-o", "%i|%T|%j"] + ([f"--jobs={','.join(bases)}"] if bases else ["--jobs=0"])
        try:
            proc = subprocess.run(args, capture_output=True, text=True, timeout=120)
        except FileNotFoundError as exc:
            raise StringsBenchError("--executor slurm: the Slurm command 'squeue' is not installed here",
                                    hint="run strings-bench on a machine of the cluster (a login node) where sbatch, "
                                         "squeue and scontrol work") from exc
        except subprocess.TimeoutExpired as exc:
            raise StringsBenchError("squeue gave no answer in 120 s (is slurmctld up?)") from exc
        # squeue refuses ids it no longer knows ("Invalid job id specified") with status 1: none of them is queued.
        if proc.returncode != 0 and "Invalid job id" not in proc.stderr:
            raise StringsBenchError(f"squeue failed: {(proc.stderr or proc.stdout).strip()}",
                                    hint="is the Slurm controller up? (`sinfo`)")
        out = {}
        for line in proc.stdout.splitlines():
            sid, state, name = (line.strip().split("|", 2) + ["", ""])[:3]
            if sid and name == JOB_NAME:  # a job id Slurm has given again to another job is not ours
                out[sid] = state
        return out

    # -- the run folder's record --------------------------------------------------------------
    def _records_path(self) -> Path:
        return self._run_dir / SLURM_FOLDER / JOBS_FILE

    def _records(self) -> dict:
        try:
            return json.loads(self._records_path().read_text(encoding="utf-8"))
        except FileNotFoundError:
            return {}
        except ValueError as exc:
            raise StringsBenchError(f"{self._records_path()} is not JSON: {exc}",
                                    hint="remove it (the jobs it names are then not followed) and re-run") from exc

    # -- running --------------------------------------------------------------------------------
    def submit(self, job) -> Future:
        return self.submit_many([job])[0]

    def submit_many(self, jobs: list) -> list[Future]:
        """Follow the jobs an earlier run submitted that are still queued; submit the others, one array per
        distinct resources. Returns a Future per job: its cells, or its error."""
        if not jobs:
            return []
        if self._run_dir is None:
            self.start(Path(jobs[0].run_dir), jobs)
        records = self._records()
        recorded = {job_key(j): records[job_key(j)] for j in jobs if job_key(j) in records}
        queue = self._squeue([r["job_id"] for r in recorded.values()])
        futures: dict[int, Future] = {}
        new: dict[Resources, list[tuple[int, Any]]] = {}
        for i, job in enumerate(jobs):
            rec = recorded.get(job_key(job))
            if rec is not None and rec["job_id"] in queue:
                futures[i] = self._follow(job, rec["job_id"], Path(rec["folder"]))
                self.followed.append(rec["job_id"])
                log.info("%s on %s/%s: following Slurm job %s (%s), submitted by an earlier run", job.method,
                         job.dataset, job.scene, rec["job_id"], queue[rec["job_id"]])
            else:
                new.setdefault(self.resources(job), []).append((i, job))
        for res, group in new.items():
            for (i, _job), fut in zip(group, self._submit_array(res, [j for _, j in group])):
                futures[i] = fut
        self._start_monitor()
        return [futures[i] for i in range(len(jobs))]

    def _submit_array(self, res: Resources, jobs: list) -> list[Future]:
        submitit = self.submitit
        folder = self._run_dir / SLURM_FOLDER / "%j"
        ex = submitit.SlurmExecutor(folder=folder, max_num_timeout=3)
        params = {**res.sbatch(), "job_name": JOB_NAME, "signal_delay_s": 90,
                  # torch, numba and OCR use the task's CPUs, as many threads as it has (not the node's)
                  "setup": ["export OMP_NUM_THREADS=${SLURM_CPUS_PER_TASK:-1}"]}
        if self.partition:
            params["partition"] = self.partition
        if self.array_parallelism:
            params["array_parallelism"] = int(self.array_parallelism)
        if self.sbatch_options:
            params["additional_parameters"] = dict(self.sbatch_options)
        ex.update_parameters(**params)
        call = RunOnNode(self.runner, self._env)
        sent = []
        for job in jobs:
            device = slurm_device(job.device, res.gpus)
            # paths as the driver resolves them: a task's working folder need not be the driver's (abspath, not
            # resolve: symlinks stay, so a state saved by a local run still matches its fingerprint)
            sent.append(dataclasses.replace(job, device=device, run_dir=os.path.abspath(job.run_dir),
                                            scene_path=os.path.abspath(job.scene_path)))
        try:
            with ex.batch():
                handles = [ex.submit(call, j) for j in sent]
        except Exception as exc:  # noqa: BLE001 - sbatch's refusal (a bad partition, options) comes back as several types
            text = str(exc).strip()
            raise StringsBenchError(f"sbatch refused the {len(jobs)} job(s) ({res.describe()}): {text[-800:]}",
                                    hint="check --slurm-partition (`sinfo -s` lists them), --slurm-gpus-per-task, "
                                         "--slurm-mem, --slurm-time and --slurm-option against the partition's limits") from exc
        records = self._records()
        futures = []
        for job, handle in zip(jobs, handles):
            sid = str(handle.job_id)
            task_folder = Path(str(folder).replace("%j", sid))
            paths = handle.paths
            records[job_key(job)] = {"job_id": sid, "folder": str(task_folder), "log_out": str(paths.stdout),
                                     "log_err": str(paths.stderr), "resources": dataclasses.asdict(res),
                                     "partition": self.partition, "submitted": time.time()}
            futures.append(self._follow(job, sid, task_folder))
            self.submitted.append(sid)
        atomic_write_json(self._records_path(), records)
        log.info("Slurm: submitted %d job(s) (%s): %s", len(jobs), res.describe(), _id_range(self.submitted[-len(jobs):]))
        return futures

    def _follow(self, job, sid: str, folder: Path) -> Future:
        fut: Future = Future()
        with self._lock:
            self._tasks[sid] = _Task(job, sid, folder, fut)
        return fut

    def _start_monitor(self) -> None:
        if self.detach or (self._monitor is not None and self._monitor.is_alive()):
            return
        self._stop.clear()
        self._monitor = threading.Thread(target=self._watch, name="slurm-monitor", daemon=True)
        self._monitor.start()

    def _watch(self) -> None:
        while not self._stop.is_set():
            try:
                self.poll()
            except StringsBenchError as exc:  # squeue failing for a while (controller restart): try again
                log.warning("%s", exc)
            except Exception:  # noqa: BLE001 - the thread must go on, or the driver would wait for ever
                log.exception("following the Slurm tasks")
            self._stop.wait(self.poll_seconds)

    def poll(self) -> None:
        """One look at the queue and the result files: settle the futures of the tasks that have ended."""
        with self._lock:
            tasks = list(self._tasks.values())
        if not tasks:
            return
        queue = self._squeue([t.slurm_id for t in tasks])  # the queue first, then the files (a task writes its
        self._queue = queue                                  # result before it leaves the queue)
        for task in tasks:
            result = task.paths().result_pickle
            if result.exists():
                self._settle(task, result)
            elif task.slurm_id in queue:
                task.absent_since = None
            elif task.absent_since is None:
                task.absent_since = time.monotonic()
            elif time.monotonic() - task.absent_since >= self.lost_after:
                self._lost(task)

    def _end(self, task: _Task) -> None:
        with self._lock:
            self._tasks.pop(task.slurm_id, None)

    def _settle(self, task: _Task, result: Path) -> None:
        from submitit.core.utils import pickle_load

        try:
            outcome, value = pickle_load(result)
        except Exception as exc:  # noqa: BLE001 - a result file being written, or corrupt: look again next poll
            log.debug("%s: %s", result, exc)
            return
        self._end(task)
        if outcome == "success":
            task.future.set_result(value)
            return
        where = f"Slurm job {task.slurm_id}{self._node(task)}; its log: {task.paths().stderr}"
        try:
            error = json.loads((Path(task.job.state_path()).parent / ERROR_FILE).read_text(encoding="utf-8"))
            if error.get("slurm_job_id") != task.slurm_id:
                raise ValueError("an earlier task's error")
        except (OSError, ValueError):  # it failed before RunOnNode ran (unpickling, imports): the traceback's end
            lines = [ln.strip() for ln in str(value).strip().splitlines() if ln.strip()]
            error = {"message": lines[-1] if lines else "unknown error", "hint": None}
        task.future.set_exception(StringsBenchError(f"{error['message']}\n{where}", hint=error.get("hint")))

    def _node(self, task: _Task) -> str:
        try:
            host = json.loads((Path(task.job.state_path()).parent / WORKER_FILE).read_text(encoding="utf-8"))
        except (OSError, ValueError):
            return ""
        return f" on {host['host']}" if host.get("slurm_job_id") == task.slurm_id else ""

    def _lost(self, task: _Task) -> None:
        """The task left the queue without a result: cancelled, its node failed, a time limit, a preemption."""
        self._end(task)
        state = reason = ""
        info = self._slurm(["scontrol", "show", "job", "-o", task.slurm_id], check=False)
        fields = dict(f.split("=", 1) for f in info.split() if "=" in f)
        state, reason = fields.get("JobState", ""), fields.get("Reason", "")
        how = f"ended as {state}" + (f" ({reason})" if reason and reason != "None" else "") if state else "left the queue"
        task.future.set_exception(StringsBenchError(
            f"Slurm job {task.slurm_id}{self._node(task)} {how} before the job finished (cancelled, preempted, its "
            f"node lost or its time limit reached)\nits log: {task.paths().stderr}",
            hint="re-run the same command: the job is submitted again and continues from its saved training state "
                 "(a job that ended COMPLETED without a result file: is the run folder shared? " + SHARED_FS_HINT + ")"))

    def progress_note(self) -> str | None:
        """For the progress bar: how many of this run's tasks are pending and running in Slurm."""
        with self._lock:
            ids = list(self._tasks)
        if not ids:
            return None
        states = [self._queue.get(i, "") for i in ids]
        return f"slurm: {states.count('RUNNING')} running, {states.count('PENDING')} pending"

    def cancel(self) -> None:
        """Ctrl-C: scancel every task still followed and wait until they have left the queue."""
        with self._lock:
            ids = list(self._tasks)
        if not ids:
            return
        self._slurm(["scancel", *ids], check=False)
        end = time.monotonic() + 120
        while time.monotonic() < end and self._squeue(ids):
            time.sleep(1)

    def close(self) -> None:
        self._stop.set()
        if self._monitor is not None:
            self._monitor.join(timeout=self.poll_seconds + 5)


def _id_range(ids: list[str]) -> str:
    if len(ids) > 3 and "_" in ids[0]:
        return f"{ids[0].split('_')[0]}_[{ids[0].split('_')[1]}-{ids[-1].split('_')[1]}]"
    return ", ".join(ids)
