"""On-disk cache of OCR results, so that re-scoring a scene costs almost nothing.

One JSON file per (backend name, version, settings, image hash, mask hash) under
`cache_root()/ocr/<2 hex>/<key>.json`, written atomically. Only successful reads are cached.
"""

from __future__ import annotations

import hashlib
import json
import logging
from pathlib import Path
from typing import Any

from strings_bench.core.io import atomic_write_json, cache_root
from strings_bench.eval.ocr.base import Word, words_from_json, words_to_json

log = logging.getLogger(__name__)

CACHE_FORMAT = 1


class OCRCache:
    def __init__(self, root: str | Path | None = None):
        self.root = Path(root) if root is not None else cache_root() / "ocr"

    @staticmethod
    def key(backend: dict[str, Any], image_sha256: str, mask_sha256: str | None) -> str:
        blob = json.dumps(
            {"format": CACHE_FORMAT, "backend": backend, "image": image_sha256, "mask": mask_sha256},
            sort_keys=True,
        )
        return hashlib.sha256(blob.encode()).hexdigest()

    def path(self, key: str) -> Path:
        return self.root / key[:2] / f"{key}.json"

    def get(self, key: str) -> list[Word] | None:
        path = self.path(key)
        try:
            data = json.loads(path.read_text(encoding="utf-8"))
            return words_from_json(data["words"])
        except FileNotFoundError:
            return None
        except Exception as exc:  # a damaged entry is a miss; it is rewritten on the next read
            log.warning("ignoring unreadable OCR cache entry %s (%s)", path, exc)
            return None

    def put(self, key: str, words: list[Word], backend: dict[str, Any]) -> None:
        atomic_write_json(self.path(key), {"format": CACHE_FORMAT, "backend": backend, "words": words_to_json(words)})
