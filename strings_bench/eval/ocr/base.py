"""The OCR backend interface: words with polygons, image loading, masking, hashing."""

from __future__ import annotations

import hashlib
import json
import logging
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar, Iterable, Mapping, Sequence

import numpy as np

from strings_bench.core.cpus import usable_cores
from strings_bench.core.errors import OCRError

log = logging.getLogger(__name__)

OCR_WORKERS_ENV = "STRINGS_BENCH_OCR_WORKERS"


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
    """Base class of the OCR engines: subclass it for an engine of your own.

    A subclass sets `name`, passes `settings` (everything that changes the result, JSON-serialisable,
    never a secret) to `__init__`, and implements `_recognize(rgb) -> list[Word]` plus `version` and `status()`.
    `read` does the rest: loading, masking, the on-disk cache (keyed by `describe()` and the pixels) and turning an
    engine's exception into an `OCRError`. An engine object is accepted wherever an engine name is: `run(...,
    ocr_backend=engine)`, `EvaluateOptions(ocr=engine)`.

    Args:
        settings: the engine's settings (JSON-serialisable; stored with every result).
        cache: an `OCRCache` (results on disk), or None for none.
    Raises:
        TypeError: `settings` is not JSON-serialisable.
    """

    name: ClassVar[str] = "base"
    # Whether `read` may run in several threads at once (read_many's pool). Engines that are one
    # process per read (Tesseract) or release the GIL in a thread-safe session (ONNX Runtime) say so.
    parallel_reads: ClassVar[bool] = False
    threads: int = 1  # cores one read uses (the engine's own threads); read_many divides the cores by it

    def __init__(self, settings: dict[str, Any], cache: Any = None):
        self.settings: dict[str, Any] = dict(settings)
        self.cache = cache  # an OCRCache or None
        json.dumps(self.settings)  # settings go into cache keys and result files

    @property
    def version(self) -> str:  # pragma: no cover - overridden
        """The engine's version (its models' too, where they change the result): part of the cache key."""
        raise NotImplementedError

    @classmethod
    def status(cls) -> BackendStatus:  # pragma: no cover - overridden
        """Whether the engine can run on this machine, without building it (`strings-bench ocr check`)."""
        raise NotImplementedError

    def describe(self) -> dict[str, Any]:
        """Name, version and settings: stored with every result made by this backend."""
        return {"name": self.name, "version": self.version, "settings": dict(self.settings)}

    def __repr__(self) -> str:
        return f"{type(self).__name__}(name={self.name!r}, version={self.version!r}, settings={self.settings!r})"

    def supported_scripts(self) -> frozenset[str] | None:
        """The scripts (core.scripts names) this backend can read with its settings; None: any script."""
        return None

    def require_scripts(self, scripts: Iterable[str], what: str = "this text") -> None:
        """Raise OCRError naming the backend, the scripts it cannot read and who can read them, when
        `scripts` holds one it cannot read (rather than scoring text it cannot read as CER 1)."""
        supported = self.supported_scripts()
        if supported is None:
            return
        missing = [s for s in scripts if s not in supported]
        if missing:
            from strings_bench.eval.ocr.languages import readers_hint

            why = "".join(f" ({s}: {self.unreadable_reason(s)})" for s in missing if self.unreadable_reason(s))
            raise OCRError(
                f"OCR backend {self.name} ({self.settings_summary()}) cannot read {', '.join(missing)} text in {what}"
                f"{why}; it reads {', '.join(sorted(supported)) or 'no known script'}",
                hint=readers_hint(missing),
            )

    def unreadable_reason(self, script: str) -> str | None:
        """Why this backend does not read `script`, where more than 'not supported' is known."""
        return None

    def settings_summary(self) -> str:
        """A short description of the settings that decide the scripts read (for messages)."""
        return "default models"

    def read(self, image: np.ndarray | str | os.PathLike, mask: np.ndarray | str | os.PathLike | None = None) -> list[Word]:
        """The words in `image`, read after `image * mask` when a mask is given.

        Args:
            image: (H, W, 3) uint8 RGB array, or an image file.
            mask: (H, W) text mask (bool, or uint8 > 127 = text; resized to the image when its size differs), a
                mask file, or None to read the whole image.
        Returns:
            the engine's `Word`s (from the cache when these pixels were read before with these settings).
        Raises:
            OCRError: the engine failed; failures are never cached.
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
        """The engine itself: the words in one image. Called by `read` on a cache miss, after masking.

        Args:
            rgb: (H, W, 3) uint8 RGB, already multiplied by the text mask when one was given.
        Returns:
            the words found, each with its text, its box (polygon in pixels of `rgb`) and a confidence in [0, 1];
            [] when there is none.
        Raises:
            OCRError: the engine failed (any other exception is turned into one by `read`).
        """
        raise NotImplementedError

    def default_workers(self) -> int:
        """Reads run at once by read_many (see default_workers below)."""
        return default_workers(self)

    def read_many(self, images: Sequence[Any], masks: Sequence[Any] | None = None, workers: int | None = None,
                  progress: bool = False, desc: str = "OCR") -> list[list[Word] | OCRError]:
        """`read` of many images at once (see read_many below)."""
        return read_many(self, images, masks, workers=workers, progress=progress, desc=desc)


def default_workers(engine: Any) -> int:
    """Reads run at once by read_many: STRINGS_BENCH_OCR_WORKERS when set, else the usable cores
    divided by the cores one read takes (`engine.threads`); 1 for engines that are not thread-safe
    (no `parallel_reads = True`, e.g. user-supplied engines)."""
    if not getattr(engine, "parallel_reads", False):
        return 1
    env = os.environ.get(OCR_WORKERS_ENV, "").strip()
    if env:
        try:
            n = int(env)
        except ValueError:
            n = 0
        if n < 1:
            raise OCRError(f"{OCR_WORKERS_ENV}={env!r} is not a positive whole number",
                           hint="e.g. 4; unset it to use the cores divided by the engine's threads")
        return n
    return max(1, usable_cores() // max(1, int(getattr(engine, "threads", 1) or 1)))


def read_many(engine: Any, images: Sequence[Any], masks: Sequence[Any] | None = None, workers: int | None = None,
              progress: bool = False, desc: str = "OCR") -> list[list[Word] | OCRError]:
    """`engine.read` of every image (array, file, or a no-argument function that returns one, called
    in the worker), with its mask, in a pool of `workers` threads (default: default_workers(engine);
    engines without `parallel_reads = True` read one image at a time).

    The results are in the order of `images`; a read that fails gives its OCRError in its place (the
    other reads are kept). The words do not depend on the number of workers
    (tests/eval/test_ocr_parallel.py checks this against one-at-a-time reads).
    """
    images = list(images)
    masks = [None] * len(images) if masks is None else list(masks)
    if len(masks) != len(images):
        raise OCRError(f"read_many: {len(images)} images but {len(masks)} masks", hint="give one mask (or None) per image")
    workers = default_workers(engine) if workers is None else int(workers)
    if workers < 1:
        raise OCRError(f"read_many: workers={workers} must be at least 1", hint="1 reads one image at a time")
    if not getattr(engine, "parallel_reads", False):
        workers = 1

    def one(k: int) -> list[Word] | OCRError:
        img = images[k]
        try:
            return engine.read(img() if callable(img) else img, masks[k])
        except OCRError as exc:
            return exc

    bar = None
    if progress and len(images) > 1:
        from tqdm import tqdm

        bar = tqdm(total=len(images), desc=desc, unit="img", leave=False)
    try:
        if workers == 1 or len(images) <= 1:
            out = []
            for k in range(len(images)):
                out.append(one(k))
                if bar is not None:
                    bar.update(1)
            return out
        from concurrent.futures import ThreadPoolExecutor, as_completed

        results: list[Any] = [None] * len(images)
        with ThreadPoolExecutor(max_workers=min(workers, len(images)),
                                thread_name_prefix=f"ocr-{getattr(engine, 'name', 'engine')}") as pool:
            futures = {pool.submit(one, k): k for k in range(len(images))}
            for fut in as_completed(futures):
                results[futures[fut]] = fut.result()
                if bar is not None:
                    bar.update(1)
        return results
    finally:
        if bar is not None:
            bar.close()


@dataclass
class BackendSettings:
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
