"""OCR backends: the interface, masking, the disk cache, RapidOCR on rendered text, Tesseract, `ocr check`."""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from strings_bench.eval.cer import known_text_cer, scene_cer
from strings_bench.core.errors import OCRError, StringsBenchError
from strings_bench.eval.ocr import (
    BACKENDS,
    OCRBackend,
    OCRCache,
    Word,
    apply_mask,
    available_backends,
    get_backend,
    load_image,
)
from strings_bench.eval.ocr.base import BackendStatus
from strings_bench.eval.ocr.rapid import RapidOCRBackend, split_line_into_words
from strings_bench.eval.ocr.sample import random_text_image, render_lines, sample_image
from strings_bench.eval.ocr.tesseract import TesseractBackend, parse_tesseract_tsv

REPO = Path(__file__).resolve().parents[2]


class CountingBackend(OCRBackend):
    """A backend without an engine: reports one word per non-black column band; counts its calls."""

    name = "counting"

    def __init__(self, cache=None, **settings):
        super().__init__({"mode": "test", **settings}, cache)
        self.calls = 0
        self.seen: list[np.ndarray] = []

    @property
    def version(self):
        return "1"

    @classmethod
    def status(cls):
        return BackendStatus(cls.name, True, "1")

    def _recognize(self, rgb):
        self.calls += 1
        self.seen.append(rgb.copy())
        if self.settings.get("fail"):
            raise RuntimeError("engine exploded")
        return [Word.from_box(f"n{int(rgb.sum()) % 997}", 0, 0, 10, 10, 0.5)]


# --------------------------------------------------------------------------- interface
def test_word_validation_and_round_trip():
    w = Word("abc", [[0, 0], [10, 0], [10, 5]], 0.7)
    assert w.polygon.dtype == np.float64 and w.polygon.shape == (3, 2)
    assert Word.from_dict(w.to_dict()) == w
    nan_conf = Word("x", np.zeros((4, 2)), float("nan"))
    assert nan_conf.to_dict()["confidence"] is None
    assert Word.from_dict(nan_conf.to_dict()) == nan_conf
    with pytest.raises(OCRError, match="polygon has shape"):
        Word("abc", [1, 2, 3])
    with pytest.raises(OCRError, match="lacks"):
        Word.from_dict({"text": "a"})


def test_load_image_and_errors(tmp_path):
    from PIL import Image

    rgb = np.random.default_rng(0).integers(0, 256, (12, 16, 3), dtype=np.uint8)
    Image.fromarray(rgb).save(tmp_path / "x.png")
    assert np.array_equal(load_image(tmp_path / "x.png"), rgb)
    assert load_image(rgb[:, :, 0]).shape == (12, 16, 3)
    with pytest.raises(OCRError, match="dtype float"):
        load_image(rgb.astype(np.float32))
    with pytest.raises(OCRError, match="HxWx3"):
        load_image(np.zeros((4, 4, 4), np.uint8))
    with pytest.raises(OCRError, match="does not exist"):
        load_image(tmp_path / "nope.png")
    (tmp_path / "bad.png").write_bytes(b"not an image")
    with pytest.raises(OCRError, match="cannot read image"):
        load_image(tmp_path / "bad.png")


def test_mask_is_applied_before_the_engine(tmp_path):
    rgb = np.full((20, 30, 3), 200, np.uint8)
    mask = np.zeros((20, 30), bool)
    mask[5:10, 5:25] = True
    b = CountingBackend()
    b.read(rgb, mask=mask)
    seen = b.seen[-1]
    assert np.all(seen[mask] == 200) and np.all(seen[~mask] == 0)
    assert np.array_equal(apply_mask(rgb, mask), seen)
    # A mask file (non-black = text) and a 0/255 array mean the same.
    from PIL import Image

    Image.fromarray((mask * 255).astype(np.uint8)).save(tmp_path / "m.png")
    b.read(rgb, mask=tmp_path / "m.png")
    b.read(rgb, mask=(mask * 255).astype(np.uint8))
    assert np.array_equal(b.seen[-1], seen) and np.array_equal(b.seen[-2], seen)
    with pytest.raises(OCRError, match="mask has shape"):
        b.read(rgb, mask=np.ones((10, 10), bool))


def test_cache_hits_misses_and_failures(tmp_path):
    cache = OCRCache(tmp_path / "ocr")
    rgb = np.random.default_rng(1).integers(0, 256, (16, 16, 3), dtype=np.uint8)
    mask = np.zeros((16, 16), bool)
    mask[4:12, 4:12] = True
    b = CountingBackend(cache=cache)
    first = b.read(rgb)
    assert b.read(rgb) == first and b.calls == 1  # hit: the engine is not called again
    b.read(rgb, mask=mask)
    assert b.calls == 2  # another mask is another key
    b.read(rgb, mask=mask)
    assert b.calls == 2
    CountingBackend(cache=cache, extra=1).read(rgb)  # other settings: another key
    files = sorted((tmp_path / "ocr").rglob("*.json"))
    assert len(files) == 3
    entry = json.loads(files[0].read_text())
    assert entry["backend"]["name"] == "counting" and "words" in entry
    assert not list((tmp_path / "ocr").rglob("*.tmp"))  # atomic writes leave no temporaries
    # A damaged entry is a miss and is rewritten.
    key = cache.key(b.describe(), __import__("strings_bench.eval.ocr.base", fromlist=["x"]).array_sha256(rgb), None)
    cache.path(key).write_text("{truncated")
    assert b.read(rgb) == first and b.calls == 3
    assert b.read(rgb) == first and b.calls == 3
    # Failures are OCRError and are not cached.
    bad = CountingBackend(cache=cache, fail=True)
    for _ in range(2):
        with pytest.raises(OCRError, match="engine exploded"):
            bad.read(rgb)
    assert bad.calls == 2


def test_registry():
    assert set(BACKENDS) == {"rapidocr", "tesseract", "gcv"}
    st = available_backends()
    assert set(st) == set(BACKENDS)
    assert st["rapidocr"].available, st["rapidocr"].detail
    with pytest.raises(OCRError, match="unknown OCR backend"):
        get_backend("abbyy")
    with pytest.raises(OCRError, match="unknown setting"):
        get_backend("rapidocr", cache=False, txt_score=0.3)
    with pytest.raises(OCRError, match="word_boxes"):
        get_backend("rapidocr", cache=False, word_boxes="magic")
    a = get_backend("rapidocr", cache=False, text_score=0.55)
    assert get_backend("rapidocr", cache=False, text_score=0.55) is a
    d = a.describe()
    assert d["name"] == "rapidocr" and d["settings"]["text_score"] == 0.55 and "rapidocr 3." in d["version"]
    json.dumps(d)


def test_split_line_into_words_proportional():
    quad = np.array([[0, 0], [100, 0], [100, 20], [0, 20]], float)
    words = split_line_into_words("ab  cdefgh ij", quad, 0.9)  # 13 characters
    assert [w.text for w in words] == ["ab", "cdefgh", "ij"]
    np.testing.assert_allclose(words[0].polygon[:, 0], [0, 200 / 13, 200 / 13, 0])
    np.testing.assert_allclose(words[1].polygon[:, 0], [400 / 13, 1000 / 13, 1000 / 13, 400 / 13])
    np.testing.assert_allclose(words[2].polygon[:, 1], [0, 0, 20, 20])
    # A slanted line: words follow both edges.
    slanted = np.array([[0, 0], [100, 50], [90, 70], [-10, 20]], float)
    w = split_line_into_words("a b", slanted, 1.0)[1]
    np.testing.assert_allclose(w.polygon, [[200 / 3, 100 / 3], [100, 50], [90, 70], [170 / 3, 160 / 3]])


# --------------------------------------------------------------------------- RapidOCR
@pytest.fixture(scope="module")
def rapid():
    return RapidOCRBackend(cache=None)


def _noisy(img, seed, sigma=6.0):
    rng = np.random.default_rng(seed)
    return np.clip(img.astype(np.float64) + rng.normal(0, sigma, img.shape), 0, 255).astype(np.uint8)


def test_rapidocr_reads_rendered_words(rapid):
    per_image = {}
    for seed in range(3):
        img, known = random_text_image(np.random.default_rng(100 + seed))
        per_image[seed] = (known, rapid.read(_noisy(img, seed)))
    s = scene_cer(per_image)
    assert s.chars > 40
    assert s.cer <= 0.10, {k: ([w.text for w in g], [w.text for w in p]) for k, (g, p) in per_image.items()}
    # Word level: roughly one predicted word per known word, each inside the image.
    for known, words in per_image.values():
        assert abs(len(words) - len(known)) <= 1
        for w in words:
            assert w.polygon.shape[1] == 2 and 0 <= w.confidence <= 1


def test_rapidocr_proportional_word_boxes():
    img, known = sample_image()
    b = RapidOCRBackend(cache=None, word_boxes="proportional")
    words = b.read(img)
    assert known_text_cer(known, words).cer <= 0.10
    assert len(words) == len(known)


def test_rapidocr_mask_hides_unmasked_text(rapid):
    img, known = render_lines([["ALPHA", "BRAVO"], ["CHARLIE", "DELTA"]], font_size=44)
    mask = np.zeros(img.shape[:2], bool)
    first_line = known[:2]
    y1 = int(max(w.polygon[:, 1].max() for w in first_line)) + 8
    mask[:y1] = True
    words = rapid.read(img, mask=mask)
    texts = {w.text.lower() for w in words}
    assert {"alpha", "bravo"} <= texts
    assert not texts & {"charlie", "delta"}
    assert known_text_cer(first_line, words).errors == 0


def test_rapidocr_cache_hit_skips_engine(tmp_path, rapid):
    img, known = sample_image()
    b = RapidOCRBackend(cache=OCRCache(tmp_path / "ocr"))
    first = b.read(img)
    assert known_text_cer(known, first).cer <= 0.10

    class NoEngine:
        def __call__(self, *a, **k):
            raise AssertionError("engine called despite a cached result")

    b._engine = NoEngine()
    assert b.read(img) == first
    with pytest.raises(OCRError, match="engine called"):  # a different image does reach the engine
        b.read(img[:, ::-1].copy())


def test_rapidocr_blank_image_has_no_words(rapid):
    assert rapid.read(np.zeros((64, 128, 3), np.uint8)) == []


def test_rapidocr_writes_only_into_the_cache_folder(tmp_path):
    """Run in a fresh process with a fake home: onnxruntime must not leave its telemetry id there."""
    home = tmp_path / "home"
    home.mkdir()
    cache = tmp_path / "cache"
    code = (
        "import numpy as np\n"
        "from strings_bench.eval.ocr import get_backend\n"
        "from strings_bench.eval.ocr.sample import sample_image\n"
        "img, known = sample_image()\n"
        "print(len(get_backend('rapidocr').read(img)))\n"
    )
    env = {k: v for k, v in os.environ.items() if k not in ("ORT_DISABLE_TELEMETRY", "XDG_CACHE_HOME")}
    env.update(HOME=str(home), STRINGS_BENCH_CACHE=str(cache), PYTHONPATH=str(REPO))
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=300, cwd=tmp_path)
    assert out.returncode == 0, out.stderr
    assert int(out.stdout.strip()) > 0
    assert [p for p in home.rglob("*")] == []
    assert list((cache / "ocr").rglob("*.json"))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cache", "home"]


# --------------------------------------------------------------------------- Tesseract
TSV = (
    "level\tpage_num\tblock_num\tpar_num\tline_num\tword_num\tleft\ttop\twidth\theight\tconf\ttext\n"
    "1\t1\t0\t0\t0\t0\t0\t0\t500\t200\t-1\t\n"
    "4\t1\t1\t1\t1\t0\t20\t30\t300\t40\t-1\t\n"
    '5\t1\t1\t1\t1\t1\t20\t30\t100\t40\t96.5\t"Quoted"\n'
    "5\t1\t1\t1\t1\t2\t140\t30\t80\t40\t12.0\tnoise\n"
    "5\t1\t1\t1\t1\t3\t240\t30\t80\t40\t95\t \n"
)


def test_parse_tesseract_tsv():
    words = parse_tesseract_tsv(TSV)
    assert [w.text for w in words] == ['"Quoted"', "noise"]
    np.testing.assert_allclose(words[0].polygon, [[20, 30], [120, 30], [120, 70], [20, 70]])
    assert words[0].confidence == pytest.approx(0.965)
    assert [w.text for w in parse_tesseract_tsv(TSV, min_confidence=50)] == ['"Quoted"']


def test_tesseract_reports_not_installed(monkeypatch):
    monkeypatch.setenv("STRINGS_BENCH_TESSERACT", "/nonexistent/tesseract")
    st = TesseractBackend.status()
    assert not st.available and "not installed" in st.detail
    b = TesseractBackend(cache=None)
    with pytest.raises(OCRError, match="not installed"):
        b.read(np.zeros((8, 8, 3), np.uint8))


@pytest.mark.skipif(shutil.which("tesseract") is None, reason="tesseract is not installed")
def test_tesseract_reads_sample():
    img, known = sample_image()
    b = TesseractBackend(cache=None)
    assert TesseractBackend.status().available
    assert known_text_cer(known, b.read(img)).cer <= 0.10
    with pytest.raises(OCRError, match="lang"):
        TesseractBackend(cache=None, lang="zzz_no_such_lang").read(img)


# --------------------------------------------------------------------------- ocr check / read CLI
def _run_cli(argv, capsys):
    from strings_bench.cli import cer, ocr

    parser = argparse.ArgumentParser(prog="strings-bench")
    sub = parser.add_subparsers(dest="command")
    ocr.add_parser(sub)
    cer.add_parser(sub)
    args = parser.parse_args(argv)
    try:
        rc = args.func(args)
    except StringsBenchError as exc:
        print(f"error: {exc}")
        rc = 1
    out = capsys.readouterr()
    return rc, out.out, out.err


def test_ocr_check_cli(capsys):
    rc, out, _ = _run_cli(["ocr", "check"], capsys)
    assert rc == 0, out
    for name in BACKENDS:
        assert name in out
    assert "'Extinguisher'" in out and "known-text CER" in out and "second read" in out


def test_ocr_read_then_cer_cli(tmp_path, capsys, monkeypatch):
    from PIL import Image

    monkeypatch.setenv("STRINGS_BENCH_CACHE", str(tmp_path / "cache"))
    (tmp_path / "gt").mkdir()
    (tmp_path / "render").mkdir()
    (tmp_path / "masks").mkdir()
    img, known = sample_image()
    Image.fromarray(img).save(tmp_path / "gt" / "v0.png")
    Image.fromarray(_noisy(img, 3, sigma=4)).save(tmp_path / "render" / "v0.png")
    Image.fromarray(np.full(img.shape[:2], 255, np.uint8)).save(tmp_path / "masks" / "v0.png")
    for side in ("gt", "render"):
        rc, out, _ = _run_cli(["ocr", "read", str(tmp_path / side), "--masks", str(tmp_path / "masks"),
                               "-o", str(tmp_path / f"{side}.json")], capsys)
        assert rc == 0, out
    doc = json.loads((tmp_path / "gt.json").read_text())
    assert doc["backend"]["name"] == "rapidocr" and "v0.png" in doc["images"]
    rc, out, _ = _run_cli(["cer", str(tmp_path / "gt.json"), str(tmp_path / "render.json"), "--json"], capsys)
    res = json.loads(out)
    assert rc == 0 and res["chars"] >= 45 and res["cer"] <= 0.10
