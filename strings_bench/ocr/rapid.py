"""Local default OCR: RapidOCR 3.x (PP-OCR models shipped inside the package) on ONNX Runtime.

Word boxes: RapidOCR detects text *lines*. With `return_word_box=True` it also returns word boxes
(for Latin/digit lines: one box per space-separated word; for CJK: one box per character), placed
from the CTC column positions of the recogniser. We use those (setting word_boxes="rapidocr"), and
check them: when a line's word texts do not join up to the line text, that line is split instead
by proportional character positions along the line box (the same as word_boxes="proportional").

ONNX Runtime writes a telemetry id under the home folder when imported unless ORT_DISABLE_TELEMETRY
is set first; `strings_bench.ocr._ort_guard` sets it (see there and docs/ocr.md).
"""

from __future__ import annotations

import json
import logging
import threading
from typing import Any

import numpy as np

from ..errors import OCRError
from . import _ort_guard
from .base import BackendStatus, OCRBackend, Word, _Settings

log = logging.getLogger(__name__)

DEFAULTS: dict[str, Any] = {
    "text_score": 0.5,  # drop lines whose recognition score is below this
    "box_thresh": 0.5,  # detector box score threshold
    "unclip_ratio": 1.6,  # detector box expansion
    "use_cls": True,  # 180-degree line orientation classifier
    "max_side_len": 2000,  # RapidOCR shrinks larger images to this side length before detection
    "word_boxes": "rapidocr",  # "rapidocr" (its word boxes, checked) or "proportional"
}


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


def split_line_into_words(text: str, quad: np.ndarray, confidence: float) -> list[Word]:
    """Split a text line into words, placing each word by its character positions along the line.

    `quad` is the line box, corners clockwise from top-left. Word k spanning characters [s, e) of the
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


class RapidOCRBackend(OCRBackend):
    name = "rapidocr"

    def __init__(self, cache: Any = None, threads: int | None = None, **settings: Any):
        merged = _Settings(DEFAULTS, settings).merged(self.name)
        if merged["word_boxes"] not in ("rapidocr", "proportional"):
            raise OCRError(
                f"rapidocr setting word_boxes={merged['word_boxes']!r} is not one of 'rapidocr', 'proportional'",
                hint="use word_boxes='rapidocr' (default) or 'proportional'",
            )
        super().__init__(merged, cache)
        self.threads = threads  # runtime only: does not change results, so not a setting
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

    def _get_engine(self):
        if self._engine is not None:
            return self._engine
        memo = json.dumps([self.settings, self.threads], sort_keys=True)
        with _ENGINES_LOCK:
            if memo not in _ENGINES:
                _ENGINES[memo] = self._new_engine()
            self._engine = _ENGINES[memo]
        return self._engine

    def _new_engine(self):
        if _ort_guard.imported_unguarded:
            log.warning(
                "onnxruntime was imported before strings_bench.ocr; it may write a telemetry id under "
                "~/.cache/Microsoft (set ORT_DISABLE_TELEMETRY=1 in the environment to prevent it)"
            )
        try:
            from rapidocr import RapidOCR
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
                line_words = split_line_into_words(txt, quad, float(score))
            words.extend(line_words)
        return words
