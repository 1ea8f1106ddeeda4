"""The OCR results file format read by `strings-bench cer` and written by `strings-bench ocr read`.

One JSON file for many images:

    {"format": "strings-bench-ocr/1",
     "backend": {"name": "rapidocr", "version": "...", "settings": {...}},      (optional)
     "images": {"00000.png": [{"text": "EXIT", "polygon": [[x, y], ...], "confidence": 0.98}, ...],
                "00008.png": null,                          (OCR failed: left out and counted)
                "00016.png": {"error": "timed out"},        (the same, with the reason)
                "00024.png": {"responses": [...]}}}         (a raw Cloud Vision annotate answer)

or a folder of per-image JSON files, the image name being the file's path relative to the folder
without ".json"; each file holds what one "images" value above may hold (a word list, null,
{"error": ...}, {"words": [...]}, or a raw Cloud Vision answer). A single JSON file without an
"images" key is one image, named after the file.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any, Mapping

from strings_bench.core.errors import OCRError, StringsBenchError
from strings_bench.core.io import atomic_write_json
from strings_bench.eval.ocr.base import Word, words_from_json, words_to_json
from strings_bench.eval.ocr.gcv import GCVImageError, parse_gcv_response

FORMAT = "strings-bench-ocr/1"

# image name -> words, or None when the OCR failed on it
OCRResults = dict[str, "list[Word] | None"]


class OCRResultsError(StringsBenchError):
    """An OCR results file or folder is malformed."""


def parse_entry(value: Any, where: str) -> list[Word] | None:
    """The words of one image entry, or None for a recorded OCR failure."""
    if value is None:
        return None
    try:
        if isinstance(value, list):
            return words_from_json(value)
        if isinstance(value, Mapping):
            if any(k in value for k in ("responses", "textAnnotations", "fullTextAnnotation")) or not value:
                try:
                    return parse_gcv_response(value)  # {} is Cloud Vision's answer for "no text"
                except GCVImageError:
                    return None  # an error response: an OCR failure, counted
            if "words" in value:
                return None if value["words"] is None else words_from_json(value["words"])
            if "error" in value:
                return None
    except OCRError as exc:
        raise OCRResultsError(f"{where}: {exc.message}", hint=FORMAT_HINT) from None
    raise OCRResultsError(f"{where}: cannot read {type(value).__name__} {json.dumps(value)[:120]} as OCR words", hint=FORMAT_HINT)


FORMAT_HINT = (
    'use {"images": {name: [{"text": ..., "polygon": [[x, y], ...], "confidence": ...}, ...]}}, '
    "a folder of per-image JSON files, or raw Cloud Vision answers (see docs/ocr.md)"
)


def _read_json(path: Path) -> Any:
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError) as exc:
        raise OCRResultsError(f"cannot read OCR results {path}: {exc}", hint="check the path") from None
    except json.JSONDecodeError as exc:
        raise OCRResultsError(f"OCR results {path} are not valid JSON: {exc}", hint=FORMAT_HINT) from None


def load_ocr_results(path: str | os.PathLike) -> tuple[OCRResults, dict[str, Any]]:
    """(image name -> words or None, metadata) from a results file or folder.

    metadata has "kind": "file" | "folder" | "single", plus "backend" when the file records one.
    """
    path = Path(path)
    if path.is_dir():
        files = sorted(p for p in path.rglob("*.json") if p.is_file())
        if not files:
            raise OCRResultsError(f"OCR results folder {path} holds no .json files", hint=FORMAT_HINT)
        out: OCRResults = {}
        for f in files:
            name = f.relative_to(path).as_posix()[: -len(".json")]
            out[name] = parse_entry(_read_json(f), str(f))
        return out, {"kind": "folder"}
    if not path.is_file():
        raise OCRResultsError(f"OCR results {path} do not exist", hint="give a results JSON file or a folder of them")
    data = _read_json(path)
    if isinstance(data, Mapping) and "images" in data:
        images = data["images"]
        if not isinstance(images, Mapping):
            raise OCRResultsError(f"{path}: 'images' is a {type(images).__name__}, expected an object name -> words", hint=FORMAT_HINT)
        out = {str(name): parse_entry(v, f"{path} image {name!r}") for name, v in images.items()}
        meta = {"kind": "file"}
        if "backend" in data:
            meta["backend"] = data["backend"]
        return out, meta
    name = path.name[: -len(".json")] if path.name.endswith(".json") else path.name
    return {name: parse_entry(data, str(path))}, {"kind": "single"}


def save_ocr_results(path: str | os.PathLike, results: Mapping[str, list[Word] | None | str], backend: dict[str, Any] | None = None) -> Path:
    """Write results atomically; a str value is recorded as a failure with that reason."""
    images: dict[str, Any] = {}
    for name, v in results.items():
        if v is None:
            images[name] = None
        elif isinstance(v, str):
            images[name] = {"error": v}
        else:
            images[name] = words_to_json(v)
    doc: dict[str, Any] = {"format": FORMAT, "images": images}
    if backend is not None:
        doc["backend"] = backend
    return atomic_write_json(path, doc)
