"""The floor on GT characters applies to every scene without known text (a user's own photos included): a run whose
held-out GT reads fewer characters than the floor warns in the log, leaves `cer` empty and its report says why."""

from __future__ import annotations

import csv
import json
import logging

from strings_bench.eval.floors import MIN_GT_CHARS


def _scene_without_known_text(tmp_path):
    from tests.runner_fakes import make_scene

    root = make_scene(tmp_path / "scenes")
    (root / "text_annotations.json").unlink()  # as `prepare` makes a scene from photos: no known text
    return root


def test_a_scene_without_known_text_gets_the_default_floor(tmp_path):
    from strings_bench.eval.protocol import Evaluator
    from strings_bench.scene.scene import Scene
    from tests.runner_fakes import FakeOCR, make_scene

    photos = Scene.load(_scene_without_known_text(tmp_path))
    ev = Evaluator.for_scene(photos, FakeOCR(), 1, with_lpips=False, with_readability=False)
    assert ev.min_gt_chars == MIN_GT_CHARS
    known = Scene.load(make_scene(tmp_path / "known"))  # synthetic-like: known text, no floor
    assert Evaluator.for_scene(known, FakeOCR(), 1, with_lpips=False, with_readability=False).min_gt_chars is None
    own = Scene.load(_scene_without_known_text(tmp_path / "own"), settings={"min_gt_chars": 3})
    assert Evaluator.for_scene(own, FakeOCR(), 1, with_lpips=False, with_readability=False).min_gt_chars == 3


def test_a_run_on_photos_whose_gt_reads_too_little_warns_and_leaves_cer_empty(tmp_path, monkeypatch, caplog):
    import tests.runner_fakes as rf
    from strings_bench import bench
    from strings_bench.datasets import registry
    from strings_bench.datasets.card import DatasetCard, SceneCard
    from strings_bench.datasets.registry import register_dataset
    from strings_bench.reports import figures, write_report

    registry.list_datasets()
    monkeypatch.setattr(registry, "_REGISTRY", dict(registry._REGISTRY))  # the test's card goes with the test
    rf.register_fakes()
    path = _scene_without_known_text(tmp_path)
    register_dataset(DatasetCard(id="mine", title="my photos", scenes=[SceneCard("toy", {})],
                                 locate=lambda scene, _p=path: _p))
    out = tmp_path / "run"
    with caplog.at_level(logging.WARNING):
        bench.run(["fake-a"], ["mine"], run_dir=out, schedule="tiny", ocr="fake", ocr_backend=rf.FakeOCR(),
                  with_lpips=False, progress=False, write_report=False)
    rows = list(csv.DictReader((out / "results.csv").open()))
    # FakeOCR reads "hello" on each of the 2 held-out GT views: 10 characters, below the floor of 50
    assert rows and all(r["cer"] == "" and r["cer_chars"] == "10" for r in rows), rows
    result = json.loads(next((out / "cells").rglob("result.json")).read_text())
    assert result["cer"]["cer"] is None and "10 characters" in result["cer"]["not_scored"]
    assert any("OCR-CER not scored" in r.getMessage() and r.levelno == logging.WARNING for r in caplog.records)
    monkeypatch.setattr(figures, "write_figures", lambda *a, **k: {})  # the note is the point, not the figures
    report = write_report(out).read_text()
    assert "OCR-CER is not scored on mine/toy (its GT reads 10 characters" in report
    assert "Too little text for a CER" in report
