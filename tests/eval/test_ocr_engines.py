"""A second OCR opinion: `run --ocr rapidocr,tesseract`, per-engine CER, the engines' agreement, resume."""

from __future__ import annotations

import strings_bench.bench as bench
from strings_bench.bench.plan import plan_run
from strings_bench.store import check_manifest

import json
import math
import shutil

import numpy as np
import pandas as pd
import pytest
from PIL import Image

import runner_fakes as rf
import strings_bench.bench.runner as runner
from strings_bench.reports.ocr_agreement import ocr_agreement
from strings_bench.reports.table_model import to_csv, to_markdown
from strings_bench.reports.tables import build_tables
from strings_bench.store import iter_cells
from strings_bench.core.errors import OCRError, StringsBenchError
from strings_bench.core.io import atomic_write_json
from strings_bench.core.method import CheckpointResult, MethodAdapter
from strings_bench.eval.cer import word_agreement
from strings_bench.eval.ocr import Word, parse_engines
from strings_bench.eval.ocr.sample import render_lines
from strings_bench.methods.registry import MethodSpec, register_method
from strings_bench.scene.camera import Camera
from strings_bench.scene.colmap import ColmapModel, write_model

needs_tesseract = pytest.mark.skipif(
    shutil.which("tesseract") is None,
    reason="tesseract is not installed (scripts/system_deps.sh installs Debian's tesseract-ocr where apt and root allow)")


# --------------------------------------------------------------------------- the --ocr list
def test_parse_engines():
    assert parse_engines("rapidocr") == ["rapidocr"]
    assert parse_engines("rapid, tess") == ["rapidocr", "tesseract"]
    assert parse_engines("tesseract,rapidocr") == ["tesseract", "rapidocr"]  # the order picks the primary
    with pytest.raises(OCRError, match="unknown OCR backend 'tesserct'"):
        parse_engines("rapidocr,tesserct")
    with pytest.raises(OCRError, match="named twice"):
        parse_engines("rapidocr,rapid")
    with pytest.raises(OCRError, match="no OCR engine"):
        parse_engines(" , ")
    assert parse_engines("rapidocr,fake", strict=False) == ["rapidocr", "fake"]


def test_resume_notices_a_changed_ocr_list(tmp_path):
    scene = rf.make_scene(tmp_path)
    run_dir = tmp_path / "run"
    plan = plan_run(["3dgs"], [str(scene)], run_dir=run_dir, schedule="tiny", ocr="rapid,tess")
    assert plan.manifest["ocr"] == "rapidocr,tesseract" and plan.jobs[0].ocr == ("rapidocr", "tesseract")
    atomic_write_json(run_dir / "run.json", plan.manifest)
    same = plan_run(["3dgs"], [str(scene)], run_dir=run_dir, schedule="tiny", ocr="rapidocr,tesseract")
    check_manifest(run_dir, same.manifest)  # the same list, spelt otherwise: resumes
    for other in ("rapidocr", "tesseract,rapidocr", "rapidocr,tesseract,gcv"):
        changed = plan_run(["3dgs"], [str(scene)], run_dir=run_dir, schedule="tiny", ocr=other)
        with pytest.raises(StringsBenchError, match="--ocr engine list 'rapidocr,tesseract'"):
            check_manifest(run_dir, changed.manifest)


def test_run_refuses_an_unknown_engine_before_training(tmp_path):
    with pytest.raises(OCRError, match="unknown OCR backend 'nope'"):
        bench.run(["3dgs"], [str(rf.make_scene(tmp_path))], run_dir=tmp_path / "run", schedule="tiny", ocr="rapidocr,nope")
    assert not (tmp_path / "run").exists()


# --------------------------------------------------------------------------- word agreement
def test_word_agreement_hand_computed():
    a = [Word.from_box("Hello", 0, 0, 50, 20), Word.from_box("World", 60, 0, 110, 20),
         Word.from_box("foo", 0, 40, 30, 60), Word.from_box("New York", 0, 80, 100, 100)]
    b = [Word.from_box("hello", 1, 1, 50, 20),  # same word (the paper profile lowercases)
         Word.from_box("W0rld", 60, 0, 110, 20),  # one character off
         Word.from_box("bar", 200, 200, 230, 220),  # read by b only
         Word.from_box("New", 0, 80, 45, 100), Word.from_box("York", 55, 80, 100, 100)]  # a's line, word by word
    agree = word_agreement(a, b)
    # regions: hello (same), world (differs), foo (a only), bar (b only), new york (same): 2 of 5
    assert (agree.words, agree.identical, agree.only_a, agree.only_b) == (5, 2, 1, 1)
    assert agree.share == pytest.approx(0.4)
    assert word_agreement(a, a).share == 1.0
    assert math.isnan(word_agreement([], []).share)
    # IoU below 0.1 joins nothing: "Hello" shifted by 46 px overlaps a's Hello by 4 px (IoU 4/96)
    far = word_agreement([Word.from_box("Hello", 0, 0, 50, 20)], [Word.from_box("Hello", 46, 0, 96, 20)])
    assert (far.words, far.identical, far.only_a, far.only_b) == (2, 0, 1, 1)


def _rows(groups):
    rows = []
    for (scene, label), methods in groups.items():
        for m, (c1, c2, words, same, gt_words, gt_same) in methods.items():
            rows.append({"method": m, "dataset": "synthetic", "scene": scene, "label": label, "iteration": 5,
                         "cer": c1, "cer_tesseract": c2, "agree_words_tesseract": words, "agree_identical_tesseract": same,
                         "agree_gt_words_tesseract": gt_words, "agree_gt_identical_tesseract": gt_same,
                         "ocr_backend": "rapidocr", "cer_known": math.nan, "psnr": 20.0, "ssim": 0.5, "lpips": math.nan,
                         "gaussians": 100, "train_seconds": 1.0, "total_seconds": 1.0, "ocr_failed": 0})
    return pd.DataFrame(rows)


def test_ocr_agreement_against_hand_computed_values():
    df = _rows({
        # ranks (1,2,3,4) against (2,1,4,3): sum d^2 = 4, rho = 1 - 6*4/(4*15) = 0.6
        ("books", "7K"): {"a": (0.1, 0.2, 4, 2, 8, 6), "b": (0.2, 0.1, 6, 3, 8, 6),
                          "c": (0.3, 0.4, 0, 0, 8, 6), "d": (0.4, 0.3, 10, 5, 8, 6)},
        # a tie: ranks (1,2,3,4) against (1.5,1.5,3,4): Pearson of the ranks = 4.5 / sqrt(5 * 4.5) = 3 / sqrt(10)
        ("globe", "7K"): {"a": (0.1, 0.1, 1, 1, 2, 0), "b": (0.2, 0.1, 1, 0, 2, 0),
                          "c": (0.3, 0.3, 1, 1, 2, 0), "d": (0.4, 0.4, 1, 1, 2, 0)},
        # the other engine gives every method the same CER: no ranking to compare
        ("shelf", "7K"): {"a": (0.1, 1.0, 2, 0, 0, 0), "b": (0.5, 1.0, 2, 0, 0, 0)},
        # one method has no CER of the primary (nothing scored): left out of the correlation
        ("chemicals", "7K"): {"a": (0.1, 0.5, 2, 1, 4, 1), "b": (0.3, 0.2, 2, 1, 4, 1), "c": (math.nan, 0.9, 2, 1, 4, 1)},
    })
    agree = ocr_agreement(df).set_index("scene")
    assert agree.loc["books", "spearman"] == pytest.approx(0.6)
    assert agree.loc["books", "methods"] == 4
    assert agree.loc["books", "share"] == pytest.approx(10 / 20)  # (2+3+0+5) / (4+6+0+10)
    assert agree.loc["books", "gt_share"] == pytest.approx(6 / 8)
    assert agree.loc["globe", "spearman"] == pytest.approx(3 / math.sqrt(10))
    assert agree.loc["globe", "gt_share"] == 0.0
    assert math.isnan(agree.loc["shelf", "spearman"])
    assert math.isnan(agree.loc["shelf", "gt_share"])  # neither engine read a GT word
    assert agree.loc["chemicals", "methods"] == 2
    assert agree.loc["chemicals", "spearman"] == pytest.approx(-1.0)  # (0.1, 0.3) against (0.5, 0.2)

    tables = {t.name: t for t in build_tables(df, {"ocr": "rapidocr,tesseract"})}
    md = to_markdown(tables["ocr_agreement"])
    assert "| synthetic/books @7K | 0.60 | 4 | 0.500 | 0.750 |" in md
    assert "| synthetic/shelf @7K | n/a | 2 | 0.000 | n/a |" in md
    assert to_csv(tables["ocr_agreement"]).splitlines()[0].startswith("cell_group,rapidocr vs tesseract Spearman rho")
    by_engine = tables["ocr_cer_by_engine"]
    assert [c.sub_plain for c in by_engine.columns] == ["7K rapidocr", "7K tesseract"]
    # dataset means over the four scenes, per method: a = (0.1+0.1+0.1+0.1)/4 with the primary
    assert by_engine.columns[0].values["a"] == pytest.approx(0.1)
    assert by_engine.columns[1].values["a"] == pytest.approx((0.2 + 0.1 + 1.0 + 0.5) / 4)


def test_single_engine_run_has_no_engine_tables():
    df = _rows({("books", "7K"): {"a": (0.1, 0.2, 4, 2, 8, 6)}}).drop(
        columns=[c for c in ["cer_tesseract", "agree_words_tesseract", "agree_identical_tesseract",
                             "agree_gt_words_tesseract", "agree_gt_identical_tesseract"]])
    names = {t.name for t in build_tables(df)}
    assert "ocr_cer" in names and not names & {"ocr_cer_by_engine", "ocr_agreement"}


# --------------------------------------------------------------------------- GT OCR per engine
class Counting:
    """An OCR engine double that counts its reads and reads a fixed word."""

    def __init__(self, name, text):
        self.name, self.text, self.calls = name, text, 0

    def describe(self):
        return {"name": self.name, "version": "1", "settings": {}}

    def read(self, image, mask=None):
        self.calls += 1
        return [Word.from_box(self.text, *rf.TEXT_BOX)]


def test_gt_ocr_is_read_once_per_engine(tmp_path):
    from strings_bench.eval.protocol import Evaluator
    from strings_bench.scene.scene import Scene

    scene = Scene.load(rf.make_scene(tmp_path))
    one, two = Counting("one", "hello"), Counting("two", "hallo")
    ev = Evaluator.for_scene(scene, [one, two], 1.0, with_lpips=False)
    name = ev.names[0]
    assert [w.text for w in ev.gt_words(name)] == ["hello"]
    assert [w.text for w in ev.gt_words(name, two)] == ["hallo"]
    ev.gt_words(name), ev.gt_words(name, two)
    assert (one.calls, two.calls) == (1, 1)
    with pytest.raises(StringsBenchError, match="twice"):
        Evaluator.for_scene(scene, [one, Counting("one", "x")], 1.0)


# --------------------------------------------------------------------------- real engines, end to end
TEXT_W, TEXT_H = 240, 96


def _text_scene(root):
    """9 views of two words (views 0 and 8 are the test views), cameras on a line, a few points."""
    scene = root / "signs"
    (scene / "images").mkdir(parents=True)
    cams = []
    for v in range(9):
        img, _ = render_lines([["OPEN", "42"]], font_size=36, size=(TEXT_W, TEXT_H))
        Image.fromarray(img).save(scene / "images" / f"view_{v:02d}.png")
        cams.append(Camera(200.0, 200.0, TEXT_W / 2, TEXT_H / 2, TEXT_W, TEXT_H, np.eye(3),
                           np.array([0.1 * v, 0.0, 4.0]), f"view_{v:02d}.png"))
    rng = np.random.default_rng(0)
    model = ColmapModel(cams, rng.normal(0, 0.3, (20, 3)), np.full((20, 3), 128, np.uint8),
                        np.arange(0, 41, 2, dtype=np.int64), np.array([0, 1] * 20, np.int32),
                        np.tile([[TEXT_W / 2, TEXT_H / 2]], (40, 1)), np.arange(1, 21, dtype=np.int64))
    write_model(model, scene / "sparse" / "0")
    return scene


def _number_left_edge() -> int:
    _, words = render_lines([["OPEN", "42"]], font_size=36, size=(TEXT_W, TEXT_H))
    return int(words[1].polygon[:, 0].min()) - 2


class CopyViews(MethodAdapter):
    """Renders = the ground-truth views; with `erase`, the number painted over with the white background."""

    def train(self, scene, checkpoints, downscale=1):
        for it in checkpoints:
            renders = {}
            for i in scene.test_idx:
                r = scene.load_image(i, downscale).copy()
                if self.settings.get("erase"):
                    r[:, _number_left_edge():] = 1.0
                renders[scene.names[i]] = r
            yield CheckpointResult(iteration=it, renders=renders, train_seconds=1.0, gaussians=-1)


@needs_tesseract
def test_two_real_engines_end_to_end(tmp_path, monkeypatch):
    from strings_bench.datasets import registry
    from strings_bench.datasets.card import DatasetCard, SceneCard

    register_method(MethodSpec(name="copy-views", implementation=CopyViews, description="the GT views"))
    register_method(MethodSpec(name="erase-number", implementation=lambda **s: CopyViews(erase=True, **s),
                               description="the GT views without the number"))
    scene = _text_scene(tmp_path)
    # Its GT reads 12 characters, under the floor of a scene without known text (eval/floors.py): scored here all
    # the same, as a card may say, since the test is of the engines, not of the CER's weight.
    registry.list_datasets()
    monkeypatch.setattr(registry, "_REGISTRY", dict(registry._REGISTRY))
    registry.register_dataset(DatasetCard(id="signs", title="test", scenes=[SceneCard("signs", {"min_gt_chars": 1})],
                                          locate=lambda name, _p=scene: _p))
    out = bench.run(["copy-views", "erase-number"], ["signs"], run_dir=tmp_path / "run", schedule="tiny", ocr="rapidocr,tesseract",
                     with_lpips=False, progress=False, checkpoints=[1000])
    cells = {c["method"]: c for c in iter_cells(out)}
    for c in cells.values():
        assert c["ocr"]["backend"]["name"] == "rapidocr"
        second = c["ocr_engines"]["tesseract"]
        assert second["backend"]["name"] == "tesseract" and set(second["views"]) == {"view_00.png", "view_08.png"}
        for view in second["views"].values():
            assert [w["text"].lower() for w in view["gt_words"]] == ["open", "42"]  # Tesseract reads the GT
            assert view["gt_error"] is None and view["render_error"] is None
    copy, erased = cells["copy-views"], cells["erase-number"]
    # The renders are the GT views: each engine reads them as it reads the GT, and the engines agree on the
    # renders exactly as on the GT views.
    assert copy["cer"]["cer"] == 0.0 and copy["ocr_engines"]["tesseract"]["cer"]["cer"] == 0.0
    assert copy["ocr_engines"]["tesseract"]["agreement"]["renders"] == copy["ocr_engines"]["tesseract"]["agreement"]["gt"]
    # Erasing "42" costs Tesseract, which read exactly OPEN and 42 on the GT, 2 of 6 characters per view;
    # RapidOCR loses at least as much (it may also read a stray glyph on the GT).
    assert erased["ocr_engines"]["tesseract"]["cer"]["cer"] == pytest.approx(2 / 6)
    assert erased["cer"]["cer"] >= 2 / 7
    gt_agree = copy["ocr_engines"]["tesseract"]["agreement"]["gt"]
    rapid_gt = copy["ocr"]["views"]["view_00.png"]["gt_words"]
    expected = word_agreement(rapid_gt, second["views"]["view_00.png"]["gt_words"])
    assert gt_agree["words"] == 2 * expected.words and gt_agree["identical"] == 2 * expected.identical

    csv = pd.read_csv(out / "results.csv").set_index("method")
    assert csv.loc["erase-number", "cer_tesseract"] == pytest.approx(2 / 6)
    assert csv.loc["copy-views", "agree_gt_words_tesseract"] == gt_agree["words"]
    agreement = pd.read_csv(out / "report" / "tables" / "ocr_agreement.csv")
    assert agreement.iloc[0, 0] == "signs/signs @1K"  # one cell group: the run's dataset/scene @label
    assert agreement["rapidocr vs tesseract Spearman rho"].iloc[0] == pytest.approx(1.0)  # both rank copy < erased
    assert "ocr_agreement" in (out / "report" / "report.md").read_text()
    run_json = json.loads((out / "run.json").read_text())
    assert run_json["ocr"] == "rapidocr,tesseract"
