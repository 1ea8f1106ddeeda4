"""The kernel warm-up (bench/warmup.py): which modules it covers, when it starts, and (slow) that a run after it
compiles no kernel of its own."""

from __future__ import annotations

import os
import re
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

import strings_bench
import strings_bench.bench.warmup as warmup

PACKAGE = Path(strings_bench.__file__).resolve().parent


def test_kernel_modules_are_the_modules_with_cached_kernels():
    cached = set()
    for path in PACKAGE.rglob("*.py"):
        if re.search(r"^@njit\([^)]*cache=True", path.read_text(), re.MULTILINE):
            cached.add(".".join(("strings_bench",) + path.relative_to(PACKAGE).with_suffix("").parts))
    assert cached == set(warmup.KERNEL_MODULES)


def test_a_changed_kernel_file_changes_the_key(tmp_path, monkeypatch):
    kernel = tmp_path / "kernels.py"
    kernel.write_text("x = 1\n")
    monkeypatch.setattr(warmup, "_module_file", lambda name: kernel)
    before = warmup.cache_key("3dgs")
    assert warmup.cache_key("3dgs") == before
    assert warmup.cache_key("strings") != before
    os.utime(kernel, ns=(kernel.stat().st_atime_ns, kernel.stat().st_mtime_ns + 1_000_000_000))
    assert warmup.cache_key("3dgs") != before


def test_no_child_when_off_or_every_method_is_marked(tmp_path, monkeypatch):
    started = []

    class Child:
        pid = 0

        def __init__(self, args, **kwargs):
            started.append(args)

        def poll(self):
            return 0

    monkeypatch.setattr(warmup.subprocess, "Popen", Child)
    monkeypatch.setattr(warmup, "marker", lambda method: tmp_path / f"{method}.done")
    monkeypatch.setenv(warmup.ENV, "0")
    assert warmup.start(["3dgs"]) is None and not started
    monkeypatch.setenv(warmup.ENV, "1")
    (tmp_path / "3dgs.done").write_text("{}")
    assert warmup.start(["3dgs"]) is None and not started
    warmup.start(["3dgs", "strings", "3dgs"])
    assert len(started) == 1 and started[0][-1:] == ["strings"]  # only the unmarked method, once
    warmup._children.clear()


def test_plan_run_starts_it_only_for_runs_on_this_cpu(monkeypatch, scene_dir, tmp_path):
    from strings_bench.bench.plan import plan_run

    asked = []
    monkeypatch.setattr(warmup, "start", lambda methods: asked.append(list(methods)))
    plan_run(["fake-a"], [str(scene_dir)], run_dir=tmp_path / "run", schedule="tiny", device="cpu")
    assert asked == [["fake-a"]]


@pytest.mark.heavy
def test_a_run_after_the_warm_up_compiles_no_kernel(tmp_path, synthetic_books_small):
    """A fresh numba cache: the warm-up compiles, then a training of both methods on another scene (the shared small
    books scene, 150 steps of the tiny schedule) finds every kernel it calls in the cache (numba's own counters)."""
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "numba"), warmup.ENV: "1"}
    done = subprocess.run([sys.executable, "-m", "strings_bench.bench.warmup", "strings", "3dgs"], env=env,
                          capture_output=True, text=True, timeout=900)
    assert done.returncode == 0, done.stdout + done.stderr
    script = textwrap.dedent(f"""
        import importlib
        from strings_bench.bench.plan import with_steps_scale
        from strings_bench.bench.warmup import KERNEL_MODULES, marker
        from strings_bench.core.schedules import get_schedule
        from strings_bench.engine.trainer import SaveEvery, Trainer
        from strings_bench.methods.registry import get_method
        from strings_bench.scene.scene import Scene

        assert all(marker(m).exists() for m in ("strings", "3dgs"))
        for name in ("strings", "3dgs"):
            spec = get_method(name)
            method = spec.build(**with_steps_scale(spec, get_schedule("tiny").steps_scale, {{}}))
            method.progress = False
            trainer = Trainer(method, Scene.load({str(synthetic_books_small)!r}), [150], device="cpu", progress=False,
                              state_path=None, save_every=SaveEvery.parse("off"))
            for _ in trainer.train():
                pass
        hits = misses = 0
        for module in KERNEL_MODULES:
            for obj in vars(importlib.import_module(module)).values():
                stats = getattr(obj, "stats", None)
                if stats is not None and hasattr(stats, "cache_misses"):
                    hits += sum(stats.cache_hits.values())
                    misses += sum(stats.cache_misses.values())
        print(hits, misses)
    """)
    out = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True, timeout=900)
    assert out.returncode == 0, out.stdout + out.stderr
    hits, misses = map(int, out.stdout.split()[-2:])
    assert misses == 0 and hits >= 10, out.stdout


class _Child:
    """A stand-in for the warm-up's child process: running until `ended` is set."""

    pid = 4242

    def __init__(self):
        self.ended = False

    def poll(self):
        return 0 if self.ended else None


def test_a_job_waits_for_its_methods_marker(tmp_path, monkeypatch):
    import threading

    monkeypatch.setattr(warmup, "marker", lambda method: tmp_path / f"{method}.done")
    monkeypatch.setattr(warmup, "POLL_S", 0.01)
    assert warmup.wait_for("3dgs") == 0.0  # no child of this process: nothing to wait for
    child = _Child()
    monkeypatch.setattr(warmup, "_children", [child])
    timer = threading.Timer(0.3, lambda: (tmp_path / "3dgs.done").write_text("{}"))
    timer.start()
    waited = warmup.wait_for("3dgs", limit_s=30)
    timer.join()
    assert 0.25 <= waited < 10  # until the marker was written, with the child still running
    assert warmup.wait_for("3dgs") == 0.0  # marked: no wait
    # a child that ends without writing the marker (its warm-up failed) ends the wait too
    threading.Timer(0.2, lambda: setattr(child, "ended", True)).start()
    assert 0.15 <= warmup.wait_for("strings", limit_s=30) < 10
    # a child that never ends: the job compiles for itself after the limit
    monkeypatch.setattr(warmup, "_children", [_Child()])
    assert 0.2 <= warmup.wait_for("strings", limit_s=0.2) < 5


def test_the_runner_waits_before_a_cpu_training_only(monkeypatch, tmp_path):
    """Runner._checkpoints starts the warm-up where none ran (a worker) and waits for the method's kernels before it
    makes a Trainer on the CPU; not on a GPU."""
    from types import SimpleNamespace

    import strings_bench.engine.trainer as trainer_module
    from strings_bench.bench.runner import Runner
    from strings_bench.core.method import Method

    events = []
    monkeypatch.setattr(warmup, "ensure", lambda method: events.append(("ensure", method)))
    monkeypatch.setattr(warmup, "wait_for", lambda method, *a, **k: events.append(("wait", method)) or 0.0)

    class StubTrainer:
        def __init__(self, method, scene, checkpoints, **kwargs):
            events.append(("trainer", kwargs["device"]))

        def train(self):
            return iter(())

    monkeypatch.setattr(trainer_module, "Trainer", StubTrainer)
    stub = type("StubMethod", (Method,), {name: None for name in Method.__abstractmethods__})
    method = stub.__new__(stub)  # only its type is read before the Trainer is made
    for device in ("cpu", "cuda:0"):
        job = SimpleNamespace(method="3dgs", device=device, checkpoints=[2], downscale=1.0, save_every=None,
                              keep_models=False, scene_path="scene", dataset="d", scene="s", run_dir=str(tmp_path),
                              state_path=lambda: tmp_path / "state.pt")
        list(Runner(tmp_path)._checkpoints(job, method, None, {"settings": {}}))
    assert events == [("ensure", "3dgs"), ("wait", "3dgs"), ("trainer", "cpu"), ("trainer", "cuda:0")]


def test_a_worker_starts_the_warm_up_once_per_method_and_not_beside_a_running_one(tmp_path, monkeypatch):
    started = []

    class Child(_Child):
        def __init__(self, args, **kwargs):
            super().__init__()
            started.append(args[-1])

    monkeypatch.setattr(warmup.subprocess, "Popen", Child)
    monkeypatch.setattr(warmup, "marker", lambda method: tmp_path / f"{method}.done")
    monkeypatch.setattr(warmup, "_children", [])
    monkeypatch.setattr(warmup, "_started", set())
    monkeypatch.setattr(warmup.atexit, "register", lambda fn: None)
    monkeypatch.setenv(warmup.ENV, "1")
    warmup.ensure("3dgs")
    assert started == ["3dgs"]
    warmup.ensure("strings")  # the first child still runs: no second one beside it
    assert started == ["3dgs"]
    warmup._children[0].ended = True  # it ended without a marker (its warm-up failed): not started again
    warmup.ensure("3dgs")
    assert started == ["3dgs"]
    warmup.ensure("strings")
    assert started == ["3dgs", "strings"]
    warmup._children[-1].ended = True
    (tmp_path / "mcmc.done").write_text("{}")
    warmup.ensure("mcmc")  # cached already
    assert started == ["3dgs", "strings"]
