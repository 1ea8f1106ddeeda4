"""Text in other scripts (issue 31): script detection, OCR languages, the graphemes CER profile."""

from __future__ import annotations

import math
import shutil

import numpy as np
import pytest

from strings_bench.core.errors import OCRError, StringsBenchError
from strings_bench.core.scripts import LANGUAGES, alphabet_coverage, char_script, split_lang, text_script, text_scripts
from strings_bench.eval.cer import graphemes, image_cer
from strings_bench.eval.ocr import engine_settings, parse_engines
from strings_bench.eval.ocr.base import Word


def _w(text, x0=0.0, y0=0.0, x1=40.0, y1=10.0):
    return Word.from_box(text, x0, y0, x1, y1)


# --------------------------------------------------------------------------- scripts
@pytest.mark.parametrize("text,script", [
    ("Привет", "Cyrillic"), ("ΦΑΡΜΑΚΕΙΟ", "Greek"), ("पुस्तकालय", "Devanagari"), ("مكتبة", "Arabic"),
    ("图书馆", "Han"), ("Library", "Latin"), ("А-12", "Cyrillic"), ("2026", None), ("", None),
])
def test_text_script(text, script):
    assert text_script(text) == script


def test_marks_and_digits():
    assert char_script("\u093e") == "Devanagari"  # DEVANAGARI VOWEL SIGN AA: a mark of its script
    assert char_script("\u0301") is None  # COMBINING ACUTE ACCENT: inherited, no script of its own
    assert char_script("7") is None and char_script(" ") is None
    assert text_scripts("Москва 2026 Moscow") == ["Cyrillic", "Latin"]


def test_split_lang_and_languages():
    assert split_lang("rus+eng") == ["rus", "eng"]
    with pytest.raises(StringsBenchError):
        split_lang("+")
    assert LANGUAGES["ara"].direction == "rtl" and LANGUAGES["chi_sim"].script == "Han"


def test_alphabet_coverage_counts_letters():
    cov = alphabet_coverage(set("abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ") | {"Ж"})
    assert cov["Latin"] == 1.0
    assert cov["Cyrillic"] == pytest.approx(1 / 64)
    assert cov["Arabic"] == 0.0


# --------------------------------------------------------------------------- graphemes CER profile
def test_graphemes_of_devanagari_and_rtl():
    assert graphemes("नमस्ते") == ("न", "म", "स्ते")  # a conjunct with its vowel sign is one cluster
    assert len(graphemes("पुस्तकालय")) == 5 and len("पुस्तकालय") == 9
    assert graphemes("مرحبا") == tuple("مرحبا")  # unshaped Arabic letters are one cluster each
    assert graphemes("e\u0301") == ("e\u0301",)


@pytest.mark.parametrize("gt,pred,paper,graph", [
    # a dropped vowel sign: 1 code point of 6, but 1 cluster of 3
    ("पुस्तक", "पस्तक", (1, 6), (1, 3)),
    # a dropped virama splits a conjunct: 1 code point, but 2 clusters change (स्ते -> स, ते)
    ("नमस्ते", "नमसते", (1, 6), (2, 3)),
    # Cyrillic: no combining marks, the two profiles agree
    ("Аптека", "Аптека", (0, 6), (0, 6)),
    ("Аптека", "Алтека", (1, 6), (1, 6)),
])
def test_graphemes_profile_against_codepoints(gt, pred, paper, graph):
    p = image_cer([_w(gt)], [_w(pred)], "paper")
    g = image_cer([_w(gt)], [_w(pred)], "graphemes")
    assert (p.errors, p.chars) == paper
    assert (g.errors, g.chars) == graph


def test_paper_profile_on_caseless_and_rtl_scripts():
    # str.lower leaves caseless scripts alone and lowers Cyrillic and Greek (final sigma included).
    assert image_cer([_w("ΑΠΟΘΗΚΗ")], [_w("αποθηκη")], "paper").errors == 0
    assert image_cer([_w("СКЛАД")], [_w("склад")], "paper").errors == 0
    assert "ΟΔΟΣ".lower() == "οδος"  # not "οδοσ": str.lower knows the final sigma at a word's end
    assert image_cer([_w("ΟΔΟΣ")], [_w("οδοσ")], "paper").errors == 1
    # Arabic words are compared in logical (reading) order; an OCR that returns them in visual order
    # (reversed code points) is wrong on every mirrored character.
    gt = "مكتبة"
    assert image_cer([_w(gt)], [_w(gt)], "paper").errors == 0
    assert image_cer([_w(gt)], [_w(gt[::-1])], "paper").errors == 4


def test_graphemes_in_a_component_of_several_words():
    gt = [_w("पुस्तक", 0, 0, 40, 10), _w("घर", 45, 0, 60, 10)]
    pred = [_w("पुस्तकघर", 0, 0, 60, 10)]
    assert image_cer(gt, pred, "graphemes").errors == 0
    assert image_cer(gt, pred, "graphemes").chars == 3 + 2


# --------------------------------------------------------------------------- OCR engines and languages
def test_engine_spec_with_settings():
    assert parse_engines("tesseract:lang=rus+eng,rapidocr") == ["tesseract:lang=rus+eng", "rapidocr"]
    assert parse_engines("tess:lang=ell:psm=6") == ["tesseract:lang=ell:psm=6"]
    assert engine_settings("tesseract:lang=chi_sim:psm=6") == {"lang": "chi_sim", "psm": 6}
    with pytest.raises(OCRError):
        parse_engines("tesseract:lang")
    with pytest.raises(OCRError):
        parse_engines("tesseract:lang=rus,tesseract")


def test_rapidocr_refuses_scripts_its_dictionary_lacks():
    from strings_bench.eval.ocr import get_backend
    from strings_bench.eval.ocr.languages import rapidocr_scripts

    cover = rapidocr_scripts()
    # measured on rapidocr 3.10's PP-OCRv6 dictionary: no Cyrillic, Devanagari or Arabic letter at all
    assert cover["Cyrillic"] == cover["Devanagari"] == cover["Arabic"] == 0.0
    assert cover["Latin"] == 1.0
    ocr = get_backend("rapidocr", cache=False)
    assert ocr.supported_scripts() == frozenset({"Latin", "Han"})
    ocr.require_scripts(["Latin", "Han"])
    with pytest.raises(OCRError, match="0.892"):  # Greek letters it has, but it was measured not to read them
        ocr.require_scripts(["Greek"])
    with pytest.raises(OCRError) as err:
        ocr.require_scripts(["Cyrillic"], "synthetic-multi/cyrillic")
    assert "rapidocr" in err.value.message and "Cyrillic" in err.value.message
    assert "tesseract" in err.value.hint and "rus" in err.value.hint


needs_tesseract = pytest.mark.skipif(shutil.which("tesseract") is None, reason="tesseract is not installed "
                                     "(scripts/system_deps.sh installs Debian's tesseract-ocr where apt and root allow)")


@needs_tesseract
def test_tesseract_lang_checked_against_installed_data():
    from strings_bench.eval.ocr import get_backend
    from strings_bench.eval.ocr.languages import tesseract_languages

    ocr = get_backend("tesseract", cache=False, lang="zzz")
    with pytest.raises(OCRError) as err:
        ocr.version
    assert "zzz" in err.value.message and "apt-get install" in err.value.hint
    assert "eng" in tesseract_languages()
    eng = get_backend("tesseract", cache=False)
    assert eng.supported_scripts() == frozenset({"Latin"})
    with pytest.raises(OCRError):
        eng.require_scripts(["Arabic"])


@needs_tesseract
@pytest.mark.parametrize("lang,text", [("rus", "АПТЕКА"), ("ell", "ΦΑΡΜΑΚΕΙΟ"), ("chi_sim", "图书馆"),
                                       ("hin", "पुस्तकालय"), ("ara", "مكتبة")])
def test_tesseract_reads_a_word_of_each_language(lang, text):
    """A word drawn large with its Noto font, read with its language: the lang setting reaches Tesseract."""
    from strings_bench.eval.ocr import get_backend
    from strings_bench.eval.ocr.languages import tesseract_languages

    if lang not in tesseract_languages():
        pytest.skip(f"no Tesseract data for {lang} (apt-get install {LANGUAGES[lang].debian_package})")
    from strings_bench.datasets.synthetic.fonts import font_for, missing_fonts

    script = LANGUAGES[lang].script
    if missing_fonts([script]):
        pytest.skip(f"no Noto font for {script}: {missing_fonts([script])[script]}")
    from PIL import Image, ImageDraw

    font = font_for(script, 48)
    im = Image.new("RGB", (600, 120), "white")
    ImageDraw.Draw(im).text((30, 20), text, font=font, fill="black", direction="rtl" if lang == "ara" else None)
    words = get_backend("tesseract", cache=False, lang=lang, psm=7).read(np.asarray(im))
    read = "".join(w.text for w in words)
    assert image_cer([_w(text)], [_w(read)], "paper").cer <= 0.2, read


def test_tesseract_optional_settings_stay_out_of_the_key_at_their_defaults():
    from strings_bench.eval.ocr.tesseract import TesseractBackend

    plain = TesseractBackend(lang="rus")
    assert "upscale" not in plain.settings and "mask_fill" not in plain.settings
    assert plain.settings["lang"] == "rus"
    tuned = TesseractBackend(lang="rus+eng", upscale=3, mask_fill=128)
    assert tuned.settings["upscale"] == 3.0 and tuned.settings["mask_fill"] == 128
    assert tuned.supported_scripts() == frozenset({"Cyrillic", "Latin"})
    for bad in ({"upscale": 0.5}, {"upscale": "x"}, {"mask_fill": 300}, {"lang": ""}):
        with pytest.raises(OCRError):
            TesseractBackend(**bad)


@needs_tesseract
def test_tesseract_upscale_maps_polygons_back():
    """Words read from the enlarged image come back in the original pixels: same place as unscaled."""
    from PIL import Image, ImageDraw

    from strings_bench.datasets.synthetic.textures import load_font
    from strings_bench.eval.ocr.tesseract import TesseractBackend

    im = Image.new("RGB", (400, 100), "white")
    ImageDraw.Draw(im).text((40, 30), "HELLO WORLD", font=load_font("sans-bold", 32), fill="black")
    arr = np.asarray(im)
    a = TesseractBackend(psm=7).read(arr)
    b = TesseractBackend(psm=7, upscale=2).read(arr)
    assert [w.text for w in a] == [w.text for w in b] == ["HELLO", "WORLD"]
    for wa, wb in zip(a, b):
        assert np.abs(wa.polygon - wb.polygon).max() <= 3


# --------------------------------------------------------------------------- fonts and scenes
from strings_bench.datasets.synthetic import fonts as _fonts  # noqa: E402
from strings_bench.datasets.synthetic.multiscript import SCENE_NAMES_MULTI, WORDS, scene_script  # noqa: E402

_MISSING = _fonts.missing_fonts(["Cyrillic", "Greek", "Devanagari", "Arabic", "Han"])
needs_fonts = pytest.mark.skipif(bool(_MISSING), reason=f"Noto fonts missing: {_MISSING} "
                                 "(scripts/system_deps.sh installs fonts-noto-core and fonts-noto-cjk)")


@needs_fonts
def test_every_word_of_every_scene_is_in_its_font_and_its_script():
    for scene in SCENE_NAMES_MULTI:
        w = WORDS[scene]
        script = scene_script(scene)
        texts = [t for pair in w.books for t in pair] + list(w.jars) + list(w.signs)
        for text in texts:
            assert _fonts.uncovered(script, text) == [], (scene, text)
            assert text_scripts(text) == [script], (scene, text)


@needs_fonts
def test_glyph_check_refuses_a_character_the_font_lacks():
    from strings_bench.core.errors import DatasetError
    from strings_bench.datasets.synthetic.textures import Canvas

    assert _fonts.uncovered("Devanagari", "नमक 日本") == ["日", "本"]  # the Devanagari font has no Han glyph
    cv = Canvas(np.full((60, 300, 3), 255, np.uint8))
    with pytest.raises(DatasetError, match="no glyph"):
        cv.word("नमक日", 5, 5, 30, style="noto-Devanagari")
    assert cv.words == []  # nothing drawn


def test_missing_font_is_refused_with_the_reason(monkeypatch, tmp_path):
    from strings_bench.core.errors import DatasetError
    from strings_bench.datasets.synthetic.multiscript import check_fonts

    monkeypatch.setattr(_fonts, "SYSTEM_FONT_DIR", str(tmp_path / "none"))
    monkeypatch.setenv(_fonts.FONT_DIRS_ENV, str(tmp_path))
    _fonts._find.cache_clear()
    try:
        assert "Han" in _fonts.missing_fonts(["Han"])
        with pytest.raises(DatasetError, match="fonts-noto-cjk"):
            check_fonts("chinese")
    finally:
        _fonts._find.cache_clear()


@needs_fonts
def test_arabic_lines_read_right_to_left():
    from strings_bench.datasets.synthetic.textures import Canvas

    cv = Canvas(np.full((80, 600, 3), 255, np.uint8))
    boxes = cv.text_line("ألف ليلة وليلة", 300, 40, 36, (0, 0, 0), "noto-Arabic", anchor="mm")
    assert [b.text for b in boxes] == ["ألف", "ليلة", "وليلة"]  # recorded in reading order
    xs = [b.corners[:, 0].mean() for b in boxes]
    assert xs[0] > xs[1] > xs[2]  # placed right to left
    ink = np.asarray(cv.image).min(axis=2) < 128
    for b in boxes:  # each box holds ink (the word was drawn where its box says)
        x0, y0 = b.corners.min(0).astype(int)
        x1, y1 = b.corners.max(0).astype(int)
        assert ink[y0:y1, x0:x1].sum() > 50
    assert ink.sum() == sum(ink[int(b.corners[:, 1].min()):int(b.corners[:, 1].max()),
                                int(b.corners[:, 0].min()):int(b.corners[:, 0].max())].sum() for b in boxes)


@needs_fonts
@pytest.mark.parametrize("scene", SCENE_NAMES_MULTI)
def test_scene_annotations_record_language_and_script(scene):
    from strings_bench.datasets.synthetic.generate import SyntheticSettings, make_spec, orbit_cameras, visible_words

    st = SyntheticSettings()
    spec = make_spec(scene, 0, st)
    lang = WORDS[scene].lang
    assert {w.lang for w in spec.words} == {lang} and {w.script for w in spec.words} == {scene_script(scene)}
    drawn = [w.text for w in spec.words]
    # every drawn word is one of the scene's words (the lines split at spaces), none else
    expected = {t for pair in WORDS[scene].books for line in pair for t in line.split()}
    expected |= {t for line in (*WORDS[scene].jars, *WORDS[scene].signs) for t in line.split()}
    assert set(drawn) == expected
    cams = orbit_cameras(spec, st, np.random.default_rng([0, 2]))
    seen = visible_words(spec, cams[8], st)
    assert seen and all(k.lang == lang and k.script == scene_script(scene) for k in seen)


@needs_tesseract
@needs_fonts
@pytest.mark.parametrize("scene,bound", [("cyrillic", 0.6), ("greek", 0.6), ("devanagari", 0.9), ("arabic", 0.85),
                                         ("chinese", 0.9)])
def test_tesseract_reads_the_drawn_words_of_a_view(scene, bound):
    """Annotations against the drawn text: Tesseract with the scene's language, on two rendered views,
    finds the known words at their polygons (known-text CER with the legibility filter; docs/ocr.md has
    the figures on the six test views of each built scene)."""
    from strings_bench.datasets.synthetic.generate import SyntheticSettings, make_spec, orbit_cameras, visible_words
    from strings_bench.eval.cer import known_scene_cer
    from strings_bench.eval.ocr.tesseract import TesseractBackend

    lang = WORDS[scene].lang
    if lang not in __import__("strings_bench.eval.ocr.languages", fromlist=["x"]).tesseract_languages():
        pytest.skip(f"no Tesseract data for {lang}")
    st = SyntheticSettings()
    spec = make_spec(scene, 0, st)
    cams = orbit_cameras(spec, st, np.random.default_rng([0, 2]))
    ocr = TesseractBackend(lang=lang, upscale=3)
    pairs = {}
    for i in (8, 32):  # views facing the front and the back of the objects
        res = spec.world.render(cams[i], 2)
        pairs[str(i)] = ([(k.text, k.polygon) for k in visible_words(spec, cams[i], st)], ocr.read(res.rgb))
    r = known_scene_cer(pairs)
    assert r.chars > 20
    assert r.cer <= bound, (r.cer, r.errors, r.chars)
    wrong = known_scene_cer({k: (g, []) for k, (g, _) in pairs.items()})
    assert wrong.cer == 1.0  # reading nothing costs every character: the figure above is earned


# --------------------------------------------------------------------------- evaluation and reports
def test_evaluator_refuses_an_engine_that_cannot_read_the_scene():
    from strings_bench.eval.protocol import EvalView, Evaluator
    from strings_bench.scene.scene import KnownWord

    class LatinOnly:
        name = "latin-only"

        def supported_scripts(self):
            return frozenset({"Latin"})

        require_scripts = __import__("strings_bench.eval.ocr.base", fromlist=["x"]).OCRBackend.require_scripts
        unreadable_reason = __import__("strings_bench.eval.ocr.base", fromlist=["x"]).OCRBackend.unreadable_reason

        def settings_summary(self):
            return "test"

    poly = np.array([[0, 0], [20, 0], [20, 8], [0, 8]], float)
    view = EvalView("v.png", np.zeros((16, 32, 3), np.float32),
                    known_words=(KnownWord("СОЛЬ", poly, lang="rus", script="Cyrillic"),))
    with pytest.raises(OCRError, match="cannot read Cyrillic"):
        Evaluator([view], LatinOnly(), with_lpips=False, with_readability=False)
    latin = EvalView("v.png", np.zeros((16, 32, 3), np.float32), known_words=(KnownWord("SALT", poly),))
    ev = Evaluator([latin], LatinOnly(), with_lpips=False, with_readability=False)
    assert ev.known_scripts == ["Latin"] and ev.known_languages == []


def test_cer_per_script_and_the_report_table(tmp_path):
    import pandas as pd

    from strings_bench.reports import tables
    from strings_bench.reports.aggregate import cer_per_script
    from strings_bench.store import script_columns

    assert script_columns({"text": {"scripts": ["Cyrillic", "Latin"], "languages": ["rus"]}}) == \
        {"script": "Cyrillic+Latin", "language": "rus"}
    assert script_columns({}) == {}
    rows = []
    for scene, script, cer in (("cyrillic", "Cyrillic", 0.4), ("greek", "Greek", 0.5), ("arabic", "Arabic", 0.8),
                               ("books", "Latin", 0.2), ("globe", "Latin", 0.4)):
        for method, d in (("3dgs", 0.1), ("strings", 0.0)):
            rows.append({"method": method, "dataset": "synthetic-multi" if script != "Latin" else "synthetic",
                         "scene": scene, "iteration": 100, "label": "7K", "cer": cer + d, "cer_known": math.nan,
                         "script": script, "psnr": 20.0, "ssim": 0.8, "lpips": 0.2, "train_seconds": 10.0,
                         "preprocess_seconds": 0.0, "total_seconds": 10.0, "gaussians": 1000})
    per = cer_per_script(rows)
    latin = [r for r in per if r["script"] == "Latin" and r["method"] == "strings"][0]
    assert latin["cer"] == pytest.approx(0.3) and latin["scenes"] == 2  # mean over the Latin scenes, across datasets
    assert {r["script"] for r in per} == {"Arabic", "Cyrillic", "Greek", "Latin"}
    assert cer_per_script([{"method": "m", "label": "7K", "script": "", "cer": 0.1}]) == []
    df = pd.DataFrame(rows)
    built = {t.name: t for t in tables.script_tables(df)}
    assert "ocr_cer_by_script" in built and "known_cer_by_script" not in built  # no known-text CER given
    md = built["ocr_cer_by_script"].markdown()
    assert "Latin (2 scenes)" in md and "Cyrillic (1 scene)" in md
    assert "0.300" in md and "0.900" in md  # Latin strings; Arabic 3dgs
    assert tables.script_tables(df[df["script"] == "Latin"]) == []  # one script: no table


def test_tesseract_lang_auto_takes_the_scene_languages():
    from strings_bench.eval.ocr.tesseract import TesseractBackend
    from strings_bench.eval.protocol import EvalView, Evaluator
    from strings_bench.scene.scene import KnownWord

    auto = TesseractBackend(lang="auto", upscale=3, mask_fill=128)
    assert auto.supported_scripts() is None
    with pytest.raises(OCRError, match="not resolved"):
        auto.languages()
    ara = auto.for_languages(["ara"])
    assert ara.settings == {**auto.settings, "lang": "ara"} and ara.cache is auto.cache
    assert TesseractBackend(lang="rus").for_languages(["ara"]).settings["lang"] == "rus"  # only auto is resolved
    with pytest.raises(OCRError, match="no annotated language"):
        auto.for_languages([])
    poly = np.array([[0, 0], [20, 0], [20, 8], [0, 8]], float)
    view = EvalView("v.png", np.zeros((16, 32, 3), np.float32),
                    known_words=(KnownWord("ملح", poly, lang="ara", script="Arabic"),
                                 KnownWord("عسل", poly, lang="ara", script="Arabic")))
    ev = Evaluator([view], [auto], with_lpips=False, with_readability=False)
    assert ev.ocr.settings["lang"] == "ara" and ev.known_languages == ["ara"]


def test_no_word_crop_readability_on_scripts_its_recogniser_cannot_read():
    from strings_bench.eval.protocol import EvalView, Evaluator
    from strings_bench.eval.ocr.tesseract import TesseractBackend
    from strings_bench.scene.scene import KnownWord

    poly = np.array([[0, 0], [20, 0], [20, 8], [0, 8]], float)
    view = EvalView("v.png", np.zeros((16, 32, 3), np.float32), known_words=(KnownWord("СОЛЬ", poly, lang="rus"),))
    ev = Evaluator([view], TesseractBackend(lang="rus"), with_lpips=False)
    assert ev.readability({}) is None


# --------------------------------------------------------------------------- Bundler scenes (saharov32)
def _bundler_project(f, k1, k2, R, t, X, w, h):
    """Bundler's own camera model (its manual), written out independently: stored-image pixel of X."""
    P = R @ X + t
    p = -P[:2] / P[2]
    r2 = p @ p
    q = f * (1 + k1 * r2 + k2 * r2 * r2) * p
    return np.array([q[0] + w / 2, h / 2 - q[1]])  # Bundler's y points up from the centre


def _random_bundle(rng, n_cams=3, n_pts=40):
    cams = []
    for _ in range(n_cams):
        a = rng.normal(size=3) * 0.2
        from scipy.spatial.transform import Rotation

        R = Rotation.from_rotvec(a).as_matrix() @ np.diag([1.0, -1.0, -1.0])  # looking roughly down -z of the camera
        t = rng.normal(size=3) * 0.1 + np.array([0, 0, -4.0])
        cams.append((float(rng.uniform(300, 400)), -0.1, 0.05, R, t))
    X = rng.normal(size=(n_pts, 3)) * 0.5
    return cams, X


@pytest.mark.parametrize("orientation", [1, 6, 8, 3])
def test_bundler_cameras_reproject_like_bundler(orientation, tmp_path):
    import pycolmap

    from strings_bench.datasets.bundler import bundler_reconstruction, read_bundler

    rng = np.random.default_rng(7)
    w, h = 320, 240
    cams, X = _random_bundle(rng)
    lines = ["# Bundle file v0.3", f"{len(cams)} {len(X)}"]
    for f, k1, k2, R, t in cams:
        lines += [f"{f} {k1} {k2}", *(" ".join(map(str, row)) for row in R), " ".join(map(str, t))]
    obs = {}
    for i, x in enumerate(X):
        lines += [" ".join(map(str, x)), "10 20 30"]
        views = []
        for c, (f, k1, k2, R, t) in enumerate(cams):
            u, v = _bundler_project(f, k1, k2, R, t, x, w, h)
            views.append(f"{c} {i} {u - w / 2} {h / 2 - v}")
            obs[(i, c)] = (u, v)
        lines.append(f"{len(cams)} " + " ".join(views))
    (tmp_path / "bundle.out").write_text("\n".join(lines) + "\n")
    model = read_bundler(tmp_path / "bundle.out")
    assert model.focal.shape == (3,) and model.xyz.shape == (40, 3) and len(model.tracks) == 40
    names = [f"im{c}.jpg" for c in range(len(cams))]
    rec, kept = bundler_reconstruction(model, names, [(w, h)] * 3, [orientation] * 3)
    assert kept == names and rec.num_points3D() == 40
    # The stored pixel (u, v) in the upright image, as PIL's exif_transpose turns it.
    up = {1: lambda u, v: (u, v), 3: lambda u, v: (w - u, h - v), 6: lambda u, v: (h - v, u), 8: lambda u, v: (v, w - u)}
    err = []
    for p in rec.points3D.values():
        i = int(np.argmin(np.linalg.norm(X - p.xyz, axis=1)))
        for el in p.track.elements:
            im = rec.images[el.image_id]
            cam = rec.cameras[im.camera_id]
            uv = np.asarray(cam.img_from_cam(im.cam_from_world() * p.xyz)).ravel()[:2]
            err.append(np.linalg.norm(uv - np.array(up[orientation](*obs[(i, el.image_id - 1)]))))
    assert max(err) < 1e-6


def test_prepare_bundler_scene_end_to_end(tmp_path):
    from PIL import Image

    from strings_bench.datasets.bundler import prepare_bundler_scene
    from strings_bench.scene.scene import Scene

    rng = np.random.default_rng(3)
    w, h = 320, 240
    cams, X = _random_bundle(rng, n_cams=8, n_pts=60)
    src = tmp_path / "src"
    (src / "images").mkdir(parents=True)
    lines = ["# Bundle file v0.3", f"{len(cams)} {len(X)}"]
    for f, k1, k2, R, t in cams:
        lines += [f"{f} {k1} {k2}", *(" ".join(map(str, row)) for row in R), " ".join(map(str, t))]
    for i, x in enumerate(X):
        views = [f"{c} {i} {u - w / 2} {h / 2 - v}"
                 for c, cam in enumerate(cams) for u, v in [_bundler_project(*cam, x, w, h)]]
        lines += [" ".join(map(str, x)), "10 20 30", f"{len(cams)} " + " ".join(views)]
    (src / "cameras.out").write_text("\n".join(lines) + "\n")
    names = [f"IMG_{c}.JPG" for c in range(len(cams))]
    (src / "ordered_filenames.txt").write_text(f"{len(names)}\n" + "\n".join(names) + "\n")
    for n in names:
        Image.fromarray(rng.integers(0, 255, (h, w, 3), dtype=np.uint8)).save(src / "images" / n)
    res = prepare_bundler_scene(src, "bundler-test", out=tmp_path / "scene", masks=False, register=False,
                                progress=False, echo=lambda s: None)
    assert res.num_registered == 8 and res.num_points == 60 and res.matcher.startswith("none")
    scene = Scene.load(tmp_path / "scene")
    assert len(scene.names) == 8 and (tmp_path / "scene" / "images_2").is_dir()
