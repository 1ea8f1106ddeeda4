"""The OCR backend interface: words with polygons, image loading, masking, hashing."""

from __future__ import annotations

import hashlib
import json
import logging
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar, Iterable, Mapping

import numpy as np

from strings_bench.core.errors import OCRError

log = logging.getLogger(__name__)


@dataclass(eq=False)
class Word:
    """One recognised (or known) word: its text, its outline in pixels and a confidence in [0, 1]."""

    text: str
    polygon: np.ndarray  # (K, 2) float64, x then y, in pixel coordinates of the full image
    confidence: float = 1.0

    def __post_init__(self) -> None:
        self.text = str(self.text)
        try:
            poly = np.asarray(self.polygon, dtype=np.float64)
            self.confidence = float(self.confidence)
        except (ValueError, TypeError) as exc:
            raise OCRError(f"word {self.text!r}: polygon or confidence is not numbers: {exc}",
                           hint="give the polygon as a list of [x, y] pairs and the confidence as a number") from None
        if poly.ndim != 2 or poly.shape[1] != 2:
            raise OCRError(
                f"word {self.text!r}: polygon has shape {poly.shape}, expected (K, 2) points",
                hint="give the polygon as a list of [x, y] pairs",
            )
        self.polygon = poly

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Word):
            return NotImplemented
        return (
            self.text == other.text
            and self.polygon.shape == other.polygon.shape
            and bool(np.array_equal(self.polygon, other.polygon))
            and (self.confidence == other.confidence or (np.isnan(self.confidence) and np.isnan(other.confidence)))
        )

    def to_dict(self) -> dict[str, Any]:
        return {
            "text": self.text,
            "polygon": [[float(x), float(y)] for x, y in self.polygon],
            # NaN = the engine gives no confidence (Google Vision words); JSON has no NaN, so null.
            "confidence": None if np.isnan(self.confidence) else self.confidence,
        }

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "Word":
        if "text" not in d or "polygon" not in d:
            raise OCRError(
                f"OCR word entry {dict(d)!r:.200} lacks 'text' or 'polygon'",
                hint='each word is {"text": ..., "polygon": [[x, y], ...], "confidence": ...}',
            )
        conf = d.get("confidence")
        return cls(text=d["text"], polygon=d["polygon"], confidence=float("nan") if conf is None else conf)

    @classmethod
    def from_box(cls, text: str, x0: float, y0: float, x1: float, y1: float, confidence: float = 1.0) -> "Word":
        """A word with an axis-aligned rectangle outline (corners clockwise from top-left)."""
        return cls(text, np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]], dtype=np.float64), confidence)


def words_to_json(words: Iterable[Word]) -> list[dict[str, Any]]:
    return [w.to_dict() for w in words]


def words_from_json(items: Iterable[Mapping[str, Any]]) -> list[Word]:
    return [Word.from_dict(d) for d in items]


def load_image(image: np.ndarray | str | os.PathLike) -> np.ndarray:
    """An RGB HxWx3 uint8 array from an array (HxWx3 or HxW uint8) or an image file path."""
    if isinstance(image, (str, os.PathLike)):
        from PIL import Image, UnidentifiedImageError

        path = Path(image)
        if not path.is_file():
            raise OCRError(f"image {path} does not exist", hint="check the path")
        try:
            with Image.open(path) as im:
                return np.asarray(im.convert("RGB"))
        except (UnidentifiedImageError, OSError) as exc:
            raise OCRError(f"cannot read image {path}: {exc}", hint="give a PNG or JPEG file") from exc
    arr = np.asarray(image)
    if arr.dtype != np.uint8:
        raise OCRError(
            f"image array has dtype {arr.dtype}, expected uint8",
            hint="convert with (np.clip(img, 0, 1) * 255).round().astype(np.uint8)",
        )
    if arr.ndim == 2:
        arr = np.repeat(arr[:, :, None], 3, axis=2)
    if arr.ndim != 3 or arr.shape[2] != 3:
        raise OCRError(f"image array has shape {arr.shape}, expected HxWx3 (RGB)", hint="drop the alpha channel")
    if arr.shape[0] == 0 or arr.shape[1] == 0:
        raise OCRError(f"image array has shape {arr.shape}: it is empty", hint="give a non-empty image")
    return np.ascontiguousarray(arr)


def load_mask(mask: np.ndarray | str | os.PathLike, shape: tuple[int, int]) -> np.ndarray:
    """A HxW bool mask (arrays: bool, or numbers where > 0 is text; files: non-black pixels are text)."""
    if isinstance(mask, (str, os.PathLike)):
        from PIL import Image

        path = Path(mask)
        if not path.is_file():
            raise OCRError(f"mask {path} does not exist", hint="check the path")
        with Image.open(path) as im:
            arr = np.asarray(im.convert("L")) > 0
    else:
        arr = np.asarray(mask)
        if arr.ndim == 3 and arr.shape[2] == 1:
            arr = arr[:, :, 0]
        arr = arr.astype(bool) if arr.dtype == bool else arr > 0
    if arr.shape != tuple(shape):
        raise OCRError(
            f"mask has shape {arr.shape} but the image is {tuple(shape)}",
            hint="the text mask must be the size of the image it masks",
        )
    return arr


def apply_mask(image: np.ndarray, mask: np.ndarray, fill: int = 0) -> np.ndarray:
    """image * mask, as the authors do: pixels outside the text mask become black (fill 0), or the
    grey level `fill` (a backend setting: RapidOCR's detector finds no line at all in some
    black-surrounded views; see docs/ocr.md)."""
    if not fill:
        return image * mask[:, :, None].astype(np.uint8)
    return np.where(mask[:, :, None], image, np.uint8(fill)).astype(np.uint8)


def array_sha256(arr: np.ndarray) -> str:
    """Hash of an array's shape, dtype and bytes."""
    h = hashlib.sha256()
    h.update(f"{arr.shape}|{arr.dtype.str}|".encode())
    h.update(np.ascontiguousarray(arr).tobytes())
    return h.hexdigest()


def mask_sha256(mask: np.ndarray) -> str:
    return array_sha256(np.packbits(mask.astype(bool), axis=None)) + f"-{mask.shape[0]}x{mask.shape[1]}"


@dataclass(frozen=True)
class BackendStatus:
    """Whether a backend can run here; `detail` is its version when available, else why not."""

    name: str
    available: bool
    detail: str


class OCRBackend:
    """Base class of the OCR backends.

    Subclasses set `name`, fill `self.settings` (everything that changes the result, JSON-serialisable,
    never a secret) and implement `_recognize(rgb) -> list[Word]` plus `version` and `status()`.
    `read` handles loading, masking and the on-disk cache.
    """

    name: ClassVar[str] = "base"

    def __init__(self, settings: dict[str, Any], cache: Any = None):
        self.settings: dict[str, Any] = dict(settings)
        self.cache = cache  # an OCRCache or None
        json.dumps(self.settings)  # settings go into cache keys and result files

    @property
    def version(self) -> str:  # pragma: no cover - overridden
        raise NotImplementedError

    @classmethod
    def status(cls) -> BackendStatus:  # pragma: no cover - overridden
        raise NotImplementedError

    def describe(self) -> dict[str, Any]:
        """Name, version and settings: stored with every result made by this backend."""
        return {"name": self.name, "version": self.version, "settings": dict(self.settings)}

    def __repr__(self) -> str:
        return f"{type(self).__name__}(name={self.name!r}, version={self.version!r}, settings={self.settings!r})"

    def read(self, image: np.ndarray | str | os.PathLike, mask: np.ndarray | str | os.PathLike | None = None) -> list[Word]:
        """Words found in `image` (RGB HxWx3 uint8 array or file), after `image * mask` when a mask is given.

        Raises OCRError when the backend fails; failures are never cached.
        """
        rgb = load_image(image)
        mask_arr = None if mask is None else load_mask(mask, rgb.shape[:2])
        key = None
        if self.cache is not None:
            key = self.cache.key(
                self.describe(), array_sha256(rgb), None if mask_arr is None else mask_sha256(mask_arr)
            )
            hit = self.cache.get(key)
            if hit is not None:
                return hit
        masked = rgb if mask_arr is None else apply_mask(rgb, mask_arr, int(self.settings.get("mask_fill", 0)))
        try:
            words = self._recognize(masked)
        except OCRError:
            raise
        except Exception as exc:  # engine bugs and crashes become OCR failures, counted by the scorer
            raise OCRError(
                f"{self.name} failed on an image of shape {masked.shape}: {type(exc).__name__}: {exc}",
                hint="the image is excluded from CER and counted as an OCR failure; run with -v for details",
            ) from exc
        if key is not None:
            self.cache.put(key, words, self.describe())
        return words

    def _recognize(self, rgb: np.ndarray) -> list[Word]:  # pragma: no cover - overridden
        raise NotImplementedError


@dataclass
class _Settings:
    """Helper for backends: defaults merged with user settings, rejecting unknown names."""

    defaults: dict[str, Any]
    given: dict[str, Any] = field(default_factory=dict)

    def merged(self, backend: str) -> dict[str, Any]:
        unknown = sorted(set(self.given) - set(self.defaults))
        if unknown:
            raise OCRError(
                f"unknown setting(s) {', '.join(unknown)} for OCR backend {backend!r}",
                hint=f"known settings: {', '.join(sorted(self.defaults))}",
            )
        out = dict(self.defaults)
        out.update(self.given)
        return out
