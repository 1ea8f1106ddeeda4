"""Scene draws (issue 40): a synthetic360 room at another generator seed, registered as a scene ROOM@N of every
synthetic360 card; draw 0 is the room itself, with the cache keys (and so the figures) it had before draws; the
draws reach `datasets list/prepare`, `run`, `evaluate` (resolve_scenes) and `calibrate --draws`, whose tables give the
mean over draws with the draws' range. The comparison tool's side is tests/reports/test_comparison_tables.py."""

from __future__ import annotations

import strings_bench.bench as bench

import argparse
import csv
import io
import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

import strings_bench.datasets.synthetic.generate as generate
from strings_bench.cli import main as cli_main
from strings_bench.core.draws import REGISTERED_DRAWS, draw_name, parse_draws, split_draw
from strings_bench.core.errors import DatasetError, StringsBenchError
from strings_bench.datasets.registry import get_dataset, register_dataset, resolve_scenes, select_scenes
from strings_bench.datasets.synthetic import (SCENE_NAMES_360, SYNTHETIC360_CPU, SYNTHETIC360_DEFAULTS, default_settings,
                                              read_meta, settings_with, synthetic360_card)

# The cache keys (scene generator version 4) of draws 1 and 2 of synthetic360-cpu: the folders `datasets prepare synthetic360-cpu --seed N`
# builds (the same settings), which the issue-40 calibration trains on. Draw 0 keeps the keys pinned in
# test_synthetic360.py (5ddc335574f8, 7231c35af058, f49a673bafe6).
CPU_DRAW_KEYS = {1: {"pantry": "60053935cc3a", "office": "4eec66663185", "storeroom": "f73b5e529e70"},
                 2: {"pantry": "0e0545dc94ac", "office": "d2fb695e8c7f", "storeroom": "6167f539b4ed"}}


def test_draw_names_parse_and_refuse_what_is_no_draw():
    assert split_draw("pantry@2") == ("pantry", 2) and split_draw("pantry") == ("pantry", 0)
    assert draw_name("pantry", 0) == "pantry" and draw_name("pantry", 3) == "pantry@3"
    assert parse_draws("0, 1,2,1") == [0, 1, 2]
    for bad in ("pantry@x", "pantry@-1", "pantry@", "pantry@1.5", "@1"):
        with pytest.raises(DatasetError, match="not a draw|no room"):
            split_draw(bad)
    with pytest.raises(DatasetError, match="no draws"):
        parse_draws(" , ")
    with pytest.raises(DatasetError, match="not a non-negative integer"):
        draw_name("pantry", -1)


def test_draws_are_scenes_of_every_synthetic360_card_and_draw_0_keeps_its_keys(monkeypatch, tmp_path):
    cpu = settings_with(**SYNTHETIC360_CPU)
    card = get_dataset("synthetic360-cpu")
    assert card.draws == REGISTERED_DRAWS == (0, 1, 2) and "registered: @0, @1, @2" in card.notes
    assert [s.name for s in card.scenes] == list(SCENE_NAMES_360)  # the dataset itself: draw 0, as before
    assert default_settings("pantry@0", "synthetic360-cpu") == default_settings("pantry", "synthetic360-cpu") == cpu
    assert cpu.key("pantry") == "5ddc335574f8"
    for n, keys in CPU_DRAW_KEYS.items():
        for room, key in keys.items():
            st = default_settings(f"{room}@{n}", "synthetic360-cpu")
            assert st == replace(cpu, seed=n) and st.key(room) == key
    calls = []
    monkeypatch.setattr("strings_bench.datasets.synthetic.build_scene",
                        lambda scene, settings, progress=True, force=False: calls.append((scene, settings)) or tmp_path)
    refs = resolve_scenes(["synthetic360-cpu/pantry@1", "synthetic360-cpu/pantry@0", "synthetic360-cpu@2",
                           "synthetic360/office@3"])
    assert [r.id for r in refs] == ["synthetic360-cpu/pantry@1", "synthetic360-cpu/pantry", "synthetic360-cpu/pantry@2",
                                    "synthetic360-cpu/office@2", "synthetic360-cpu/storeroom@2", "synthetic360/office@3"]
    assert calls == [("pantry", replace(cpu, seed=1)), ("pantry", cpu), ("pantry", replace(cpu, seed=2)),
                     ("office", replace(cpu, seed=2)), ("storeroom", replace(cpu, seed=2)),
                     ("office", settings_with(**SYNTHETIC360_DEFAULTS, seed=3))]
    assert "generator seed 1" in select_scenes("synthetic360-cpu/pantry@1")[1][0].description
    # a calibration grid point's card has draws too; one whose settings set a seed of their own has none
    assert synthetic360_card("s360-x", cpu).draws == (0, 1, 2)
    seeded = synthetic360_card("s360-seed3", replace(cpu, seed=3))
    assert seeded.draws == () and seeded.scene("pantry").name == "pantry"
    with pytest.raises(DatasetError, match="has no scene draws"):
        seeded.scene("pantry@1")


@pytest.mark.parametrize("spec, message", [
    ("synthetic360-cpu/pantry@x", "is not a draw"), ("synthetic360-cpu/pantry@-1", "is not a draw"),
    ("synthetic360-cpu@x", "is not a draw"), ("synthetic/books@1", "has no scene draws"),
    ("synthetic360-cpu@1/pantry", "put the draw on the scene"), ("synthetic360-cpu/kitchen@1", "has no scene 'kitchen@1'"),
    ("synthetic@1", "has no scene draws")])
def test_bad_draws_are_clear_errors(spec, message, capsys):
    with pytest.raises(DatasetError, match=message):
        resolve_scenes([spec])
    assert cli_main(["datasets", "prepare", spec]) == 1  # the message, no traceback
    assert message.split()[-1].strip("'") in capsys.readouterr().err


def test_datasets_prepare_and_list_know_draws(monkeypatch, tmp_path, capsys):
    cpu = settings_with(**SYNTHETIC360_CPU)
    calls = []
    monkeypatch.setattr("strings_bench.datasets.synthetic.build_scene",
                        lambda scene, settings, progress=True, force=False: calls.append((scene, settings)) or tmp_path)
    monkeypatch.setattr("strings_bench.cli.datasets._stats", lambda scene_id, path, seconds: {"id": scene_id})
    monkeypatch.setattr("strings_bench.cli.datasets._format", lambda row: row["id"])
    assert cli_main(["datasets", "prepare", "synthetic360-cpu/pantry@1", "synthetic360-cpu@2"]) == 0
    assert calls == [("pantry", replace(cpu, seed=1))] + [(r, replace(cpu, seed=2)) for r in SCENE_NAMES_360]
    assert "synthetic360-cpu/office@2" in capsys.readouterr().out
    # --seed N is the same scene as @N; both at once with different seeds is refused
    assert cli_main(["datasets", "prepare", "synthetic360-cpu/pantry", "--seed", "1"]) == 0
    assert calls[-1] == ("pantry", replace(cpu, seed=1))
    assert cli_main(["datasets", "prepare", "synthetic360-cpu/pantry@1", "--seed", "2"]) == 1
    assert "already have seed 2" in capsys.readouterr().err
    monkeypatch.setattr("strings_bench.datasets.synthetic.is_built", lambda scene, settings: settings.seed == 1)
    assert cli_main(["datasets", "list"]) == 0
    out = capsys.readouterr().out
    assert "draws: registered @0, @1, @2; any N >= 0 works: synthetic360-cpu/SCENE@N" in out
    assert "synthetic360-cpu/pantry" in out and "not built (built on first use); draws cached: @1" in out


@pytest.fixture(scope="module")
def tiny_card():
    """A synthetic360 card at a tiny size (its scenes built for real, SfM included), registered as s360-tiny."""
    st = settings_with(width=96, height=72, n_views=8, min_points=50, **SYNTHETIC360_DEFAULTS)
    return register_dataset(synthetic360_card("s360-tiny", st)), st


def test_a_draw_is_another_build_of_the_room_and_its_cells_are_its_own(tiny_card, tmp_path):
    """Built for real: office@1 is the room at generator seed 1 (other words, another cache folder, its own
    scene_meta with its points on text); a run names its cells office@1 in results.csv (folder office_1), next to
    office's, and `evaluate --scene s360-tiny/office@1` resolves the same folder."""
    import runner_fakes as rf

    import strings_bench.bench.runner as runner
    from strings_bench.bench.evaluate import EvaluateOptions, _source

    card, st = tiny_card
    (zero,), (one,) = resolve_scenes(["s360-tiny/office"]), resolve_scenes(["s360-tiny/office@1"])
    assert resolve_scenes(["s360-tiny/office@0"])[0].path == zero.path != one.path
    m0, m1 = read_meta(zero.path), read_meta(one.path)
    assert (m0["settings"]["seed"], m1["settings"]["seed"]) == (0, 1) and m1["key"] == replace(st, seed=1).key("office")
    # another draw of the room: the same room plan, words (mostly the same strings) laid out elsewhere, other views
    spec0, spec1 = generate.make_spec("office", 0, st), generate.make_spec("office", 1, st)
    placed = [(w.text, w.prim, tuple(np.round(w.uv, 6).ravel())) for w in spec0.words]
    moved = sum(p != (w.text, w.prim, tuple(np.round(w.uv, 6).ravel())) for p, w in zip(placed, spec1.words))
    assert moved >= len(placed) // 4, (moved, len(placed))
    first = sorted((zero.path / "images").iterdir())[0].name
    assert not np.array_equal(np.asarray(Image.open(zero.path / "images" / first)),
                              np.asarray(Image.open(one.path / "images" / first)))
    assert m1["text_points"] > 0 and m1["text_points"] <= m1["points"]
    rf.register_fakes()
    out = tmp_path / "run"
    bench.run(["fake-a"], ["s360-tiny/office", "s360-tiny/office@1"], run_dir=out, schedule="tiny", ocr="fake",
               ocr_backend=rf.FakeOCR(), with_lpips=False, progress=False, write_report=False)
    results = list(csv.DictReader((out / "results.csv").open()))
    assert sorted({r["scene"] for r in results}) == ["office", "office@1"]
    assert (out / "cells" / "fake-a" / "s360-tiny" / "office_1").is_dir()
    rec = json.loads(next((out / "cells" / "fake-a" / "s360-tiny" / "office_1").rglob("result.json")).read_text())
    assert rec["scene"] == "office@1" and rec["config"]["scene"]["path"] == str(one.path)
    source = _source(None, EvaluateOptions(scene="s360-tiny/office@1"), tmp_path)
    assert (source.dataset, source.scene, source.scene_obj.root) == ("s360-tiny", "office@1", one.path)


# ---- calibrate ------------------------------------------------------------------------------------------------
def _calibrate():
    import strings_bench.cli.calibrate as mod

    return mod


def test_calibrate_expands_draws_for_the_dataset_and_every_grid_point(tmp_path, monkeypatch, capsys):
    cal = _calibrate()
    assert cal.expand_scenes("pantry,office", "0,1,2") == ["pantry", "office", "pantry@1", "office@1", "pantry@2",
                                                           "office@2"]
    assert cal.expand_scenes("pantry@3,office", "0,1") == ["pantry@3", "office", "office@1"]
    for scenes, draws, match in (("kitchen", "0", "unknown synthetic360 scene"), ("pantry", "0,x", "not a draw"),
                                 ("pantry@-1", "0", "not a draw")):
        with pytest.raises(StringsBenchError, match=match):
            cal.expand_scenes(scenes, draws)
    import strings_bench.bench.runner as runner

    calls = []
    monkeypatch.setattr(bench, "run", lambda methods, specs, **kw: calls.append(specs))
    (tmp_path / "run").mkdir()
    base = ["calibrate", "--regime", "cpu", "--scenes", "pantry,office", "--draws", "0,1", "--out", str(tmp_path / "run")]
    assert cli_main([*base, "--dataset", "synthetic360-cpu"]) == 0
    assert calls[-1] == ["synthetic360-cpu/pantry", "synthetic360-cpu/office", "synthetic360-cpu/pantry@1",
                         "synthetic360-cpu/office@1"]
    assert cli_main([*base, "--grid", "room_scale=0.6,1"]) == 0
    assert calls[-1] == [f"{p}/{s}" for p in ("s360-r0.6", "s360-r1") for s in ("pantry", "office", "pantry@1", "office@1")]
    assert cli_main([*base, "--grid", "seed=0,1"]) == 1  # the seed given twice
    assert "--draws 0,1,2, or a grid axis seed=0,1,2" in capsys.readouterr().err
    assert cli_main([*base[:-2], "--draws", "1,x", "--out", str(tmp_path / "run")]) == 1
    assert "is not a draw" in capsys.readouterr().err


def _row(scene, known, ocr=1.0, text_points=100.0, setting="s360-base", label="7K"):
    return {"setting": setting, "scene": scene, "label": label, "iteration": 700, "cer": ocr, "cer_known": known,
            "word_cer": 0.5, "text_nll": 2.0, "psnr": 20.0, "gaussians": 10, "train_seconds": 1.0,
            "text_points": text_points}


def test_calibrate_tables_give_the_mean_over_draws_with_the_draws_range():
    cal = _calibrate()
    # known-text CER: draw 0 pantry 0.6, office 0.8 (mean 0.7); draw 1 0.7, 0.9 (0.8); draw 2 0.5, 0.7 (0.6)
    rows = [_row(draw_name(room, d), k, text_points=tp) for d, ks, tps in
            ((0, (0.6, 0.8), (100, 300)), (1, (0.7, 0.9), (200, 400)), (2, (0.5, 0.7), (150, 250)))
            for room, k, tp in zip(("pantry", "office"), ks, tps)]
    scenes = cal.expand_scenes("pantry,office", "0,1,2")
    md = cal.tables(rows, scenes, "cer_known")
    # mean over draws 0.7, range 0.6-0.8, within 0.1 of 0.736; SfM text points: draw means 200, 300, 200
    assert ("| s360-base | 7K | 6/6 | 3 | 1.000 (1.000-1.000) | 0.700 (0.600-0.800) | 0.500 (0.500-0.500) | "
            "2.00 (2.00-2.00) | 233 (200-300) | 0.736 | yes |") in md
    # per room: pantry 0.6, 0.7, 0.5 -> 0.6 (0.5-0.7), text points 150 (100-200); office 0.8 (0.7-0.9)
    assert "| s360-base | 7K | pantry | 3 | 1.000 (1.000-1.000) | 0.600 (0.500-0.700) | 0.500 (0.500-0.500) |" in md
    assert "| 2.00 (2.00-2.00) | 150 (100-200) |" in md
    assert "| s360-base | 7K | office | 3 | 1.000 (1.000-1.000) | 0.800 (0.700-0.900) |" in md
    assert "| s360-base | office@2 | 7K | 1.000 | 0.700 |" in md and md.count("| s360-base | pantry") == 3
    # draw 2 still training (office@2 not done): every draw is averaged over pantry only, 0.6, 0.7, 0.5
    part = cal.tables(rows[:-1], scenes, "cer_known")
    assert "| s360-base | 7K | 5/6 | 3 | 1.000 (1.000-1.000) | 0.600 (0.500-0.700) |" in part
    assert "| s360-base | 7K | office | 2 | 1.000 (1.000-1.000) | 0.850 (0.800-0.900) |" in part
    # one draw: today's table, no draws column and no per-room table
    one = cal.tables(rows[:2], ["pantry", "office"], "cer_known")
    assert "| s360-base | 7K | 2/2 | 1.000 | 0.700 | 0.500 | 2.00 | 200 | 0.736 | yes |" in one and "Per room" not in one


def _cell(run: Path, dataset: str, scene: str, known: float, scene_path: Path, iteration=700, label="7K"):
    rec = {"method": "3dgs", "dataset": dataset, "scene": scene, "iteration": iteration, "label": label,
           "metrics": {"psnr": 20.0, "ssim": 0.7, "lpips": 0.3}, "timings": {"train_seconds": 60.0},
           "config": {"method": {"name": "3dgs", "settings": {}}, "scene": {"path": str(scene_path)}},
           "cer": {"cer": 1.0}, "cer_known": {"cer": known}, "gaussians": 1000}
    folder = run / "cells" / "3dgs" / dataset / scene.replace("@", "_") / str(iteration)
    folder.mkdir(parents=True)
    (folder / "result.json").write_text(json.dumps(rec))


def test_calibrate_report_reads_draws_of_a_seed_grid_and_the_text_points_of_each_scene(tmp_path):
    """A grid axis seed=0,1 (how a calibration over draws could be run before --draws) is grouped as draws of one
    setting; every row carries its scene's SfM points on text, read from the scene_meta.json the cell trained on."""
    run = tmp_path / "run"
    metas = {}
    for seed, known, text in ((0, 0.6, 120), (1, 0.9, 80)):
        metas[seed] = tmp_path / f"scene{seed}"
        metas[seed].mkdir()
        (metas[seed] / "scene_meta.json").write_text(json.dumps({"points": 1000 + seed, "text_points": text}))
        _cell(run, f"s360-seed{seed}", "pantry", known, metas[seed])
    _cell(run, "s360-seed0", "office", 0.4, tmp_path / "gone")  # its scene folder is gone: text points unknown
    args = ["calibrate", "--regime", "cpu", "--grid", "seed=0,1", "--scenes", "pantry", "--checkpoints", "7K",
            "--out", str(run), "--report-only"]
    assert cli_main(args) == 0
    md = (run / "calibration.md").read_text()
    assert "Draws (generator seeds): 0, 1" in md
    # pantry: draw 0 0.6, draw 1 0.9: mean 0.75 (0.6-0.9), text points 100 (80-120); office is not in --scenes
    assert "| s360-base | 7K | 2/2 | 2 | 1.000 (1.000-1.000) | 0.750 (0.600-0.900) |" in md and "| 100 (80-120) |" in md
    rows = list(csv.DictReader(io.StringIO((run / "calibration.csv").read_text())))
    assert [(r["setting"], r["room"], r["draw"], r["text_points"], r["sfm_points"]) for r in rows] == [
        ("s360-seed0", "pantry", "0", "120.0", "1000.0"), ("s360-seed1", "pantry", "1", "80.0", "1001.0")]
    assert cli_main([*args[:5], "seed=0", "--scenes", "pantry,office", *args[7:]]) == 0
    rows = list(csv.DictReader(io.StringIO((run / "calibration.csv").read_text())))
    assert [(r["scene"], r["text_points"]) for r in rows] == [("pantry", "120.0"), ("office", "nan")]


def test_a_named_schedule_is_one_table_entry_for_run_and_calibrate(monkeypatch, tmp_path):
    """Freezing a schedule (issue 40's `cpu-long`) is one line in core/schedules.py SCHEDULES: `run --schedule NAME`
    and `calibrate --regime NAME` (the cpu regime at its scale, its own run folder) accept it."""
    from strings_bench.cli import build_parser
    from strings_bench.core.schedules import SCHEDULES, Schedule

    cal = _calibrate()
    monkeypatch.setitem(SCHEDULES, "cpu-test", Schedule("cpu-test", 0.2, datasets=("synthetic360-cpu/storeroom",)))
    assert build_parser(["run"]).parse_args(["run", "--schedule", "cpu-test"]).schedule == "cpu-test"
    assert build_parser(["calibrate"]).parse_args(["calibrate", "--regime", "cpu-test"]).regime == "cpu-test"
    args = argparse.Namespace(regime="cpu-test", device=None, width=None, height=None, views=None, steps_scale=None,
                              grid=None, out=None, target=None, seed=0)
    cal.apply_regime(args)
    assert (args.device, args.width, args.views, args.steps_scale, args.target) == ("cpu", 320, 48, 0.2, "cer_known")
    assert args.out == "runs/calibrate-cpu-test"
    assert cal.regimes()["cpu"] == cal.REGIMES["cpu"] and cal.regimes()["paper"] == cal.REGIMES["paper"]
    # the runner gets what `--regime cpu --steps-scale 0.2` gives it: a folder started so resumes under the name
    import strings_bench.bench.runner as runner

    calls = []
    monkeypatch.setattr(bench, "run", lambda methods, specs, **kw: calls.append(kw))
    (tmp_path / "run").mkdir()
    base = ["calibrate", "--dataset", "synthetic360-cpu", "--scenes", "pantry", "--out", str(tmp_path / "run")]
    assert cli_main([*base, "--regime", "cpu-test"]) == 0 and cli_main([*base, "--regime", "cpu", "--steps-scale", "0.2"]) == 0
    assert calls[0] == calls[1] and (calls[0]["schedule"], calls[0]["steps_scale"]) == ("paper", 0.2)


def test_a_room_built_on_first_use_shows_its_bars_only_when_the_command_does(monkeypatch, tmp_path):
    """`run --no-progress` (plan: `progress_bars(False)` around resolving the scenes) reaches the scene build that a
    card's `locate(scene)` starts: the bars follow the command's switch, and the switch is restored after."""
    from strings_bench.core.progress import progress_bars, progress_shown

    calls = []
    monkeypatch.setattr("strings_bench.datasets.synthetic.build_scene",
                        lambda scene, settings, progress=True, force=False: calls.append(progress) or tmp_path)
    resolve_scenes(["synthetic360-cpu/pantry"])
    with progress_bars(False):
        resolve_scenes(["synthetic360-cpu/pantry", "synthetic/books"])
        assert not progress_shown()
    assert progress_shown() and calls == [True, False, False]
