"""The captures dataset on the real photographs in ../shared/data (fast cases; the whole builds are in
tests/datasets/test_captures_slow.py): where the data is looked for, EXIF orientation and sideways frames, PNG frames
named by timestamp with known intrinsics and a photo that does not register, the split of a sparse capture,
and the floor on GT characters below which OCR-CER is not scored."""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import numpy as np
import pytest
from PIL import Image, ImageOps

from strings_bench.core.errors import DatasetError
from strings_bench.datasets import captures

DATA = Path(os.environ.get(captures.CAPTURES_ENV, captures.DEFAULT_DATA_ROOT))
needs_data = pytest.mark.skipif(not (DATA / "bundler_et").is_dir(), reason=f"the captures' photos are not at {DATA}")


pytestmark = pytest.mark.usefixtures("private_cache")  # tests/conftest.py


# ---- where the data is --------------------------------------------------------------------------
def test_missing_data_folder_says_where_it_looked_and_how_to_point_at_it(tmp_path, monkeypatch):
    monkeypatch.setenv(captures.CAPTURES_ENV, str(tmp_path / "nowhere"))
    with pytest.raises(DatasetError) as e:
        captures.capture_source("bundler_et")
    assert str(tmp_path / "nowhere") in str(e.value) and captures.CAPTURES_ENV in e.value.hint
    (tmp_path / "some").mkdir()
    monkeypatch.setenv(captures.CAPTURES_ENV, str(tmp_path / "some"))
    with pytest.raises(DatasetError, match="bundler_et"):
        captures.capture_source("bundler_et")
    with pytest.raises(DatasetError, match="has no scene"):
        captures.capture_source("mouse_colmap")


def test_data_folder_from_the_environment_then_the_index_then_the_default(tmp_path, monkeypatch):
    from strings_bench.cli.datasets import add_local_copy

    monkeypatch.delenv(captures.CAPTURES_ENV, raising=False)
    assert captures.data_root()[0] == captures.DEFAULT_DATA_ROOT
    mine = tmp_path / "mine"
    (mine / "bundler_et").mkdir(parents=True)
    with pytest.raises(DatasetError, match="none of the captures"):
        add_local_copy("captures", tmp_path, echo=lambda s: None)
    add_local_copy("captures", mine, echo=lambda s: None)
    assert captures.data_root()[0] == mine.resolve()
    monkeypatch.setenv(captures.CAPTURES_ENV, str(tmp_path / "env"))
    assert captures.data_root()[0] == tmp_path / "env"


def test_the_card_is_registered_and_a_scene_not_built_is_reported_as_such(capsys):
    from strings_bench.cli import main

    assert main(["datasets", "list"]) == 0
    out = capsys.readouterr().out
    assert all(f"captures/{n}" in out for n in captures.CAPTURES)
    assert main(["datasets", "show", "captures/bundler_et"]) == 0
    assert "not built yet" in capsys.readouterr().out
    assert not captures.is_built("bundler_et")  # show builds nothing without --build


# ---- EXIF orientation and sideways frames ------------------------------------------------------
@needs_data
def test_exif_orientation_is_applied_before_sfm(tmp_path):
    """saharov32 stores its pixels sideways with EXIF orientation 8: the copy SfM and OCR see is upright. A
    bundler_et frame given the same treatment (pixels turned, orientation 6) comes back as it was."""
    from strings_bench.datasets.sfm import _write_upright_resized

    src = DATA / "saharov32" / "images" / "IMG_3023.JPG"
    with Image.open(src) as im:
        assert im.size == (1092, 728) and im.getexif().get(0x0112) == 8
        upright = ImageOps.exif_transpose(im).convert("RGB")
    _write_upright_resized(src, tmp_path / "a.png", 0)
    out = np.asarray(Image.open(tmp_path / "a.png"))
    assert out.shape == (1092, 728, 3) and np.array_equal(out, np.asarray(upright))

    frame = np.asarray(Image.open(DATA / "bundler_et" / "et001.jpg").convert("RGB"))
    turned = Image.fromarray(np.rot90(frame, 1))  # as a phone stores a portrait frame: pixels turned ...
    exif = Image.Exif()
    exif[0x0112] = 6  # ... and the tag that turns them back (90 degrees clockwise)
    turned.save(tmp_path / "turned.png", exif=exif)
    _write_upright_resized(tmp_path / "turned.png", tmp_path / "back.png", 0)
    assert np.array_equal(np.asarray(Image.open(tmp_path / "back.png")), frame)


@needs_data
def test_sideways_frames_are_read_by_ocr():
    """bundler_et's et000 was shot with the camera turned (pixels rotated, orientation tag 1), so its book spines
    run vertically: the default OCR also reads text turned by 90 degrees; upright-only reading finds none of it."""
    from strings_bench.eval.ocr import get_engine

    with Image.open(DATA / "bundler_et" / "et000.jpg") as im:
        assert im.getexif().get(0x0112, 1) == 1
        spine = np.asarray(im.convert("RGB"))[200:300, 0:60]  # the spine of "BYTE WARS", running vertically
    words = " ".join(w.text for w in get_engine("rapidocr").read(spine)).upper()
    assert "BYTE" in words and "WARS" in words, words
    assert not get_engine("rapidocr:rotations=[0]").read(spine)


# ---- PNG frames named by timestamp, known intrinsics, a photo that does not register -------------
@needs_data
def test_timestamp_frames_known_intrinsics_and_an_unregistered_photo(tmp_path):
    from strings_bench.datasets.sfm import prepare_scene
    from strings_bench.scene.scene import Scene

    tum = sorted((DATA / "tum_freiburg3_office").glob("*.png"))
    photos = tmp_path / "photos"
    photos.mkdir()
    for p in tum[:5]:
        shutil.copy(p, photos / p.name)
    # A photo of another capture, at the frames' size: SfM cannot place it; it is listed, not fatal.
    with Image.open(DATA / "watch_clock" / "images" / sorted(os.listdir(DATA / "watch_clock" / "images"))[0]) as im:
        ImageOps.exif_transpose(im).convert("RGB").resize((640, 480)).save(photos / "1341847999.000000.png")
    fx, fy, cx, cy = captures.CAPTURES["tum_freiburg3_office"].intrinsics
    r = prepare_scene(photos, "tum6", out=tmp_path / "scene", masks=False, register=False, progress=False,
                      echo=lambda s: None, intrinsics=(fx, fy, cx, cy), num_threads=2)
    assert r.num_photos == 6 and "1341847999.000000.png" in r.unregistered, r.summary()
    assert r.num_registered >= 4, r.summary()
    record = json.loads((tmp_path / "scene" / "prepare.json").read_text())
    assert record["unregistered"] == r.unregistered and record["intrinsics"]["refined"] is False
    scene = Scene.load(tmp_path / "scene")
    assert set(scene.names) <= {p.name for p in tum[:5]}  # the timestamps' dots survive as names
    assert scene.names == sorted(scene.names)
    for cam in scene.model.cameras:  # undistorted PINHOLE = the published calibration, kept fixed (+0.5: COLMAP)
        assert (cam.width, cam.height) == (640, 480)
        assert np.allclose([cam.fx, cam.fy, cam.cx, cam.cy], [fx, fy, cx + 0.5, cy + 0.5], atol=1e-3)


# ---- the split of a sparse capture -----------------------------------------------------------------
@needs_data
def test_a_capture_too_sparse_for_every_eighth_view_holds_out_one_in_three():
    from strings_bench.scene.scene import default_split, sparse_split

    names = sorted(p.name for p in (DATA / "bundler_et").glob("*.jpg"))
    assert len(names) == 9 and len(default_split(names)[1]) == 2  # every 8th: 2 test views, too few
    test, every = sparse_split(names)
    assert every == 3 and test == ["et000.jpg", "et003.jpg", "et006.jpg"]
    tum = sorted(p.name for p in (DATA / "tum_freiburg3_office").glob("*.png"))
    assert sparse_split(tum) == ([tum[0], tum[8], tum[16]], 8)  # 17 frames: every 8th is already 3
    assert sparse_split([f"{i:02d}.png" for i in range(5)]) == (["00.png", "03.png"], 3)  # never more than a third


def test_the_sparse_split_is_written_where_it_departs_from_every_eighth(tmp_path):
    from strings_bench.datasets.sfm import write_sparse_split
    from strings_bench.scene.colmap import read_model
    from strings_bench.scene.scene import Scene
    from tests.runner_fakes import make_scene

    root = make_scene(tmp_path, with_masks=False)  # 9 views
    names = read_model(root).names
    assert len(Scene.load(root).test_idx) == 2  # every 8th, before
    assert write_sparse_split(root)["every"] == 3
    scene = Scene.load(root)
    assert [scene.names[i] for i in scene.test_idx] == sorted(names)[::3]
    assert json.loads((root / "split.json").read_text())["test"] == sorted(names)[::3]


# ---- the floor on GT characters --------------------------------------------------------------------
def test_cer_is_not_scored_below_the_floor_on_gt_characters(tmp_path):
    from strings_bench.eval.protocol import EvalView, Evaluator
    from tests.runner_fakes import TEXT_BOX, FakeOCR

    gt = np.ones((48, 64, 3), np.float32)
    x0, y0, x1, y1 = TEXT_BOX
    gt[y0:y1, x0:x1] = 0.0  # FakeOCR reads "hello" (5 characters) on the GT
    view = EvalView("v.png", gt)
    scored = Evaluator([view], FakeOCR(), with_lpips=False, with_readability=False).evaluate("m", {"v.png": gt})
    assert scored["cer"]["cer"] == 0.0 and scored["cer"]["chars"] == 5
    for floor, cer in ((5, 0.0), (6, None)):
        ev = Evaluator([view], FakeOCR(), with_lpips=False, with_readability=False, min_gt_chars=floor)
        res = ev.evaluate("m", {"v.png": gt})["cer"]
        assert res["cer"] == cer and res["chars"] == 5
        assert ("not_scored" in res) == (cer is None)
    assert "below this scene's floor of 6" in res["not_scored"]


def test_the_floor_comes_from_the_scene_settings(tmp_path):
    from strings_bench.eval.protocol import Evaluator
    from strings_bench.scene.scene import Scene
    from tests.runner_fakes import FakeOCR, make_scene

    root = make_scene(tmp_path)
    ev = Evaluator.for_scene(Scene.load(root, settings=captures.scene_settings(captures.CAPTURES["bundler_et"])),
                             FakeOCR(), 1, with_lpips=False, with_readability=False)
    assert ev.min_gt_chars == captures.MIN_GT_CHARS
    assert Evaluator.for_scene(Scene.load(root), FakeOCR(), 1, with_lpips=False, with_readability=False).min_gt_chars is None


def test_a_run_leaves_the_cer_of_a_scene_below_its_floor_unscored_and_the_report_says_why(tmp_path, monkeypatch):
    """Through the runner: a scene card setting `min_gt_chars` above what the GT reads ("hello": 5 characters per
    test view, 2 test views) gives an empty `cer` in results.csv, `not_scored` in result.json, a note in the report."""
    import csv

    import tests.runner_fakes as rf
    from strings_bench import bench
    from strings_bench.datasets.card import DatasetCard, SceneCard
    from strings_bench.datasets import registry
    from strings_bench.datasets.registry import register_dataset
    from strings_bench.reports import write_report

    registry.list_datasets()
    monkeypatch.setattr(registry, "_REGISTRY", dict(registry._REGISTRY))  # the test's cards go with the test
    rf.register_fakes()
    path = rf.make_scene(tmp_path / "scenes")
    for floor, scored in ((10, True), (11, False)):
        register_dataset(DatasetCard(id=f"floor{floor}", title="test", scenes=[SceneCard("toy", {"min_gt_chars": floor})],
                                     locate=lambda scene, _p=path: _p))
        out = tmp_path / f"run{floor}"
        bench.run(["fake-a"], [f"floor{floor}"], run_dir=out, schedule="tiny", ocr="fake", ocr_backend=rf.FakeOCR(),
                  with_lpips=False, progress=False, write_report=False)
        rows = list(csv.DictReader((out / "results.csv").open()))
        assert rows and all((r["cer"] != "") == scored and r["cer_chars"] == "10" for r in rows), rows
        result = json.loads(next((out / "cells").rglob("result.json")).read_text())
        assert ("not_scored" in result["cer"]) == (not scored)
    from strings_bench.reports import figures

    monkeypatch.setattr(figures, "write_figures", lambda *a, **k: {})  # the note is the point, not the figures
    assert "OCR-CER is not scored on floor11/toy (its GT reads 10 characters" in write_report(out).read_text()


# ---- the engine that reads a capture's text -------------------------------------------------------------------
def test_a_scene_that_names_its_gt_engine_is_read_by_it_first():
    from strings_bench.eval.ocr import scene_engines

    assert scene_engines("rapidocr", None) == ("rapidocr", None)
    assert scene_engines("rapid", {"gt_ocr": "rapidocr"}) == ("rapidocr", None)  # aliases compare as their names
    engines, note = scene_engines("rapidocr", {"gt_ocr": "tesseract:lang=rus:upscale=3"})
    assert engines == "tesseract:lang=rus:upscale=3,rapidocr" and "rapidocr scored beside it" in note
    # a run engine of the same kind gives way to the scene's settings; the others stay, in order
    engines, note = scene_engines("gcv,tesseract:lang=eng", {"gt_ocr": "tesseract:lang=rus"})
    assert engines == "tesseract:lang=rus,gcv" and "run's --ocr: gcv,tesseract:lang=eng" in note


def test_a_run_reads_each_scene_with_its_own_gt_engine(tmp_path, monkeypatch):
    """Through plan and runner: a run with the default engine on a scene whose settings name another engine (as
    saharov32's Tesseract, Russian) evaluates that scene with the scene's engine first, the run's beside it; a scene
    without one keeps the run's engine."""
    import strings_bench.eval.ocr as ocr_mod
    import tests.runner_fakes as rf
    from strings_bench import bench
    from strings_bench.bench.plan import plan_run
    from strings_bench.datasets import registry
    from strings_bench.datasets.card import DatasetCard, SceneCard
    from strings_bench.datasets.registry import register_dataset

    registry.list_datasets()
    monkeypatch.setattr(registry, "_REGISTRY", dict(registry._REGISTRY))
    rf.register_fakes()
    path = rf.make_scene(tmp_path / "scenes")
    register_dataset(DatasetCard(id="own-engine", title="test", locate=lambda scene, _p=path: _p,
                                 scenes=[SceneCard("cyrillic", {"gt_ocr": "tesseract:lang=rus"}), SceneCard("latin", {})]))
    plan = plan_run(["fake-a"], ["own-engine"], run_dir=tmp_path / "run", schedule="tiny", ocr="rapidocr")
    assert {j.scene: j.ocr for j in plan.jobs} == {"cyrillic": ("tesseract:lang=rus", "rapidocr"), "latin": ("rapidocr",)}
    assert plan.manifest["ocr"] == "rapidocr"  # the run's own choice is what run.json records
    asked = []
    def fake_engine(spec):  # a fake reader under each engine's own name
        asked.append(spec)
        engine = rf.FakeOCR()
        engine.name = spec.partition(":")[0]
        return engine

    monkeypatch.setattr(ocr_mod, "get_engine", fake_engine)
    bench.run(["fake-a"], ["own-engine"], run_dir=tmp_path / "run", schedule="tiny", ocr="rapidocr", with_lpips=False,
              progress=False, write_report=False)
    assert sorted(asked) == ["rapidocr", "rapidocr", "tesseract:lang=rus"]  # each job's engines, one by one


# ---- the captures' comparison (tools/captures_compare.py; the claims are judged by `strings-bench verdicts`) -------------------------------
def _captures_compare():
    from _scripts import load_tool

    return load_tool("captures_compare")


def _capture_cell(run, method, scene, label, iteration, *, seed=0, cer=1.0, gaussians=1000, seconds=60.0,
                  peak_mb=None, scope="", dataset="captures"):
    """A finished cell's result.json as `strings-bench run` writes it (the fields the comparison reads)."""
    rec = {"method": method, "dataset": dataset, "scene": scene, "iteration": iteration, "label": label,
           "metrics": {"psnr": 17.0, "ssim": 0.6, "lpips": 0.5}, "timings": {"train_seconds": seconds},
           "config": {"method": {"name": method, "settings": {"seed": seed}}}, "evaluation": "full",
           "cer": {"cer": cer}, "gaussians": gaussians, "extra": {"peak_memory_scope": scope},
           **({} if peak_mb is None else {"peak_memory_mb": peak_mb})}
    folder = Path(run) / "cells" / method / dataset / scene / str(iteration)
    folder.mkdir(parents=True)
    (folder / "result.json").write_text(json.dumps(rec))


def test_the_comparison_keeps_each_cells_largest_peak_memory_over_the_folders(tmp_path):
    cc = _captures_compare()
    for seed, mb, scope in ((0, 900.5, "training"), (1, 1200.0, "training"), (2, 800.0, "")):
        d = tmp_path / f"seed{seed}"
        _capture_cell(d, "3dgs", "bundler_et", "30K", 1500, seed=seed, peak_mb=mb, scope=scope)
        _capture_cell(d, "3dgs", "storeroom", "30K", 1500, seed=seed, peak_mb=5000.0, scope="training",
                      dataset="synthetic360-cpu")
    own = [tmp_path / "seed0", tmp_path / "seed1", tmp_path / "none"]
    assert cc.peak_memory(own) == {("3dgs", "bundler_et", "30K"): (1200.0, "training")}
    # a cell written before the per-training reset (no scope) makes the figure a process peak
    assert cc.peak_memory(own + [tmp_path / "seed2"]) == {("3dgs", "bundler_et", "30K"): (1200.0, "process")}


def test_a_capture_below_the_floor_is_compared_without_a_cer_and_other_captures_keep_their_banked_rows(tmp_path,
                                                                                                      capsys):
    """Cells of a capture whose GT reads below the floor (no OCR-CER), seeds 0-1 split over folders one method each
    (as two lanes run them): its rows have no OCR-CER and both seeds; the rows of a capture compared before (already
    in --out) are kept; the tool writes no verdicts of its own (`strings-bench verdicts` judges the claims)."""
    cc = _captures_compare()
    import csv

    for seed in (0, 1):
        for label, it in (("3K", 150), ("7K", 350), ("30K", 1500)):
            _capture_cell(tmp_path / f"s{seed}-strings", "strings", "tum", label, it, seed=seed, cer=None,
                          gaussians=1000 + seed, seconds=100.0 + 50 * seed)
            _capture_cell(tmp_path / f"s{seed}-3dgs", "3dgs", "tum", label, it, seed=seed, cer=None,
                          gaussians=2000 + seed, seconds=120.0)
    out = tmp_path / "bank"
    out.mkdir()
    (out / "comparison.csv").write_text("capture,method,checkpoint,seeds,OCR-CER\nbundler_et,3dgs,30K,3,0.957\n"
                                        "tum,3dgs,30K,1,\n")
    folders = [tmp_path / f"s{s}-{m}" for s in (0, 1) for m in ("strings", "3dgs")]
    assert cc.main([*map(str, folders), "--out", str(out)]) == 0
    assert "verdicts" not in capsys.readouterr().out
    assert not (out / "verdicts.csv").exists()
    rows = list(csv.DictReader((out / "comparison.csv").open()))
    assert [(r["capture"], r["method"], r["checkpoint"]) for r in rows][:1] == [("bundler_et", "3dgs", "30K")]
    tum = [r for r in rows if r["capture"] == "tum"]
    assert len(tum) == 6 and all(r["seeds"] == "2" and r["OCR-CER"] == "" for r in tum)  # the old tum row replaced
    assert {r["Gaussians"] for r in tum if r["method"] == "strings"} == {"1000"}  # mean of 1000 and 1001, rounded
    cells = list(csv.DictReader((out / "cells.csv").open()))  # where each figure came from, a row per cell
    assert [(c["method"], c["seed"], c["checkpoint"]) for c in cells][:4] == [
        ("3dgs", "0", "3K"), ("3dgs", "0", "7K"), ("3dgs", "0", "30K"), ("3dgs", "1", "3K")]
    assert len(cells) == 12 and {c["training s"] for c in cells if c["method"] == "strings"} == {"100", "150"}
    assert all(c["source commit"] == "" and c["training CPU s"] == "" for c in cells)  # not recorded by these cells


def test_banked_cells_compare_as_their_run_folder_and_a_conflict_is_an_error(tmp_path, capsys):
    from _scripts import load_tool

    from strings_bench.core.errors import StringsBenchError
    from strings_bench.reports.compare import collect

    bank = load_tool("bank_cells")
    run = tmp_path / "runs" / "cap-tum-seed1-3dgs"
    _capture_cell(run, "3dgs", "tum", "30K", 1500, seed=1, gaussians=2001)
    _capture_cell(run, "3dgs", "tum", "7K", 350, seed=1)
    (run / "cells" / "3dgs" / "captures" / "tum" / "7K-unfinished").mkdir()  # no result.json yet: skipped
    (run / "state").mkdir()
    (run / "state" / "big.pt").write_bytes(b"x" * 1000)  # training states are not banked
    out = tmp_path / "bank"
    assert bank.main([str(run), "--out", str(out)]) == 0
    assert "2 cell(s) banked, 0 already banked" in capsys.readouterr().out
    assert collect([out / run.name], "captures") == collect([run], "captures")
    assert sorted(p.name for p in (out / run.name).rglob("*") if p.is_file()) == ["result.json", "result.json"]
    assert bank.bank(run, out) == (0, 2)  # banking again changes nothing
    cell = run / "cells" / "3dgs" / "captures" / "tum" / "1500" / "result.json"
    cell.write_text(cell.read_text().replace("2001", "2002"))
    with pytest.raises(StringsBenchError, match="banked with other content"):
        bank.bank(run, out)
    assert bank.bank(run, out, replace=True) == (1, 1)
    assert '"gaussians": 2002' in (out / run.name / cell.relative_to(run)).read_text()
    log = tmp_path / "runs" / "cap-tum-seed1-3dgs.log"  # what a shell glob over runs/cap-* also matches
    log.write_text("")
    assert bank.main([str(log), "--out", str(out)]) == 2
    assert "has no cells/ folder" in capsys.readouterr().err


_FAKE_STRINGS_BENCH = r'''
import json, sys
from pathlib import Path
args = sys.argv[1:]
with open(LOG, "a") as fh:
    fh.write(" ".join(args) + "\n")
if args[0] == "datasets":
    sys.exit(0)
opt = {args[i]: args[i + 1] for i in range(1, len(args) - 1) if args[i].startswith("--")}
method, seed = opt["--methods"], int(opt["--set"].split("=")[1])
scene = opt["--datasets"].split("/")[1]
if method == "strings-pos-lr":
    sys.exit(3)  # a run that fails
for label, it in (("3K", 150), ("7K", 350), ("30K", 1500)):
    rec = {"method": method, "dataset": "captures", "scene": scene, "iteration": it, "label": label,
           "metrics": {"psnr": 17.0}, "timings": {"train_seconds": 1.0}, "evaluation": "full", "cer": {"cer": 1.0},
           "config": {"method": {"name": method, "settings": {"seed": seed}}}, "gaussians": 10, "extra": {}}
    folder = Path(opt["--out"]) / "cells" / method / "captures" / scene / str(it)
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "result.json").write_text(json.dumps(rec))
'''


def _fake_strings_bench(tmp_path):
    """An executable stand-in for strings-bench (_FAKE_STRINGS_BENCH) and the file it logs its calls to."""
    import stat
    import sys

    calls = tmp_path / "calls.txt"
    fake = tmp_path / "fake-strings-bench"
    fake.write_text(f"#!{sys.executable}\nLOG = {str(calls)!r}\n" + _FAKE_STRINGS_BENCH)
    fake.chmod(fake.stat().st_mode | stat.S_IEXEC)
    return fake, calls


def test_captures_cells_runs_what_is_not_banked_a_few_at_a_time_and_banks_each(tmp_path, capsys, monkeypatch):
    """tools/captures_cells.py against a stand-in for strings-bench: a banked cell is skipped, a finished run
    folder is banked without a run, the capture is built once before its runs, a failed run is reported (rc 1)
    while the other cells still run and are banked; each run gets the regime's command and one thread."""
    from _scripts import load_tool

    cells = load_tool("captures_cells")
    fake, calls = _fake_strings_bench(tmp_path)
    runs, bank = tmp_path / "runs", tmp_path / "bank"
    for label, it in (("3K", 150), ("7K", 350), ("30K", 1500)):
        _capture_cell(bank / "cap-bundler_et-seed0-3dgs", "3dgs", "bundler_et", label, it)  # banked before
        _capture_cell(runs / "cap-bundler_et-seed1-3dgs", "3dgs", "bundler_et", label, it, seed=1)  # run before
    _capture_cell(runs / "cap-bundler_et-seed0-strings", "strings", "bundler_et", "3K", 150)  # interrupted
    monkeypatch.setattr(cells, "is_built", lambda name: False)
    monkeypatch.setattr(cells.time, "sleep", lambda s: None)
    argv = ["--captures", "bundler_et", "--methods", "3dgs,strings,strings-pos-lr", "--seeds", "0-1", "--lanes", "2",
            "--runs", str(runs), "--bank", str(bank), "--strings-bench", str(fake)]
    assert cells.main(argv + ["--dry-run"]) == 0
    assert capsys.readouterr().out.splitlines() == [
        "cap-bundler_et-seed0-3dgs: banked", "cap-bundler_et-seed0-strings: to run",
        "cap-bundler_et-seed0-strings-pos-lr: to run", "cap-bundler_et-seed1-3dgs: finished",
        "cap-bundler_et-seed1-strings: to run", "cap-bundler_et-seed1-strings-pos-lr: to run"]
    assert cells.main(argv) == 1  # the strings-pos-lr runs fail
    out = capsys.readouterr().out
    assert "cap-bundler_et-seed0-strings-pos-lr: FAILED (rc 3)" in out and "seed1-strings-pos-lr: FAILED" in out
    lines = calls.read_text().splitlines()
    assert lines[0] == "datasets prepare captures/bundler_et" and sum(ln.startswith("datasets") for ln in lines) == 1
    runs_made = sorted(ln for ln in lines if ln.startswith("run "))
    assert len(runs_made) == 4 and all(ln.startswith("run --schedule cpu --downscale 1 --methods ") for ln in runs_made)
    assert f"--set seed=0 --datasets captures/bundler_et --ocr rapidocr --out {runs / 'cap-bundler_et-seed0-strings'}" \
           " --no-progress" in "\n".join(runs_made)
    for name in ("cap-bundler_et-seed0-3dgs", "cap-bundler_et-seed0-strings", "cap-bundler_et-seed1-3dgs",
                 "cap-bundler_et-seed1-strings"):
        assert len(list((bank / name).rglob("result.json"))) == 3, name
    assert not (bank / "cap-bundler_et-seed0-strings-pos-lr").exists()
    assert cells.main(argv + ["--dry-run"]) == 0  # a second look: everything but the failed cells banked
    assert capsys.readouterr().out.count(": banked") == 4
    assert cells.seeds_arg("0,2-3") == [0, 2, 3]
    with pytest.raises(Exception, match="seeds are numbers"):
        cells.seeds_arg("a-b")
    assert cells.main(["--captures", "nowhere", "--dry-run"]) == 2
    assert "unknown capture(s): nowhere" in capsys.readouterr().err


def test_captures_cells_leaves_a_cell_run_by_another_process_to_it_and_counts_its_lane(tmp_path, capsys, monkeypatch):
    """A cell whose run folder another run holds (its lock) is not started again: it takes a lane until that run
    ends, then is banked if it finished, or resumed here first if it stopped before its last checkpoint."""
    import contextlib

    from _scripts import load_tool
    from strings_bench.store import run_folder_lock

    cells = load_tool("captures_cells")
    fake, calls = _fake_strings_bench(tmp_path)
    runs, bank = tmp_path / "runs", tmp_path / "bank"
    for label, it in (("3K", 150), ("7K", 350), ("30K", 1500)):
        _capture_cell(runs / "cap-bundler_et-seed0-3dgs", "3dgs", "bundler_et", label, it)  # finishing elsewhere
    _capture_cell(runs / "cap-bundler_et-seed0-strings", "strings", "bundler_et", "3K", 150)  # will stop elsewhere
    others = contextlib.ExitStack()
    for name in ("cap-bundler_et-seed0-3dgs", "cap-bundler_et-seed0-strings"):
        others.enter_context(run_folder_lock(runs / name))
    monkeypatch.setattr(cells, "is_built", lambda name: True)
    polls = []

    def sleep(seconds):  # the other runs end at the first poll
        polls.append(seconds)
        others.close()

    monkeypatch.setattr(cells.time, "sleep", sleep)
    argv = ["--captures", "bundler_et", "--methods", "3dgs,strings", "--seeds", "0-1", "--lanes", "2",
            "--runs", str(runs), "--bank", str(bank), "--strings-bench", str(fake)]
    try:
        assert cells.main(argv + ["--dry-run"]) == 0
        assert capsys.readouterr().out.splitlines()[:2] == ["cap-bundler_et-seed0-3dgs: running elsewhere",
                                                            "cap-bundler_et-seed0-strings: running elsewhere"]
        assert cells.main(argv) == 0
    finally:
        others.close()
    out = capsys.readouterr().out.splitlines()
    first_start = next(i for i, ln in enumerate(out) if ln.endswith(": started"))
    assert out[first_start - 2].startswith("cap-bundler_et-seed0-3dgs: ended in the other process; ")
    assert out[first_start - 1] == "cap-bundler_et-seed0-strings: stopped in the other process before finishing; " \
                                   "resumed here"
    assert out[first_start] == "cap-bundler_et-seed0-strings: started"  # resumed first, once both lanes were free
    runs_made = [ln for ln in calls.read_text().splitlines() if ln.startswith("run ")]
    assert len(runs_made) == 3 and not any("seed0-3dgs" in ln for ln in runs_made)
    for name in ("seed0-3dgs", "seed0-strings", "seed1-3dgs", "seed1-strings"):
        assert len(list((bank / f"cap-bundler_et-{name}").rglob("result.json"))) == 3, name


def test_cells_of_other_scenes_run_at_the_schedules_size_with_the_default_engine_in_turn(tmp_path, capsys):
    """--scenes DATASET/SCENE: the cells of a seed run its methods in turn (A, B, A, B), without the captures'
    --downscale and --ocr, in RUNS/DATASET-SCENE-seedS-M; a scene given without its dataset is refused."""
    from _scripts import load_tool

    cells = load_tool("captures_cells")
    plan = cells.plan([], ["strings", "3dgs"], [0, 1], ["synthetic360-cpu/storeroom"])
    assert [c.folder_name for c in plan] == [
        "synthetic360-cpu-storeroom-seed0-strings", "synthetic360-cpu-storeroom-seed0-3dgs",
        "synthetic360-cpu-storeroom-seed1-strings", "synthetic360-cpu-storeroom-seed1-3dgs"]
    assert plan[1].command(tmp_path, "sb") == [
        "sb", "run", "--schedule", "cpu", "--methods", "3dgs", "--set", "seed=0", "--datasets",
        "synthetic360-cpu/storeroom", "--out", str(tmp_path / "synthetic360-cpu-storeroom-seed0-3dgs"), "--no-progress"]
    with pytest.raises(Exception, match="--scenes takes DATASET/SCENE"):
        cells.plan([], ["3dgs"], [0], ["storeroom"])
    with pytest.raises(SystemExit):
        cells.main(["--dry-run"])  # neither --captures nor --scenes
    assert "give --captures, --scenes or both" in capsys.readouterr().err
