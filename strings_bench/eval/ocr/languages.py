"""Which languages and scripts the OCR backends can read here.

- Tesseract reads the languages whose traineddata is installed (`tesseract --list-langs`; Debian's
  `tesseract-ocr-<lang>` packages); its `lang` setting picks them ("rus", "rus+eng").
- RapidOCR's bundled recogniser reads what its character dictionary holds (the model's `character`
  metadata): a script counts as read when the dictionary holds at least
  `core.scripts.MIN_ALPHABET_COVERAGE` of its basic letters (`rapidocr_scripts`) and it was not measured
  unreadable (`RAPIDOCR_MEASURED_UNREADABLE`: Greek).
- Google Cloud Vision reads every script (not checked here).
"""

from __future__ import annotations

import os
import shutil
import subprocess
from functools import lru_cache

from strings_bench.core.errors import OCRError
from strings_bench.core.scripts import LANGUAGES, MIN_ALPHABET_COVERAGE, alphabet_coverage, languages_for_script


@lru_cache(maxsize=8)
def tesseract_languages(binary: str | None = None) -> tuple[str, ...]:
    """The language codes Tesseract has traineddata for (sorted); () when Tesseract is not installed."""
    binary = binary or os.environ.get("STRINGS_BENCH_TESSERACT", "tesseract")
    if shutil.which(binary) is None:
        return ()
    try:
        out = subprocess.run([binary, "--list-langs"], capture_output=True, text=True, timeout=30)
    except (OSError, subprocess.TimeoutExpired) as exc:
        raise OCRError(f"cannot run {binary} --list-langs: {exc}", hint="check the Tesseract installation") from exc
    lines = (out.stdout + out.stderr).splitlines()
    # The first line is 'List of available languages in "<dir>" (N):'.
    return tuple(sorted(ln.strip() for ln in lines if ln.strip() and not ln.startswith("List of") and " " not in ln.strip()))


@lru_cache(maxsize=2)
def rapidocr_charset(model_path: str | None = None) -> frozenset[str]:
    """The characters RapidOCR's bundled recogniser can output (its model's `character` metadata; the
    model file is rapid.REC_MODEL_FILE, read here without importing the backend)."""
    from pathlib import Path

    import strings_bench.eval.ocr._ort_guard  # noqa: F401 - before onnxruntime

    try:
        import onnxruntime
        import rapidocr
    except Exception as exc:  # noqa: BLE001
        raise OCRError(f"RapidOCR cannot be loaded: {type(exc).__name__}: {exc}", hint="pip install rapidocr==3.10.0 onnxruntime") from exc
    path = Path(model_path) if model_path else Path(rapidocr.__file__).parent / "models" / "PP-OCRv6_rec_small.onnx"
    if not path.is_file():
        raise OCRError(f"RapidOCR's recognition model {path} is missing", hint="pip install --force-reinstall rapidocr==3.10.0")
    session = onnxruntime.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    meta = session.get_modelmeta().custom_metadata_map
    if "character" not in meta:
        raise OCRError(f"{path} carries no character dictionary (metadata 'character')", hint="use rapidocr 3.10.0's model")
    return frozenset(c for c in meta["character"].splitlines() if len(c) == 1)


def rapidocr_scripts(model_path: str | None = None) -> dict[str, float]:
    """Script -> share of its letters in RapidOCR's dictionary, for every script of core.scripts.ALPHABETS."""
    return alphabet_coverage(rapidocr_charset(model_path))


# Scripts whose letters RapidOCR's dictionary holds but which it was measured not to read (docs/ocr.md,
# "Other scripts"): it refuses them too, with this reason.
RAPIDOCR_MEASURED_UNREADABLE = {
    "Greek": "its dictionary holds 48 of the 49 Greek capitals and small letters, but on the GT test views of "
             "synthetic-multi/greek its known-text CER was 0.892 (Tesseract ell: 0.431)",
}


def rapidocr_supported_scripts(model_path: str | None = None) -> frozenset[str]:
    """The scripts RapidOCR reads: its dictionary holds at least MIN_ALPHABET_COVERAGE of their letters and
    they were not measured unreadable (Latin and Han with rapidocr 3.10)."""
    return frozenset(s for s, share in rapidocr_scripts(model_path).items()
                     if share >= MIN_ALPHABET_COVERAGE and s not in RAPIDOCR_MEASURED_UNREADABLE)


def readers_hint(scripts: list[str]) -> str:
    """Which backends and languages read `scripts`, and how to install what is missing."""
    installed = set(tesseract_languages())
    parts = []
    for script in scripts:
        codes = languages_for_script(script)
        if not codes:
            parts.append(f"{script}: no Tesseract language of the suite's list ({', '.join(LANGUAGES)}); gcv reads it")
            continue
        have = [c for c in codes if c in installed]
        if have:
            parts.append(f"{script}: --ocr tesseract:lang={'+'.join(have)} (installed)")
        else:
            pkgs = " ".join(LANGUAGES[c].debian_package for c in codes)
            parts.append(f"{script}: tesseract with lang={'+'.join(codes)} after apt-get install tesseract-ocr {pkgs}")
    return "; ".join(parts) + "; gcv (Google Cloud Vision) reads every script"
