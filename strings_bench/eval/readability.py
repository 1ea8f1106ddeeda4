"""Word-crop readability: the recogniser alone on each reference word, read from the render and the GT view.

OCR-CER (detector + recogniser) saturates at 1.0 while text is blurred: the detector finds no line in
the render and every method scores the same. Here no detector runs. For each *reference word* of a
test view (a polygon and a string) the word's quadrilateral is rectified from the render and from
the ground-truth view to the recogniser's input (`rectify`), and RapidOCR's recognition model
(`strings_bench.eval.ocr.rapid.Recognizer`) gives per-column probabilities over its dictionary.
Per cell, for the render and for the GT view (the ceiling):

- `word_cer`: total edit distance of the recognised text (greedy CTC decoding, as RapidOCR
  decodes) to the reference, over the total reference characters; both normalised as the paper
  (`str.lower`, the space character removed). Characters outside the dictionary count as
  reference characters here (the recogniser cannot produce them: each is an error).
- `word_acc`: the fraction of reference words read exactly (after that normalisation).
- `text_nll`: the CTC negative log-likelihood of the normalised reference string under the
  per-column output, summed over words and divided by the reference characters scored (nats per
  character). The output is folded to the normalisation first: the probabilities of classes with
  the same `str.lower` are added, and the space class is added to the blank (spaces are not
  characters of the normalised text). Reference characters outside the folded dictionary are
  left out of the string and counted (`oov_chars`); a word the recogniser's columns cannot hold
  (fewer columns than the CTC path needs) is left out and counted (`infeasible_words`).

Reference words per view (`reference_words`): on scenes with known text, the known words at least
`cer.KNOWN_TEXT_MIN_HEIGHT_PX` tall (the known-text CER's legibility filter; excluded ones counted);
on every scene, the words the GT view's OCR read (the paper's reference). A GT-OCR word that
overlaps a legible known word (IoU >= 0.1, the CER's matching rule) is the same word: the known one
stands for it in the headline figures. (A GT-OCR word over a known word below the height filter
stays: the OCR found it legible.) Each source's own figures are kept too (`by_source`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Iterable, Mapping

import numpy as np

from strings_bench.core import vec3
from strings_bench.core.errors import StringsBenchError

REC_HEIGHT = 48  # the recogniser's input height (rapid.REC_HEIGHT; kept here so tests need no model)
# Margin around the word's box in the rectified crop, as a fraction of the box height: RapidOCR's
# detector boxes are unclipped (ratio 1.6) around the glyphs; known-word polygons are tight.
CROP_MARGIN = 0.15
# A crop this many times taller than wide (after rectification, words of 2+ characters) is vertical
# text whose box is not in reading order: it is turned by 90 degrees (RapidOCR's own rule is 1.5).
VERTICAL_RATIO = 1.5
PROB_FLOOR = 1e-12  # probabilities are clipped below here before the log (float32 softmax underflows to 0)
SOURCES = ("known", "gt_ocr")


def normalize(text: str) -> str:
    """The paper's text normalisation: lower case, the space character removed."""
    return str(text).lower().replace(" ", "")


# ---- CTC --------------------------------------------------------------------------------------------
def ctc_nll(log_probs: np.ndarray, labels: Iterable[int], blank: int = 0) -> float:
    """-log P(labels | per-column log-probabilities) under CTC (sum over all alignments), in nats.

    log_probs: (T, C) natural-log probabilities per column. labels: class indices (no blank).
    Returns inf when no alignment exists (T smaller than the labels plus their repeated neighbours).
    Forward algorithm in log space, float64.
    """
    lp = np.asarray(log_probs, dtype=np.float64)
    lab = [int(x) for x in labels]
    if lp.ndim != 2:
        raise StringsBenchError(f"ctc_nll: log_probs must be (T, C), got shape {lp.shape}", hint="one crop at a time")
    if any(x == blank for x in lab):
        raise StringsBenchError("ctc_nll: the label sequence contains the blank", hint="labels are characters only")
    T = lp.shape[0]
    ext = [blank]
    for x in lab:
        ext += [x, blank]
    S = len(ext)
    ext_a = np.array(ext)
    # s may come from s - 2 when ext[s] is a label different from ext[s - 2].
    skip = np.zeros(S, dtype=bool)
    skip[2:] = (ext_a[2:] != blank) & (ext_a[2:] != ext_a[:-2])
    neg = -np.inf
    alpha = np.full(S, neg)
    if T == 0:
        return 0.0 if not lab else math.inf
    alpha[0] = lp[0, blank]
    if S > 1:
        alpha[1] = lp[0, ext[1]]
    for t in range(1, T):
        prev = alpha
        a1 = np.concatenate([[neg], prev[:-1]])
        a2 = np.full(S, neg)
        a2[2:] = np.where(skip[2:], prev[:-2], neg)
        alpha = np.logaddexp(np.logaddexp(prev, a1), a2) + lp[t, ext_a]
    total = np.logaddexp(alpha[-1], alpha[-2]) if S > 1 else alpha[-1]
    return float(-total) if np.isfinite(total) else math.inf


def ctc_min_columns(labels: Iterable[int]) -> int:
    """Fewest columns a CTC path for `labels` needs: one per label plus a blank between repeats."""
    lab = list(labels)
    return len(lab) + sum(1 for a, b in zip(lab, lab[1:]) if a == b)


def greedy_decode(probs: np.ndarray, characters: list[str], blank: int = 0) -> str:
    """RapidOCR's CTC decoding: argmax per column, repeats collapsed, blanks dropped."""
    idx = np.asarray(probs).argmax(axis=1)
    keep = np.ones(len(idx), dtype=bool)
    keep[1:] = idx[1:] != idx[:-1]
    keep &= idx != blank
    return "".join(characters[i] for i in idx[keep])


class FoldedAlphabet:
    """The recogniser's classes folded to the normalised text: classes with the same `str.lower` are one
    character; the space class joins the blank (index 0)."""

    def __init__(self, characters: list[str], blank: int = 0):
        self.characters = list(characters)
        self.blank = blank
        groups: dict[str, list[int]] = {}
        space = []
        for i, ch in enumerate(self.characters):
            if i == blank:
                continue
            if ch == " ":
                space.append(i)
                continue
            low = ch.lower()
            groups.setdefault(low if len(low) == 1 else ch, []).append(i)
        self.groups = groups
        self.blank_group = [blank] + space

    def encode(self, text: str) -> tuple[list[str], int]:
        """(the normalised text's characters that the dictionary has, the number it lacks)."""
        chars = list(normalize(text))
        kept = [c for c in chars if c in self.groups]
        return kept, len(chars) - len(kept)

    def nll(self, probs: np.ndarray, text: str) -> tuple[float, int, int]:
        """(CTC NLL in nats of the normalised `text` under folded probabilities, characters scored,
        characters outside the dictionary). NaN NLL when nothing is left to score."""
        kept, oov = self.encode(text)
        if not kept:
            return math.nan, 0, oov
        p = np.asarray(probs)
        uniq = list(dict.fromkeys(kept))

        def folded(idx: list[int]) -> np.ndarray:  # the columns taken first, then float64: the same sums
            return p[:, idx].astype(np.float64, copy=False).sum(axis=1)

        cols = [folded(self.blank_group)] + [folded(self.groups[c]) for c in uniq]
        lp = np.log(np.maximum(np.stack(cols, axis=1), PROB_FLOOR))
        labels = [uniq.index(c) + 1 for c in kept]
        if ctc_min_columns(labels) > lp.shape[0]:
            return math.inf, len(kept), oov
        return ctc_nll(lp, labels, blank=0), len(kept), oov


# ---- rectification -----------------------------------------------------------------------------------
def reading_box(polygon: Any) -> np.ndarray | None:
    """A word's outline as 4 corners in reading order (TL, TR, BR, BL as read), or None when unusable.

    4-point polygons are taken as given (known words and the OCR backends give reading order); other
    polygons become their minimum rotated rectangle, long side first, starting at the top-left.
    """
    pts = np.asarray(polygon, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 2 or len(pts) < 3 or not np.all(np.isfinite(pts)):
        return None
    if len(pts) == 4:
        q = pts
    else:
        import cv2

        q = cv2.boxPoints(cv2.minAreaRect(pts.astype(np.float32))).astype(np.float64)
        if vec3.norm_2d(q[1] - q[0]) < vec3.norm_2d(q[2] - q[1]):
            q = np.roll(q, -1, axis=0)  # long side first
        if q[0, 0] + q[0, 1] > q[2, 0] + q[2, 1]:
            q = np.roll(q, 2, axis=0)  # start at the top-left
    w = 0.5 * (vec3.norm_2d(q[1] - q[0]) + vec3.norm_2d(q[2] - q[3]))
    h = 0.5 * (vec3.norm_2d(q[3] - q[0]) + vec3.norm_2d(q[2] - q[1]))
    return q if w > 0.5 and h > 0.5 else None


def box_size(quad: np.ndarray) -> tuple[float, float]:
    """(width along the reading direction, height across it) of a reading-order quad: mean edge lengths."""
    q = np.asarray(quad, dtype=np.float64)
    return (0.5 * (vec3.norm_2d(q[1] - q[0]) + vec3.norm_2d(q[2] - q[3])),
            0.5 * (vec3.norm_2d(q[3] - q[0]) + vec3.norm_2d(q[2] - q[1])))


def rectify(image: np.ndarray, quad: np.ndarray, height: int = REC_HEIGHT, margin: float = CROP_MARGIN,
            turn: int = 0) -> np.ndarray:
    """The word inside `quad` (reading order) warped to an upright `height`-pixel crop, aspect ratio kept.

    A perspective warp (bicubic, borders replicated) maps the quad to a rectangle with `margin` x its
    height of context on every side. `turn` (0, 90, 270) turns the box counterclockwise first: the
    corners are re-ordered so the crop comes out turned by that many degrees. image: HxWx3 uint8 RGB.
    """
    import cv2

    q = np.asarray(quad, dtype=np.float64)
    if turn:
        # Turning the crop counterclockwise by 90 = its top-right corner becomes the top-left.
        q = np.roll(q, -(turn // 90) % 4, axis=0)
    w, h = box_size(q)
    hh = height / (1 + 2 * margin)  # the box's height in the crop
    m = margin * hh
    ww = w * hh / h
    out_w = max(1, int(round(ww + 2 * m)))
    dst = np.array([[m, m], [m + ww, m], [m + ww, m + hh], [m, m + hh]], dtype=np.float32)
    H = cv2.getPerspectiveTransform(q.astype(np.float32), dst)
    img = np.ascontiguousarray(image)
    return cv2.warpPerspective(img, H, (out_w, height), flags=cv2.INTER_CUBIC, borderMode=cv2.BORDER_REPLICATE)


def turn_candidates(quad: np.ndarray, text: str, ratio: float = VERTICAL_RATIO) -> list[int]:
    """Turns to try for a word: [0], or, for a box `ratio` times taller than wide holding 2+ characters
    (vertical text whose corners are not in reading order), [90, 270] (counterclockwise; 90 first,
    RapidOCR's own turn). One-character words are never turned: an "I" is tall."""
    w, h = box_size(quad)
    return [90, 270] if len(normalize(text)) >= 2 and h >= ratio * w else [0]


# ---- reference words ------------------------------------------------------------------------------------
@dataclass
class RefWord:
    """One reference word of a view: its string, reading-order box, where it came from, and whether it
    counts in the headline figures (a GT-OCR word overlapping a known word does not)."""

    text: str
    quad: np.ndarray
    source: str  # "known" | "gt_ocr"
    headline: bool = True
    turn: int | None = None  # chosen on the GT view (None: not yet)
    angle_deg: float | None = None  # viewing angle and distance where the scene knows them (scene.KnownWord)
    distance: float | None = None


def reference_words(known: Iterable[Any] | None, gt_ocr: Iterable[Any] | None,
                    min_text_height_px: float | None = None) -> tuple[list[RefWord], dict]:
    """The reference words of one view and what was left out.

    known: the view's known words (objects with .text/.polygon or (text, polygon)), None when the
    scene has no known text; gt_ocr: the GT view's OCR words, None when that OCR failed.
    Returns (words, {"known_illegible", "unusable_box", "empty_text"} counts).
    """
    import strings_bench.eval.cer as cer

    thr = cer.KNOWN_TEXT_MIN_HEIGHT_PX if min_text_height_px is None else min_text_height_px
    left = {"known_illegible": 0, "unusable_box": 0, "empty_text": 0}
    words: list[RefWord] = []
    known_geoms = []
    for k in known or []:
        text, poly = (k.text, k.polygon) if hasattr(k, "text") else k
        if not normalize(text):
            left["empty_text"] += 1
            continue
        h = cer.text_height_px(poly)
        if not (h >= thr):
            left["known_illegible"] += 1
            continue
        q = reading_box(poly)
        if q is None:
            left["unusable_box"] += 1
            continue
        words.append(RefWord(str(text), q, "known", angle_deg=getattr(k, "angle_deg", None),
                             distance=getattr(k, "distance", None)))
        g = cer.polygon_geometry(poly, "repair")
        if g is not None:
            known_geoms.append(g)
    for w in gt_ocr or []:
        if not normalize(w.text):
            left["empty_text"] += 1
            continue
        q = reading_box(w.polygon)
        if q is None:
            left["unusable_box"] += 1
            continue
        g = cer.polygon_geometry(w.polygon, "repair")
        overlaps = g is not None and any(
            g.intersects(k) and g.intersection(k).area >= cer.IOU_THRESHOLD * g.union(k).area for k in known_geoms)
        words.append(RefWord(str(w.text), q, "gt_ocr", headline=not overlaps))
    return words, left


# ---- reading and scoring ------------------------------------------------------------------------------
@dataclass
class Reading:
    """What the recogniser made of one crop of one reference word."""

    read: str
    nll: float  # nats, the whole word (NaN: no character to score; inf: infeasible)
    chars: int  # normalised reference characters
    nll_chars: int  # of them, in the dictionary (scored by the NLL)
    oov_chars: int
    errors: int  # edit distance of the normalised reading to the normalised reference

    @property
    def exact(self) -> bool:
        return self.errors == 0

    def to_dict(self) -> dict:
        return {"read": self.read, "nll": self.nll, "errors": self.errors, "nll_chars": self.nll_chars}


def score(probs: np.ndarray, characters: list[str], alphabet: FoldedAlphabet, text: str) -> Reading:
    """Score one crop's per-column probabilities against the reference `text`."""
    from rapidfuzz.distance import Levenshtein

    read = greedy_decode(probs, characters)
    ref = normalize(text)
    nll, n_scored, oov = alphabet.nll(probs, text)
    return Reading(read, nll, len(ref), n_scored, oov, int(Levenshtein.distance(normalize(read), ref)))


def read_crops(recognizer, alphabet: FoldedAlphabet, crops: list[np.ndarray], texts: list[str]) -> list[Reading]:
    """Recognise rectified crops (one batch) and score each against its reference text."""
    if not crops:
        return []
    # float32, as the model gives them: score() converts only the columns it reads (the same values)
    probs = recognizer.probabilities(crops, dtype=np.float32)
    return [score(p, recognizer.characters, alphabet, t) for p, t in zip(probs, texts)]


def summarize(readings: list[Reading]) -> dict:
    """word_cer, word_acc, text_nll over a list of readings (NaN when empty), with their counts."""
    feasible = [r for r in readings if math.isfinite(r.nll)]
    chars = sum(r.chars for r in readings)
    nll_chars = sum(r.nll_chars for r in feasible)
    return {
        "word_cer": sum(r.errors for r in readings) / chars if chars else math.nan,
        "word_acc": sum(r.exact for r in readings) / len(readings) if readings else math.nan,
        "text_nll": sum(r.nll for r in feasible) / nll_chars if nll_chars else math.nan,
        "words": len(readings), "chars": chars, "nll_chars": nll_chars,
        "oov_chars": sum(r.oov_chars for r in readings),
        "infeasible_words": sum(1 for r in readings if r.nll == math.inf),
    }


def _u8(img: np.ndarray) -> np.ndarray:
    a = np.asarray(img)
    if a.dtype == np.uint8:
        return a
    return (np.clip(a.astype(np.float32), 0, 1) * 255.0 + 0.5).astype(np.uint8)


class SceneReadability:
    """Word-crop readability of one scene's test views; the GT side (references, turns, GT readings) is
    computed once and reused for every render of the scene."""

    def __init__(self, recognizer=None, min_text_height_px: float | None = None):
        if recognizer is None:
            from strings_bench.eval.ocr.rapid import get_recognizer

            recognizer = get_recognizer()
        self.recognizer = recognizer
        self.alphabet = FoldedAlphabet(recognizer.characters)
        self.min_text_height_px = min_text_height_px
        self._views: dict[str, tuple[list[RefWord], dict, list[Reading]]] = {}

    def describe(self) -> dict:
        import strings_bench.eval.cer as cer

        return {"recognizer": getattr(self.recognizer, "model", type(self.recognizer).__name__),
                "crop_height": REC_HEIGHT, "crop_margin": CROP_MARGIN, "vertical_ratio": VERTICAL_RATIO,
                "normalisation": "str.lower, ' ' removed", "prob_floor": PROB_FLOOR,
                "known_min_text_height_px": (cer.KNOWN_TEXT_MIN_HEIGHT_PX if self.min_text_height_px is None
                                             else self.min_text_height_px)}

    def _gt_side(self, name: str, gt: np.ndarray, known, gt_ocr):
        if name not in self._views:
            refs, left = reference_words(known, gt_ocr, self.min_text_height_px)
            img = _u8(gt)
            jobs = [(k, turn) for k, ref in enumerate(refs) for turn in turn_candidates(ref.quad, ref.text)]
            reads = read_crops(self.recognizer, self.alphabet, [rectify(img, refs[k].quad, turn=t) for k, t in jobs],
                               [refs[k].text for k, _ in jobs])
            best: dict[int, tuple[float, int, Reading]] = {}
            for (k, turn), r in zip(jobs, reads):
                key = r.nll if not math.isnan(r.nll) else math.inf
                if k not in best or key < best[k][0]:
                    best[k] = (key, turn, r)
            for k, ref in enumerate(refs):
                ref.turn = best[k][1]  # the turn that reads the GT view best is used for every render
            readings = [best[k][2] for k in range(len(refs))]
            self._views[name] = (refs, left, readings)
        return self._views[name]

    def evaluate(self, views: Mapping[str, tuple[np.ndarray, np.ndarray, Any, Any]]) -> dict:
        """Readability of one cell. views: {name: (render, gt, known words or None, GT OCR words or None)}.

        Returns {"render": summary, "gt": summary, "by_source": {source: {"render", "gt"}},
        "left_out": counts, "views": {name: [per-word records]}, "settings": describe()}.
        """
        import time

        import strings_bench.eval.cer as cer

        t0 = time.perf_counter()
        per_view: dict[str, list[dict]] = {}
        pooled: dict[tuple[str, str], list[Reading]] = {}
        left_total = {"known_illegible": 0, "unusable_box": 0, "empty_text": 0, "gt_ocr_failed_views": 0}
        for name, (render, gt, known, gt_ocr) in views.items():
            refs, left, gt_reads = self._gt_side(name, gt, known, gt_ocr)
            for k, v in left.items():
                left_total[k] += v
            left_total["gt_ocr_failed_views"] += gt_ocr is None
            img = _u8(render)
            records = []
            reads = read_crops(self.recognizer, self.alphabet, [rectify(img, ref.quad, turn=ref.turn or 0) for ref in refs],
                               [ref.text for ref in refs])
            for ref, g, r in zip(refs, gt_reads, reads):
                groups = [ref.source] + (["headline"] if ref.headline else [])
                for grp in groups:
                    pooled.setdefault((grp, "render"), []).append(r)
                    pooled.setdefault((grp, "gt"), []).append(g)
                width, _ = box_size(ref.quad)
                records.append({"text": ref.text, "source": ref.source, "headline": ref.headline,
                                "polygon": ref.quad.tolist(), "height_px": cer.text_height_px(ref.quad),
                                "width_px": width, "angle_deg": ref.angle_deg, "distance": ref.distance,
                                "turn": ref.turn or 0, "chars": r.chars,
                                "oov_chars": r.oov_chars, "gt": g.to_dict(), "render": r.to_dict()})
            per_view[name] = records
        return {
            "render": summarize(pooled.get(("headline", "render"), [])),
            "gt": summarize(pooled.get(("headline", "gt"), [])),
            "by_source": {s: {side: summarize(pooled.get((s, side), [])) for side in ("render", "gt")}
                          for s in SOURCES},
            "left_out": left_total,
            "views": per_view,
            "settings": self.describe(),
            "seconds": time.perf_counter() - t0,  # wall time of this call (GT crops included when first seen)
        }
