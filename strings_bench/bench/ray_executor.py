"""Run a benchmark's jobs as Ray tasks: `strings-bench run --executor ray` (docs/guide/cluster.md, "Ray").

One job, a (method, scene) with all its checkpoints, is one Ray task. The run folder is the single
source of truth: workers write cells into it (atomically, as a local run does) and the driver
rebuilds results.csv and the report from them, so the run folder must be on a filesystem that every
node mounts at the same path. `start` checks that before any job is sent: a probe task on every node
reads a token file the driver wrote, writes a reply the driver must see, and looks for every scene
folder of the run.

Faults. A worker that dies (a system failure: the process is killed, its node is lost) has its task
retried by Ray up to `max_retries` times, and the retry continues from the job's saved training state
(engine.trainer), skipping cells already written. A job that raises (bad settings, a corrupt scene, a
bug) is not retried (`retry_exceptions=False`): its error comes back to the driver, which lists its
unwritten cells once the other jobs have finished. `cancel` (Ctrl-C) force-cancels every task.

Ray is an optional dependency (`pip install -e '.[ray]'`), imported only when this executor is built.
This module duck-types the runner's `Job` (run_dir, method, dataset, scene, scene_path, device,
state_path()); it imports nothing of the runner.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import os
import secrets
import socket
import time
from concurrent.futures import Future
from pathlib import Path
from typing import Any, Callable, Iterable

from strings_bench.bench.executors import Executor
from strings_bench.core.errors import StringsBenchError
from strings_bench.core.io import atomic_write_json, atomic_write_text

log = logging.getLogger(__name__)

INSTALL_HINT = "install the Ray extra: pip install -e '.[ray]' (or pip install 'ray>=2.9')"
SHARED_FS_HINT = ("the run folder (--out) and the scene folders must be on a filesystem that every Ray node mounts "
                  "at the same path (docs/guide/running.md, 'Ray'); synthetic scenes live in STRINGS_BENCH_CACHE")
WORKER_FILE = "worker.json"  # in a job's state folder: the host, pid and attempt of the worker that ran it last
# Environment a worker takes from the driver when the driver sets it: where scenes and caches are.
FORWARDED_ENV = ("STRINGS_BENCH_CACHE", "NUMBA_CACHE_DIR")
DEFAULT_MAX_RETRIES = 3
OBJECT_STORE_BYTES = 256 * 2**20  # a local Ray's object store: jobs return only the keys of their cells


def import_ray():
    """The `ray` module, or a StringsBenchError with the install hint when it is not installed."""
    try:
        import ray
    except ImportError as exc:
        raise StringsBenchError(f"--executor ray needs Ray, which is not installed ({exc})", hint=INSTALL_HINT) from exc
    return ray


def _check_number(name: str, value, minimum: float, integer: bool) -> None:
    ok = isinstance(value, int) if integer else isinstance(value, (int, float))
    if isinstance(value, bool) or not ok or value < minimum:
        kind = "an integer" if integer else "a number"
        raise StringsBenchError(f"--{name.replace('_', '-')} must be {kind} >= {minimum:g}, got {value!r}",
                                hint=f"e.g. --{name.replace('_', '-')} {DEFAULT_MAX_RETRIES if integer else 1}")


def ray_device(device: str, cluster_gpus: float) -> str:
    """The device a job asks for on Ray: `cpu`, or `cuda` (the one GPU Ray assigns the task).

    `auto` trains on a GPU when the cluster has any; `cuda:N` is refused, since Ray chooses the GPU.
    """
    device = str(device)
    if device.startswith("cuda:"):
        raise StringsBenchError(f"--device {device} names a GPU, but on Ray each job gets the GPU Ray assigns it",
                                hint="use --device cuda (or auto) with --executor ray")
    if device == "auto":
        return "cuda" if cluster_gpus > 0 else "cpu"
    return device


# ---- what runs on the workers -------------------------------------------------------------------
def probe_worker(token_file: str, token: str, reply_file: str, scene_paths: list[str]) -> dict:
    """Run on one node by `RayExecutor.start`: can this worker read the driver's token, write a reply
    the driver will look for, and see every scene folder?"""
    path = Path(token_file)
    try:
        seen = path.read_text(encoding="utf-8")
    except OSError:
        seen = None
    write_error = None
    if seen is not None:
        try:
            atomic_write_text(reply_file, socket.gethostname())
        except OSError as exc:
            write_error = str(exc)
    return {"host": socket.gethostname(), "pid": os.getpid(), "token_ok": seen == token,
            "write_error": write_error, "missing_scenes": [p for p in scene_paths if not Path(p).is_dir()]}


def run_job_on_worker(runner: Callable, job, token_file: str, env: dict) -> Any:
    """The Ray task of one job: check the run folder is here, record this worker, run the job."""
    os.environ.update(env)
    if not Path(token_file).is_file():
        raise StringsBenchError(f"the Ray worker on {socket.gethostname()} cannot see the run folder {job.run_dir} "
                                f"(no {Path(token_file).name} there)", hint=SHARED_FS_HINT)
    record = Path(job.state_path()).parent / WORKER_FILE
    attempt = 1
    try:
        previous = json.loads(record.read_text(encoding="utf-8"))
        if previous.get("token_file") == token_file:  # the same run: Ray retries this task after a worker died
            attempt = int(previous.get("attempt", 0)) + 1
    except (OSError, ValueError):
        pass
    atomic_write_json(record, {"host": socket.gethostname(), "pid": os.getpid(), "attempt": attempt,
                               "token_file": token_file, "started": time.time()})
    if attempt > 1:
        log.warning("%s on %s/%s: attempt %d (a worker died); continuing from its saved training state",
                    job.method, job.dataset, job.scene, attempt)
    return runner(job)


# ---- the driver side ------------------------------------------------------------------------------
class RayExecutor(Executor):
    """Runs each job as a Ray task (`submit` returns a concurrent Future of the job's cells).

    address: a Ray cluster to join ("auto", "ray://host:10001", "host:6379"); None: RAY_ADDRESS, else
    a local Ray is started (num_cpus: its CPUs, default all) and shut down after the run. An already
    initialised Ray (ray.init in this process) is used as it is. max_retries: how often a job whose
    worker died is run again. cpus_per_job: CPUs each job asks for (GPU jobs ask for one GPU too).
    log_to_driver: show the workers' output here (it is always in Ray's session logs).
    """

    in_process = False

    def __init__(self, runner: Callable, address: str | None = None, max_retries: int = DEFAULT_MAX_RETRIES,
                 cpus_per_job: float = 1, num_cpus: int | None = None, log_to_driver: bool = False,
                 probe_timeout: float = 300.0):
        self.check_options(address=address, max_retries=max_retries, cpus_per_job=cpus_per_job)
        self.ray = import_ray()
        self.runner = runner
        self.address = address
        self.max_retries = int(max_retries)
        self.cpus_per_job = cpus_per_job
        self.num_cpus = num_cpus
        self.log_to_driver = log_to_driver
        self.probe_timeout = probe_timeout
        self._started_ray = False
        self._token_file: Path | None = None
        self._runner_ref = None
        self._task = None
        self._gpus = 0.0
        self._env = {k: os.path.abspath(os.environ[k]) for k in FORWARDED_ENV if os.environ.get(k)}
        self._running: dict[Any, Any] = {}  # ObjectRef -> job, until it has ended

    @staticmethod
    def check_options(device: str = "auto", address: str | None = None, max_retries: int = DEFAULT_MAX_RETRIES,
                      cpus_per_job: float = 1, **_ignored) -> None:
        """Refuse what cannot work before any scene is built: Ray missing, a bad number, `cuda:N`."""
        import_ray()
        _check_number("max_retries", max_retries, 0, integer=True)
        _check_number("cpus_per_job", cpus_per_job, 0.01, integer=False)
        ray_device(device, cluster_gpus=1)

    # -- connecting -----------------------------------------------------------------------------
    def connect(self) -> None:
        """Join the cluster at `address` / RAY_ADDRESS, or start a lean local Ray (no dashboard)."""
        ray = self.ray
        if ray.is_initialized():
            return
        address = self.address or os.environ.get("RAY_ADDRESS") or None
        try:
            if address:
                ray.init(address=address, log_to_driver=self.log_to_driver, logging_level=logging.WARNING)
            else:
                os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")  # no network calls from a local run
                ray.init(num_cpus=self.num_cpus, include_dashboard=False, log_to_driver=self.log_to_driver,
                         object_store_memory=OBJECT_STORE_BYTES, logging_level=logging.WARNING)
                self._started_ray = True
        except (ConnectionError, RuntimeError, ValueError) as exc:
            where = f"the Ray cluster at {address}" if address else "a local Ray"
            raise StringsBenchError(f"could not start or join {where}: {exc}",
                                    hint="check --ray-address / RAY_ADDRESS (e.g. `ray status` on the head node); "
                                         "without either a local Ray is started") from exc

    def start(self, run_dir: Path, jobs: list) -> None:
        """Connect, check the cluster can run the jobs, and check every node sees the run folder."""
        ray = self.ray
        self.connect()
        run_dir = Path(os.path.abspath(run_dir))
        resources = ray.cluster_resources()
        self._gpus = float(resources.get("GPU", 0))
        devices = {ray_device(j.device, self._gpus) for j in jobs}
        if "cuda" in devices and self._gpus == 0:
            raise StringsBenchError("--device cuda asks for a GPU, but the Ray cluster has none",
                                    hint="use --device auto or cpu, or add GPU nodes (`ray status` lists them)")
        nodes = [n for n in ray.nodes() if n.get("Alive") and (n["Resources"].get("CPU", 0) or n["Resources"].get("GPU", 0))]
        if not any(n["Resources"].get("CPU", 0) >= self.cpus_per_job for n in nodes):
            raise StringsBenchError(f"no Ray node has {self.cpus_per_job:g} CPUs for a job "
                                    f"(largest: {max((n['Resources'].get('CPU', 0) for n in nodes), default=0):g})",
                                    hint="lower --cpus-per-job")
        self._token_file = run_dir / f".ray-run-{secrets.token_hex(6)}"
        atomic_write_text(self._token_file, self._token_file.name)
        self._probe(nodes, sorted({os.path.abspath(j.scene_path) for j in jobs}))
        self._task = ray.remote(run_job_on_worker)
        self._runner_ref = ray.put(self.runner)  # sent once, not with every task
        log.info("Ray: %d node(s), %g CPUs, %g GPUs; %d job(s), each %s", len(nodes), resources.get("CPU", 0),
                 self._gpus, len(jobs), "on 1 GPU" if devices == {"cuda"} else f"on {self.cpus_per_job:g} CPU(s)")

    def _probe(self, nodes: list[dict], scene_paths: list[str]) -> None:
        ray = self.ray
        from ray.util.scheduling_strategies import NodeAffinitySchedulingStrategy

        token = self._token_file.name
        probe = ray.remote(probe_worker)
        replies = {n["NodeID"]: self._token_file.with_name(f"{token}.{n['NodeID'][:12]}.reply") for n in nodes}
        refs = {probe.options(num_cpus=0, max_retries=0, scheduling_strategy=NodeAffinitySchedulingStrategy(
                    n["NodeID"], soft=False)).remote(str(self._token_file), token, str(replies[n["NodeID"]]), scene_paths):
                n for n in nodes}
        problems = []
        try:
            ready, late = ray.wait(list(refs), num_returns=len(refs), timeout=self.probe_timeout)
            for ref in late:
                ray.cancel(ref, force=True)
                problems.append(f"node {refs[ref]['NodeManagerAddress']} gave no answer within {self.probe_timeout:g} s")
            for ref in ready:
                where = refs[ref]["NodeManagerAddress"]
                try:
                    answer = ray.get(ref)
                except self.ray.exceptions.RayError as exc:
                    problems.append(f"the probe on node {where} failed: {str(exc).splitlines()[0]}")
                    continue
                where = f"{answer['host']} ({where})"
                if not answer["token_ok"]:
                    problems.append(f"a worker on {where} cannot see the run folder {self._token_file.parent}")
                elif answer["write_error"]:
                    problems.append(f"a worker on {where} cannot write into the run folder: {answer['write_error']}")
                elif not replies[refs[ref]["NodeID"]].is_file():
                    problems.append(f"a file a worker on {where} wrote into the run folder does not appear here")
                if answer["missing_scenes"]:
                    problems.append(f"a worker on {where} cannot see the scene folder(s) "
                                    f"{', '.join(answer['missing_scenes'][:3])}")
        finally:
            for reply in replies.values():
                reply.unlink(missing_ok=True)
        if problems:
            raise StringsBenchError("the Ray workers cannot use this run: " + "; ".join(problems), hint=SHARED_FS_HINT)

    # -- running --------------------------------------------------------------------------------
    def submit(self, job) -> Future:
        """Send `job` to Ray; the Future holds its return value, or the job's own exception."""
        if self._task is None:
            self.start(Path(job.run_dir), [job])
        device = ray_device(job.device, self._gpus)
        # Paths as the driver resolves them: a worker's working folder is not the driver's.
        # (abspath, not resolve: symlinks stay, so a state saved by a local run still matches its fingerprint).
        sent = dataclasses.replace(job, device=device, run_dir=os.path.abspath(job.run_dir),
                                   scene_path=os.path.abspath(job.scene_path))
        ref = self._task.options(
            num_cpus=self.cpus_per_job, num_gpus=1 if device == "cuda" else 0,
            max_retries=self.max_retries, retry_exceptions=False,  # only system failures are retried
            name=f"{job.method} {job.dataset}/{job.scene}",
        ).remote(self._runner_ref, sent, str(self._token_file), self._env)
        self._running[ref] = job
        fut: Future = Future()
        ref.future().add_done_callback(lambda done: self._settle(ref, done, fut))
        return fut

    def map(self, jobs: Iterable) -> list[Any]:
        """Run `jobs` concurrently; their return values in order (the first error is raised)."""
        jobs = list(jobs)
        if jobs and self._task is None:
            self.start(Path(jobs[0].run_dir), jobs)
        return [f.result() for f in [self.submit(j) for j in jobs]]

    def _settle(self, ref, done: Future, fut: Future) -> None:
        job = self._running.pop(ref, None)
        try:
            fut.set_result(done.result())
        except BaseException as exc:  # noqa: BLE001 - handed to the caller through the future
            fut.set_exception(self.explain(exc, job))

    def explain(self, exc: BaseException, job) -> BaseException:
        """The error a failed task stands for: the job's own exception (never retried), or a
        StringsBenchError saying its worker died more often than --max-retries allows."""
        errors = self.ray.exceptions
        if isinstance(exc, errors.RayTaskError):
            cause = getattr(exc, "cause", None)
            log.debug("%s", exc)  # the worker's traceback
            return cause if isinstance(cause, BaseException) else StringsBenchError(str(exc).splitlines()[0])
        if isinstance(exc, errors.TaskCancelledError):
            return exc
        if isinstance(exc, errors.RayError):
            what = job and f"{job.method} on {job.dataset}/{job.scene}"
            first = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
            return StringsBenchError(
                f"the Ray worker running {what} died, and {self.max_retries} retr{'y' if self.max_retries == 1 else 'ies'} "
                f"did not finish it ({type(exc).__name__}: {first})",
                hint="Ray's logs are in /tmp/ray/session_latest/logs on each node (out of memory? the node lost?); "
                     "raise --max-retries, or re-run the same command to continue from the saved state")
        return exc

    def cancel(self) -> None:
        """Force-cancel every task still running (Ctrl-C) and wait until they have ended."""
        ray = self.ray
        running = dict(self._running)
        for ref in running:
            try:
                ray.cancel(ref, force=True)
            except Exception as exc:  # noqa: BLE001 - an ended task cannot be cancelled; nothing to do
                log.debug("cancel: %s", exc)
        if running:
            ray.wait(list(running), num_returns=len(running), timeout=60)
        # A force-cancelled worker is killed; on this host, wait until its process is gone so that
        # nothing is written after the driver has cleaned up.
        here = socket.gethostname()
        for job in running.values():
            try:
                record = json.loads((Path(job.state_path()).parent / WORKER_FILE).read_text(encoding="utf-8"))
            except (OSError, ValueError):
                continue
            if record.get("host") == here and record.get("token_file") == str(self._token_file):
                _wait_gone(int(record["pid"]), timeout=20)

    def close(self) -> None:
        """Remove the run folder's token file; shut down a local Ray this executor started."""
        if self._token_file is not None:
            self._token_file.unlink(missing_ok=True)
        if self._started_ray:
            self.ray.shutdown()
            self._started_ray = False


def _wait_gone(pid: int, timeout: float) -> None:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return
        except PermissionError:
            return  # another user's process with this number: ours is gone
        time.sleep(0.1)
