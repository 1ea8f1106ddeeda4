"""`strings-bench evaluate` and the evaluation protocol: each layout scored against an independent
computation, run and evaluate agreeing to the last digit, the release's masks, bad input, nerfbaselines."""

from __future__ import annotations

import strings_bench.bench as bench

import csv
import json
import math
import shutil
import subprocess
import sys
import tarfile
import zipfile
from pathlib import Path

import numpy as np
import pytest
from PIL import Image, ImageDraw, ImageFont

import runner_fakes as rf
import strings_bench.bench.runner as runner
from strings_bench.bench.evaluate import EvaluateOptions, PredictionsError, detect_layout, evaluate
from strings_bench.core.errors import StringsBenchError
from tests.eval.test_cer import ref_image_cer

WORDS = ["HELLO", "ATLAS", "OPTICS"]
TW, TH = 240, 96


def _quiet(*a, **k):
    pass


def _text_image(word: str, second: str | None = None) -> np.ndarray:
    """A light card with `word` in large dark letters (and `second` on the right half)."""
    im = Image.new("RGB", (TW * (2 if second else 1), TH), (235, 235, 225))
    d = ImageDraw.Draw(im)
    font = ImageFont.load_default(size=34)
    d.text((14, 26), word, font=font, fill=(20, 20, 20))
    if second:
        d.text((TW + 14, 26), second, font=font, fill=(20, 20, 20))
    return np.asarray(im)


def _save(path: Path, img: np.ndarray) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(img).save(path)
    return path


def _blur(img: np.ndarray, sigma: float) -> np.ndarray:
    from scipy.ndimage import gaussian_filter

    return np.clip(gaussian_filter(img.astype(np.float64), sigma=(sigma, sigma, 0)) + 0.5, 0, 255).astype(np.uint8)


def _rows(out: Path) -> list[dict]:
    with open(out / "results.csv", newline="") as f:
        return list(csv.DictReader(f))


def _cells(out: Path) -> list[dict]:
    return [json.loads(p.read_text()) for p in sorted((out / "cells").glob("*/*/*/*/result.json"))]


def _independent(cell: dict, gt_files: dict, render_files: dict) -> tuple[float, dict]:
    """OCR-CER from the words the cell recorded, by the test's own implementation of the authors' rules
    (test_cer.ref_image_cer), and PSNR per view from the files, paired by name here."""
    from skimage.metrics import peak_signal_noise_ratio

    errors = chars = 0
    for name, v in cell["ocr"]["views"].items():
        gt = [(w["text"], w["polygon"]) for w in v["gt_words"]]
        if not gt:
            continue  # images whose GT OCR reads nothing are left out (docs/sources.md §3)
        pred = [(w["text"], w["polygon"]) for w in (v["render_words"] or [])]
        e, c = ref_image_cer(gt, pred)
        errors, chars = errors + e, chars + c
    psnr = {n: peak_signal_noise_ratio(np.asarray(Image.open(gt_files[n]).convert("RGB")),
                                       np.asarray(Image.open(render_files[n]).convert("RGB")), data_range=255)
            for n in render_files}
    return errors / chars, psnr


@pytest.fixture(scope="module")
def ocr():
    """RapidOCR reading each image upright only: these tests are about layouts, masks and CER bookkeeping, and the
    turned reads (the default's 90 and 270 degrees, tests/eval/test_ocr_rotation.py) would triple their OCR time.
    The test against `nerfbaselines evaluate` uses the default settings, as that command does."""
    from strings_bench.eval.ocr import get_backend

    return get_backend("rapidocr", rotations=[0])


# --------------------------------------------------------------------------- layouts, real OCR
def test_plain_folder_with_gt_dir(tmp_path, ocr):
    gt_dir, pred = tmp_path / "gt", tmp_path / "renders"
    gts = {f"view_{i}.png": _text_image(w) for i, w in enumerate(WORDS)}
    renders = {"view_0.png": gts["view_0.png"], "view_1.png": _blur(gts["view_1.png"], 1.2),
               "view_2.png": np.full_like(gts["view_2.png"], 128)}
    gt_files = {n: _save(gt_dir / n, g) for n, g in gts.items()}
    render_files = {n: _save(pred / n.replace(".png", ".jpg") if n == "view_1.png" else pred / n, r)
                    for n, r in renders.items()}  # a .jpg render matches its view by stem
    said = []
    out = evaluate(pred, EvaluateOptions(min_gt_chars=0, gt=gt_dir, out=tmp_path / "ev", ocr=ocr, with_lpips=False, report=False),
                   say=said.append)
    assert said[0].startswith("layout: folder")
    (cell,) = _cells(out)
    cer, psnr = _independent(cell, gt_files, render_files)
    assert cell["cer"]["cer"] == pytest.approx(cer, abs=1e-12)
    assert cell["ocr"]["views"]["view_2.png"]["render_words"] == []  # flat gray reads nothing
    assert math.isinf(psnr["view_0.png"]) and cell["metrics"]["per_view"]["view_0.png"]["psnr"] == "inf"  # JSON's inf
    for n in ("view_1.png", "view_2.png"):
        # rel 1e-7: the suite holds the 8-bit values as float32 k/255, skimage the integers in float64
        assert cell["metrics"]["per_view"][n]["psnr"] == pytest.approx(psnr[n], rel=1e-7)
    row = _rows(out)[0]
    assert row["cer_known"] == "" and row["train_seconds"] == "" and row["gaussians"] == ""  # n/a, never 0
    assert float(row["cer"]) == pytest.approx(cer, abs=1e-12)


def test_a_gt_folder_with_too_little_text_warns_and_leaves_the_cer_empty(tmp_path, ocr, caplog):
    """Images without known text get the GT floor (50 characters) by default, as a run on a user's own photos does:
    the cell keeps its characters and errors, its CER is empty with the reason, and the log warns once;
    --min-gt-chars 0 keeps the CER; a negative floor is refused."""
    gt_dir, pred = tmp_path / "gt", tmp_path / "renders"
    for i, w in enumerate(WORDS):
        _save(gt_dir / f"view_{i}.png", _text_image(w))
        _save(pred / f"view_{i}.png", _text_image(w))
    with caplog.at_level("WARNING"):
        out = evaluate(pred, EvaluateOptions(gt=gt_dir, out=tmp_path / "ev", ocr=ocr, with_lpips=False, report=False),
                       say=_quiet)
    (cell,) = _cells(out)
    chars = cell["cer"]["chars"]
    assert 0 < chars < 50 and cell["cer"]["cer"] is None and "below this scene's floor of 50" in cell["cer"]["not_scored"]
    assert _rows(out)[0]["cer"] == ""
    assert sum("OCR-CER not scored" in r.getMessage() for r in caplog.records) == 1
    kept = evaluate(pred, EvaluateOptions(min_gt_chars=0, gt=gt_dir, out=tmp_path / "ev0", ocr=ocr, with_lpips=False,
                                          report=False), say=_quiet)
    (cell0,) = _cells(kept)
    assert cell0["cer"]["chars"] == chars and cell0["cer"]["cer"] is not None
    with pytest.raises(PredictionsError, match="min_gt_chars must be 0"):
        evaluate(pred, EvaluateOptions(min_gt_chars=-1, gt=gt_dir, out=tmp_path / "evn", ocr=ocr, with_lpips=False,
                                       report=False), say=_quiet)


def test_gt_as_renders_reads_like_gt_and_gray_reads_nothing(tmp_path, ocr):
    gt_dir = tmp_path / "gt"
    for i, w in enumerate(WORDS):
        _save(gt_dir / f"v{i}.png", _text_image(w))
    gray = tmp_path / "gray"
    for i in range(len(WORDS)):
        _save(gray / f"v{i}.png", np.full((TH, TW, 3), 128, np.uint8))
    same = evaluate(gt_dir, EvaluateOptions(min_gt_chars=0, gt=gt_dir, out=tmp_path / "same", ocr=ocr, with_lpips=False, report=False),
                    say=_quiet)
    (cell,) = _cells(same)
    assert cell["cer"]["chars"] >= 12 and cell["cer"]["cer"] == 0.0
    rd = cell["readability"]
    assert rd["render"]["word_cer"] == pytest.approx(rd["gt"]["word_cer"], abs=1e-12)  # the GT ceiling
    # evaluate writes the cell's words.csv too; its sums are the cell's word-crop figures (issue 30)
    from strings_bench.store import WORDS_FILE, read_words_csv, words_summary

    (words_csv,) = sorted((tmp_path / "same" / "cells").glob(f"*/*/*/*/{WORDS_FILE}"))
    rows = read_words_csv(words_csv)
    assert len(rows) == rd["render"]["words"] + sum(not w["headline"] for v in rd["views"].values() for w in v)
    for side in ("render", "gt"):
        assert words_summary(rows, side)["word_cer"] == rd[side]["word_cer"]
        assert words_summary(rows, side)["text_nll"] == rd[side]["text_nll"]
    gray_out = evaluate(gray, EvaluateOptions(min_gt_chars=0, gt=gt_dir, out=tmp_path / "grayout", ocr=ocr, with_lpips=False,
                                              report=False), say=_quiet)
    (cell,) = _cells(gray_out)
    assert cell["cer"]["cer"] == 1.0


def _inria_model(root: Path, masked: bool = True) -> tuple[Path, dict]:
    """MODEL/test/ours_3000 (gray renders) and ours_7000 (renders = GT), index-named like 3DGS' render.py; each
    GT card has a second word outside the mask (masks/ as the STRinGS release's render.py writes them)."""
    model = root / "my_model"
    gts = [_text_image(w, second="WORLD") for w in WORDS]
    for n, renders in ((3000, [np.full_like(g, 128) for g in gts]), (7000, gts)):
        base = model / "test" / f"ours_{n}"
        for i, (g, r) in enumerate(zip(gts, renders)):
            _save(base / "gt" / f"{i:05d}.png", g)
            _save(base / "renders" / f"{i:05d}.png", r)
            if masked:
                m = np.zeros(g.shape[:2], np.uint8)
                m[:, :TW] = 200  # > 127: the left word only
                _save(base / "masks" / f"{i:05d}.png", m)
        (model / "train" / f"ours_{n}" / "renders").mkdir(parents=True)  # train renders are not evaluated
    return model, {i: g for i, g in enumerate(gts)}


def test_inria_layout_with_release_masks(tmp_path, ocr):
    model, _ = _inria_model(tmp_path)
    said = []
    out = evaluate(model, EvaluateOptions(min_gt_chars=0, out=tmp_path / "ev", ocr=ocr, with_lpips=False, report=False), say=said.append)
    assert said[0] == "layout: inria (2 checkpoint(s): 3000, 7000)"
    cells = {c["iteration"]: c for c in _cells(out)}
    assert set(cells) == {3000, 7000} and cells[7000]["label"] == "7K" and cells[7000]["method"] == "my_model"
    for c in cells.values():
        for v in c["ocr"]["views"].values():
            texts = "".join(w["text"] for w in v["gt_words"]).upper()
            assert "WORLD" not in texts  # image x (mask > 127): the word outside the mask is never read
            assert v["mask"].startswith("given mask")
    assert cells[7000]["cer"]["cer"] == 0.0 and cells[3000]["cer"]["cer"] == 1.0
    base = model / "test" / "ours_7000"
    files = {f"{i:05d}.png": base / "gt" / f"{i:05d}.png" for i in range(3)}
    cer, _ = _independent(cells[3000], files, {k: model / "test/ours_3000/renders" / k for k in files})
    assert cells[3000]["cer"]["cer"] == pytest.approx(cer, abs=1e-12)
    # without masks/ the whole image is read, and the right-hand word is found
    model2, _ = _inria_model(tmp_path / "nomask", masked=False)
    out2 = evaluate(model2 / "test" / "ours_7000", EvaluateOptions(min_gt_chars=0, out=tmp_path / "ev2", ocr=ocr, with_lpips=False,
                                                                   report=False), say=_quiet)
    (c2,) = _cells(out2)
    assert c2["method"] == "my_model"
    assert any("WORLD" in "".join(w["text"] for w in v["gt_words"]).upper() for v in c2["ocr"]["views"].values())


def _nerfbaselines_predictions(path: Path, with_masks: bool = False) -> dict:
    """Predictions written by nerfbaselines' own save_predictions (folder, or .tar.gz when the path says so)."""
    nb = pytest.importorskip("nerfbaselines", reason="nerfbaselines is a test extra (scripts/bootstrap.sh --test)")
    from nerfbaselines.io import save_predictions

    gts = [_text_image(w) for w in WORDS]
    n = len(gts)
    cams = nb.new_cameras(poses=np.tile(np.eye(4, dtype=np.float32)[:3][None], (n, 1, 1)),
                          intrinsics=np.tile(np.array([100, 100, TW / 2, TH / 2], np.float32), (n, 1)),
                          camera_models=np.zeros(n, np.int32), image_sizes=np.tile(np.array([TW, TH], np.int32), (n, 1)))
    masks = None
    if with_masks:
        masks = [np.ones((TH, TW), bool) for _ in range(n)]
    ds = nb.new_dataset(cameras=cams, image_paths=[f"/data/images/frame_{i}.png" for i in range(n)],
                        image_paths_root="/data/images", images=gts, masks=masks,
                        metadata={"color_space": "srgb", "evaluation_protocol": "strings-ocr"})
    preds = [{"color": gts[0]}, {"color": _blur(gts[1], 1.0)}, {"color": np.full_like(gts[2], 128)}]
    save_predictions(str(path), preds, ds, nb_info={"method": "nb-toy", "evaluation_protocol": "strings-ocr"})
    return {f"frame_{i}.png": g for i, g in enumerate(gts)}


def test_nerfbaselines_folder_tar_and_zip_agree(tmp_path, ocr):
    folder = tmp_path / "pred"
    _nerfbaselines_predictions(folder)
    _nerfbaselines_predictions(tmp_path / "pred.tar.gz")
    with zipfile.ZipFile(tmp_path / "pred.zip", "w") as zf:
        for p in sorted(folder.rglob("*")):
            if p.is_file():
                zf.write(p, Path("pred") / p.relative_to(folder))  # an archive of the folder
    results = []
    for i, src in enumerate((folder, tmp_path / "pred.tar.gz", tmp_path / "pred.zip")):
        said = []
        out = evaluate(src, EvaluateOptions(min_gt_chars=0, out=tmp_path / f"ev{i}", ocr=ocr, with_lpips=False, report=False),
                       say=said.append)
        assert said[0].startswith("layout: nerfbaselines")
        (cell,) = _cells(out)
        assert cell["method"] == "nb-toy"
        results.append(cell)
    files = {n: folder / "gt-color" / n for n in results[0]["ocr"]["views"]}
    cer, psnr = _independent(results[0], files, {n: folder / "color" / n for n in files})
    for cell in results:
        assert cell["cer"] == results[0]["cer"] and cell["metrics"]["psnr"] == results[0]["metrics"]["psnr"]
        assert cell["cer"]["cer"] == pytest.approx(cer, abs=1e-12)
    assert results[0]["metrics"]["per_view"]["frame_1.png"]["psnr"] == pytest.approx(psnr["frame_1.png"], rel=1e-7)


def test_nerfbaselines_evaluate_reports_ocr_cer_through_its_entry_points(tmp_path):
    """`nerfbaselines evaluate` itself, with the strings-ocr protocol found through the entry points."""
    from strings_bench.eval.ocr import get_backend

    pred = tmp_path / "pred"
    _nerfbaselines_predictions(pred, with_masks=True)
    from nerfbaselines.evaluation import build_evaluation_protocol
    from nerfbaselines.evaluation import evaluate as nb_evaluate

    out = nb_evaluate(str(pred), str(tmp_path / "nb.json"), evaluation_protocol=build_evaluation_protocol("strings-ocr"))
    ours = evaluate(pred, EvaluateOptions(min_gt_chars=0, out=tmp_path / "ev", ocr=get_backend("rapidocr"), with_lpips=False,
                                          report=False), say=_quiet)  # the protocol's settings: the default ones
    (cell,) = _cells(ours)
    m = out["metrics"]
    assert m["ocr_cer_chars"] == cell["cer"]["chars"] and m["ocr_cer_errors"] == cell["cer"]["errors"]
    assert m["ocr_cer"] == pytest.approx(cell["cer"]["cer"], abs=1e-12) and 0 < m["ocr_cer"] < 1.5
    # the command line, in a fresh interpreter: info.json names the protocol, nothing is overridden
    proc = subprocess.run([sys.executable, "-m", "nerfbaselines", "evaluate", str(pred), "-o", str(tmp_path / "cli.json")],
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-2000:]
    cli = json.loads((tmp_path / "cli.json").read_text())["metrics"]
    assert cli["ocr_cer"] == pytest.approx(m["ocr_cer"], abs=1e-12)


# --------------------------------------------------------------------------- run and evaluate agree
@pytest.fixture(scope="module")
def toy_run(tmp_path_factory):
    rf.register_fakes()
    root = tmp_path_factory.mktemp("agree")
    scene = rf.make_scene(root / "scenes", glyphs=True)
    out = root / "run"
    bench.run(["fake-a"], [str(scene)], run_dir=out, schedule="tiny", ocr="fake", ocr_backend=rf.FakeOCR(),
               with_lpips=True, lpips_at="all", progress=False, write_report=False)
    return scene, out


def test_run_and_evaluate_agree_to_the_last_digit(tmp_path, toy_run):
    scene, run_dir = toy_run
    cells = _cells(run_dir)
    assert len(cells) == 3  # the tiny preset: 3K, 7K, 30K
    for cell in cells:
        renders = run_dir / "cells" / cell["method"] / cell["dataset"] / cell["scene"] / str(cell["iteration"]) / "renders"
        out = evaluate(renders, EvaluateOptions(scene=str(scene), out=tmp_path / f"ev{cell['iteration']}",
                                                ocr=rf.FakeOCR(), method=cell["method"], report=False), say=_quiet)
        (ev,) = _cells(out)
        assert (ev["dataset"], ev["scene"]) == (cell["dataset"], cell["scene"])
        for key in ("metrics", "cer", "cer_known"):
            assert ev[key] == cell[key], key  # every digit
        timing = {"seconds"}  # how long the crops took: not a metric
        assert {k: v for k, v in ev["readability"].items() if k not in timing} == \
            {k: v for k, v in cell["readability"].items() if k not in timing}
        assert ev["ocr"]["views"] == cell["ocr"]["views"] and ev["ocr"]["mask_settings"] == cell["ocr"]["mask_settings"]
        assert cell["cer_known"] is not None and cell["metrics"]["lpips"] is not None
        row_run = [r for r in _rows(run_dir) if r["iteration"] == str(cell["iteration"])][0]
        row_ev = _rows(out)[0]
        for col in ("cer", "cer_known", "psnr", "ssim", "lpips", "word_cer", "text_nll", "text_psnr", "cer_errors"):
            assert row_ev[col] == row_run[col], col
        # One cell record (store.write_cell): the same fields and the same render file names.
        assert set(ev) == set(cell) and set(ev["timings"]) == set(cell["timings"])
        ev_renders = out / "cells" / ev["method"] / ev["dataset"] / ev["scene"] / str(ev["iteration"]) / "renders"
        assert sorted(p.name for p in ev_renders.iterdir()) == sorted(p.name for p in renders.iterdir())


def test_allow_missing_scores_unread_views(tmp_path, toy_run):
    scene, run_dir = toy_run
    cell = _cells(run_dir)[-1]
    src = run_dir / "cells" / cell["method"] / cell["dataset"] / cell["scene"] / str(cell["iteration"]) / "renders"
    renders = tmp_path / "renders"
    shutil.copytree(src, renders)
    gone = sorted(renders.iterdir())[0]
    gone.unlink()
    with pytest.raises(PredictionsError, match=r"no render for 1 of 2 test view\(s\): view_00.png"):
        evaluate(renders, EvaluateOptions(scene=str(scene), out=tmp_path / "ev", ocr=rf.FakeOCR(), report=False),
                 say=_quiet)
    out = evaluate(renders, EvaluateOptions(scene=str(scene), out=tmp_path / "ev2", ocr=rf.FakeOCR(), report=False,
                                            allow_missing=True, with_lpips=False), say=_quiet)
    (ev,) = _cells(out)
    assert ev["missing_renders"] == ["view_00.png"]
    v = ev["ocr"]["views"]["view_00.png"]
    assert v["render_missing"] and v["render_words"] == []
    assert ev["cer"]["images"]["view_00.png"]["errors"] == ev["cer"]["images"]["view_00.png"]["chars"] > 0
    assert "view_00.png" not in ev["metrics"]["per_view"]  # no image metrics for a missing render


# --------------------------------------------------------------------------- bad input
def _toy_renders(tmp_path, toy_run) -> tuple[Path, Path]:
    scene, run_dir = toy_run
    cell = _cells(run_dir)[-1]
    src = run_dir / "cells" / cell["method"] / cell["dataset"] / cell["scene"] / str(cell["iteration"]) / "renders"
    dst = tmp_path / "renders"
    shutil.copytree(src, dst)
    return scene, dst


def _err(pred, tmp_path, match, **kw):
    with pytest.raises(StringsBenchError, match=match):
        evaluate(pred, EvaluateOptions(out=tmp_path / "bad", ocr=rf.FakeOCR(), report=False, **kw), say=_quiet)
    assert not list((tmp_path / "bad").glob("cells/*/*/*/*/result.json"))  # nothing half-written


def test_bad_input_is_refused_naming_the_files(tmp_path, toy_run):
    scene, renders = _toy_renders(tmp_path, toy_run)
    (tmp_path / "empty").mkdir()
    _err(tmp_path / "empty", tmp_path, "holds no renders", scene=str(scene))
    _err(tmp_path / "nowhere", tmp_path, "do not exist", scene=str(scene))
    # names matching nothing
    other = tmp_path / "other"
    other.mkdir()
    for p in renders.iterdir():
        shutil.copy(p, other / f"frame_{p.name}")
    _err(other, tmp_path, r"no render in .* is named after a test view.*frame_view_00", scene=str(scene))
    extra = tmp_path / "extra"
    shutil.copytree(renders, extra)
    shutil.copy(next(renders.iterdir()), extra / "stray.png")
    _err(extra, tmp_path, r"stray.png .*match no test view", scene=str(scene))
    # a size mismatch
    small = tmp_path / "small"
    shutil.copytree(renders, small)
    first = sorted(small.iterdir())[1]
    Image.open(first).resize((32, 24)).save(first)
    _err(small, tmp_path, rf"render .*{first.name} is 32x24, its ground truth .* is 64x48", scene=str(scene),
         downscale=1.0)
    # an unreadable image
    broken = tmp_path / "broken"
    shutil.copytree(renders, broken)
    victim = sorted(broken.iterdir())[0]
    victim.write_bytes(b"\x89PNG not really")
    _err(broken, tmp_path, rf"cannot read image .*{victim.name}", scene=str(scene))
    # no ground truth at all
    _err(renders, tmp_path, "carry no ground truth")


def test_archives_with_escaping_paths_or_links_are_refused(tmp_path, toy_run):
    _, renders = _toy_renders(tmp_path, toy_run)
    bad_zip = tmp_path / "evil.zip"
    with zipfile.ZipFile(bad_zip, "w") as zf:
        zf.writestr("color/a.png", b"x")
        zf.writestr("../escaped.png", b"x")
    _err(bad_zip, tmp_path, r"holds '\.\./escaped\.png', a path outside the archive")
    assert not (tmp_path / "escaped.png").exists()
    bad_tar = tmp_path / "evil.tar.gz"
    with tarfile.open(bad_tar, "w:gz") as tf:
        tf.add(next(renders.iterdir()), arcname="color/a.png")
        link = tarfile.TarInfo("color/b.png")
        link.type, link.linkname = tarfile.SYMTYPE, "/etc/passwd"
        tf.addfile(link)
    _err(bad_tar, tmp_path, "holds links or special files")
    abs_tar = tmp_path / "abs.tar"
    with tarfile.open(abs_tar, "w") as tf:
        data = next(renders.iterdir()).read_bytes()
        info = tarfile.TarInfo("/tmp/abs.png")  # tarfile.add would strip the leading /
        info.size = len(data)
        import io
        tf.addfile(info, io.BytesIO(data))
    _err(abs_tar, tmp_path, "a path outside the archive")
    corrupt = tmp_path / "corrupt.zip"
    corrupt.write_bytes(b"PK\x03\x04 truncated")
    _err(corrupt, tmp_path, "cannot read archive")


def test_layout_detection(tmp_path):
    model, _ = _inria_model(tmp_path, masked=False)
    assert detect_layout(model).layout == "inria"
    assert [c.iteration for c in detect_layout(model / "test").checkpoints] == [3000, 7000]
    assert [c.iteration for c in detect_layout(model / "test" / "ours_3000").checkpoints] == [3000]
    assert detect_layout(model / "test" / "ours_3000" / "renders").layout == "folder"


def test_output_folder_of_another_evaluation_is_refused(tmp_path, toy_run):
    scene, renders = _toy_renders(tmp_path, toy_run)
    opts = dict(scene=str(scene), out=tmp_path / "ev", ocr=rf.FakeOCR(), report=False, with_lpips=False)
    evaluate(renders, EvaluateOptions(**opts), say=_quiet)
    said = []
    evaluate(renders, EvaluateOptions(**opts), say=said.append)  # resumes: nothing to do
    assert any("already evaluated" in s for s in said)
    with pytest.raises(StringsBenchError, match="other method"):
        evaluate(renders, EvaluateOptions(**opts, method="someone-else"), say=_quiet)


def test_report_on_an_evaluation_folder(tmp_path, toy_run):
    from strings_bench.reports import write_report

    scene, renders = _toy_renders(tmp_path, toy_run)
    out = evaluate(renders, EvaluateOptions(scene=str(scene), out=tmp_path / "ev", ocr=rf.FakeOCR(), with_lpips=False,
                                            train_seconds=12.5), say=_quiet)
    assert (out / "report" / "index.html").exists()
    assert _rows(out)[0]["train_seconds"] == "12.5"
    report = write_report(out)
    assert "renders" in report.read_text()  # the method is named after the folder


def test_cli_evaluate(tmp_path, toy_run, capsys):
    from strings_bench.cli import main

    scene, renders = _toy_renders(tmp_path, toy_run)
    rc = main(["evaluate", str(renders), "--out", str(tmp_path / "ev"), "--no-lpips", "--no-report", "--ocr", "nope"])
    assert rc == 1 and "nope" in capsys.readouterr().err
    rc = main(["evaluate", str(tmp_path / "missing"), "--gt", str(renders), "--out", str(tmp_path / "ev")])
    assert rc == 1 and "do not exist" in capsys.readouterr().err


# --------------------------------------------------------------------------- the release's masks
def _release_scene(root: Path, release: bool = True) -> Path:
    """The toy scene in the STRinGS release's layout: hisam_jsons/ images/ input/ masks/ masks_vis/ sparse/;
    its masks/ hold the text block grown by a few pixels, as the release's dilated Hi-SAM masks are."""
    scene = rf.make_scene(root, name="release" if release else "plain")
    x0, y0, x1, y1 = rf.TEXT_BOX
    for p in (scene / "masks").iterdir():
        m = np.zeros((rf.H, rf.W), np.uint8)
        m[y0 - 3:y1 + 3, x0 - 3:x1 + 3] = 255
        m[0, 0] = 100  # <= 127: not text, as the release reads it
        Image.fromarray(m).save(p)
    if release:
        for d in ("hisam_jsons", "input", "masks_vis"):
            (scene / d).mkdir()
        (scene / "hisam_jsons" / "view_00.json").write_text("{}")
    return scene


def test_release_masks_are_used_as_shipped_for_training_and_evaluation(tmp_path):
    from strings_bench.eval.protocol import Evaluator
    from strings_bench.eval.text_masks import masks_shipped_dilated, text_masks
    from strings_bench.methods.strings.method import StringsSettings
    from strings_bench.scene.scene import Scene

    release = Scene.load(_release_scene(tmp_path / "a"))
    plain = Scene.load(_release_scene(tmp_path / "b", release=False))
    assert masks_shipped_dilated(release) and not masks_shipped_dilated(plain)
    for scene in (release, plain):
        shipped = {i: np.asarray(Image.open(scene.mask_path(i)).convert("L")) > 127 for i in scene.train_idx}
        trained = text_masks(scene, scene.train_idx, 1.0, StringsSettings().mask_settings(), progress=False)
        ev = Evaluator.for_scene(scene, rf.FakeOCR(), 1.0, with_lpips=False)
        evaluated = {n: ev.mask(n) for n in ev.names}
        shipped_test = {scene.names[i]: np.asarray(Image.open(scene.mask_path(i)).convert("L")) > 127 for i in scene.test_idx}
        if scene is release:  # the release's masks, exactly: no second dilation
            assert all(np.array_equal(trained[i], shipped[i]) for i in scene.train_idx)
            assert all(np.array_equal(evaluated[n], shipped_test[n]) for n in evaluated)
        else:  # masks of unknown origin are tight: dilated by 5 % of the width, as before
            assert all(trained[i].sum() > shipped[i].sum() and (trained[i] >= shipped[i]).all() for i in scene.train_idx)
            assert all(evaluated[n].sum() > shipped_test[n].sum() for n in evaluated)
    forced = text_masks(release, release.train_idx, 1.0, StringsSettings(mask_predilated="no").mask_settings(),
                        progress=False)
    i = release.train_idx[0]
    assert forced[i].sum() > (np.asarray(Image.open(release.mask_path(i)).convert("L")) > 127).sum()


def test_strings360_card_marks_its_masks_dilated():
    from strings_bench.datasets.registry import get_dataset

    card = get_dataset("strings360")
    assert all(s.settings.get("masks_dilated") is True for s in card.scenes)
