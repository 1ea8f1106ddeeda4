"""Noto fonts for text in other scripts (the multilingual scenes), and a glyph-coverage check.

The fonts come from Debian's `fonts-noto-core` (Latin, Cyrillic, Greek, Devanagari, Arabic) and
`fonts-noto-cjk` (Simplified Chinese), installed by the test command's system step
(scripts/system_deps.sh). They are looked up under `STRINGS_BENCH_FONT_DIRS` (colon-separated) and then
/usr/share/fonts; nothing is downloaded. Without them the multilingual scenes are not built
(`missing_fonts` says why), never drawn with missing glyphs (tofu boxes): `uncovered` checks every
character of a word against the font's character map (cmap) before it is drawn.

Text is laid out by Pillow with libraqm (HarfBuzz shaping, FriBiDi bidi): Arabic letters are joined
and ordered right to left, Devanagari vowel signs and conjuncts are placed. `layout_problem` says
when this Pillow has no raqm (then Arabic and Devanagari scenes are refused too).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

from PIL import ImageFont

from strings_bench.core.errors import DatasetError

FONT_DIRS_ENV = "STRINGS_BENCH_FONT_DIRS"
SYSTEM_FONT_DIR = "/usr/share/fonts"


@dataclass(frozen=True)
class NotoFont:
    file: str  # file name, searched for under the font folders
    family: str | None = None  # for a collection (.ttc): the family to take from it
    package: str = "fonts-noto-core"


# Bold sans faces: labels, signs and spines are printed bold.
NOTO_FONTS: dict[str, NotoFont] = {
    "Latin": NotoFont("NotoSans-Bold.ttf"),
    "Cyrillic": NotoFont("NotoSans-Bold.ttf"),
    "Greek": NotoFont("NotoSans-Bold.ttf"),
    "Devanagari": NotoFont("NotoSansDevanagari-Bold.ttf"),
    "Arabic": NotoFont("NotoNaskhArabic-Bold.ttf"),
    "Han": NotoFont("NotoSansCJK-Bold.ttc", family="Noto Sans CJK SC", package="fonts-noto-cjk"),
}
# Scripts whose words need shaping (joining, reordering, mark placement) and hence libraqm.
NEEDS_SHAPING = frozenset({"Arabic", "Devanagari"})


def font_dirs() -> list[Path]:
    extra = [Path(p) for p in os.environ.get(FONT_DIRS_ENV, "").split(":") if p.strip()]
    return extra + [Path(SYSTEM_FONT_DIR)]


@lru_cache(maxsize=None)
def _find(file: str, dirs: tuple[str, ...]) -> str | None:
    for d in dirs:
        root = Path(d)
        if not root.is_dir():
            continue
        direct = [p for p in (root / file, root / "truetype" / "noto" / file, root / "opentype" / "noto" / file) if p.is_file()]
        if direct:
            return str(direct[0])
        for p in root.rglob(file):
            return str(p)
    return None


@lru_cache(maxsize=None)
def _collection_index(path: str, family: str) -> int:
    from fontTools.ttLib import TTCollection

    coll = TTCollection(path, lazy=True)
    for i, font in enumerate(coll.fonts):
        name = font["name"]
        names = {name.getDebugName(1), name.getDebugName(16)}
        if family in names:
            return i
    raise DatasetError(f"font collection {path} holds no {family!r}", hint="reinstall fonts-noto-cjk")


def layout_problem() -> str | None:
    """Why this Pillow cannot shape complex scripts (no libraqm), or None."""
    from PIL import features

    if not features.check("raqm"):
        return "Pillow was built without libraqm (no shaping of Arabic or Devanagari): install libraqm0 and reinstall Pillow"
    return None


def font_file(script: str) -> tuple[str, int]:
    """(path, index in its collection) of the Noto font for `script`; DatasetError when missing."""
    if script not in NOTO_FONTS:
        raise DatasetError(f"no font is set for the {script} script", hint=f"scripts with fonts: {', '.join(NOTO_FONTS)}")
    spec = NOTO_FONTS[script]
    path = _find(spec.file, tuple(str(d) for d in font_dirs()))
    if path is None:
        raise DatasetError(f"the {script} font {spec.file} is not installed (looked under {', '.join(map(str, font_dirs()))})",
                           hint=f"apt-get install {spec.package} (scripts/system_deps.sh does it), or point "
                                f"{FONT_DIRS_ENV} at a folder that holds it")
    return path, (_collection_index(path, spec.family) if spec.family else 0)


def missing_fonts(scripts) -> dict[str, str]:
    """Script -> why it cannot be drawn here (font missing, no shaping), for the scripts that cannot."""
    out = {}
    for script in scripts:
        try:
            font_file(script)
        except DatasetError as exc:
            out[script] = f"{exc.message}; {exc.hint}"
            continue
        if script in NEEDS_SHAPING and layout_problem():
            out[script] = layout_problem()
    return out


@lru_cache(maxsize=256)
def load_noto(script: str, size_px: int) -> ImageFont.FreeTypeFont:
    path, index = font_file(script)
    return ImageFont.truetype(path, size=max(4, int(round(size_px))), index=index, layout_engine=ImageFont.Layout.RAQM
                              if layout_problem() is None else ImageFont.Layout.BASIC)


def font_for(script: str, size_px: float) -> ImageFont.FreeTypeFont:
    return load_noto(script, int(round(size_px)))


@lru_cache(maxsize=None)
def _cmap(script: str) -> frozenset[int]:
    from fontTools.ttLib import TTFont

    path, index = font_file(script)
    font = TTFont(path, fontNumber=index, lazy=True)
    return frozenset(font.getBestCmap() or {})


def uncovered(script: str, text: str) -> list[str]:
    """The characters of `text` (spaces aside) that the script's font has no glyph for."""
    cmap = _cmap(script)
    return sorted({ch for ch in text if not ch.isspace() and ord(ch) not in cmap})


def check_glyphs(script: str, text: str) -> None:
    """DatasetError when the script's font lacks a glyph for a character of `text` (it would be drawn
    as a tofu box)."""
    missing = uncovered(script, text)
    if missing:
        path, _ = font_file(script)
        raise DatasetError(f"the font {path} has no glyph for {' '.join(f'{c!r} (U+{ord(c):04X})' for c in missing)} "
                           f"in {text!r}", hint="use a font that covers the text (fonts.NOTO_FONTS)")
