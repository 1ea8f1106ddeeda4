"""OCR-CER per the authors' protocol: hand-worked cases, an independent implementation of the
authors' rules (written here, not cer.py's helpers) checked on hand cases and random images, the CLI."""

from __future__ import annotations

import argparse
import json
import math
import unicodedata

import numpy as np
import pytest
import shapely.geometry

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
    r = image_cer(gt, [B("FIRE EXIT", 0, 0, 220, 40)])  # the space character is removed by the profile
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
    bowtie = [[0, 0], [100, 30], [100, 0], [0, 30]]  # self-intersecting
    # paper: never repaired, so the GT word is alone and costs its length even under a perfect reading.
    assert polygon_geometry(bowtie, "strict") is None
    assert image_cer([Word("abc", bowtie)], [B("abc", 0, 0, 100, 30)]).errors == 3
    assert image_cer([B("abc", 0, 0, 100, 30)], [Word("abc", bowtie)]).errors == 3
    # robust (deviation): repaired into two triangles of 750 px^2 each.
    geom = polygon_geometry(bowtie, "repair")
    assert geom is not None and geom.is_valid and geom.area == pytest.approx(1500.0)
    assert image_cer([Word("abc", bowtie)], [B("abc", 0, 0, 100, 30)], profile="robust").errors == 0
    degenerate = [
        [[0, 0], [50, 0], [100, 0]],  # collinear: zero area
        [[0, 0], [100, 30]],  # two points
        [[0, 0], [0, 0], [0, 0], [0, 0]],  # a point
        [[0, 0], [np.nan, 0], [100, 30], [0, 30]],  # not finite
    ]
    for poly in degenerate:
        for profile, rule in (("paper", "strict"), ("robust", "repair")):
            assert polygon_geometry(poly, rule) is None
            # A degenerate GT word never matches: it costs its length even under a perfect reading.
            assert image_cer([Word("abc", poly)], [B("abc", 0, 0, 100, 30)], profile=profile).errors == 3
            # A degenerate prediction never matches either.
            assert image_cer([B("abc", 0, 0, 100, 30)], [Word("abc", poly)], profile=profile).errors == 3
    # Google Vision can give an empty polygon: never matches, and does not crash ordering.
    assert image_cer([B("abc", 0, 0, 100, 30)], [Word("abc", np.zeros((0, 2)))]).errors == 3
    with pytest.raises(StringsBenchError, match="polygon rule"):
        polygon_geometry(bowtie, "fix")


def test_non_ascii_text():
    nfc = "café"
    nfd = unicodedata.normalize("NFD", nfc)
    assert nfc != nfd and len(nfd) == 5
    box = (0, 0, 100, 30)
    # paper: no Unicode normalisation; é (1 code point) vs e + U+0301 = 1 substitution + 1 insertion.
    assert image_cer([B(nfc, *box)], [B(nfd.upper(), *box)]).errors == 2
    assert image_cer([B(nfc, *box)], [B(nfd.upper(), *box)], profile="robust").errors == 0  # NFC + lower-case
    for profile in ("paper", "robust"):
        r = image_cer([B("Straße", *box)], [B("STRASSE", *box)], profile=profile)
        assert (r.errors, r.chars) == (2, 6)  # ß -> s plus one inserted s
        assert image_cer([B("東京駅", *box)], [B("東京", *box)], profile=profile).errors == 1
        r = image_cer([B("नमस्ते", *box)], [B("नमस्ते", *box)], profile=profile)
        assert r.errors == 0 and r.chars == len("नमस्ते")


def test_profiles():
    box = (0, 0, 100, 30)
    assert image_cer([B("Exit Now", *box)], [B("exitnow", *box)], profile="paper").errors == 0
    assert image_cer([B("Exit Now", *box)], [B("exitnow", *box)], profile="case-sensitive").errors == 2
    assert image_cer([B("ﬁre", *box)], [B("fire", *box)], profile="nfkc-casefold").errors == 0
    assert image_cer([B("ﬁre", *box)], [B("fire", *box)], profile="paper").errors == 2  # ﬁ is one code point
    assert PROFILES["paper"].normalize(" A\tb\u00a0C\n") == "a\tb\u00a0c\n"  # only ' ' goes
    assert PROFILES["robust"].normalize(" A\tb\u00a0C\n") == "abc"
    assert PROFILES["paper"].to_dict() == {"name": "paper", "unicode_form": None, "case": "lower",
                                           "whitespace": "space", "polygons": "strict"}
    assert PROFILES["robust"].to_dict() == {"name": "robust", "unicode_form": "NFC", "case": "lower",
                                            "whitespace": "all", "polygons": "repair"}
    # Only "robust" repairs polygons; the text variants keep the paper's polygon rule.
    assert [n for n, p in PROFILES.items() if p.polygons == "repair"] == ["robust"]
    assert NormalizationProfile("old", "NFC", "lower", "remove").whitespace == "all"  # the older name
    with pytest.raises(StringsBenchError, match="unknown CER profile"):
        image_cer([], [], profile="nope")
    with pytest.raises(StringsBenchError):
        NormalizationProfile("bad", case="upper")
    with pytest.raises(StringsBenchError, match="polygon rule"):
        NormalizationProfile("bad", polygons="fix")
    with pytest.raises(StringsBenchError, match="must be > 0"):
        image_cer([B("a", *box)], [], iou_threshold=0)


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
                norm = text.lower().replace(" ", "")
                if rng.random() < 0.15:  # missed by the OCR
                    edits += len(norm)
                else:
                    read = _perturb(rng, text)
                    jitter = rng.uniform(-8, 8, 4)
                    pred.append(B(read, x0 + jitter[0], y0 + jitter[1], x0 + 150 + jitter[2], y0 + 40 + jitter[3]))
                    edits += plain_levenshtein(norm, read.lower().replace(" ", ""))
                chars += len(norm)
        rng.shuffle(pred)
        per_image[f"img{k}"] = (gt, pred)
    s = scene_cer(per_image)
    if chars == 0:
        assert math.isnan(s.cer)
        return
    assert (s.errors, s.chars) == (edits, chars)
    assert s.cer == pytest.approx(edits / chars, abs=1e-12)


# --------------------------------------------------------------------------- the authors' rules, independently
# A second implementation of docs/sources.md section 3, written from the rules and sharing no code with
# strings_bench.eval.cer: shapely Polygon.is_valid (never repaired), intersection/union areas, a plain
# union-find, the textbook Levenshtein above and the 4 orderings by mean x / mean y.
def ref_normalize(text: str) -> str:
    return text.lower().replace(" ", "")


def ref_polygon(points):
    pts = [(float(x), float(y)) for x, y in points]
    if len(pts) < 3 or not all(math.isfinite(c) for p in pts for c in p):
        return None  # the authors' code would raise here; such a word matches nothing
    poly = shapely.geometry.Polygon(pts)
    return poly if poly.is_valid else None


def ref_iou(a, b) -> float:
    if a is None or b is None:
        return 0.0
    union = a.union(b).area
    return a.intersection(b).area / union if union > 0 else 0.0


def ref_image_cer(gt, pred, threshold=0.1):
    """gt, pred: lists of (text, points). Returns (errors, chars)."""
    n, m = len(gt), len(pred)
    parent = list(range(n + m))

    def find(a):
        while parent[a] != a:
            parent[a] = parent[parent[a]]
            a = parent[a]
        return a

    gpoly = [ref_polygon(p) for _, p in gt]
    ppoly = [ref_polygon(p) for _, p in pred]
    for i in range(n):
        for j in range(m):
            if ref_iou(gpoly[i], ppoly[j]) >= threshold:
                parent[find(i)] = find(n + j)

    def mean(points, axis):
        return sum(float(p[axis]) for p in points) / len(points) if len(points) else 0.0

    groups: dict[int, tuple[list, list]] = {}
    for i in range(n):
        groups.setdefault(find(i), ([], []))[0].append(i)
    for j in range(m):
        if find(n + j) in groups:
            groups[find(n + j)][1].append(j)
    errors = 0
    for gi, pj in groups.values():
        best = None
        for ga in (0, 1):
            g_str = "".join(ref_normalize(gt[i][0]) for i in sorted(gi, key=lambda i: mean(gt[i][1], ga)))
            for pa in (0, 1):
                p_str = "".join(ref_normalize(pred[j][0]) for j in sorted(pj, key=lambda j: mean(pred[j][1], pa)))
                d = plain_levenshtein(g_str, p_str)
                best = d if best is None else min(best, d)
        errors += best
    return errors, sum(len(ref_normalize(t)) for t, _ in gt)


def box(x0, y0, x1, y1):
    return [(x0, y0), (x1, y0), (x1, y1), (x0, y1)]


def bowtie(x0, y0, x1, y1):
    return [(x0, y0), (x1, y1), (x1, y0), (x0, y1)]  # the box's corners in the wrong order: self-intersecting


NAN = float("nan")
PENTAGRAM = [(50, 0), (79, 91), (2, 35), (98, 35), (21, 91)]  # a star drawn in one stroke: self-intersecting
SPIKE = [(0, 0), (10, 0), (10, 10), (20, 10), (10, 10), (0, 10)]  # a zero-width spike: invalid ring
ANY = object()  # no hand value for the robust profile

# (id, gt words, pred words, (errors, chars) under paper, (errors, chars) under robust or None = same as paper).
# Every word is (text, points). The expected numbers are worked out by hand in the comments.
HAND_CASES = [
    # ---- invalid polygons: never repaired, the word joins no component
    ("bowtie-gt", [("abc", bowtie(0, 0, 100, 30))], [("abc", box(0, 0, 100, 30))], (3, 3),
     (0, 3)),  # robust: repaired to 1500 px^2 inside the 3000 px^2 box, IoU 0.5
    ("bowtie-pred", [("abc", box(0, 0, 100, 30))], [("abc", bowtie(0, 0, 100, 30))], (3, 3), (0, 3)),
    ("bowtie-both", [("abc", bowtie(0, 0, 100, 30))], [("abc", bowtie(0, 0, 100, 30))], (3, 3), (0, 3)),
    ("bowtie-pred-costs-nothing", [("abc", box(0, 0, 100, 30))], [("abc", box(0, 0, 100, 30)), ("zzz", bowtie(0, 0, 100, 30))],
     (0, 3), (3, 3)),  # robust: zzz joins (IoU 0.5); best order appends 3 characters
    ("collinear-3-gt", [("ab", [(0, 0), (50, 0), (100, 0)])], [("ab", box(0, 0, 100, 30))], (2, 2), None),
    ("collinear-4-pred", [("ab", box(0, 0, 100, 30))], [("ab", [(0, 0), (50, 0), (100, 0), (20, 0)])], (2, 2), None),
    ("collinear-diagonal-gt", [("abcd", [(0, 0), (10, 10), (20, 20), (5, 5)])], [("abcd", box(0, 0, 20, 20))], (4, 4), None),
    ("one-point-repeated", [("abc", [(0, 0)] * 4)], [("abc", box(0, 0, 100, 30))], (3, 3), None),
    ("duplicate-vertex-still-valid", [("abc", [(0, 0), (100, 0), (100, 0), (100, 30), (0, 30)])], [("abc", box(0, 0, 100, 30))],
     (0, 3), None),  # repeated vertices are valid in shapely: IoU 1
    ("duplicate-makes-triangle", [("ab", [(0, 0), (100, 0), (100, 0), (0, 30)])], [("ab", box(0, 0, 100, 30))],
     (0, 2), None),  # a valid triangle of 1500 px^2 inside 3000: IoU 0.5
    ("closed-ring", [("ab", box(0, 0, 100, 30) + [(0, 0)])], [("ab", box(0, 0, 100, 30))], (0, 2), None),
    ("counter-clockwise", [("ab", box(0, 0, 100, 30)[::-1])], [("ab", box(0, 0, 100, 30))], (0, 2), None),
    ("two-points-gt", [("abc", [(0, 0), (100, 30)])], [("abc", box(0, 0, 100, 30))], (3, 3), None),
    ("two-points-pred", [("abc", box(0, 0, 100, 30))], [("abc", [(0, 0), (100, 30)])], (3, 3), None),
    ("nan-gt", [("abc", [(0, 0), (NAN, 0), (100, 30), (0, 30)])], [("abc", box(0, 0, 100, 30))], (3, 3), None),
    ("nan-pred", [("abc", box(0, 0, 100, 30))], [("abc", [(0, 0), (100, 0), (100, NAN), (0, 30)])], (3, 3), None),
    ("inf-pred", [("abc", box(0, 0, 100, 30))], [("abc", [(0, 0), (math.inf, 0), (100, 30), (0, 30)])], (3, 3), None),
    ("empty-polygon-pred", [("abc", box(0, 0, 100, 30))], [("abc", [])], (3, 3), None),
    ("pentagram-gt", [("star", PENTAGRAM)], [("star", box(2, 0, 98, 91))], (4, 4), ANY),
    ("spike-gt", [("ab", SPIKE)], [("ab", box(0, 0, 10, 10))], (2, 2), (0, 2)),  # robust: the square left after repair
    ("bowtie-half-of-split", [("hello", box(0, 0, 100, 30))], [("hel", box(0, 0, 50, 30)), ("lo", bowtie(50, 0, 100, 30))],
     (2, 5), (0, 5)),  # paper: hello vs hel; robust: the bow-tie (750 px^2, IoU 0.25) joins, x order gives hello
    ("bowtie-among-valid", [("fire", bowtie(0, 0, 100, 30)), ("exit", box(120, 0, 220, 30))],
     [("fire", box(0, 0, 100, 30)), ("exit", box(120, 0, 220, 30))], (4, 8), (0, 8)),
    # ---- case and space
    ("case", [("Hello", box(0, 0, 100, 30))], [("hELLO", box(0, 0, 100, 30))], (0, 5), None),
    ("space-inside", [("Exit Now", box(0, 0, 100, 30))], [("exitnow", box(0, 0, 100, 30))], (0, 7), None),
    ("spaces-everywhere", [("a b c", box(0, 0, 100, 30))], [("abc", box(0, 0, 100, 30))], (0, 3), None),
    ("leading-trailing-spaces", [(" abc ", box(0, 0, 100, 30))], [("abc", box(0, 0, 100, 30))], (0, 3), None),
    ("double-space", [("a  b", box(0, 0, 100, 30))], [("ab", box(0, 0, 100, 30))], (0, 2), None),
    ("one-typo", [("Hello", box(0, 0, 100, 30)), ("World", box(150, 0, 250, 30))],
     [("Helo", box(0, 0, 100, 30)), ("World", box(150, 0, 250, 30))], (1, 10), None),
    # ---- other whitespace and Unicode forms: kept by the authors
    ("tab-in-gt", [("ab\tc", box(0, 0, 100, 30))], [("abc", box(0, 0, 100, 30))], (1, 4), (0, 3)),
    ("nbsp-in-gt", [("ab\u00a0c", box(0, 0, 100, 30))], [("ab c", box(0, 0, 100, 30))], (1, 4), (0, 3)),
    ("newline-in-pred", [("abc", box(0, 0, 100, 30))], [("ab\nc", box(0, 0, 100, 30))], (1, 3), (0, 3)),
    ("tab-vs-space", [("EXIT NOW", box(0, 0, 100, 30))], [("Exit\tNow", box(0, 0, 100, 30))], (1, 7), (0, 7)),
    ("ideographic-space", [("東京\u3000駅", box(0, 0, 100, 30))], [("東京駅", box(0, 0, 100, 30))], (1, 4), (0, 3)),
    ("nfc-gt-nfd-pred", [("caf\u00e9", box(0, 0, 100, 30))], [("cafe\u0301", box(0, 0, 100, 30))],
     (2, 4), (0, 4)),  # é -> e (substitution) + U+0301 (insertion)
    ("nfd-gt-nfc-pred", [("cafe\u0301", box(0, 0, 100, 30))], [("caf\u00e9", box(0, 0, 100, 30))],
     (2, 5), (0, 4)),  # the decomposed GT has 5 code points
    ("upper-accent", [("CAF\u00c9", box(0, 0, 100, 30))], [("caf\u00e9", box(0, 0, 100, 30))], (0, 4), None),
    ("sharp-s", [("Straße", box(0, 0, 100, 30))], [("STRASSE", box(0, 0, 100, 30))], (2, 6), None),
    ("dotted-capital-i", [("\u0130", box(0, 0, 100, 30))], [("i", box(0, 0, 100, 30))],
     (1, 2), None),  # str.lower gives i + U+0307 (2 code points, no composed form)
    ("ligature", [("\ufb01re", box(0, 0, 100, 30))], [("fire", box(0, 0, 100, 30))], (2, 3), None),
    # ---- split words (one GT word, several predictions)
    ("split-in-two", [("Extinguisher", box(0, 0, 240, 40))], [("Extin", box(0, 0, 100, 40)), ("guisher", box(100, 0, 240, 40))],
     (0, 12), None),  # IoU 100/240 and 140/240; x order
    ("split-listed-right-to-left", [("Extinguisher", box(0, 0, 240, 40))],
     [("guisher", box(100, 0, 240, 40)), ("Extin", box(0, 0, 100, 40))], (0, 12), None),
    ("split-with-typo", [("Extinguisher", box(0, 0, 240, 40))], [("Extln", box(0, 0, 100, 40)), ("guisher", box(100, 0, 240, 40))],
     (1, 12), None),
    ("split-fragment-below-iou", [("Extinguisher", box(0, 0, 240, 40))], [("Ex", box(0, 0, 20, 40)), ("tinguisher", box(20, 0, 240, 40))],
     (2, 12), None),  # Ex: IoU 20/240 = 0.083 < 0.1, left out; tinguisher joins: 2 deletions
    ("split-in-three-shuffled", [("abcdef", box(0, 0, 300, 30))],
     [("ef", box(200, 0, 300, 30)), ("ab", box(0, 0, 100, 30)), ("cd", box(100, 0, 200, 30))], (0, 6), None),
    # ---- merged words (several GT words, one prediction)
    ("merged", [("FIRE", box(0, 0, 100, 40)), ("EXIT", box(120, 0, 220, 40))], [("FIRE EXIT", box(0, 0, 220, 40))],
     (0, 8), None),  # IoU 100/220 each
    ("merged-with-typo", [("FIRE", box(0, 0, 100, 40)), ("EXIT", box(120, 0, 220, 40))], [("FIREEXT", box(0, 0, 220, 40))],
     (1, 8), None),
    ("merged-gt-listed-reversed", [("EXIT", box(120, 0, 220, 40)), ("FIRE", box(0, 0, 100, 40))], [("fireexit", box(0, 0, 220, 40))],
     (0, 8), None),
    ("merged-plus-unmatched", [("a", box(0, 0, 10, 10)), ("b", box(10, 0, 20, 10)), ("cccccccccc", box(0, 100, 1000, 110))],
     [("ab", box(0, 0, 20, 10))], (10, 12), None),  # c... matched by nothing: 10
    ("merged-and-split", [("New", box(0, 0, 60, 20)), ("York", box(70, 0, 140, 20))],
     [("Ne", box(0, 0, 30, 20)), ("wYork", box(30, 0, 140, 20))],
     (0, 7), None),  # IoUs: Ne-New 0.5, wYork-New 600/2800, wYork-York 1400/2200: one component
    ("chain-component", [("ab", box(0, 0, 100, 10)), ("cd", box(100, 0, 200, 10))],
     [("bc", box(50, 0, 150, 10)), ("d", box(150, 0, 250, 10))],
     (1, 4), None),  # one component through bc (IoU 1/3 with both): abcd vs bcd
    # ---- unmatched GT, unmatched predictions
    ("gt-missing", [("abc", box(0, 0, 60, 20)), ("defg", box(100, 0, 180, 20)), ("hi", box(0, 100, 40, 120))],
     [("abc", box(0, 0, 60, 20))], (6, 9), None),
    ("no-predictions", [("abc", box(0, 0, 60, 20)), ("defg", box(100, 0, 180, 20))], [], (7, 7), None),
    ("far-prediction", [("abc", box(0, 0, 60, 20))], [("abc", box(0, 0, 60, 20)), ("zzzz", box(300, 300, 380, 320))], (0, 3), None),
    ("low-iou-prediction-free", [("word", box(0, 0, 100, 10))], [("word", box(0, 0, 100, 10)), ("x", box(95, 0, 105, 10))],
     (0, 4), None),  # x: IoU 50/1050 < 0.1, its own component
    ("overlapping-prediction-costs", [("abc", box(0, 0, 60, 20))], [("abc", box(0, 0, 50, 20)), ("x", box(40, 0, 60, 20))],
     (1, 3), None),  # x: IoU 1/3, joins; abc + x
    ("read-lands-on-other-word", [("abc", box(0, 0, 60, 20)), ("de", box(200, 0, 240, 20))], [("abc", box(200, 0, 260, 20))],
     (6, 5), None),  # the read overlaps "de" (IoU 800/1200): abc missed (3) + de vs abc (3)
    ("cer-above-one", [("ab", box(0, 0, 40, 20))], [("abcdefg", box(0, 0, 40, 20))], (5, 2), None),
    # ---- the IoU threshold (inclusive)
    ("iou-0.053", [("word", box(0, 0, 100, 10))], [("word", box(90, 0, 190, 10))], (4, 4), None),  # 100/1900
    ("iou-0.111", [("word", box(0, 0, 100, 10))], [("word", box(80, 0, 180, 10))], (0, 4), None),  # 200/1800
    ("iou-exactly-0.1", [("ab", box(0, 0, 10, 10))], [("a", box(0, 0, 1, 10))], (1, 2), None),  # 10/100: joined
    ("iou-0.09", [("ab", box(0, 0, 10, 10))], [("a", box(0, 0, 0.9, 10))], (2, 2), None),  # 9/100: not joined
    # ---- orderings
    ("vertical-by-y", [("TOP", box(10, 0, 50, 30)), ("BOTTOM", box(0, 40, 40, 70))], [("TOPBOTTOM", box(0, 0, 50, 70))],
     (0, 9), None),  # x order would give bottomtop
    ("column-listed-bottom-first", [("A", box(0, 0, 20, 20)), ("B", box(0, 20, 20, 40)), ("C", box(0, 40, 20, 60))],
     [("BC", box(0, 25, 20, 60)), ("A", box(0, 0, 20, 22))], (0, 3), None),
    ("diagonal-rising", [("ab", box(0, 40, 40, 60)), ("cd", box(40, 0, 80, 20))], [("abcd", box(0, 0, 80, 60))],
     (0, 4), None),  # x order: abcd; IoU 800/4800 each
    ("diagonal-rising-read-by-y", [("ab", box(0, 40, 40, 60)), ("cd", box(40, 0, 80, 20))], [("cdab", box(0, 0, 80, 60))],
     (0, 4), None),  # y order of the GT: cd (mean y 10) then ab (50)
    ("preds-ordered-by-x-not-listed-order", [("ab", box(0, 0, 40, 20)), ("cd", box(40, 0, 80, 20))],
     [("cd", box(30, 0, 80, 12)), ("ab", box(0, 2, 50, 20))],
     (0, 4), None),  # one component (pred ab overlaps gt cd with IoU 180/1520); preds by x: ab, cd; by y: cd, ab
]


def _word(text, points):
    return Word(text, np.asarray(points, dtype=np.float64).reshape(-1, 2))


@pytest.mark.parametrize("case", HAND_CASES, ids=[c[0] for c in HAND_CASES])
def test_hand_cases_paper_profile(case):
    _, gt, pred, expected, _ = case
    r = image_cer([_word(*w) for w in gt], [_word(*w) for w in pred])  # default profile: paper
    assert (r.errors, r.chars) == expected
    assert ref_image_cer(gt, pred) == expected  # the independent implementation agrees with the hand value


@pytest.mark.parametrize("case", [c for c in HAND_CASES if c[4] is not ANY], ids=[c[0] for c in HAND_CASES if c[4] is not ANY])
def test_hand_cases_robust_profile(case):
    _, gt, pred, paper, robust = case
    r = image_cer([_word(*w) for w in gt], [_word(*w) for w in pred], profile="robust")
    assert (r.errors, r.chars) == (paper if robust is None else robust)


def test_hand_case_set_covers_the_brief():
    assert len(HAND_CASES) >= 50 and len({c[0] for c in HAND_CASES}) == len(HAND_CASES)
    # Every polygon the cases call invalid is invalid for shapely, and is not only a degenerate point list.
    for poly in (bowtie(0, 0, 100, 30), PENTAGRAM, SPIKE, [(0, 0), (50, 0), (100, 0)]):
        assert not shapely.geometry.Polygon(poly).is_valid
    assert shapely.geometry.Polygon([(0, 0), (100, 0), (100, 0), (100, 30), (0, 30)]).is_valid


def test_tab_only_gt_is_scored_by_paper_and_empty_for_robust():
    # A GT OCR that returns only a tab has one character for the authors (only ' ' is removed).
    per_image = {"tab": ([B("\t", 0, 0, 10, 10)], []), "ok": ([B("ab", 0, 0, 20, 10)], [B("ab", 0, 0, 20, 10)])}
    s = scene_cer(per_image)
    assert (s.errors, s.chars) == (1, 3) and s.ignored_empty_gt == ()
    s = scene_cer(per_image, profile="robust")
    assert (s.errors, s.chars) == (0, 2) and s.ignored_empty_gt == ("tab",)
    assert s.to_dict()["profile"]["name"] == "robust"


# --------------------------------------------------------------------------- random images vs the reference
_ALPHABET = list("abcXYZ09é") + ["e\u0301", " ", " ", "\t", "\u00a0", "\u0130", "ß", "\n"]


def _rand_text(rng, lo=1, hi=6):
    return "".join(_ALPHABET[int(k)] for k in rng.integers(0, len(_ALPHABET), size=int(rng.integers(lo, hi + 1))))


def _rand_polygon(rng, x0, y0, x1, y1):
    """A box with jittered corners, or one of the shapes OCR engines give: bow-tie, collinear points,
    repeated vertices, too few points, NaN."""
    kind = rng.choice(["box", "box", "box", "box", "box", "bowtie", "bowtie", "collinear", "duplicate", "two", "nan", "triangle"])
    j = rng.uniform(-2, 2, size=(4, 2))
    quad = [(x0 + j[0, 0], y0 + j[0, 1]), (x1 + j[1, 0], y0 + j[1, 1]), (x1 + j[2, 0], y1 + j[2, 1]), (x0 + j[3, 0], y1 + j[3, 1])]
    if kind == "box":
        return quad
    if kind == "bowtie":
        return [quad[0], quad[2], quad[1], quad[3]]
    if kind == "collinear":
        t = sorted(rng.uniform(0, 1, size=int(rng.integers(3, 5))))
        return [(x0 + (x1 - x0) * a, y0 + (y1 - y0) * a) for a in t]
    if kind == "duplicate":
        k = int(rng.integers(0, 4))
        return quad[: k + 1] + [quad[k]] + quad[k + 1:]
    if kind == "two":
        return [quad[0], quad[2]]
    if kind == "nan":
        quad[int(rng.integers(0, 4))] = (float("nan"), quad[0][1])
        return quad
    return quad[:3]


def _perturb_text(rng, text):
    chars = list(text)
    for _ in range(int(rng.integers(0, 3))):
        op, pos = int(rng.integers(0, 4)), int(rng.integers(0, len(chars) + 1))
        if op == 0:
            chars.insert(pos, _ALPHABET[int(rng.integers(0, len(_ALPHABET)))])
        elif op == 1 and chars:
            chars.pop(min(pos, len(chars) - 1))
        elif op == 2 and chars:
            chars[min(pos, len(chars) - 1)] = _ALPHABET[int(rng.integers(0, len(_ALPHABET)))]
        elif chars:
            k = min(pos, len(chars) - 1)
            chars[k] = chars[k].upper() if rng.random() < 0.5 else chars[k].lower()
    return "".join(chars)


def random_image(rng):
    """GT words crowded into a small area (so reads overlap several words), and reads of them:
    missed, read whole, split in two, merged with the next word, plus stray reads."""
    gt = []
    for _ in range(int(rng.integers(1, 7))):
        x0, y0 = rng.uniform(0, 200), rng.uniform(0, 80)
        w, h = rng.uniform(10, 120), rng.uniform(8, 40)
        gt.append((_rand_text(rng), _rand_polygon(rng, x0, y0, x0 + w, y0 + h), (x0, y0, x0 + w, y0 + h)))
    pred = []
    for k, (text, _, (x0, y0, x1, y1)) in enumerate(gt):
        u = rng.random()
        if u < 0.15:
            continue
        if u < 0.6:
            pred.append((_perturb_text(rng, text), _rand_polygon(rng, x0, y0, x1, y1)))
        elif u < 0.8:
            cut = int(rng.integers(0, len(text) + 1))
            xm = x0 + (x1 - x0) * rng.uniform(0.2, 0.8)
            pred.append((_perturb_text(rng, text[:cut]), _rand_polygon(rng, x0, y0, xm, y1)))
            pred.append((_perturb_text(rng, text[cut:]), _rand_polygon(rng, xm, y0, x1, y1)))
        else:
            nxt = gt[(k + 1) % len(gt)]
            bx0, by0, bx1, by1 = nxt[2]
            pred.append((_perturb_text(rng, text + " " + nxt[0]),
                         _rand_polygon(rng, min(x0, bx0), min(y0, by0), max(x1, bx1), max(y1, by1))))
    for _ in range(int(rng.integers(0, 3))):
        x0, y0 = rng.uniform(0, 250), rng.uniform(0, 100)
        pred.append((_rand_text(rng), _rand_polygon(rng, x0, y0, x0 + rng.uniform(10, 80), y0 + rng.uniform(8, 30))))
    rng.shuffle(pred)
    return [(t, p) for t, p, _ in gt], pred


RANDOM_SEED, RANDOM_IMAGES = 20260515, 400


def test_random_images_match_the_authors_rules_exactly():
    rng = np.random.default_rng(RANDOM_SEED)
    per_image, expected = {}, {}
    disagree_robust = 0
    for k in range(RANDOM_IMAGES):
        gt, pred = random_image(rng)
        gt_w, pred_w = [_word(*w) for w in gt], [_word(*w) for w in pred]
        ref = ref_image_cer(gt, pred)
        r = image_cer(gt_w, pred_w)
        assert (r.errors, r.chars) == ref, f"image {k}: gt={gt!r} pred={pred!r}"
        rob = image_cer(gt_w, pred_w, profile="robust")
        disagree_robust += (rob.errors, rob.chars) != ref
        per_image[f"img{k:03d}"] = (gt_w, pred_w)
        expected[f"img{k:03d}"] = ref
    # Scene totals: character-weighted over the images with GT characters.
    s = scene_cer(per_image)
    scored = {n: e for n, e in expected.items() if e[1] > 0}
    assert set(s.images) == set(scored)
    assert (s.errors, s.chars) == (sum(e for e, _ in scored.values()), sum(c for _, c in scored.values()))
    # The set exercises what separates the profiles (docs/ocr.md quotes this count: 400 images, seed above).
    assert disagree_robust > RANDOM_IMAGES // 10


# --------------------------------------------------------------------------- CLI
def _run_cli(argv, capsys):
    from strings_bench.cli.cer import add_parser

    parser = argparse.ArgumentParser(prog="strings-bench")
    add_parser(parser.add_subparsers(dest="command"))
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

    assert cli.COMMANDS["cer"].module == "strings_bench.cli.cer"


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


def test_cli_cer_profile(tmp_path, capsys):
    # A bow-tie GT box (as OCR engines give) and a tab inside a word: the two profiles part ways.
    gt_dir, pred_dir = tmp_path / "gt", tmp_path / "pred"
    gt_dir.mkdir()
    pred_dir.mkdir()
    bow = [{"text": "EXIT", "polygon": [[0, 0], [80, 30], [80, 0], [0, 30]]}]
    (gt_dir / "a.png.json").write_text(json.dumps(bow))
    (pred_dir / "a.png.json").write_text(json.dumps(_words(("EXIT", 0, 0, 80, 30))))
    (gt_dir / "b.png.json").write_text(json.dumps(_words(("ab\tc", 0, 0, 80, 30))))
    (pred_dir / "b.png.json").write_text(json.dumps(_words(("ABC", 0, 0, 80, 30))))
    # paper (default): the bow-tie never matches (4 errors / 4); the tab is a character (1 / 4).
    rc, out, _ = _run_cli(["cer", str(gt_dir), str(pred_dir), "--json"], capsys)
    doc = json.loads(out)
    assert rc == 0 and doc["profile"]["name"] == "paper" and doc["profile"]["polygons"] == "strict"
    assert doc["images"]["a.png"] == {"errors": 4, "chars": 4, "cer": 1.0}
    assert doc["images"]["b.png"] == {"errors": 1, "chars": 4, "cer": 0.25}
    # robust: repaired bow-tie (IoU 0.5) and the tab removed: no error.
    for flag in ("--cer-profile", "--profile"):  # --profile: the older name
        rc, out, _ = _run_cli(["cer", str(gt_dir), str(pred_dir), "--json", flag, "robust"], capsys)
        doc = json.loads(out)
        assert rc == 0 and doc["profile"]["name"] == "robust"
        assert (doc["errors"], doc["chars"]) == (0, 7)
    rc, out, _ = _run_cli(["cer", str(gt_dir), str(pred_dir)], capsys)
    assert rc == 0 and "CER profile paper" in out and "invalid polygons: strict" in out
    rc, out, _ = _run_cli(["cer", str(gt_dir), str(pred_dir), "--cer-profile", "nope"], capsys)
    assert rc == 1 and "unknown CER profile" in out
