"""kill -9 at random points of a whole run (issue 19, item 2).

A child process builds a small synthetic scene (the real generator: rendering, pycolmap SfM, masks,
annotations) and runs the `tiny` grid on it (3DGS, evaluation with RapidOCR and its on-disk cache,
results.csv, the report). The harness SIGKILLs it again and again at random moments spread over the
four stages - scene preparation, training, evaluation, report writing - and then lets it run to the end.
A kill lands at the n-th event of a stage (n drawn with a seeded generator), an event being a rendered
view, an SfM attempt, a training step, the start of a checkpoint's evaluation or any atomic file write
of the stage, which the child dies in the middle of (its temporary file written, not yet renamed).
The child kills itself with SIGKILL: no clean-up of any kind runs, as with kill -9.

Between kills the harness also damages the caches as a crash of an older version or a broken copy
would: an image of the cached scene is cut short (the scene must be detected and rebuilt) and every
OCR cache entry is cut in half (each must be detected, recomputed and rewritten).

Afterwards: every cell is complete, valid JSON; results.csv's metric columns equal those of an
uninterrupted run at the same seed; no temporary file is left in the run folder or the cache.

tests/integration/test_resume.py kills training alone (and checks the parameters); this file kills the whole run.
"""

from __future__ import annotations

import strings_bench.bench as bench
from strings_bench.bench.plan import plan_run

import csv
import json
import os
import random
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
SCENE = "books"
SCENE_SETTINGS = {"width": 64, "height": 48, "n_views": 8}
METHODS = ["3dgs"]
CHECKPOINTS = [3000, 7000]  # tiny schedule: 15 and 35 steps
RUN_KW = dict(schedule="tiny", ocr="rapidocr", with_lpips=False, progress=False, save_every="5steps",
              method_overrides={"*": {"sh_degree": 1}}, checkpoints=CHECKPOINTS)
# results.csv columns that must equal the uninterrupted run's (times, memory and eval time may differ)
METRIC_COLUMNS = ["method", "dataset", "scene", "iteration", "label", "cer", "cer_known", "psnr", "ssim", "lpips",
                  "word_cer", "word_acc", "text_nll", "text_psnr", "text_ssim", "text_lpips", "word_cer_gt",
                  "text_nll_gt", "read_words", "read_oov_chars", "gaussians", "cer_errors", "cer_chars", "cer_views",
                  "ocr_failed", "gt_empty_ignored", "known_views", "schedule", "downscale", "ocr_backend"]
STAGES = ("prep", "train", "eval", "report")

CHILD = textwrap.dedent("""
    import json, os, signal, sys
    import strings_bench.core.io as io
    import strings_bench.datasets.synthetic.generate as generate
    from strings_bench.engine.splatting import GaussianSplatting
    import strings_bench.bench as bench
    import strings_bench.eval.protocol as protocol

    spec = json.loads(os.environ.get("KILL_SPEC") or "null")
    counts = {}

    def event(stage):
        counts[stage] = counts.get(stage, 0) + 1
        if counts[stage] == 1:
            print("STAGE", stage, flush=True)
        if spec and spec["stage"] == stage and counts[stage] == spec["n"]:
            print("KILL", stage, spec["n"], flush=True)
            os.kill(os.getpid(), signal.SIGKILL)  # no clean-up of any kind, as kill -9

    def wrap(owner, name, stage):
        real = getattr(owner, name)
        def hooked(*a, **k):
            event(stage)
            return real(*a, **k)
        setattr(owner, name, hooked)

    real_render_views = generate.render_views
    def render_views(*a, **k):
        for item in real_render_views(*a, **k):
            event("prep")
            yield item
    generate.render_views = render_views
    for name in ("triangulate_with_known_poses", "write_model", "write_annotations"):
        wrap(generate, name, "prep")
    wrap(GaussianSplatting, "train_step", "train")
    wrap(protocol.Evaluator, "evaluate", "eval")

    class _Os:  # os for core.io: a kill between writing a temporary file and renaming it
        def __getattr__(self, name):
            return getattr(os, name)
        def replace(self, src, dst):
            dst = str(dst)
            stage = ("prep" if "/.build-" in dst else "report" if "/report/" in dst
                     else "train" if "/state/" in dst else "setup" if dst.endswith("run.json") else "eval")
            event(stage)
            return os.replace(src, dst)
    io.os = _Os()

    from strings_bench.datasets.synthetic import build_scene, settings_with
    scene = build_scene(__SCENE__, settings_with(**__SETTINGS__), progress=False)
    bench.run(__METHODS__, [str(scene)], run_dir=__RUN_DIR__, **__RUN_KW__)
    print("DONE", flush=True)
""")


def _child(run_dir: Path, env: dict, spec: dict | None, timeout: float = 400) -> tuple[int, str]:
    code = CHILD
    for name, value in (("__SCENE__", SCENE), ("__SETTINGS__", SCENE_SETTINGS), ("__METHODS__", METHODS),
                        ("__RUN_DIR__", str(run_dir)), ("__RUN_KW__", RUN_KW)):
        code = code.replace(name, repr(value))
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=timeout,
                          env={**env, "KILL_SPEC": json.dumps(spec)})
    return proc.returncode, proc.stdout + proc.stderr


def _temporaries(*folders: Path) -> list[Path]:
    found = []
    for folder in folders:
        for p in folder.rglob("*"):
            n = p.name
            if n.endswith((".tmp", ".tmp-write", ".extract-tmp", ".prepare-tmp", ".part")) or n.startswith(".build-"):
                found.append(p)
    return found


def _rows(path: Path) -> list[dict]:
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def _same(a: str, b: str) -> bool:
    if a == b:
        return True
    try:
        return abs(float(a) - float(b)) <= 1e-6 * max(1.0, abs(float(b)))
    except ValueError:
        return False


def kill_schedule(rng: random.Random, per_stage: dict[str, int]) -> list[dict]:
    """Kills in pipeline order. n is drawn where the stage surely reaches it in any child that gets there:
    a prep child renders 8 views first; a training child resumes at most 4 steps before its kill; an
    evaluation holds >= 6 writes; a report >= 10."""
    top = {"prep": 8, "train": 6, "eval": 6, "report": 10}
    return [{"stage": s, "n": rng.randint(1, top[s])} for s in STAGES for _ in range(per_stage[s])]


def run_kill_harness(tmp_path: Path, per_stage: dict[str, int], seed: int, monkeypatch) -> dict:
    from strings_bench.store import check_cell

    cache, run_dir = tmp_path / "cache", tmp_path / "run"
    env = {**os.environ, "PYTHONPATH": str(REPO), "STRINGS_BENCH_CACHE": str(cache)}
    env.setdefault("NUMBA_CACHE_DIR", str(Path.home() / ".cache" / "strings-bench" / "numba"))
    rng = random.Random(seed)
    kills: list[dict] = []
    log: list[str] = []
    damaged = {"scene": None, "ocr_entries": 0}
    schedule = kill_schedule(rng, per_stage)
    last_eval = max(k for k, s in enumerate(schedule) if s["stage"] == "eval")
    for k, spec in enumerate(schedule):
        built = list((cache / "synthetic").glob(f"{SCENE}-*")) if (cache / "synthetic").is_dir() else []
        if spec["stage"] == "train" and damaged["scene"] is None and built:
            # A scene cut short by a broken copy (or an older version's crash): detected and rebuilt.
            scene_dir = built[0]
            victim = scene_dir / "images" / "view_003.png"
            victim.write_bytes(victim.read_bytes()[: victim.stat().st_size // 2])
            damaged["scene"] = str(victim)
        if k == last_eval:
            # Before the last evaluation kill: every OCR cache entry half-written.
            for entry in (cache / "ocr").rglob("*.json"):
                entry.write_bytes(entry.read_bytes()[: entry.stat().st_size // 2])
                damaged["ocr_entries"] += 1
        rc, out = _child(run_dir, env, spec)
        killed = rc == -signal.SIGKILL
        stage_seen = [ln.split()[1] for ln in out.splitlines() if ln.startswith("STAGE ")]
        kills.append({**spec, "killed": killed, "rc": rc, "stages_reached": stage_seen})
        log.append(out[-3000:])
        assert killed or rc == 0, f"child {k} ({spec}) failed with {rc}:\n{out[-3000:]}"
        if damaged["scene"] and "rebuilding it" in out:
            damaged["scene_rebuilt"] = True
    rc, out = _child(run_dir, env, None)
    assert rc == 0 and "DONE" in out, out[-3000:]

    # Every cell complete, valid JSON with the fields results.csv reads.
    cells = sorted(run_dir.glob("cells/*/*/*/*/result.json"))
    assert len(cells) == len(METHODS) * len(CHECKPOINTS)
    for p in cells:
        check_cell(json.loads(p.read_text()), p)
    # No temporary file left anywhere, no training state once every cell is written.
    assert not _temporaries(run_dir, cache), _temporaries(run_dir, cache)
    assert not list(run_dir.glob("state/**/training_state.pt"))
    assert (run_dir / "report" / "report.md").is_file()
    # The damaged scene was rebuilt; the damaged OCR entries were rewritten, valid, by the runs that needed them.
    assert damaged["scene"] and damaged.get("scene_rebuilt"), "the cut-short scene image was not detected"
    assert damaged["ocr_entries"] > 0

    # The uninterrupted run at the same seed, in this process, on the same scene folder and OCR cache.
    from strings_bench.bench import runner
    from strings_bench.datasets.synthetic import build_scene, settings_with

    monkeypatch.setenv("STRINGS_BENCH_CACHE", str(cache))
    scene = build_scene(SCENE, settings_with(**SCENE_SETTINGS), progress=False)
    whole = bench.run(METHODS, [str(scene)], run_dir=tmp_path / "whole", **RUN_KW)
    for entry in (cache / "ocr").rglob("*.json"):
        assert "words" in json.loads(entry.read_text()), entry  # every half-written entry was rewritten
    got, want = _rows(run_dir / "results.csv"), _rows(whole / "results.csv")
    assert len(got) == len(want) == len(METHODS) * len(CHECKPOINTS)
    for g, w in zip(got, want):
        diff = {c: (g[c], w[c]) for c in METRIC_COLUMNS if not _same(g[c], w[c])}
        assert not diff, diff
    return {"kills": kills, "killed": sum(k["killed"] for k in kills),
            "by_stage": {s: sum(k["killed"] for k in kills if k["stage"] == s) for s in STAGES},
            "cells": len(cells), "rows_equal": len(got), "ocr_entries_damaged": damaged["ocr_entries"]}


def _report(summary: dict, name: str) -> None:
    target = os.environ.get("STRINGS_BENCH_KILL_SUMMARY")  # docs/reliability.md counts these
    if target:
        Path(target).with_name(Path(target).stem + f"-{name}.json").write_text(json.dumps(summary, indent=1))


def test_kill_9_at_random_points_of_a_run(tmp_path, monkeypatch):
    """Ten kills (prep 2, train 3, eval 3, report 2), then a run to the end."""
    summary = run_kill_harness(tmp_path, {"prep": 2, "train": 3, "eval": 3, "report": 2}, seed=19, monkeypatch=monkeypatch)
    _report(summary, "default")
    assert summary["killed"] >= 10 and all(summary["by_stage"][s] >= 1 for s in STAGES), summary


@pytest.mark.slow
def test_kill_9_many_times(tmp_path, monkeypatch):
    """Thirty kills at other random points (another seed)."""
    summary = run_kill_harness(tmp_path, {"prep": 6, "train": 8, "eval": 10, "report": 6}, seed=1919,
                               monkeypatch=monkeypatch)
    _report(summary, "slow")
    assert summary["killed"] >= 30, summary


def test_a_half_written_ocr_entry_and_scene_are_detected_and_rebuilt(tmp_path, monkeypatch):
    """In-process, without killing: the checks the harness relies on, each on its own."""
    from strings_bench.core.io import sweep_stale_temps, writer_tag
    from strings_bench.datasets.synthetic import build_scene, settings_with
    from strings_bench.datasets.synthetic.generate import intact_problem
    from strings_bench.eval.ocr import OCRCache
    from strings_bench.eval.ocr.base import Word

    monkeypatch.setenv("STRINGS_BENCH_CACHE", str(tmp_path / "cache"))
    cache = OCRCache(tmp_path / "ocr")
    key = cache.key({"name": "x"}, "img", None)
    cache.put(key, [Word.from_box("EXIT", 0, 0, 10, 5)], {"name": "x"})
    good = cache.path(key).read_bytes()
    cache.path(key).write_bytes(good[: len(good) // 2])
    assert cache.get(key) is None  # a half-written entry is a miss, never words
    cache.put(key, [Word.from_box("EXIT", 0, 0, 10, 5)], {"name": "x"})
    assert cache.path(key).read_bytes() == good

    settings = settings_with(width=48, height=36, n_views=8)
    scene = build_scene(SCENE, settings, progress=False)
    assert intact_problem(scene) is None
    image = scene / "images" / "view_002.png"
    before = image.read_bytes()
    image.write_bytes(before[:100])
    assert "view_002.png has 100 bytes" in intact_problem(scene)
    # A killed build's folder and a killed writer's temporary file: removed by the next build.
    dead_pid = 2 ** 22 + 12345
    host = writer_tag().split("-")[0]
    (scene.parent / f".build-{scene.name}-~{host}-{dead_pid}-abc123").mkdir()
    (scene.parent / f".x.json.~{host}-{dead_pid}.q1w2e3r4.tmp").write_text("{")
    assert build_scene(SCENE, settings, progress=False) == scene
    assert image.read_bytes() == before and intact_problem(scene) is None
    assert not _temporaries(scene.parent)
    assert sweep_stale_temps(scene.parent) == []


def test_a_state_left_after_the_last_cell_is_removed(tmp_path, monkeypatch):
    """Regression (found by the 30-kill run): killed after writing its last cell but before removing the
    training state, a run left training_state.pt for ever - the re-run skipped the finished job."""
    import runner_fakes as rf
    from strings_bench.bench import runner
    from strings_bench.core.io import atomic_write_json

    monkeypatch.setenv("STRINGS_BENCH_CACHE", str(tmp_path / "cache"))
    rf.register_fakes()
    scene = rf.make_scene(tmp_path, "scene")
    plan = plan_run(["fake-a"], [str(scene)], run_dir=tmp_path / "run", schedule="tiny")
    job = plan.jobs[0]
    for key in job.cells():  # every cell finished (as the killed run left them)
        atomic_write_json(key.path(plan.run_dir) / "result.json", {
            "method": key.method, "dataset": key.dataset, "scene": key.scene, "iteration": key.iteration,
            "metrics": {"psnr": 20.0}, "timings": {}, "config": {}})
    job.state_path().parent.mkdir(parents=True)
    job.state_path().write_bytes(b"a state the killed run did not remove")
    runner.execute(plan, ocr=rf.FakeOCR(), progress=False, write_report=False)
    assert not job.state_path().exists()
    assert len((plan.run_dir / "results.csv").read_text().splitlines()) == 1 + len(job.cells())
