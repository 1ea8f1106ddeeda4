"""Writing systems: which script a text is in, and the languages the suite knows.

Script names follow Unicode (ISO 15924 names): Latin, Cyrillic, Greek, Devanagari, Arabic, Han, ...
A character's script is taken from the first word of its Unicode name (`unicodedata.name`), which for
letters and marks of these blocks is the script ("CYRILLIC SMALL LETTER A", "DEVANAGARI VOWEL SIGN AA",
"CJK UNIFIED IDEOGRAPH-4E2D" -> Han). Digits, punctuation, spaces and generic combining marks belong
to no script (Common / Inherited) and are ignored, so "А-12" is Cyrillic.

Languages are keyed by their Tesseract code (ISO 639-2 based: eng, rus, ell, hin, ara, chi_sim), the
name of its traineddata file; `direction` is the reading direction of the script's lines.
"""

from __future__ import annotations

import unicodedata
from dataclasses import dataclass
from functools import lru_cache
from typing import Iterable

from strings_bench.core.errors import StringsBenchError

# First word of a character's Unicode name -> script name.
_NAME_TO_SCRIPT = {
    "LATIN": "Latin", "CYRILLIC": "Cyrillic", "GREEK": "Greek", "DEVANAGARI": "Devanagari", "ARABIC": "Arabic",
    "CJK": "Han", "HIRAGANA": "Hiragana", "KATAKANA": "Katakana", "HANGUL": "Hangul", "HEBREW": "Hebrew",
    "THAI": "Thai", "BENGALI": "Bengali", "TAMIL": "Tamil", "ARMENIAN": "Armenian", "GEORGIAN": "Georgian",
}
RTL_SCRIPTS = frozenset({"Arabic", "Hebrew"})


@dataclass(frozen=True)
class Language:
    code: str  # Tesseract's code (traineddata name)
    name: str
    script: str
    direction: str  # "ltr" or "rtl"
    debian_package: str  # the Debian package with its Tesseract traineddata


LANGUAGES: dict[str, Language] = {
    "eng": Language("eng", "English", "Latin", "ltr", "tesseract-ocr-eng"),
    "rus": Language("rus", "Russian", "Cyrillic", "ltr", "tesseract-ocr-rus"),
    "ell": Language("ell", "Greek", "Greek", "ltr", "tesseract-ocr-ell"),
    "hin": Language("hin", "Hindi", "Devanagari", "ltr", "tesseract-ocr-hin"),
    "ara": Language("ara", "Arabic", "Arabic", "rtl", "tesseract-ocr-ara"),
    "chi_sim": Language("chi_sim", "Simplified Chinese", "Han", "ltr", "tesseract-ocr-chi-sim"),
}


def get_language(code: str) -> Language:
    if code not in LANGUAGES:
        raise StringsBenchError(f"unknown language {code!r}", hint=f"known languages: {', '.join(LANGUAGES)}")
    return LANGUAGES[code]


def languages_for_script(script: str) -> list[str]:
    """Codes of the known languages written in `script`."""
    return [c for c, lang in LANGUAGES.items() if lang.script == script]


@lru_cache(maxsize=4096)
def char_script(ch: str) -> str | None:
    """The script of one character, or None for Common/Inherited ones (digits, punctuation, spaces,
    generic combining marks) and characters without a name."""
    if not ch.isalpha() and unicodedata.category(ch)[0] != "M":
        return None
    try:
        first = unicodedata.name(ch).split()[0]
    except ValueError:
        return None
    return _NAME_TO_SCRIPT.get(first)


def text_scripts(text: str) -> list[str]:
    """The scripts of a text's characters, most frequent first (ties: first seen); [] for none."""
    counts: dict[str, int] = {}
    for ch in text:
        s = char_script(ch)
        if s is not None:
            counts[s] = counts.get(s, 0) + 1
    return sorted(counts, key=lambda s: -counts[s])


def text_script(text: str) -> str | None:
    """The main script of a text (the most frequent), or None when it has no letters."""
    scripts = text_scripts(text)
    return scripts[0] if scripts else None


def scripts_of(texts: Iterable[str]) -> list[str]:
    """The scripts of several texts together, most frequent character count first."""
    return text_scripts("".join(texts))


def split_lang(lang: str) -> list[str]:
    """Tesseract's `lang` value ("rus", "rus+eng") as its language codes."""
    codes = [c.strip() for c in str(lang).split("+") if c.strip()]
    if not codes:
        raise StringsBenchError(f"empty language setting {lang!r}", hint="e.g. lang=rus or lang=rus+eng")
    return codes


# The basic letters of each script (no accents, no presentation forms): what a recogniser's character
# set must mostly hold to read the script (`alphabet_coverage`). Han: the CJK Unified Ideographs of
# the original Unicode block up to U+9FA5 (GB 2312 and the common set lie inside it).
def _chars(*ranges: tuple[int, int], skip: tuple[int, ...] = ()) -> frozenset[str]:
    return frozenset(chr(c) for lo, hi in ranges for c in range(lo, hi + 1) if c not in skip)


ALPHABETS: dict[str, frozenset[str]] = {
    "Latin": _chars((0x41, 0x5A), (0x61, 0x7A)),
    "Cyrillic": _chars((0x410, 0x44F)),
    "Greek": _chars((0x391, 0x3A9), (0x3B1, 0x3C9), skip=(0x3A2,)),
    "Devanagari": _chars((0x904, 0x939)),
    "Arabic": _chars((0x621, 0x63A), (0x641, 0x64A)),
    "Han": _chars((0x4E00, 0x9FA5)),
}
# A recogniser reads a script when its character set holds at least this share of the script's alphabet.
MIN_ALPHABET_COVERAGE = 0.7


def alphabet_coverage(charset: Iterable[str]) -> dict[str, float]:
    """Per script of ALPHABETS, the share of its letters that `charset` holds."""
    chars = set(charset)
    return {s: len(a & chars) / len(a) for s, a in ALPHABETS.items()}
