"""Optional OCR backend: the Tesseract command-line program (`tesseract stdin stdout ... tsv`).

The image goes in on stdin as PNG and the word table comes back on stdout, so nothing is written to
disk. Install with e.g. `apt-get install tesseract-ocr`; when the program is missing the backend
reports itself as not installed.
"""

from __future__ import annotations

import csv
import io
import os
import shutil
import subprocess
from functools import lru_cache
from typing import Any

import numpy as np

from strings_bench.core.errors import OCRError
from strings_bench.eval.ocr.base import BackendStatus, OCRBackend, Word, _Settings

DEFAULTS: dict[str, Any] = {
    "lang": "eng",
    "psm": 11,  # sparse text: masked scene images hold scattered words, not a page
    "oem": 1,  # LSTM engine
    "min_confidence": 0.0,  # words with a lower confidence (0..100 in Tesseract) are dropped
}


@lru_cache(maxsize=8)
def _tesseract_version(binary: str) -> str:
    try:
        out = subprocess.run([binary, "--version"], capture_output=True, text=True, timeout=30)
    except (OSError, subprocess.TimeoutExpired) as exc:
        raise OCRError(f"cannot run {binary} --version: {exc}", hint="check the Tesseract installation") from exc
    lines = (out.stdout + out.stderr).strip().splitlines()
    if not lines:
        raise OCRError(f"{binary} --version printed nothing", hint="check the Tesseract installation")
    extra = [ln.strip() for ln in lines[1:2] if ln.strip()]
    return lines[0].strip() + (f" ({extra[0]})" if extra else "")


def parse_tesseract_tsv(tsv: str, min_confidence: float = 0.0) -> list[Word]:
    """Word rows (level 5) of Tesseract's TSV output as Words; confidence scaled to [0, 1]."""
    reader = csv.DictReader(io.StringIO(tsv), delimiter="\t", quoting=csv.QUOTE_NONE)
    words = []
    for row in reader:
        try:
            if int(row["level"]) != 5:
                continue
            conf = float(row["conf"])
            text = (row.get("text") or "").strip()
            x, y, w, h = (float(row[k]) for k in ("left", "top", "width", "height"))
        except (KeyError, TypeError, ValueError) as exc:
            raise OCRError(f"unexpected Tesseract TSV row {row!r:.200}", hint="check the Tesseract version") from exc
        if not text or conf < 0 or conf < min_confidence:
            continue
        words.append(Word.from_box(text, x, y, x + w, y + h, conf / 100.0))
    return words


class TesseractBackend(OCRBackend):
    name = "tesseract"
    parallel_reads = True  # one tesseract process per read

    def __init__(self, cache: Any = None, binary: str | None = None, timeout: float = 120.0, threads: int = 1, **settings: Any):
        super().__init__(_Settings(DEFAULTS, settings).merged(self.name), cache)
        self.binary = binary or os.environ.get("STRINGS_BENCH_TESSERACT", "tesseract")
        self.timeout = float(timeout)
        self.threads = int(threads)  # OMP_THREAD_LIMIT; runtime only

    @classmethod
    def status(cls, binary: str | None = None) -> BackendStatus:
        binary = binary or os.environ.get("STRINGS_BENCH_TESSERACT", "tesseract")
        if shutil.which(binary) is None:
            return BackendStatus(cls.name, False, f"not installed ({binary!r} not found on PATH; e.g. apt-get install tesseract-ocr)")
        try:
            return BackendStatus(cls.name, True, _tesseract_version(binary))
        except OCRError as exc:
            return BackendStatus(cls.name, False, exc.message)

    @property
    def version(self) -> str:
        if shutil.which(self.binary) is None:
            raise OCRError(
                f"Tesseract is not installed ({self.binary!r} not found on PATH)",
                hint="install it (e.g. apt-get install tesseract-ocr) or use the rapidocr backend",
            )
        return _tesseract_version(self.binary)

    def _recognize(self, rgb: np.ndarray) -> list[Word]:
        from PIL import Image

        self.version  # noqa: B018 - raises the "not installed" error early
        buf = io.BytesIO()
        Image.fromarray(rgb).save(buf, format="PNG")
        s = self.settings
        cmd = [self.binary, "stdin", "stdout", "-l", str(s["lang"]), "--psm", str(int(s["psm"])), "--oem", str(int(s["oem"])), "tsv"]
        env = dict(os.environ, OMP_THREAD_LIMIT=str(self.threads))
        try:
            out = subprocess.run(cmd, input=buf.getvalue(), capture_output=True, timeout=self.timeout, env=env)
        except subprocess.TimeoutExpired as exc:
            raise OCRError(f"tesseract took longer than {self.timeout:g} s", hint="raise the timeout") from exc
        except OSError as exc:
            raise OCRError(f"cannot run tesseract: {exc}", hint="check the Tesseract installation") from exc
        if out.returncode != 0:
            err = out.stderr.decode("utf-8", "replace").strip()[-500:]
            raise OCRError(
                f"tesseract exited with status {out.returncode}: {err}",
                hint=f"check that the language data for lang={s['lang']!r} is installed (tesseract --list-langs)",
            )
        return parse_tesseract_tsv(out.stdout.decode("utf-8", "replace"), float(s["min_confidence"]))
