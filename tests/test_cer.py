"""OCR-CER per the authors' protocol: hand-worked cases, an independent pooled-CER check, the CLI."""

from __future__ import annotations

import argparse
import json
import math
import unicodedata

import numpy as np
import pytest

from strings_bench.eval.cer import (
    PROFILES,
    NormalizationProfile,
    dataset_cer,
    image_cer,
    known_text_cer,
    polygon_geometry,
    scene_cer,
)
from strings_bench.core.errors import StringsBenchError
from strings_bench.eval.ocr import Word

B = Word.from_box


def plain_levenshtein(a: str, b: str) -> int:
    """Textbook dynamic programme, independent of rapidfuzz."""
    prev = list(range(len(b) + 1))
    for i, ca in enumerate(a, 1):
        cur = [i]
        for j, cb in enumerate(b, 1):
            cur.append(min(prev[j] + 1, cur[j - 1] + 1, prev[j - 1] + (ca != cb)))
        prev = cur
    return prev[-1]


# --------------------------------------------------------------------------- hand-worked cases
def test_exact_and_one_typo():
    gt = [B("Hello", 0, 0, 100, 30), B("World", 150, 0, 250, 30)]
    assert image_cer(gt, [B("Hello", 2, 1, 101, 29), B("World", 150, 0, 250, 30)]).errors == 0
    r = image_cer(gt, [B("Helo", 0, 0, 100, 30), B("World", 150, 0, 250, 30)])
    assert (r.errors, r.chars) == (1, 10)
    assert r.cer == pytest.approx(0.1)


def test_one_gt_word_read_as_two():
    gt = [B("Extinguisher", 0, 0, 240, 40)]
    # Split into two boxes; ordering by x restores the word even when listed right-to-left.
    pred = [B("guisher", 100, 0, 240, 40), B("Extin", 0, 0, 100, 40)]
    r = image_cer(gt, pred)
    assert (r.errors, r.chars) == (0, 12)
    assert len(r.components) == 1 and r.components[0].pred_text == "extinguisher"
    # With a misread character in one part: exactly one error.
    r = image_cer(gt, [B("Extln", 0, 0, 100, 40), B("guisher", 100, 0, 240, 40)])
    assert r.errors == 1


def test_two_gt_words_read_as_one():
    gt = [B("FIRE", 0, 0, 100, 40), B("EXIT", 120, 0, 220, 40)]
    r = image_cer(gt, [B("FIRE EXIT", 0, 0, 220, 40)])  # spaces are removed by the profile
    assert (r.errors, r.chars) == (0, 8)
    r = image_cer(gt, [B("FIREEXT", 0, 0, 220, 40)])
    assert r.errors == 1


def test_vertical_text_is_ordered_by_y():
    # A vertical sign: TOP above BOTTOM, but BOTTOM's mean x is smaller, so x-order gets it wrong.
    gt = [B("TOP", 10, 0, 50, 30), B("BOTTOM", 0, 40, 40, 70)]
    pred = [B("TOPBOTTOM", 0, 0, 50, 70)]
    r = image_cer(gt, pred)
    assert r.errors == 0 and r.chars == 9
    # The test can fail: the x-ordered concatenation alone would cost this much.
    assert plain_levenshtein("bottomtop", "topbottom") > 0
    # Predictions in a column, listed bottom-first, are re-ordered by y too.
    gt_col = [B("A", 0, 0, 20, 20), B("B", 0, 20, 20, 40), B("C", 0, 40, 20, 60)]
    pred_col = [B("BC", 0, 25, 20, 60), B("A", 0, 0, 20, 22)]
    big = [B("ABC", 0, 0, 20, 60)]
    assert image_cer(big, pred_col).errors == 0
    assert image_cer(gt_col, [B("ABC", 0, 0, 20, 60)]).errors == 0


def test_missing_words_cost_their_length():
    gt = [B("abc", 0, 0, 60, 20), B("defg", 100, 0, 180, 20), B("hi", 0, 100, 40, 120)]
    r = image_cer(gt, [B("abc", 0, 0, 60, 20)])
    assert (r.errors, r.chars) == (6, 9)
    r = image_cer(gt, [])
    assert (r.errors, r.chars) == (9, 9) and r.cer == 1.0


def test_extra_rendered_words_cost_nothing_outside_gt_components():
    gt = [B("abc", 0, 0, 60, 20)]
    r = image_cer(gt, [B("abc", 0, 0, 60, 20), B("zzzz", 300, 300, 380, 320), B("q", 61, 0, 70, 20)])
    assert r.errors == 0
    # A prediction overlapping a GT word joins its component and its characters do count.
    r = image_cer(gt, [B("abc", 0, 0, 50, 20), B("x", 40, 0, 60, 20)])
    assert r.errors == 1


def test_cer_may_exceed_one():
    r = image_cer([B("ab", 0, 0, 40, 20)], [B("abcdefg", 0, 0, 40, 20)])
    assert (r.errors, r.chars) == (5, 2) and r.cer == 2.5


def test_iou_threshold_boundary():
    gt = [B("word", 0, 0, 100, 10)]
    # IoU = 100 / 1900 = 0.053 < 0.1: no match, the GT word costs its length.
    assert image_cer(gt, [B("word", 90, 0, 190, 10)]).errors == 4
    # IoU = 200 / 1800 = 0.111 >= 0.1: matched.
    assert image_cer(gt, [B("word", 80, 0, 180, 10)]).errors == 0
    # The threshold is a parameter.
    assert image_cer(gt, [B("word", 80, 0, 180, 10)], iou_threshold=0.2).errors == 4


def test_empty_gt_image():
    r = image_cer([], [B("stray", 0, 0, 10, 10)])
    assert (r.errors, r.chars) == (0, 0) and math.isnan(r.cer)
    s = scene_cer({
        "empty": ([], [B("stray", 0, 0, 10, 10)]),
        "blank_text": ([B("  ", 0, 0, 10, 10)], []),
        "ok": ([B("abcd", 0, 0, 40, 10)], [B("abcf", 0, 0, 40, 10)]),
    })
    assert s.ignored_empty_gt == ("blank_text", "empty")
    assert set(s.images) == {"ok"} and (s.errors, s.chars) == (1, 4)
    s_all_empty = scene_cer({"a": ([], [])})
    assert math.isnan(s_all_empty.cer) and s_all_empty.n_ignored_empty_gt == 1


def test_invalid_and_degenerate_polygons():
    bowtie = [[0, 0], [100, 30], [100, 0], [0, 30]]  # self-intersecting: repaired, not dropped
    geom = polygon_geometry(bowtie)
    assert geom is not None and geom.is_valid and geom.area == pytest.approx(1500.0)
    assert image_cer([Word("abc", bowtie)], [B("abc", 0, 0, 100, 30)]).errors == 0
    degenerate = [
        [[0, 0], [50, 0], [100, 0]],  # collinear: zero area
        [[0, 0], [100, 30]],  # two points
        [[0, 0], [0, 0], [0, 0], [0, 0]],  # a point
        [[0, 0], [np.nan, 0], [100, 30], [0, 30]],  # not finite
    ]
    for poly in degenerate:
        assert polygon_geometry(poly) is None
        # A degenerate GT word never matches: it costs its length even under a perfect reading.
        assert image_cer([Word("abc", poly)], [B("abc", 0, 0, 100, 30)]).errors == 3
        # A degenerate prediction never matches either.
        assert image_cer([B("abc", 0, 0, 100, 30)], [Word("abc", poly)]).errors == 3
    # Google Vision can give an empty polygon: never matches, and does not crash ordering.
    assert image_cer([B("abc", 0, 0, 100, 30)], [Word("abc", np.zeros((0, 2)))]).errors == 3


def test_non_ascii_text():
    nfc = "café"
    nfd = unicodedata.normalize("NFD", nfc)
    assert nfc != nfd
    box = (0, 0, 100, 30)
    assert image_cer([B(nfc, *box)], [B(nfd.upper(), *box)]).errors == 0  # NFC + lower-case
    r = image_cer([B("Straße", *box)], [B("STRASSE", *box)])
    assert (r.errors, r.chars) == (2, 6)  # ß -> s plus one inserted s
    assert image_cer([B("東京駅", *box)], [B("東京", *box)]).errors == 1
    r = image_cer([B("नमस्ते", *box)], [B("नमस्ते", *box)])
    assert r.errors == 0 and r.chars == len("नमस्ते")


def test_profiles():
    box = (0, 0, 100, 30)
    assert image_cer([B("Exit Now", *box)], [B("exitnow", *box)], profile="paper").errors == 0
    assert image_cer([B("Exit Now", *box)], [B("exitnow", *box)], profile="case-sensitive").errors == 2
    assert image_cer([B("ﬁre", *box)], [B("fire", *box)], profile="nfkc-casefold").errors == 0
    assert PROFILES["paper"].normalize(" A\tb\u00a0C\n") == "abc"
    with pytest.raises(StringsBenchError, match="unknown normalisation profile"):
        image_cer([], [], profile="nope")
    with pytest.raises(StringsBenchError):
        NormalizationProfile("bad", case="upper")


def test_scene_is_character_weighted_and_failures_are_counted():
    per_image = {
        "short": ([B("ab", 0, 0, 20, 10)], [B("ax", 0, 0, 20, 10)]),  # 1 / 2
        "long": ([B("abcdefghijklmnopqr", 0, 0, 180, 10)], [B("abcdefghijklmnopqr", 0, 0, 180, 10)]),  # 0 / 18
        "gt_failed": (None, [B("ab", 0, 0, 20, 10)]),
        "pred_failed": ([B("abcdef", 0, 0, 60, 10)], None),
    }
    s = scene_cer(per_image)
    assert (s.errors, s.chars) == (1, 20)
    assert s.cer == pytest.approx(0.05)  # not the mean of image CERs (0.25)
    assert s.ignored_failed == ("gt_failed", "pred_failed") and s.n_ignored_failed == 2
    assert set(s.images) == {"short", "long"}
    d = s.to_dict()
    assert d["ignored"] == {"empty_gt": [], "failed": ["gt_failed", "pred_failed"]}
    assert d["profile"]["name"] == "paper"
    json.dumps(d)
    assert dataset_cer({"a": s, "b": scene_cer({"x": ([B("ab", 0, 0, 20, 10)], [])})}) == pytest.approx((0.05 + 1.0) / 2)


def test_known_text_cer_uses_known_words_as_gt():
    known = [B("STOP", 0, 0, 80, 30), B("HERE", 0, 40, 80, 70)]
    r = known_text_cer(known, [B("STOP", 1, 1, 79, 29), B("HFRE", 0, 40, 80, 70), B("noise", 200, 200, 260, 230)])
    assert (r.errors, r.chars) == (1, 8)


def test_accepts_dicts_and_pairs():
    gt = [{"text": "abc", "polygon": [[0, 0], [30, 0], [30, 10], [0, 10]]}]
    pred = [("abd", [[0, 0], [30, 0], [30, 10], [0, 10]])]
    assert image_cer(gt, pred).errors == 1
    with pytest.raises(StringsBenchError):
        image_cer([42], [])


# --------------------------------------------------------------------------- independent pooled CER
def _random_text(rng, alphabet="abcdefghijklmnopqrstuvwxyzÄÖéß0123456789", lo=1, hi=9):
    return "".join(rng.choice(list(alphabet), size=int(rng.integers(lo, hi + 1))))


def _perturb(rng, text):
    chars = list(text)
    for _ in range(int(rng.integers(0, 4))):
        op = rng.integers(0, 3)
        pos = int(rng.integers(0, len(chars) + 1))
        if op == 0:
            chars.insert(pos, str(rng.choice(list("xyz!"))))
        elif op == 1 and chars:
            chars.pop(min(pos, len(chars) - 1))
        elif chars:
            chars[min(pos, len(chars) - 1)] = str(rng.choice(list("qrs")))
    return "".join(chars)


@pytest.mark.parametrize("seed", range(12))
def test_agrees_with_plain_pooled_cer_on_one_to_one_words(seed):
    """Well-separated words read one-to-one (or missed): both definitions coincide."""
    rng = np.random.default_rng(seed)
    per_image = {}
    edits = chars = 0
    for k in range(int(rng.integers(1, 5))):
        gt, pred = [], []
        for r in range(4):
            for c in range(3):
                if rng.random() < 0.3:
                    continue
                x0, y0 = c * 200.0, r * 100.0
                text = _random_text(rng)
                gt.append(B(text, x0, y0, x0 + 150, y0 + 40))
                norm = unicodedata.normalize("NFC", text).lower()
                if rng.random() < 0.15:  # missed by the OCR
                    edits += len(norm)
                else:
                    read = _perturb(rng, text)
                    jitter = rng.uniform(-8, 8, 4)
                    pred.append(B(read, x0 + jitter[0], y0 + jitter[1], x0 + 150 + jitter[2], y0 + 40 + jitter[3]))
                    edits += plain_levenshtein(norm, unicodedata.normalize("NFC", read).lower())
                chars += len(norm)
        rng.shuffle(pred)
        per_image[f"img{k}"] = (gt, pred)
    s = scene_cer(per_image)
    if chars == 0:
        assert math.isnan(s.cer)
        return
    assert (s.errors, s.chars) == (edits, chars)
    assert s.cer == pytest.approx(edits / chars, abs=1e-12)


# --------------------------------------------------------------------------- CLI
def _run_cli(argv, capsys):
    from strings_bench.cli.cer import add_cli

    parser = argparse.ArgumentParser(prog="strings-bench")
    add_cli(parser.add_subparsers(dest="command"))
    args = parser.parse_args(argv)
    try:
        rc = args.func(args)
    except StringsBenchError as exc:
        print(f"error: {exc}")
        rc = 1
    out = capsys.readouterr()
    return rc, out.out, out.err


def test_cli_module_is_registered():
    import strings_bench.cli as cli

    assert "strings_bench.cli.cer" in cli.COMMAND_MODULES


def _words(*items):
    return [{"text": t, "polygon": [[x0, y0], [x1, y0], [x1, y1], [x0, y1]], "confidence": 0.9} for t, x0, y0, x1, y1 in items]


def test_cli_cer_file_and_folder(tmp_path, capsys):
    gt = {
        "format": "strings-bench-ocr/1",
        "backend": {"name": "gcv", "version": "v1", "settings": {}},
        "images": {
            "a.png": _words(("Hello", 0, 0, 100, 30), ("World", 150, 0, 250, 30)),
            "b.png": _words(("EXIT", 0, 0, 80, 30)),
            "c.png": [],
            "d.png": None,
            "e.png": _words(("stop", 0, 0, 80, 30)),
        },
    }
    (tmp_path / "gt.json").write_text(json.dumps(gt))
    pred_dir = tmp_path / "pred"
    pred_dir.mkdir()
    (pred_dir / "a.png.json").write_text(json.dumps(_words(("Helo", 0, 0, 100, 30), ("World", 150, 0, 250, 30))))
    # A raw Cloud Vision answer, zero coordinates omitted as the API does.
    raw = {"responses": [{"textAnnotations": [
        {"description": "EXT", "boundingPoly": {"vertices": [{}, {"x": 80}, {"x": 80, "y": 30}, {"y": 30}]}},
        {"description": "EXT", "boundingPoly": {"vertices": [{}, {"x": 80}, {"x": 80, "y": 30}, {"y": 30}]}},
    ]}]}
    (pred_dir / "b.png.json").write_text(json.dumps(raw))
    (pred_dir / "c.png.json").write_text("[]")
    (pred_dir / "d.png.json").write_text("[]")
    (pred_dir / "extra.png.json").write_text("[]")
    # e.png has no prediction: counted as a failure, with a warning.

    rc, out, err = _run_cli(["cer", str(tmp_path / "gt.json"), str(pred_dir)], capsys)
    assert rc == 0, out + err
    assert "a.png" in out and "b.png" in out and "total" in out
    assert "1 with no GT text" in out and "2 OCR failure(s)" in out
    assert "no prediction" in err and "extra.png" in err

    rc, out, err = _run_cli(["cer", str(tmp_path / "gt.json"), str(pred_dir), "--json", "--out", str(tmp_path / "r.json")], capsys)
    assert rc == 0
    doc = json.loads(out)
    assert {"images", "errors", "chars", "cer", "ignored"} <= set(doc)
    assert doc["images"]["a.png"] == {"errors": 1, "chars": 10, "cer": 0.1}
    assert doc["images"]["b.png"] == {"errors": 1, "chars": 4, "cer": 0.25}
    assert (doc["errors"], doc["chars"]) == (2, 14)
    assert doc["cer"] == pytest.approx(2 / 14)
    assert doc["ignored"]["empty_gt"] == ["c.png"]
    assert doc["ignored"]["failed"] == ["d.png", "e.png"]
    assert doc["ignored"]["missing_prediction"] == ["e.png"]
    assert doc["gt_backend"]["name"] == "gcv"
    assert json.loads((tmp_path / "r.json").read_text()) == doc


def test_cli_cer_single_files_and_bad_input(tmp_path, capsys):
    (tmp_path / "gt_view.json").write_text(json.dumps({"words": _words(("abc", 0, 0, 30, 10))}))
    (tmp_path / "render.json").write_text(json.dumps(_words(("abd", 0, 0, 30, 10))))
    rc, out, _ = _run_cli(["cer", str(tmp_path / "gt_view.json"), str(tmp_path / "render.json"), "--json"], capsys)
    assert rc == 0 and json.loads(out)["errors"] == 1

    (tmp_path / "broken.json").write_text("{not json")
    rc, out, _ = _run_cli(["cer", str(tmp_path / "broken.json"), str(tmp_path / "render.json")], capsys)
    assert rc == 1 and "broken.json" in out and "not valid JSON" in out
    (tmp_path / "badpoly.json").write_text(json.dumps({"images": {"x": [{"text": "a", "polygon": [1, 2, 3]}]}}))
    rc, out, _ = _run_cli(["cer", str(tmp_path / "badpoly.json"), str(tmp_path / "render.json")], capsys)
    assert rc == 1 and "badpoly.json" in out and "polygon" in out
    rc, out, _ = _run_cli(["cer", str(tmp_path / "missing.json"), str(tmp_path / "render.json")], capsys)
    assert rc == 1 and "do not exist" in out
