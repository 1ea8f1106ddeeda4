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
from strings_bench.core.scripts import LANGUAGES, split_lang
from strings_bench.eval.ocr.base import BackendStatus, OCRBackend, Word, BackendSettings
from strings_bench.eval.ocr.languages import tesseract_languages

DEFAULTS: dict[str, Any] = {
    "lang": "eng",
    "psm": 11,  # sparse text: masked scene images hold scattered words, not a page
    "oem": 1,  # LSTM engine
    "min_confidence": 0.0,  # words with a lower confidence (0..100 in Tesseract) are dropped
}
# lang=auto: each scene is read in the languages of its annotations (Evaluator resolves it: for_languages).
AUTO = "auto"
# Non-default options (docs/ocr.md, "Other scripts"); at these values they are left out of the settings,
# so results and cache entries made before they existed keep their key.
OPTIONAL_DEFAULTS: dict[str, Any] = {
    "upscale": 1.0,  # bicubic enlargement before reading (small scene text); polygons are divided back
    "mask_fill": 0,  # grey level outside the text mask (0: black, image x mask as in the paper)
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
        merged = BackendSettings({**DEFAULTS, **OPTIONAL_DEFAULTS}, settings).merged(self.name)
        try:
            merged["upscale"] = float(merged["upscale"])
        except (TypeError, ValueError):
            merged["upscale"] = float("nan")
        if not 1.0 <= merged["upscale"] <= 8.0:
            raise OCRError(f"tesseract setting upscale={settings.get('upscale')!r} is not a number in [1, 8]",
                           hint="1 reads the image as it is (default); 3 helped on 320x240 synthetic views")
        if not (isinstance(merged["mask_fill"], int) and not isinstance(merged["mask_fill"], bool)
                and 0 <= merged["mask_fill"] <= 255):
            raise OCRError(f"tesseract setting mask_fill={merged['mask_fill']!r} must be an integer grey level 0..255",
                           hint="0 = black, as image x mask in the paper (default)")
        for key, default in OPTIONAL_DEFAULTS.items():
            if merged[key] == default:
                del merged[key]
        if not isinstance(merged["lang"], str) or not merged["lang"].strip():
            raise OCRError(f"tesseract setting lang={merged['lang']!r} is not a language code",
                           hint="e.g. lang=rus, lang=chi_sim or lang=rus+eng (tesseract --list-langs)")
        merged["lang"] = "+".join(split_lang(merged["lang"]))
        super().__init__(merged, cache)
        self._runtime = {"binary": binary, "timeout": timeout, "threads": threads}
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
        version = _tesseract_version(self.binary)
        self.check_languages()
        return version

    def languages(self) -> list[str]:
        """The language codes of the `lang` setting ("rus+eng" -> ["rus", "eng"])."""
        if self.settings["lang"] == AUTO:
            raise OCRError("tesseract lang=auto is not resolved: it takes the languages of a scene's annotations",
                           hint="the evaluator resolves it per scene with known text (synthetic-multi); for other scenes "
                                "give the language, e.g. lang=rus")
        return split_lang(self.settings["lang"])

    def for_languages(self, languages: list[str]) -> "TesseractBackend":
        """With lang=auto: this backend reading `languages` (a scene's annotated languages, joined with '+'),
        with the same settings and cache; otherwise itself."""
        if self.settings["lang"] != AUTO:
            return self
        if not languages:
            raise OCRError("tesseract lang=auto found no annotated language in this scene",
                           hint="give the language, e.g. --ocr tesseract:lang=rus")
        settings = {k: v for k, v in self.settings.items() if k != "lang"}
        return TesseractBackend(cache=self.cache, **self._runtime, **settings, lang="+".join(languages))

    def check_languages(self) -> None:
        """OCRError naming the Debian package when a language of `lang` has no traineddata here (lang=auto:
        checked once resolved)."""
        if self.settings["lang"] == AUTO:
            return
        installed = tesseract_languages(self.binary)
        missing = [c for c in self.languages() if c not in installed]
        if missing:
            pkgs = " ".join(LANGUAGES[c].debian_package if c in LANGUAGES else f"tesseract-ocr-{c.replace('_', '-')}"
                            for c in missing)
            raise OCRError(f"Tesseract has no language data for {', '.join(missing)} (lang={self.settings['lang']!r}; "
                           f"installed: {', '.join(installed) or 'none'})", hint=f"apt-get install {pkgs}")

    def supported_scripts(self) -> frozenset[str] | None:
        if self.settings["lang"] == AUTO:
            return None  # resolved per scene to the scene's own languages
        codes = self.languages()
        if any(c not in LANGUAGES for c in codes):
            return None  # a language the suite does not list: its script is not known here, so not checked
        return frozenset(LANGUAGES[c].script for c in codes)

    def settings_summary(self) -> str:
        return f"lang={self.settings['lang']}"

    def _recognize(self, rgb: np.ndarray) -> list[Word]:
        from PIL import Image

        self.version  # noqa: B018 - raises the "not installed" error early
        up = float(self.settings.get("upscale", 1.0))
        buf = io.BytesIO()
        im = Image.fromarray(rgb)
        if up > 1:
            im = im.resize((int(round(im.width * up)), int(round(im.height * up))), Image.Resampling.BICUBIC)
        im.save(buf, format="PNG")
        s = self.settings
        self.languages()  # lang=auto must have been resolved
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
        words = parse_tesseract_tsv(out.stdout.decode("utf-8", "replace"), float(s["min_confidence"]))
        if up > 1:
            words = [Word(w.text, w.polygon * (np.array([rgb.shape[1], rgb.shape[0]]) / np.array([im.width, im.height])),
                          w.confidence) for w in words]
        return words
