"""OCR character error rate (OCR-CER) as the STRinGS authors compute it (docs/sources.md, section 3).

Size (~580 lines): the authors' CER rules and every named profile in one file, so that the exact `paper` profile reads against each deviation from it.

Per image, with GT words = OCR of the masked ground-truth view and predicted words = OCR of the
masked rendered view, under the default profile "paper" (the authors' rules, exactly):

1. A bipartite graph joins a GT word and a predicted word when their shapely polygons have
   IoU >= 0.1. The IoU is 0 when either polygon is not valid (`Polygon.is_valid` is False:
   self-intersecting "bow-tie" quads, collinear points ...); such polygons are never repaired, so
   the word joins no component. Fewer than 3 points or non-finite coordinates never match either
   (the authors' code would stop there; we do not).
2. For every connected component holding a GT word, the GT texts and the predicted texts are each
   normalised (`text.lower().replace(' ', '')`, nothing else) and concatenated, each side ordered
   by the mean x or the mean y of its polygon's vertices (ties: input order); the smallest
   Levenshtein distance of the 4 combinations is the component's error. A GT word in no edge is its
   own component and costs its length; components with only predicted words cost nothing.
3. Image CER = errors / GT characters (same normalisation; may exceed 1). Scene CER = total errors /
   total GT characters over the images with GT text; images whose GT OCR found no text are left
   out, and images where either OCR failed are left out; both are counted and named.

The non-default profile "robust" (a deviation, see `PROFILES` and docs/ocr.md) repairs invalid
polygons (shapely make_valid, then buffer(0)), applies Unicode NFC and removes all whitespace.

`known_text_cer` scores OCR of a view against the known strings (synthetic scenes) with the same
machinery, the known words taking the place of the GT OCR. Known words whose box is less than
`min_text_height_px` tall (across the reading direction, at evaluation resolution; see
`text_height_px`) are left out of it and counted separately: no OCR reads 4 px text, and the
paper's CER is filtered the same way by construction (only what the GT OCR reads is scored).
`known_scene_cer` is the per-scene figure with that filter.
"""

from __future__ import annotations

import math
import unicodedata
from dataclasses import dataclass, field, replace
from typing import Any, Iterable, Mapping, Sequence

import numpy as np
import shapely
from rapidfuzz.distance import Levenshtein
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from strings_bench.core import vec3
from strings_bench.core.errors import StringsBenchError
from strings_bench.eval.ocr.base import Word

IOU_THRESHOLD = 0.1
# Legibility filter of the known-text CER (not of the paper's CER): known words lower than this many
# pixels (across the reading direction, at evaluation resolution) are excluded and counted.
# Chosen by measurement on the synthetic scenes' ground-truth views (docs/ocr.md).
KNOWN_TEXT_MIN_HEIGHT_PX = 6.5


# --------------------------------------------------------------------------- CER profiles
POLYGON_RULES = ("strict", "repair")
WHITESPACE_RULES = ("space", "all", "keep")
UNIT_RULES = ("codepoints", "graphemes")


def graphemes(text: str) -> tuple[str, ...]:
    """The extended grapheme clusters of `text` (Unicode UAX #29, the `regex` package's \\X)."""
    import regex

    return tuple(regex.findall(r"\X", text))


@dataclass(frozen=True)
class NormalizationProfile:
    """How texts are made comparable and how word polygons are taken; recorded with every result.

    whitespace: "space" removes the space character ' ' only (the authors), "all" removes every
    Unicode whitespace (tabs, newlines, NBSP ...), "keep" removes nothing ("remove" is read as "all",
    the name used before the "space" rule existed).
    polygons: "strict" = an invalid shapely polygon never matches (the authors); "repair" = invalid
    polygons are repaired with make_valid, then buffer(0).
    """

    name: str
    unicode_form: str | None = None  # NFC, NFKC, NFD, NFKD or None
    case: str = "lower"  # "lower", "casefold" or "keep"
    whitespace: str = "space"
    polygons: str = "strict"
    units: str = "codepoints"  # what a character is: "codepoints" (Python str, the authors) or "graphemes"

    def __post_init__(self) -> None:
        if self.whitespace == "remove":
            object.__setattr__(self, "whitespace", "all")
        if self.unicode_form not in (None, "NFC", "NFKC", "NFD", "NFKD"):
            raise StringsBenchError(f"profile {self.name!r}: unknown Unicode form {self.unicode_form!r}", hint="use NFC, NFKC, NFD, NFKD or None")
        if self.case not in ("lower", "casefold", "keep"):
            raise StringsBenchError(f"profile {self.name!r}: unknown case rule {self.case!r}", hint="use lower, casefold or keep")
        if self.whitespace not in WHITESPACE_RULES:
            raise StringsBenchError(f"profile {self.name!r}: unknown whitespace rule {self.whitespace!r}", hint=f"use one of: {', '.join(WHITESPACE_RULES)}")
        if self.polygons not in POLYGON_RULES:
            raise StringsBenchError(f"profile {self.name!r}: unknown polygon rule {self.polygons!r}", hint=f"use one of: {', '.join(POLYGON_RULES)}")
        if self.units not in UNIT_RULES:
            raise StringsBenchError(f"profile {self.name!r}: unknown character unit {self.units!r}", hint=f"use one of: {', '.join(UNIT_RULES)}")

    def normalize(self, text: str) -> str:
        if self.unicode_form:
            text = unicodedata.normalize(self.unicode_form, text)
        if self.case == "lower":
            text = text.lower()
        elif self.case == "casefold":
            text = text.casefold()
        if self.unicode_form and self.case != "keep":
            text = unicodedata.normalize(self.unicode_form, text)  # case mapping can decompose (e.g. "İ")
        if self.whitespace == "space":
            text = text.replace(" ", "")
        elif self.whitespace == "all":
            text = "".join(text.split())
        return text

    def chars(self, text: str) -> str | tuple[str, ...]:
        """A normalised text as the units the CER counts: the string itself (code points) or the tuple of
        its extended grapheme clusters (`regex`'s \\X: a base letter with its combining marks is one)."""
        if self.units == "codepoints":
            return text
        return graphemes(text)

    def to_dict(self) -> dict[str, Any]:
        d = {"name": self.name, "unicode_form": self.unicode_form, "case": self.case, "whitespace": self.whitespace,
             "polygons": self.polygons}
        if self.units != "codepoints":  # results made before the option existed read the same
            d["units"] = self.units
        return d


CERProfile = NormalizationProfile

PROFILES: dict[str, NormalizationProfile] = {
    # The authors' rules, exactly: text.lower().replace(' ', ''); invalid polygons never match.
    "paper": NormalizationProfile("paper", None, "lower", "space", "strict"),
    # Deviation, never the default: repairs invalid polygons (an OCR's bow-tie box still overlaps the
    # word it outlines), NFC (composed and decomposed accents compare equal) and removes all
    # whitespace (tabs, newlines, NBSP that some OCR engines put inside a word). Older versions of the suite
    # had only this behaviour.
    "robust": NormalizationProfile("robust", "NFC", "lower", "all", "repair"),
    # Text variants of the paper's rules; they keep its polygon rule so that only the text differs.
    "case-sensitive": NormalizationProfile("case-sensitive", None, "keep", "space", "strict"),
    "nfkc-casefold": NormalizationProfile("nfkc-casefold", "NFKC", "casefold", "all", "strict"),
    # The paper's rules, counting user-perceived characters (extended grapheme clusters) instead of code
    # points: a Devanagari consonant with its vowel sign or virama is one character, not two or three.
    # NFC first, so that composed and decomposed forms are the same clusters. docs/ocr.md measures it.
    "graphemes": NormalizationProfile("graphemes", "NFC", "lower", "space", "strict", "graphemes"),
}


def get_profile(profile: str | NormalizationProfile) -> NormalizationProfile:
    if isinstance(profile, NormalizationProfile):
        return profile
    if profile not in PROFILES:
        raise StringsBenchError(f"unknown CER profile {profile!r}", hint=f"choose one of: {', '.join(PROFILES)}")
    return PROFILES[profile]


# --------------------------------------------------------------------------- results
@dataclass(frozen=True)
class ComponentMatch:
    """One connected component with GT words: which words, the texts compared and the edit count."""

    gt: tuple[int, ...]
    pred: tuple[int, ...]
    gt_text: str
    pred_text: str
    errors: int


@dataclass(frozen=True)
class ImageCER:
    errors: int
    chars: int
    components: tuple[ComponentMatch, ...] = ()

    @property
    def cer(self) -> float:
        return self.errors / self.chars if self.chars else math.nan

    def to_dict(self) -> dict[str, Any]:
        return {"errors": self.errors, "chars": self.chars, "cer": _json_float(self.cer)}


@dataclass(frozen=True)
class SceneCER:
    """Character-weighted CER of a set of images; `images` holds only the scored ones.

    `ignored_empty_gt` and `ignored_failed` name the images left out (GT OCR found no text; an OCR
    failed on the GT or the rendered view). `cer` is NaN when nothing could be scored.
    """

    errors: int
    chars: int
    cer: float
    images: dict[str, ImageCER] = field(default_factory=dict)
    ignored_empty_gt: tuple[str, ...] = ()
    ignored_failed: tuple[str, ...] = ()
    profile: dict[str, Any] = field(default_factory=dict)
    iou_threshold: float = IOU_THRESHOLD
    # Known-text CER only: the legibility filter and what it left out (None: no filter applied).
    legibility: dict[str, Any] | None = None

    @property
    def n_ignored_empty_gt(self) -> int:
        return len(self.ignored_empty_gt)

    @property
    def n_ignored_failed(self) -> int:
        return len(self.ignored_failed)

    def to_dict(self) -> dict[str, Any]:
        return {
            "errors": self.errors,
            "chars": self.chars,
            "cer": _json_float(self.cer),
            "images": {name: r.to_dict() for name, r in self.images.items()},
            "ignored": {"empty_gt": list(self.ignored_empty_gt), "failed": list(self.ignored_failed)},
            "profile": dict(self.profile),
            "iou_threshold": self.iou_threshold,
            **({} if self.legibility is None else {"legibility": dict(self.legibility)}),
        }


def _json_float(x: float) -> float | None:
    return None if math.isnan(x) else float(x)


# --------------------------------------------------------------------------- geometry
def _polygonal_part(geom: Any) -> Any:
    if geom is None or geom.is_empty:
        return None
    if isinstance(geom, (shapely.Polygon, shapely.MultiPolygon)):
        return geom
    if isinstance(geom, shapely.GeometryCollection):
        parts = [g for g in geom.geoms if isinstance(g, (shapely.Polygon, shapely.MultiPolygon))]
        return shapely.union_all(parts) if parts else None
    return None  # a line or point: no area


def polygon_geometry(polygon: Any, polygons: str = "repair") -> Any:
    """A shapely area for a word polygon, or None when it never matches.

    polygons="strict" (the authors' rule): None unless `shapely.Polygon(points).is_valid`; nothing
    is repaired. polygons="repair": invalid polygons are repaired (make_valid, then buffer(0)) and
    kept when they have area (used by the "robust" CER profile, by `text_height_px` and by OCR
    post-processing). Both: fewer than 3 points or non-finite coordinates give None.
    """
    if polygons not in POLYGON_RULES:
        raise StringsBenchError(f"unknown polygon rule {polygons!r}", hint=f"use one of: {', '.join(POLYGON_RULES)}")
    pts = np.asarray(polygon, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 2 or pts.shape[0] < 3 or not np.all(np.isfinite(pts)):
        return None
    geom = shapely.Polygon(pts)
    if not geom.is_valid:
        if polygons == "strict":
            return None
        geom = _polygonal_part(shapely.make_valid(geom))
        if geom is not None and not geom.is_valid:
            geom = _polygonal_part(geom.buffer(0))
    if geom is None or geom.is_empty or not geom.area > 0:
        return None
    return geom


def iou_edges(gt_geoms: Sequence[Any], pred_geoms: Sequence[Any], threshold: float = IOU_THRESHOLD) -> list[tuple[int, int]]:
    """(gt index, pred index) pairs with IoU >= threshold (> 0); None geometries never match.

    IoU = area(intersection) / area(union), both computed by shapely (GEOS) as the authors do.
    """
    if not threshold > 0:
        raise StringsBenchError(f"IoU threshold {threshold!r} must be > 0", hint="the paper uses 0.1")
    gi = [i for i, g in enumerate(gt_geoms) if g is not None]
    pi = [j for j, g in enumerate(pred_geoms) if g is not None]
    if not gi or not pi:
        return []
    g_arr = np.array([gt_geoms[i] for i in gi], dtype=object)
    p_arr = np.array([pred_geoms[j] for j in pi], dtype=object)
    # Candidate pairs from an R-tree; IoU > 0 needs intersecting boxes at least.
    qa, qb = shapely.STRtree(p_arr).query(g_arr, predicate="intersects")
    if len(qa) == 0:
        return []
    inter = shapely.area(shapely.intersection(g_arr[qa], p_arr[qb]))
    union = shapely.area(shapely.union(g_arr[qa], p_arr[qb]))
    iou = np.where(union > 0, inter / np.where(union > 0, union, 1.0), 0.0)
    keep = iou >= threshold
    return sorted((gi[a], pi[b]) for a, b in zip(qa[keep], qb[keep]))


# --------------------------------------------------------------------------- scoring
def _as_word(w: Any) -> Word:
    if isinstance(w, Word):
        return w
    if isinstance(w, Mapping):
        return Word.from_dict(w)
    if isinstance(w, (tuple, list)) and len(w) >= 2:
        return Word(w[0], w[1], w[2] if len(w) > 2 else 1.0)
    raise StringsBenchError(f"cannot read {w!r:.100} as an OCR word", hint="give Word objects, dicts with text/polygon, or (text, polygon) pairs")


def _mean_xy(w: Word) -> tuple[float, float]:
    if w.polygon.size == 0:
        return 0.0, 0.0
    m = w.polygon.mean(axis=0)
    return float(m[0]), float(m[1])


def image_cer(
    gt_words: Iterable[Any],
    pred_words: Iterable[Any],
    profile: str | NormalizationProfile = "paper",
    iou_threshold: float = IOU_THRESHOLD,
) -> ImageCER:
    """Errors and GT characters of one image (recall-based, component-wise; see the module doc)."""
    prof = get_profile(profile)
    gt = [_as_word(w) for w in gt_words]
    pred = [_as_word(w) for w in pred_words]
    gt_text = [prof.chars(prof.normalize(w.text)) for w in gt]
    pred_text = [prof.chars(prof.normalize(w.text)) for w in pred]
    chars = sum(len(t) for t in gt_text)
    if not iou_threshold > 0:
        raise StringsBenchError(f"IoU threshold {iou_threshold!r} must be > 0", hint="the paper uses 0.1")
    if not gt:
        return ImageCER(0, 0, ())
    gt_centres = [_mean_xy(w) for w in gt]
    pred_centres = [_mean_xy(w) for w in pred]
    total = 0
    comps: list[ComponentMatch] = []
    for g_idx, p_idx in _iou_components(gt, pred, prof.polygons, iou_threshold):
        if not g_idx:  # predicted words outside GT components cost nothing
            continue
        d, g_str, p_str = _component_distance(g_idx, p_idx, gt_text, pred_text, gt_centres, pred_centres)
        total += d
        comps.append(ComponentMatch(tuple(g_idx), tuple(p_idx), g_str, p_str, d))
    return ImageCER(total, chars, tuple(comps))


def _iou_components(a: list[Word], b: list[Word], rule: str, iou_threshold: float) -> list[tuple[list[int], list[int]]]:
    """The connected components of the graph joining a word of `a` and a word of `b` when their
    polygons (under the profile's polygon `rule`) have IoU >= `iou_threshold`: (indices into a,
    indices into b) per component, the components holding a word of `a` first, in the order of their
    first `a` word."""
    n, m = len(a), len(b)
    edges = iou_edges([polygon_geometry(w.polygon, rule) for w in a], [polygon_geometry(w.polygon, rule) for w in b],
                      iou_threshold)
    graph = coo_matrix((np.ones(len(edges)), ([i for i, _ in edges], [n + j for _, j in edges])), shape=(n + m, n + m))
    _, labels = connected_components(graph, directed=False)
    members: dict[int, tuple[list[int], list[int]]] = {}
    for i in range(n):
        members.setdefault(int(labels[i]), ([], []))[0].append(i)
    for j in range(m):
        members.setdefault(int(labels[n + j]), ([], []))[1].append(j)
    return list(members.values())


def _component_distance(a_idx, b_idx, a_text, b_text, a_centres, b_centres) -> tuple[int, str, str]:
    """The smallest Levenshtein distance between the two sides of a component, each side's texts
    concatenated in the order of the mean x or the mean y of their polygons (4 combinations; ties:
    input order), with the two strings that give it."""
    best: tuple[int, Any, Any] | None = None
    for a_axis in (0, 1):
        a_str = _join([a_text[i] for i in sorted(a_idx, key=lambda i: (a_centres[i][a_axis], i))])
        for b_axis in (0, 1):
            b_str = _join([b_text[j] for j in sorted(b_idx, key=lambda j: (b_centres[j][b_axis], j))])
            d = Levenshtein.distance(a_str, b_str)
            if best is None or d < best[0]:
                best = (d, a_str, b_str)
    assert best is not None
    d, a_best, b_best = best
    return d, "".join(a_best), "".join(b_best)


def _join(parts: list) -> Any:
    """Texts of one side in order, as one string (code points) or one tuple of grapheme clusters."""
    if parts and isinstance(parts[0], tuple):
        return tuple(g for p in parts for g in p)
    return "".join(parts)


# --------------------------------------------------------------------------- two engines' agreement
@dataclass(frozen=True)
class WordAgreement:
    """How alike two OCR engines read one image (or, summed, several): `words` text regions, of which
    `identical` were read identically by both, `only_a` / `only_b` read by one engine alone."""

    words: int = 0
    identical: int = 0
    only_a: int = 0
    only_b: int = 0

    @property
    def share(self) -> float:
        """identical / words (NaN when neither engine read anything)."""
        return self.identical / self.words if self.words else math.nan

    def __add__(self, other: "WordAgreement") -> "WordAgreement":
        return WordAgreement(self.words + other.words, self.identical + other.identical,
                             self.only_a + other.only_a, self.only_b + other.only_b)

    def to_dict(self) -> dict[str, Any]:
        return {"words": self.words, "identical": self.identical, "only_a": self.only_a, "only_b": self.only_b,
                "share": _json_float(self.share)}


def word_agreement(
    words_a: Iterable[Any],
    words_b: Iterable[Any],
    profile: str | NormalizationProfile = "paper",
    iou_threshold: float = IOU_THRESHOLD,
) -> WordAgreement:
    """The words two OCR engines read identically in one image, matched as the CER matches words.

    The words of both engines are joined when their polygons have IoU >= `iou_threshold` (0.1, the
    profile's polygon rule), and each connected component of that graph is one text region (a word,
    or a line where one engine reads a line as one box and the other word by word). A region is read
    identically when both engines read something there and their texts, normalised by the profile and
    concatenated in reading order (mean x or mean y of the polygons, as the CER orders them), are
    equal. Regions read by one engine only count as not identical; regions whose text is empty after
    normalisation on both sides are not counted. `share` = identical / regions.
    """
    prof = get_profile(profile)
    a = [_as_word(w) for w in words_a]
    b = [_as_word(w) for w in words_b]
    a_text = [prof.chars(prof.normalize(w.text)) for w in a]
    b_text = [prof.chars(prof.normalize(w.text)) for w in b]
    if not a and not b:
        return WordAgreement()
    a_centres, b_centres = [_mean_xy(w) for w in a], [_mean_xy(w) for w in b]
    words = identical = only_a = only_b = 0
    for a_idx, b_idx in _iou_components(a, b, prof.polygons, iou_threshold):
        if not any(a_text[i] for i in a_idx) and not any(b_text[j] for j in b_idx):
            continue
        words += 1
        if not a_idx:
            only_b += 1
        elif not b_idx:
            only_a += 1
        elif _component_distance(a_idx, b_idx, a_text, b_text, a_centres, b_centres)[0] == 0:
            identical += 1
    return WordAgreement(words, identical, only_a, only_b)


def text_height_px(polygon: Any) -> float:
    """Height of a word's box across its reading direction, in pixels (NaN without a usable box).

    4-point boxes are taken in reading order (top-left, top-right, bottom-right, bottom-left as
    read): height = area / mean length of the top and bottom edges, i.e. the perpendicular
    distance between them, so a box sheared or foreshortened by perspective is as tall as its
    glyphs really are on screen. Other polygons: the short side of their minimum rotated rectangle.
    """
    geom = polygon_geometry(polygon, "repair")  # our legibility filter, not the authors' rule: a bow-tie box still has a height
    if geom is None:
        return math.nan
    pts = np.asarray(polygon, dtype=np.float64)
    if pts.shape == (4, 2):
        base = 0.5 * (vec3.norm_2d(pts[1] - pts[0]) + vec3.norm_2d(pts[2] - pts[3]))
        return float(geom.area / base) if base > 0 else math.nan
    rect = np.asarray(shapely.minimum_rotated_rectangle(geom).exterior.coords)[:4]
    sides = vec3.norm_2d(np.diff(np.vstack([rect, rect[:1]]), axis=0))
    return float(sides.min())


def split_legible(
    known_words: Iterable[Any], min_text_height_px: float
) -> tuple[list[Word], list[Word]]:
    """(legible, excluded) known words: excluded = box lower than min_text_height_px (or no usable box)."""
    legible: list[Word] = []
    excluded: list[Word] = []
    for w in (_as_word(k) for k in known_words):
        h = text_height_px(w.polygon)
        (legible if min_text_height_px <= 0 or (not math.isnan(h) and h >= min_text_height_px) else excluded).append(w)
    return legible, excluded


def known_text_cer(
    known_words: Iterable[Any],
    predicted_words: Iterable[Any],
    profile: str | NormalizationProfile = "paper",
    iou_threshold: float = IOU_THRESHOLD,
    min_text_height_px: float = 0.0,
) -> ImageCER:
    """CER of OCR output against the known strings of a view (synthetic scenes), same matching.

    Known words lower than `min_text_height_px` (see `text_height_px`) are left out; 0 keeps all.
    `known_scene_cer` also counts what was left out.
    """
    legible, _ = split_legible(known_words, min_text_height_px)
    return image_cer(legible, predicted_words, profile=profile, iou_threshold=iou_threshold)


def known_scene_cer(
    per_image: Mapping[str, tuple[Iterable[Any] | None, Iterable[Any] | None]],
    min_text_height_px: float = KNOWN_TEXT_MIN_HEIGHT_PX,
    profile: str | NormalizationProfile = "paper",
    iou_threshold: float = IOU_THRESHOLD,
) -> SceneCER:
    """Known-text CER of a scene: `scene_cer` over {name: (known words, OCR words or None)} after the
    legibility filter. The result's `legibility` records the threshold and the words and characters
    excluded (those of images whose OCR failed included); views left with no legible word are
    named in `ignored_empty_gt`.
    """
    if not (math.isfinite(min_text_height_px) and min_text_height_px >= 0):
        raise StringsBenchError(f"min_text_height_px must be a number >= 0, got {min_text_height_px!r}",
                                hint=f"0 keeps every known word; the default is {KNOWN_TEXT_MIN_HEIGHT_PX}")
    prof = get_profile(profile)
    filtered: dict[str, tuple[Any, Any]] = {}
    excl_words = excl_chars = 0
    for name, pair in per_image.items():
        if not isinstance(pair, (tuple, list)) or len(pair) != 2:
            raise StringsBenchError(f"known_scene_cer: entry {name!r} is not a (known_words, pred_words) pair",
                                    hint="pass None for a failed OCR")
        known, pred = pair
        if known is None:
            filtered[name] = (None, pred)
            continue
        legible, excluded = split_legible(known, min_text_height_px)
        excl_words += len(excluded)
        excl_chars += sum(len(prof.chars(prof.normalize(w.text))) for w in excluded)
        filtered[name] = (legible, pred)
    res = scene_cer(filtered, profile=prof, iou_threshold=iou_threshold)
    legibility = {
        "min_text_height_px": float(min_text_height_px),
        "height": "box height across the reading direction at evaluation resolution (cer.text_height_px)",
        "excluded_words": excl_words,
        "excluded_chars": excl_chars,
    }
    return replace(res, legibility=legibility)


def scene_cer(
    per_image: Mapping[str, tuple[Iterable[Any] | None, Iterable[Any] | None]],
    profile: str | NormalizationProfile = "paper",
    iou_threshold: float = IOU_THRESHOLD,
) -> SceneCER:
    """Character-weighted CER over images: {name: (gt words or None on OCR failure, pred words or None)}.

    An image with a failed GT OCR, or with GT words but a failed rendered-view OCR, is left out and
    named in `ignored_failed`; an image whose GT has no characters is left out and named in
    `ignored_empty_gt`. Never is a failure scored as 0.
    """
    prof = get_profile(profile)
    images: dict[str, ImageCER] = {}
    empty: list[str] = []
    failed: list[str] = []
    for name in sorted(per_image):
        pair = per_image[name]
        if not isinstance(pair, (tuple, list)) or len(pair) != 2:
            raise StringsBenchError(f"scene_cer: entry {name!r} is not a (gt_words, pred_words) pair", hint="pass None for a failed OCR")
        gt, pred = pair
        if gt is None:
            failed.append(name)
            continue
        gt = [_as_word(w) for w in gt]
        if sum(len(prof.chars(prof.normalize(w.text))) for w in gt) == 0:
            empty.append(name)
            continue
        if pred is None:
            failed.append(name)
            continue
        images[name] = image_cer(gt, pred, prof, iou_threshold)
    errors = sum(r.errors for r in images.values())
    chars = sum(r.chars for r in images.values())
    return SceneCER(
        errors=errors,
        chars=chars,
        cer=errors / chars if chars else math.nan,
        images=images,
        ignored_empty_gt=tuple(empty),
        ignored_failed=tuple(failed),
        profile=prof.to_dict(),
        iou_threshold=iou_threshold,
    )


def dataset_cer(scenes: Mapping[str, SceneCER]) -> float:
    """A dataset's figure: the plain mean of its scenes' CERs (scenes with nothing scored are skipped)."""
    values = [s.cer for s in scenes.values() if not math.isnan(s.cer)]
    return float(np.mean(values)) if values else math.nan
