"""The framework's training loop: it owns the steps, the device, the timing, checkpoint evaluation
and the resumable training state; the method (`strings_bench.core.method.Method`) owns the rest.

    trainer = Trainer(method, scene, checkpoints=[70, 300], device="auto",
                      state_path=run_dir / "training_state.pt", save_every=SaveEvery(minutes=10))
    for result in trainer.train():      # one CheckpointResult per checkpoint, in order
        ...

Timing: `preprocess_seconds` is `method.setup` (masks, Algorithm 1, the initial model);
`train_seconds` counts the optimisation steps (train_step and refine) and nothing else: not the
checkpoint renders, not state saving. On CUDA the device is synchronised before each clock read,
so asynchronous kernels are counted in the step that launched them. `train_cpu_seconds` is the
process's CPU time (every thread's, `time.process_time`) over the same steps: on a CPU the work done,
which the wall clock overstates when the process waits for a core it shares or is stopped (on CUDA
it counts the host's side only).

Resuming: the state (the method's `state_dict()`, the global random generators, the step and the
clocks) is written atomically at every checkpoint and every `save_every`; a Trainer given an
existing `state_path` continues from it, and the result equals an uninterrupted run under the same
seed (the CPU rasterizer is deterministic). A state made with other settings is refused.
"""

from __future__ import annotations

import ctypes
import logging
import os
import random
import re
import resource
import sys
import time
from contextlib import contextmanager, nullcontext
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Callable, Iterable, Iterator

import numpy as np
import torch

from strings_bench.core.cpus import portable_isa_in_effect
from strings_bench.core.errors import StringsBenchError
from strings_bench.core.results import CheckpointResult

if TYPE_CHECKING:
    from strings_bench.core.method import Method
    from strings_bench.scene.scene import Scene

log = logging.getLogger(__name__)

STATE_VERSION = 1
# Settings renamed since training states were first saved: old name -> today's (a state keeps the names it was saved
# with; `Trainer._renamed` reads them as today's). max_gaussians: the Gaussian budget (`TrainConfig.gaussian_budget`).
RENAMED_SETTINGS = {"max_gaussians": "gaussian_budget"}

# torch's intra-op threads while a method trains on the CPU. The CPU rasterizer's numba
# kernels use every core already; torch's own threads (SSIM convolutions, small element-wise ops)
# then only contend with them (docs/engine.md, "CPU speed"; measured in docs/results/engine-speed.md).
CPU_TORCH_THREADS = 1


# Blocks up to this size are served from glibc's heap and kept there, so a CPU step's arrays of tens of MB are
# reused instead of paid for in page faults at every step (measured: docs/engine.md, "CPU speed"). Nothing
# computed changes; the process keeps its peak heap until it exits.
CPU_MMAP_THRESHOLD = 1 << 30
_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -1, -3  # mallopt parameters (malloc.h)
_freed_memory_kept: bool | None = None  # not tried yet


def keep_freed_memory() -> bool:
    """Have glibc's malloc serve blocks up to CPU_MMAP_THRESHOLD from the heap and never trim it, once
    per process. False where the C library is not glibc, or where STRINGS_BENCH_KEEP_FREED_MEMORY=0
    (nothing is changed then)."""
    global _freed_memory_kept
    if _freed_memory_kept is None:
        if os.environ.get("STRINGS_BENCH_KEEP_FREED_MEMORY", "1") == "0":
            _freed_memory_kept = False
            return False
        try:
            libc = ctypes.CDLL("libc.so.6")
            _freed_memory_kept = bool(libc.mallopt(_M_MMAP_THRESHOLD, CPU_MMAP_THRESHOLD)
                                      and libc.mallopt(_M_TRIM_THRESHOLD, 2**31 - 1))
        except (OSError, AttributeError):
            _freed_memory_kept = False
    return _freed_memory_kept


@contextmanager
def cpu_threads(n: int | None = CPU_TORCH_THREADS):
    """Run the body with torch's intra-op thread count set to `n` (None: unchanged), restored after."""
    if n is None:
        yield
        return
    old = torch.get_num_threads()
    torch.set_num_threads(int(n))
    try:
        yield
    finally:
        torch.set_num_threads(old)


def check_device_name(device: str | None) -> None:
    """Refuse a device string torch cannot parse (availability is checked where the job runs)."""
    if device in (None, "", "auto"):
        return
    try:
        kind = torch.device(device).type
    except (RuntimeError, ValueError) as exc:
        raise StringsBenchError(f"unknown device {device!r}", hint="use auto, cpu, cuda or cuda:N") from exc
    if kind not in ("cpu", "cuda"):
        raise StringsBenchError(f"device {device!r} is not supported", hint="use auto, cpu, cuda or cuda:N")


def resolve_device(device: str | None) -> str:
    """'auto' (or None) -> 'cuda' when torch sees a GPU, else 'cpu'; 'cuda:N' is checked."""
    if device in (None, "", "auto"):
        return "cuda" if torch.cuda.is_available() else "cpu"
    try:
        dev = torch.device(device)
    except (RuntimeError, ValueError) as exc:
        raise StringsBenchError(f"unknown device {device!r}", hint="use auto, cpu, cuda or cuda:N") from exc
    if dev.type == "cuda":
        if not torch.cuda.is_available():
            raise StringsBenchError(f"device {device!r} asked for, but torch sees no CUDA GPU",
                                    hint="use --device cpu, or install a CUDA build of torch")
        if dev.index is not None and dev.index >= torch.cuda.device_count():
            raise StringsBenchError(f"device {device!r}: torch sees {torch.cuda.device_count()} GPU(s)",
                                    hint=f"use cuda:0 .. cuda:{torch.cuda.device_count() - 1}")
    elif dev.type != "cpu":
        raise StringsBenchError(f"device {device!r} is not supported", hint="use auto, cpu, cuda or cuda:N")
    return str(dev)


@dataclass(frozen=True)
class SaveEvery:
    """When to save the training state besides checkpoints: every `minutes` of training, or every
    `steps` steps (for tests). `SaveEvery.parse("10")`, `parse("2.5min")`, `parse("20steps")`, `parse("off")`."""

    minutes: float | None = 10.0
    steps: int | None = None

    @classmethod
    def parse(cls, text: str | float | int | None) -> "SaveEvery":
        if text is None:
            return cls()
        if isinstance(text, (int, float)):
            return cls(minutes=float(text))
        t = str(text).strip().lower()
        if t in ("off", "never", "0"):
            return cls(minutes=None, steps=None)
        m = re.fullmatch(r"(\d+)\s*steps?", t)
        if m and int(m.group(1)) > 0:
            return cls(minutes=None, steps=int(m.group(1)))
        m = re.fullmatch(r"(\d+(?:\.\d+)?)\s*(m|min|mins|minutes)?", t)
        if m and float(m.group(1)) > 0:
            return cls(minutes=float(m.group(1)))
        raise StringsBenchError(f"--save-every {text!r} is neither minutes nor a step count",
                                hint="e.g. --save-every 10 (minutes), 2.5min, 500steps, or off")

    def due(self, step: int, seconds_since_save: float) -> bool:
        if self.steps is not None:
            return step % self.steps == 0
        return self.minutes is not None and seconds_since_save >= 60.0 * self.minutes


def reset_peak_memory(device: str | torch.device = "cpu") -> str:
    """Start a new peak for `peak_memory_mb`, so that a training's figure is its own and not the peak of the
    methods trained before it in the same process: CUDA's allocator statistics, or on Linux the process's
    resident high-water mark (writing 5 to /proc/self/clear_refs resets VmHWM, Linux >= 4.0). Returns the
    scope recorded with the figures: "training" where the peak was reset, "process" (a process-lifetime
    peak, an upper bound) where it could not be."""
    if torch.device(device).type == "cuda":
        torch.cuda.reset_peak_memory_stats(device)
        return "training"
    try:
        with open("/proc/self/clear_refs", "w") as fh:
            fh.write("5")
        return "training"
    except OSError:
        return "process"


def peak_memory_mb(device: str | torch.device = "cpu") -> float:
    """The peak since `reset_peak_memory` (or the process's start): torch.cuda.max_memory_allocated on CUDA,
    else the resident high-water mark (VmHWM on Linux, ru_maxrss elsewhere)."""
    if torch.device(device).type == "cuda":
        return torch.cuda.max_memory_allocated(device) / 2 ** 20
    try:
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) / 2 ** 10  # kB
    except OSError:
        pass
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return rss / 2 ** 20 if sys.platform == "darwin" else rss / 2 ** 10  # bytes on macOS, KiB on Linux


def _global_rng_state() -> dict:
    state = {"torch": torch.get_rng_state(), "numpy": np.random.get_state(), "python": random.getstate()}
    if torch.cuda.is_available() and torch.cuda.is_initialized():
        state["cuda"] = torch.cuda.get_rng_state_all()
    return state


def _set_global_rng_state(state: dict) -> None:
    torch.set_rng_state(state["torch"])
    np.random.set_state(state["numpy"])
    random.setstate(state["python"])
    if "cuda" in state and torch.cuda.is_available():
        torch.cuda.set_rng_state_all(state["cuda"])


def seed_everything(seed: int) -> None:
    torch.manual_seed(seed)
    random.seed(seed)
    np.random.seed(seed)


class Trainer:
    """Trains `method` on `scene` up to the last checkpoint and yields a `CheckpointResult` at each.

    Args:
        method: a `Method` (not yet set up).
        scene: the scene; test views (`scene.test_idx`) are rendered at each checkpoint.
        checkpoints: steps actually run (already x steps_scale), e.g. [70, 300].
        downscale: image downscale factor for training and test renders.
        device: "auto" (default: CUDA when torch sees a GPU, else the CPU), "cpu", "cuda" or "cuda:N"
            (see `resolve_device`).
        seed: seeds the global generators (torch, numpy, random) and the method; default the
            method's own seed setting.
        progress: show a progress bar.
        state_path: file of the resumable training state; training continues from it when it
            exists, and it is written at every checkpoint and every `save_every`.
        save_every: `SaveEvery` (default every 10 minutes).
        model_path: step -> file; the model is written there (PLY) at each checkpoint.
        render_test: render the test views at checkpoints (False: renders are empty).
        fingerprint: what must match for a saved state to be continued (method, settings, scene).
        cpu_torch_threads: torch's intra-op threads during the optimisation steps on the CPU
            (`CPU_TORCH_THREADS`, 1: the rasterizer's numba kernels use the cores; None leaves
            torch's setting alone). Checkpoint renders and whatever the caller does between
            checkpoints run with the caller's setting. Results do not depend on it.
    """

    def __init__(self, method: "Method", scene: "Scene", checkpoints: Iterable[int], *, downscale: float = 1.0,
                 device: str | None = "auto", seed: int | None = None, progress: bool = True,
                 state_path: str | Path | None = None, save_every: SaveEvery | None = None,
                 model_path: Callable[[int], Path] | None = None, render_test: bool = True, fingerprint: dict | None = None,
                 cpu_torch_threads: int | None = CPU_TORCH_THREADS):
        steps = sorted({int(c) for c in checkpoints})
        if not steps or steps[0] < 1:
            raise StringsBenchError(f"checkpoints must be positive step numbers, got {list(checkpoints)}")
        self.method = method
        self.scene = scene
        self.checkpoints = steps
        self.downscale = float(downscale)
        self.device = resolve_device(device)
        self.seed = seed
        self.progress = progress
        self.state_path = Path(state_path) if state_path is not None else None
        self.save_every = save_every if save_every is not None else SaveEvery()
        self.model_path = model_path
        self.render_test = render_test
        self.fingerprint = fingerprint or {}
        self.resumed_from_step = 0
        self.peak_memory_scope = "process"  # until train() resets the peak
        if cpu_torch_threads is not None and int(cpu_torch_threads) < 1:
            raise StringsBenchError(f"cpu_torch_threads must be >= 1 or None, got {cpu_torch_threads}")
        self.cpu_torch_threads = cpu_torch_threads

    def _step_threads(self):
        """The thread setting of an optimisation step (CPU training only)."""
        if self.device != "cpu":
            return nullcontext()
        keep_freed_memory()
        return cpu_threads(self.cpu_torch_threads)

    def _sync(self) -> None:
        if self.device.startswith("cuda"):
            torch.cuda.synchronize(self.device)

    def _clocks(self) -> tuple[float, float]:
        """(wall clock, process CPU time), the device synchronised first."""
        self._sync()
        return time.perf_counter(), time.process_time()

    def _fingerprint(self) -> dict:
        return {"version": STATE_VERSION, "method": self.method.name, "checkpoints": self.checkpoints,
                "downscale": self.downscale, "scene": self.scene.name, **self.fingerprint}

    @staticmethod
    def _renamed(fingerprint):
        """A saved state's fingerprint with the settings renamed since it was saved under today's names
        (RENAMED_SETTINGS), so that a state saved before a rename still resumes."""
        settings = fingerprint.get("settings") if isinstance(fingerprint, dict) else None
        if not isinstance(settings, dict) or not set(settings) & set(RENAMED_SETTINGS):
            return fingerprint
        renamed = {RENAMED_SETTINGS.get(k, k): v for k, v in settings.items()}
        return {**fingerprint, "settings": dict(sorted(renamed.items()))}

    # ---- state -------------------------------------------------------------------------------------
    def save_state(self, step: int, train_seconds: float, preprocess_seconds: float,
                   train_cpu_seconds: float | None = None) -> None:
        """Write the resumable state after `step` atomically to `state_path` (torch.save of the method's
        state_dict, the global generators, the clocks and the fingerprint)."""
        from strings_bench.core.io import atomic_write

        state = {"fingerprint": self._fingerprint(), "step": step, "train_seconds": train_seconds,
                 "train_cpu_seconds": train_cpu_seconds,
                 "preprocess_seconds": preprocess_seconds, "method": self.method.state_dict(),
                 "rng": _global_rng_state()}
        atomic_write(self.state_path, lambda tmp: torch.save(state, tmp))

    def load_state(self) -> dict | None:
        """The saved state to continue from, or None; a state of other settings or an unreadable file is
        a `StringsBenchError` naming the file."""
        if self.state_path is None or not self.state_path.is_file():
            return None
        try:
            state = torch.load(self.state_path, map_location="cpu", weights_only=False)
        except Exception as exc:  # noqa: BLE001 - a truncated or foreign file
            raise StringsBenchError(f"training state {self.state_path} is unreadable: {exc}",
                                    hint="delete it to train this method and scene from the start") from exc
        if not isinstance(state, dict) or self._renamed(state.get("fingerprint")) != self._fingerprint():
            got = state.get("fingerprint") if isinstance(state, dict) else None
            raise StringsBenchError(f"training state {self.state_path} was made with other settings ({got}); "
                                    f"this run is {self._fingerprint()}",
                                    hint="delete it to train from the start, or run with the same settings")
        return state

    # ---- the loop ------------------------------------------------------------------------------------
    def train(self) -> Iterator[CheckpointResult]:
        """Set the method up (or restore it from the saved state) and train to the last checkpoint,
        yielding one `CheckpointResult` per checkpoint not yet passed, in order."""
        from tqdm.auto import tqdm

        seed = self.seed if self.seed is not None else getattr(getattr(self.method, "config", None), "seed", 0)
        seed_everything(int(seed))
        if str(self.device).startswith("cpu") and not portable_isa_in_effect():
            log.warning("torch runs its %s CPU kernels, not the AVX2 ones that make a run's figures the same "
                        "on every machine: torch computed before strings_bench was imported (import "
                        "strings_bench first, or set ATEN_CPU_CAPABILITY=avx2)",
                        torch.backends.cpu.get_cpu_capability())
        self.method.progress = self.progress
        # this training's own peak (set-up included), not the peak of what the process did before
        self.peak_memory_scope = reset_peak_memory(self.device)
        t0, _ = self._clocks()
        self.method.setup(self.scene, downscale=self.downscale, device=self.device, seed=self.seed)
        preprocess_seconds = self._clocks()[0] - t0
        train_seconds = 0.0
        train_cpu: float | None = 0.0
        start = 0
        state = self.load_state()
        if state is not None:
            self.method.load_state_dict(state["method"])
            _set_global_rng_state(state["rng"])
            start = self.resumed_from_step = int(state["step"])
            train_seconds = float(state["train_seconds"])
            # a state saved before CPU time was kept: this training's CPU time is unknown
            train_cpu = None if state.get("train_cpu_seconds") is None else float(state["train_cpu_seconds"])
            preprocess_seconds = float(state["preprocess_seconds"])
            log.info("%s on %s: resuming from the training state at step %d", self.method.name, self.scene.name, start)

        def count_since(since: tuple[float, float]) -> None:
            """Add the wall and CPU seconds from `since` (a _clocks() reading) to the training's."""
            nonlocal train_seconds, train_cpu
            now = self._clocks()
            train_seconds += now[0] - since[0]
            train_cpu = None if train_cpu is None else train_cpu + (now[1] - since[1])

        total = self.checkpoints[-1]
        at_steps = set(self.checkpoints)
        last_save = time.perf_counter()
        bar = tqdm(total=total, initial=start, desc=f"train {self.scene.name}", disable=not self.progress,
                   leave=False, dynamic_ncols=True)
        try:
            for step in range(start + 1, total + 1):
                since = self._clocks()
                with self._step_threads():
                    loss = self.method.train_step(step)
                count_since(since)
                if step in at_steps:
                    # Evaluated after the step's update, before its densification / opacity reset, as
                    # the reference code saves before it densifies (a reset on a checkpoint step, e.g.
                    # 3K in 3DGS, would otherwise be evaluated at opacity 0.01).
                    yield self.checkpoint(step, train_seconds, preprocess_seconds, train_cpu)
                since = self._clocks()
                with self._step_threads():
                    self.method.refine(step)
                count_since(since)
                bar.update(1)
                if step % 10 == 0 or step == total:
                    bar.set_postfix(loss=f"{loss:.4f}", gaussians=self.method.num_gaussians())
                if self.state_path is not None and (step in at_steps
                                                    or self.save_every.due(step, time.perf_counter() - last_save)):
                    self.save_state(step, train_seconds, preprocess_seconds, train_cpu)
                    last_save = time.perf_counter()
        finally:
            bar.close()

    @torch.no_grad()
    def checkpoint(self, step: int, train_seconds: float, preprocess_seconds: float,
                   train_cpu_seconds: float | None = None) -> CheckpointResult:
        """Evaluate the model after `step`: test-view renders, stats, peak memory, and the PLY if asked."""
        renders = {}
        if self.render_test:
            renders = {self.scene.names[i]: self.method.render(i) for i in self.scene.test_idx}
        extra = {**self.method.checkpoint_extra(step), "device": self.device,
                 "peak_memory_scope": self.peak_memory_scope}
        if self.model_path is not None:
            path = Path(self.model_path(step))
            self.method.save_model(path)
            extra["ply"] = str(path)
        return CheckpointResult(iteration=step, renders=renders, train_seconds=train_seconds,
                                gaussians=self.method.num_gaussians(), peak_memory_mb=peak_memory_mb(self.device),
                                extra=extra, preprocess_seconds=preprocess_seconds,
                                resumed_from_step=self.resumed_from_step, train_cpu_seconds=train_cpu_seconds)
