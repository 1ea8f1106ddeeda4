"""The CPU kernels compiled in a second process while a run's scenes are built.

numba compiles a kernel on its first call and keeps it in its cache (NUMBA_CACHE_DIR, strings_bench/raster/
__init__.py). On a machine where nothing ran before, that compilation (41 s on one core for the 18 kernels STRinGS
and 3DGS call, on an idle 2-core AMD EPYC) fell in the first training step, after the scene build, whose SfM runs on
one thread and leaves the other core idle. `start(methods)` trains each method a few steps on the tiny synthetic
scene (the one `methods check` uses) in a child process, which writes every kernel it calls to numba's cache. The
run's own first call of a kernel loads it from there: numba looks in its cache before it compiles. Before a job
trains on the CPU, the run waits for the child to have written that method's kernels (`wait_for`), rather than
compiling them itself: both give the same bits, but a kernel compiled in the process that calls it can run slower
than the same kernel loaded from the cache (the float32 forward blend 1.17-1.39x slower on a 2-core AMD EPYC Zen 3,
the backward blend the same: `tools/blend_ab.py --compile-new-here`, docs/results/data/engine-stages/lane-constants/),
and compiling in both processes at once does the work twice on a 2-core machine. Once a method's kernels are in the
cache, a marker beside them says so and no child starts.

Off with STRINGS_BENCH_KERNEL_WARMUP=0; never for jobs on a GPU. A job run elsewhere (a Ray or Slurm worker) starts
the second process on its own machine when it finds the kernels not cached there (`ensure`), and waits for it too.
"""

from __future__ import annotations

import atexit
import hashlib
import logging
import os
import subprocess
import sys
import time
from pathlib import Path
from typing import Iterable

log = logging.getLogger(__name__)

ENV = "STRINGS_BENCH_KERNEL_WARMUP"
# Steps of the tiny schedule the child trains each method (measured: the first 3DGS step alone compiled all 18
# kernels; tests/bench/test_warmup.py checks that a 150-step training of both methods afterwards compiles none).
WARM_STEPS = 30
WARM_SCHEDULE = "tiny"
# How long a job waits for the child before it compiles the kernels itself (a child that hangs must not stop the
# run; the child takes 40-100 s on an idle 2-core machine).
WAIT_LIMIT_S = 600.0
POLL_S = 0.2
# The modules whose kernels are compiled into numba's cache (`@njit(cache=True)`): numba reuses a kernel while its
# file keeps its size and modification time, so the marker's key holds them too.
KERNEL_MODULES = (
    "strings_bench.engine.loss_kernels",
    "strings_bench.engine.motion",
    "strings_bench.engine.optim_kernels",
    "strings_bench.engine.strategies.stats_kernels",
    "strings_bench.raster.cpu_kernels",
    "strings_bench.raster.cpu_kernels_f32",
    "strings_bench.raster.cpu_preprocess",
)

_children: list[subprocess.Popen] = []
_started: set[str] = set()  # the methods a child of this process was started for (once each)


def enabled() -> bool:
    return os.environ.get(ENV, "1").strip().lower() not in ("0", "false", "no", "off")


def _module_file(name: str) -> Path:
    import importlib.util

    spec = importlib.util.find_spec(name)
    if spec is None or spec.origin is None:
        raise ImportError(name)
    return Path(spec.origin)


def cache_key(method: str) -> str:
    """What numba's cached kernels of `method` depend on: numba and Python, the CPU the code is compiled for, and
    each kernel module's path, size and modification time."""
    import llvmlite.binding as llvm
    import numba

    parts = [method, numba.__version__, sys.version, llvm.get_host_cpu_name(), llvm.get_host_cpu_features().flatten()]
    for name in KERNEL_MODULES:
        path = _module_file(name)
        st = path.stat()
        parts.append(f"{path}|{st.st_size}|{st.st_mtime_ns}")
    return hashlib.sha256("\n".join(parts).encode()).hexdigest()[:20]


def marker_dir() -> Path:
    """The folder of the markers, beside numba's cached kernels."""
    import strings_bench.raster  # noqa: F401  (sets NUMBA_CACHE_DIR)
    from numba.core import config

    return Path(config.CACHE_DIR) / "strings-bench-warm"


def marker(method: str) -> Path:
    """The file that says `method`'s kernels are in numba's cache."""
    return marker_dir() / f"{method}-{cache_key(method)}.done"


def start(methods: Iterable[str]) -> subprocess.Popen | None:
    """Start the child that compiles the kernels of those of `methods` whose marker is missing; None when none is
    missing or the warm-up is off. The child is stopped when this process exits."""
    if not enabled():
        return None
    try:
        todo = [m for m in dict.fromkeys(methods) if not marker(m).exists()]
    except (ImportError, OSError) as exc:  # no numba here: nothing to compile
        log.debug("kernel warm-up not started: %s", exc)
        return None
    if not todo:
        return None
    _started.update(todo)
    env = {**os.environ, "NUMBA_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"}  # one core: the scene build has the other
    log_path = marker_dir() / "warmup.log"
    log_path.parent.mkdir(parents=True, exist_ok=True)
    with open(log_path, "w") as err:
        child = subprocess.Popen([sys.executable, "-m", "strings_bench.bench.warmup", *todo], env=env,
                                 stdin=subprocess.DEVNULL, stdout=err, stderr=subprocess.STDOUT)
    log.debug("compiling the kernels of %s in process %d (log: %s)", ", ".join(todo), child.pid, log_path)
    if not _children:
        atexit.register(stop)
    _children.append(child)
    return child


def ensure(method: str) -> None:
    """Start the child for `method` (as `start`) unless a child of this process is running or was started for it:
    a job run on a worker, where no plan started one."""
    if method in _started or any(c.poll() is None for c in _children):
        return
    start([method])


def wait_for(method: str, limit_s: float = WAIT_LIMIT_S) -> float:
    """Wait until `method`'s kernels are in the cache (its marker), a child compiling them has ended, or `limit_s`
    has passed; the seconds waited (0 at once when no child of this process is running)."""
    running = [c for c in _children if c.poll() is None]
    if not running:
        return 0.0
    try:
        done = marker(method)
    except (ImportError, OSError):
        return 0.0
    if done.exists():
        return 0.0
    log.info("waiting for the CPU kernels of %s, compiling in process %s", method,
             ", ".join(str(c.pid) for c in running))
    began = time.monotonic()
    while not done.exists() and any(c.poll() is None for c in running):
        if time.monotonic() - began >= limit_s:
            log.warning("the kernel warm-up did not finish in %.0f s: the run compiles the kernels itself", limit_s)
            break
        time.sleep(POLL_S)
    return time.monotonic() - began


def stop() -> None:
    """Stop the children still compiling (their kernels written so far stay in the cache)."""
    while _children:
        child = _children.pop()
        if child.poll() is None:
            child.terminate()
            try:
                child.wait(timeout=5)
            except subprocess.TimeoutExpired:
                child.kill()


def warm(method: str, steps: int = WARM_STEPS) -> None:
    """Train `method` `steps` steps of the tiny schedule on the tiny scene, on the CPU, then write its marker. A
    method that is not trained by the framework's loop (an adapter) has no kernels of ours to compile."""
    from strings_bench.core.io import atomic_write_json
    from strings_bench.core.method import Method
    from strings_bench.core.schedules import get_schedule
    from strings_bench.datasets.synthetic import tiny_scene
    from strings_bench.engine.trainer import SaveEvery, Trainer
    from strings_bench.methods.registry import get_method
    from strings_bench.scene.scene import Scene

    spec = get_method(method)
    obj = spec.build(steps_scale=get_schedule(WARM_SCHEDULE).steps_scale)
    if isinstance(obj, Method):
        obj.progress = False
        trainer = Trainer(obj, Scene.load(tiny_scene()), [steps], device="cpu", progress=False, state_path=None,
                          save_every=SaveEvery.parse("off"))
        for _ in trainer.train():
            pass
    path = marker(method)
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_json(path, {"method": method, "steps": steps})


def main(argv: list[str] | None = None) -> int:
    methods = sys.argv[1:] if argv is None else argv
    status = 0
    for method in methods:
        try:
            warm(method)
        except Exception as exc:  # noqa: BLE001 - the run compiles what is missing itself
            print(f"warm-up of {method} failed: {type(exc).__name__}: {exc}", file=sys.stderr)
            status = 1
    return status


if __name__ == "__main__":
    sys.exit(main())
