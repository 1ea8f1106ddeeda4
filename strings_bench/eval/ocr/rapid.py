"""Local default OCR: RapidOCR 3.x (PP-OCR models shipped inside the package) on ONNX Runtime.

Size (~550 lines): one backend, RapidOCR: loading, line reads, word boxes and their check, rotated text; each part is RapidOCR-specific.

Word boxes: RapidOCR detects text *lines*. With `return_word_box=True` it also returns word boxes
(for Latin/digit lines: one box per space-separated word; for CJK: one box per character), placed
from the CTC column positions of the recogniser. We use those (setting word_boxes="rapidocr"), and
check them: when a line's word texts do not join up to the line text, that line is split instead
by proportional character positions along the line box (the same as word_boxes="proportional").

ONNX Runtime writes a telemetry id under the home folder when imported unless ORT_DISABLE_TELEMETRY
is set first; `strings_bench.eval.ocr._ort_guard` sets it (see there and docs/ocr.md).
"""

from __future__ import annotations

import json
import logging
import threading
from typing import Any

import numpy as np

from strings_bench.core import vec3
from strings_bench.core.errors import OCRError
import strings_bench.eval.ocr._ort_guard as _ort_guard
from strings_bench.eval.ocr.base import BackendStatus, OCRBackend, Word, BackendSettings

log = logging.getLogger(__name__)

DEFAULTS: dict[str, Any] = {
    "text_score": 0.5,  # drop lines whose recognition score is below this
    "box_thresh": 0.5,  # detector box score threshold
    "unclip_ratio": 1.6,  # detector box expansion
    "use_cls": True,  # 180-degree line orientation classifier
    "max_side_len": 2000,  # RapidOCR shrinks larger images to this side length before detection
    "word_boxes": "rapidocr",  # "rapidocr" (its word boxes, checked) or "proportional"
    # Bicubic enlargement before reading (small text); capped so the long side stays <= max_side_len.
    "upscale": 2.0,
    # Degrees the image is turned counterclockwise for each read (90: top-to-bottom text, e.g.
    # book spines, becomes horizontal); the reads are mapped back and merged.
    "rotations": [0, 90, 270],
    # Words of different rotations whose intersection covers more than this fraction of the
    # smaller one are the same word: the more confident reading is kept.
    "merge_overlap": 0.5,
    # Grey level of the pixels outside the text mask (the paper: image x mask, i.e. 0). RapidOCR's
    # detector misses whole views surrounded by black; mid-grey reads them (docs/ocr.md).
    "mask_fill": 128,
}

ROTATIONS = (0, 90, 180, 270)
# The settings the RapidOCR engine itself is built with (the rest are applied around it).
ENGINE_SETTINGS = ("text_score", "box_thresh", "unclip_ratio", "use_cls", "max_side_len")


# Engines are shared by backends with the same settings (e.g. with different caches): loading the
# ONNX sessions is the slow part.
_ENGINES: dict[str, Any] = {}
_ENGINES_LOCK = threading.Lock()


def _rapidocr_version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("rapidocr")
    except PackageNotFoundError:
        return "unknown"


# ONNX Runtime threads of one detector+recogniser read. 1: the runner reads a cell's views with
# read_many, one read per core, which beat 2 threads x half the reads at once on a cell's 12 reads by
# 1.51x at 320x240 and 1.13x at 1280x960 on 2 cores, with the same words (studies/ocr_parallel/ocr_parallel.py).
DEFAULT_THREADS = 1
# The recogniser alone (word-crop readability) runs its crops in batches, one call at a time.
REC_DEFAULT_THREADS = 2


def _check_upscale(value: Any) -> float:
    try:
        f = float(value)
    except (TypeError, ValueError):
        f = float("nan")
    if not (np.isfinite(f) and 1.0 <= f <= 8.0):
        raise OCRError(f"rapidocr setting upscale={value!r} must be a number in [1, 8]",
                       hint="1 reads the image as it is; 2 doubles both sides (bicubic) before reading")
    return f


def _check_rotations(value: Any) -> list[int]:
    items = [value] if isinstance(value, (int, float, str)) else value
    try:
        rots = [int(v) for v in items]
    except (TypeError, ValueError):
        rots = []
    if not rots or any(r not in ROTATIONS for r in rots) or len(set(rots)) != len(rots) \
            or any(float(v) != int(v) for v in items if not isinstance(v, str)):
        raise OCRError(f"rapidocr setting rotations={value!r} must be a non-empty list of distinct values "
                       f"from {list(ROTATIONS)}",
                       hint="e.g. rotations=[0] (upright only) or [0, 90, 270] (also vertical text)")
    return rots


def _check_fraction(name: str, value: Any) -> float:
    try:
        f = float(value)
    except (TypeError, ValueError):
        f = float("nan")
    if not (0.0 < f <= 1.0):
        raise OCRError(f"rapidocr setting {name}={value!r} must be in (0, 1]", hint=f"the default is {DEFAULTS[name]}")
    return f


def rotate_image(rgb: np.ndarray, degrees: int) -> np.ndarray:
    """The image turned `degrees` (a multiple of 90) counterclockwise."""
    return np.ascontiguousarray(np.rot90(rgb, (degrees // 90) % 4))


def unrotate_points(points: np.ndarray, degrees: int, width: int, height: int) -> np.ndarray:
    """Map points of the image turned `degrees` counterclockwise back into the original image.

    Coordinates are continuous pixel coordinates (pixel edges at integers) of a `width` x `height`
    original. Turning counterclockwise by 90 sends (x, y) to (y, width - x).
    """
    p = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    x, y = p[:, 0], p[:, 1]
    k = (degrees // 90) % 4
    if k == 0:
        return p.copy()
    if k == 1:
        return np.stack([width - y, x], axis=1)
    if k == 2:
        return np.stack([width - x, height - y], axis=1)
    return np.stack([y, height - x], axis=1)


def upscale_factor(width: int, height: int, upscale: float, max_side_len: int) -> float:
    """The enlargement used: `upscale`, reduced so the long side stays within max_side_len (never < 1)."""
    return max(1.0, min(float(upscale), max_side_len / max(width, height)))


def merge_rotated_reads(reads: list[list[Word]], overlap: float) -> list[Word]:
    """Join the words of several reads (one per rotation), dropping duplicates across reads.

    Two words of different reads are the same word when their intersection covers more than
    `overlap` of the smaller one; the more confident is kept (ties: the earlier read). Words of one
    read are never merged with each other (that is the engine's business). Words without a usable
    polygon are kept.
    """
    from strings_bench.eval.cer import polygon_geometry

    if len(reads) <= 1:
        return list(reads[0]) if reads else []
    flat = [(r, j, w) for r, words in enumerate(reads) for j, w in enumerate(words)]
    geoms = [polygon_geometry(w.polygon) for _, _, w in flat]

    def conf(w: Word) -> float:
        return -np.inf if np.isnan(w.confidence) else w.confidence

    order = sorted(range(len(flat)), key=lambda k: (-conf(flat[k][2]), flat[k][0], flat[k][1]))
    kept: list[int] = []
    for k in order:
        g = geoms[k]
        duplicate = False
        if g is not None:
            for q in kept:
                h = geoms[q]
                if h is None or flat[q][0] == flat[k][0] or not g.intersects(h):
                    continue
                if g.intersection(h).area > overlap * min(g.area, h.area):
                    duplicate = True
                    break
        if not duplicate:
            kept.append(k)
    return [flat[k][2] for k in sorted(kept)]  # reads in order, engine order within a read


def reading_quad(quad: np.ndarray, turned: bool | None) -> np.ndarray:
    """A RapidOCR line box with its corners in reading order (top-left as read first).

    RapidOCR gives line boxes clockwise from the image's top-left. It turns a crop 90 degrees
    counterclockwise when the box is at least 1.5 times as high as wide (the text then reads top to
    bottom, starting at the box's top-right corner), and its classifier turns crops by 180 degrees
    (`turned`; None = unknown, taken as not turned).
    """
    q = np.asarray(quad, dtype=np.float64).reshape(4, 2)
    width = int(max(vec3.norm_2d(q[0] - q[1]), vec3.norm_2d(q[2] - q[3])))
    height = int(max(vec3.norm_2d(q[0] - q[3]), vec3.norm_2d(q[1] - q[2])))
    if width > 0 and height / width >= 1.5:  # same rule and rounding as RapidOCR's crop
        q = q[[1, 2, 3, 0]]
    if turned:
        q = np.roll(q, 2, axis=0)
    return q


def split_line_into_words(text: str, quad: np.ndarray, confidence: float) -> list[Word]:
    """Split a text line into words, placing each word by its character positions along the line.

    `quad` is the line box, corners in reading order (top-left as read first; see reading_quad). Word k spanning characters [s, e) of the
    n-character line gets the box between fractions s/n and e/n of the top and bottom edges.
    """
    quad = np.asarray(quad, dtype=np.float64).reshape(4, 2)
    n = len(text)
    words: list[Word] = []
    i = 0
    while i < n:
        if text[i].isspace():
            i += 1
            continue
        j = i
        while j < n and not text[j].isspace():
            j += 1
        a, b = i / n, j / n
        tl = quad[0] + a * (quad[1] - quad[0])
        tr = quad[0] + b * (quad[1] - quad[0])
        bl = quad[3] + a * (quad[2] - quad[3])
        br = quad[3] + b * (quad[2] - quad[3])
        words.append(Word(text[i:j], np.stack([tl, tr, br, bl]), confidence))
        i = j
    return words


_ENGINE_CLASS = None


def _engine_class():
    """RapidOCR with word boxes that follow the 180-degree orientation classifier.

    RapidOCR 3.10 places word boxes from the recogniser's CTC columns, which refer to the crop
    *after* the classifier turned it 180 degrees, but maps them back through the unturned crop:
    the words of an upside-down line come out mirrored along the line (in "MOBY DICK", MOBY
    lands where DICK is). We record which crops the classifier turned and, for those lines, map
    word boxes through the line box with its corners turned by 180 degrees (np.roll by 2), which is
    the frame the recogniser read. Uses RapidOCR's pipeline methods run_ocr_steps, cls_and_rotate
    and calc_word_boxes (rapidocr is pinned to 3.10.0); tests/eval/test_ocr_rotation.py checks it.
    """
    global _ENGINE_CLASS
    if _ENGINE_CLASS is not None:
        return _ENGINE_CLASS
    from rapidocr import RapidOCR

    missing = [m for m in ("run_ocr_steps", "cls_and_rotate", "calc_word_boxes") if not hasattr(RapidOCR, m)]
    if missing:
        log.warning("rapidocr %s lacks %s: word boxes of upside-down lines may be mirrored",
                    _rapidocr_version(), ", ".join(missing))
        _ENGINE_CLASS = RapidOCR
        return RapidOCR

    class OrientedWordBoxesRapidOCR(RapidOCR):
        _tls = threading.local()

        def cls_and_rotate(self, img):
            turned_imgs, cls_res = super().cls_and_rotate(img)
            # Turned iff the content changed (RapidOCR copies every crop, so identity says nothing).
            self._tls.turned = [a.shape == b.shape and not np.array_equal(a, b) for a, b in zip(img, turned_imgs)]
            return turned_imgs, cls_res

        def run_ocr_steps(self, img, op_record):
            self._tls.turned = self._tls.kept_turned = self._tls.final_turned = None
            det_res, cls_res, rec_res, crops = super().run_ocr_steps(img, op_record)
            turned = self._tls.turned
            txts = rec_res.txts
            # build_final_output keeps the lines with non-empty text before placing word boxes.
            self._tls.kept_turned = (None if turned is None or txts is None or len(turned) != len(txts)
                                     else [t for t, v in zip(turned, txts) if v.strip()])
            return det_res, cls_res, rec_res, crops

        def filter_by_text_score(self, ocr_res):
            # The last filter of build_final_output: keep the turned flags of the lines it keeps.
            turned = getattr(self._tls, "kept_turned", None)
            scores = list(ocr_res.scores or ())
            self._tls.final_turned = (None if turned is None or len(turned) != len(scores)
                                      else [t for t, sc in zip(turned, scores) if sc >= self.text_score])
            return super().filter_by_text_score(ocr_res)

        def last_turned(self, n_lines: int) -> list[bool] | None:
            """Which of the last call's output lines the classifier turned by 180 degrees (None: unknown)."""
            turned = getattr(self._tls, "final_turned", None)
            return turned if turned is not None and len(turned) == n_lines else None

        def calc_word_boxes(self, img, dt_boxes, rec_res):
            turned = getattr(self._tls, "kept_turned", None)
            if turned is not None and len(turned) == len(dt_boxes) and any(turned):
                dt_boxes = np.array([np.roll(b, 2, axis=0) if t else b for b, t in zip(dt_boxes, turned)])
            return super().calc_word_boxes(img, dt_boxes, rec_res)

    _ENGINE_CLASS = OrientedWordBoxesRapidOCR
    return _ENGINE_CLASS


class RapidOCRBackend(OCRBackend):
    name = "rapidocr"
    # ONNX Runtime sessions run concurrently; RapidOCR's per-call state lives in locals (and ours in
    # the thread-local _tls above); the engine is shared only by backends of the same settings.
    parallel_reads = True

    def __init__(self, cache: Any = None, threads: int | None = None, memory_arena: bool = True, **settings: Any):
        merged = BackendSettings(DEFAULTS, settings).merged(self.name)
        if merged["word_boxes"] not in ("rapidocr", "proportional"):
            raise OCRError(
                f"rapidocr setting word_boxes={merged['word_boxes']!r} is not one of 'rapidocr', 'proportional'",
                hint="use word_boxes='rapidocr' (default) or 'proportional'",
            )
        merged["upscale"] = _check_upscale(merged["upscale"])
        merged["rotations"] = _check_rotations(merged["rotations"])
        merged["merge_overlap"] = _check_fraction("merge_overlap", merged["merge_overlap"])
        if not (isinstance(merged["mask_fill"], int) and not isinstance(merged["mask_fill"], bool)
                and 0 <= merged["mask_fill"] <= 255):
            raise OCRError(f"rapidocr setting mask_fill={merged['mask_fill']!r} must be an integer grey level 0..255",
                           hint="0 = black, as image x mask in the paper; the default is 128")
        super().__init__(merged, cache)
        # Runtime only (does not change results, so not a setting). Default 1 (DEFAULT_THREADS); read_many
        # runs cores / threads reads at once. onnxruntime's own default would take every core per read.
        self.threads = DEFAULT_THREADS if threads is None else threads
        # Runtime only too: ONNX Runtime's memory arena (RapidOCR's config.yaml turns it off). With it each call
        # reuses its buffers rather than allocating them anew; memory only, the same words
        # (tests/eval/test_ocr_parallel.py); with it the OCR of the default run's views took 0.88x the time
        # (tools/evaluation_split.py, docs/results/data/evaluation-speed/arena-lpips/split.txt).
        self.memory_arena = bool(memory_arena)
        self._engine = None
        self._version: str | None = None

    @classmethod
    def status(cls) -> BackendStatus:
        try:
            import onnxruntime
            import rapidocr  # noqa: F401
        except Exception as exc:
            return BackendStatus(cls.name, False, f"not installed ({type(exc).__name__}: {exc})")
        return BackendStatus(cls.name, True, f"rapidocr {_rapidocr_version()} on onnxruntime {onnxruntime.__version__}")

    def supported_scripts(self) -> frozenset[str] | None:
        """The scripts the bundled recogniser reads (languages.rapidocr_supported_scripts): Latin and Han with
        rapidocr 3.10's PP-OCRv6 model (its dictionary has no Cyrillic, Devanagari or Arabic letter at all;
        Greek letters it has, but it was measured not to read them)."""
        from strings_bench.eval.ocr.languages import rapidocr_supported_scripts

        return rapidocr_supported_scripts()

    def settings_summary(self) -> str:
        return "its bundled PP-OCR recogniser"

    def unreadable_reason(self, script: str) -> str | None:
        from strings_bench.eval.ocr.languages import RAPIDOCR_MEASURED_UNREADABLE, rapidocr_scripts

        if script in RAPIDOCR_MEASURED_UNREADABLE:
            return RAPIDOCR_MEASURED_UNREADABLE[script]
        share = rapidocr_scripts().get(script)
        return None if share is None else f"its dictionary holds {100 * share:.0f}% of the script's letters"

    def _get_engine(self):
        if self._engine is not None:
            return self._engine
        # word_boxes too: every call sets the engine's return_word_box, so backends that differ in it
        # must not share an engine across threads.
        memo = json.dumps([{k: self.settings[k] for k in (*ENGINE_SETTINGS, "word_boxes")}, self.threads, self.memory_arena],
                          sort_keys=True)
        with _ENGINES_LOCK:
            if memo not in _ENGINES:
                _ENGINES[memo] = self._new_engine()
            self._engine = _ENGINES[memo]
        return self._engine

    def _new_engine(self):
        if _ort_guard.imported_unguarded:
            log.warning(
                "onnxruntime was imported before strings_bench.eval.ocr; it may write a telemetry id under "
                "~/.cache/Microsoft (set ORT_DISABLE_TELEMETRY=1 in the environment to prevent it)"
            )
        try:
            RapidOCR = _engine_class()
        except Exception as exc:
            raise OCRError(
                f"RapidOCR cannot be imported: {type(exc).__name__}: {exc}",
                hint="pip install rapidocr==3.10.0 onnxruntime",
            ) from exc
        s = self.settings
        params = {
            "Global.log_level": "error",
            "Global.text_score": float(s["text_score"]),
            "Global.use_cls": bool(s["use_cls"]),
            "Global.max_side_len": int(s["max_side_len"]),
            "Det.box_thresh": float(s["box_thresh"]),
            "Det.unclip_ratio": float(s["unclip_ratio"]),
        }
        if self.threads:
            params["EngineConfig.onnxruntime.intra_op_num_threads"] = int(self.threads)
        params["EngineConfig.onnxruntime.enable_cpu_mem_arena"] = self.memory_arena
        return RapidOCR(params=params)

    @property
    def version(self) -> str:
        if self._version is None:
            import onnxruntime

            cfg = self._get_engine().cfg

            def model(section) -> str:
                v = lambda x: str(getattr(x, "value", x))  # noqa: E731 - enums or plain strings
                return f"{v(section.ocr_version)} {v(section.model_type)} {v(section.lang_type)}"

            self._version = (
                f"rapidocr {_rapidocr_version()} (onnxruntime {onnxruntime.__version__}; "
                f"det {model(cfg.Det)}, rec {model(cfg.Rec)}, cls {model(cfg.Cls)})"
            )
        return self._version

    def _recognize(self, rgb: np.ndarray) -> list[Word]:
        if not rgb.any():
            return []  # all black (e.g. an empty text mask): nothing to read
        import cv2  # RapidOCR's own dependency

        h, w = rgb.shape[:2]
        f = upscale_factor(w, h, self.settings["upscale"], int(self.settings["max_side_len"]))
        reads = []
        for deg in self.settings["rotations"]:
            img = rotate_image(rgb, deg)
            rh, rw = img.shape[:2]
            sx = sy = 1.0
            if f > 1.0:
                size = (max(1, round(rw * f)), max(1, round(rh * f)))
                img = cv2.resize(img, size, interpolation=cv2.INTER_CUBIC)
                sx, sy = size[0] / rw, size[1] / rh
            words = self._read_once(img)
            for word in words:  # back to the original image's pixels
                word.polygon = unrotate_points(word.polygon / np.array([sx, sy]), deg, w, h)
            reads.append(words)
        return merge_rotated_reads(reads, self.settings["merge_overlap"])

    def _read_once(self, rgb: np.ndarray) -> list[Word]:
        engine = self._get_engine()
        use_word_boxes = self.settings["word_boxes"] == "rapidocr"
        bgr = np.ascontiguousarray(rgb[:, :, ::-1])  # RapidOCR takes arrays as BGR (OpenCV order)
        out = engine(bgr, return_word_box=use_word_boxes)
        txts = getattr(out, "txts", None)
        boxes = getattr(out, "boxes", None)
        if not txts or boxes is None:
            return []
        scores = list(out.scores)
        word_results = list(getattr(out, "word_results", ()) or ()) if use_word_boxes else []
        last_turned = getattr(engine, "last_turned", None)
        turned = last_turned(len(txts)) if last_turned is not None else None
        # RapidOCR drops lines with no word boxes from word_results, which would shift indices.
        aligned = use_word_boxes and len(word_results) == len(txts)
        words: list[Word] = []
        for i, (txt, quad, score) in enumerate(zip(txts, boxes, scores)):
            line_words = None
            if aligned:
                candidates = [
                    Word(w_txt, np.asarray(w_box, dtype=np.float64), w_score)
                    for w_txt, w_score, w_box in word_results[i]
                    if w_box is not None and str(w_txt).strip()
                ]
                if "".join(w.text for w in candidates) == "".join(txt.split()):
                    line_words = candidates
                else:
                    log.debug("rapidocr word boxes do not spell line %r; splitting proportionally", txt)
            if line_words is None:
                quad = reading_quad(quad, None if turned is None else turned[i])
                line_words = split_line_into_words(txt, quad, float(score))
            words.extend(line_words)
        return words


# ---- the recogniser alone (word-crop readability, strings_bench.eval.readability) ------------------
# RapidOCR's recognition stage (rapidocr/ch_ppocr_rec/main.py, config.yaml `Rec`): the PP-OCRv6 small
# model shipped in the package, input (N, 3, 48, W) BGR scaled to [-1, 1] ((x / 255 - 0.5) / 0.5),
# the crop resized to height 48 keeping its aspect ratio, padded on the right with 0 (mid-grey) to at
# least 320 px; output (N, W / 8, C) softmax probabilities over [blank] + the model's `character`
# metadata + [" "] (CTCLabelDecode inserts blank at 0 and the space last).
REC_HEIGHT = 48
REC_MIN_WIDTH = 320
REC_MODEL_FILE = "PP-OCRv6_rec_small.onnx"


class Recognizer:
    """RapidOCR's text recogniser run on its own (no detector, no classifier), through ONNX Runtime.

    `probabilities(crops)` gives each crop's per-column softmax (T, C) over `characters` (index 0
    is the CTC blank, the last one the space), the same numbers RapidOCR's CTC decoder reads.
    """

    def __init__(self, threads: int | None = None, model_path: str | None = None):
        from pathlib import Path

        try:
            import onnxruntime
            import rapidocr
        except Exception as exc:  # noqa: BLE001 - reported with the install hint
            raise OCRError(f"the RapidOCR recogniser cannot be loaded: {type(exc).__name__}: {exc}",
                           hint="pip install rapidocr==3.10.0 onnxruntime") from exc
        if _ort_guard.imported_unguarded:
            log.warning("onnxruntime was imported before strings_bench.eval.ocr; set ORT_DISABLE_TELEMETRY=1")
        path = Path(model_path) if model_path else Path(rapidocr.__file__).parent / "models" / REC_MODEL_FILE
        if not path.is_file():
            raise OCRError(f"RapidOCR's recognition model {path} is missing",
                           hint="reinstall the wheel: pip install --force-reinstall rapidocr==3.10.0")
        opts = onnxruntime.SessionOptions()
        opts.intra_op_num_threads = int(REC_DEFAULT_THREADS if threads is None else threads)
        opts.inter_op_num_threads = 1
        self.session = onnxruntime.InferenceSession(str(path), sess_options=opts, providers=["CPUExecutionProvider"])
        self.input_name = self.session.get_inputs()[0].name
        meta = self.session.get_modelmeta().custom_metadata_map
        if "character" not in meta:
            raise OCRError(f"{path} carries no character dictionary (metadata 'character')",
                           hint="use the model shipped with rapidocr 3.10.0")
        self.characters: list[str] = ["<blank>"] + meta["character"].splitlines() + [" "]
        self.model = f"{path.name} (rapidocr {_rapidocr_version()}, onnxruntime {onnxruntime.__version__})"

    @staticmethod
    def preprocess(crop_rgb: np.ndarray, width: int) -> np.ndarray:
        """One crop (48 px high, RGB uint8) as the model's (3, 48, width) input: BGR, [-1, 1], right-padded with 0."""
        h, w = crop_rgb.shape[:2]
        if h != REC_HEIGHT:
            raise OCRError(f"recogniser crops must be {REC_HEIGHT} px high, got {h}", hint="use readability.rectify")
        x = crop_rgb[:, :, ::-1].astype(np.float32).transpose(2, 0, 1) / 255.0
        out = np.zeros((3, REC_HEIGHT, width), dtype=np.float32)
        out[:, :, :w] = (x - 0.5) / 0.5
        return out

    def probabilities(self, crops: list[np.ndarray], batch: int = 16, dtype=np.float64) -> list[np.ndarray]:
        """Per-column class probabilities (T, C) of each crop (RGB uint8, 48 px high, any width), as `dtype`
        (the model's float32 outputs, float64 by default; np.float32 leaves them as they are, which saves
        copying every column of the dictionary when only a few are read).

        Each crop is padded to max(320, its width), as RapidOCR pads a batch of one; crops of the same
        padded width run together, up to `batch` at once. The model's last bits depend on which crops share
        a call (measured: a crop run alone differs from the same crop in a batch), so callers that must
        give the same figures keep the same calls.
        """
        out: list[np.ndarray | None] = [None] * len(crops)
        by_width: dict[int, list[int]] = {}
        for i, c in enumerate(crops):
            by_width.setdefault(max(REC_MIN_WIDTH, c.shape[1]), []).append(i)
        for width, idx in by_width.items():
            for b in range(0, len(idx), batch):
                part = idx[b:b + batch]
                x = np.stack([self.preprocess(crops[i], width) for i in part])
                y = self.session.run(None, {self.input_name: x})[0]
                for k, i in enumerate(part):
                    out[i] = np.asarray(y[k], dtype=dtype)
        return out


_RECOGNIZERS: dict[int, Recognizer] = {}


def get_recognizer(threads: int | None = None) -> Recognizer:
    """A shared Recognizer (loading the ONNX session takes a while)."""
    key = int(REC_DEFAULT_THREADS if threads is None else threads)
    with _ENGINES_LOCK:
        if key not in _RECOGNIZERS:
            _RECOGNIZERS[key] = Recognizer(threads=key)
        return _RECOGNIZERS[key]
