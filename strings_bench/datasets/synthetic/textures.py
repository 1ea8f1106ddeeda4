"""Texture images for the synthetic scenes: procedural non-text patterns and text labels.

Text is drawn with the DejaVu fonts that matplotlib ships (always installed with the suite), so the
scenes look the same on every machine. Every word is drawn separately and its box is recorded in
texture pixels, in reading order (top-left, top-right, bottom-right, bottom-left of the text as
read), so the generator can place the same box on a 3D surface.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from PIL import Image, ImageDraw, ImageFont

from strings_bench.core.errors import DatasetError

FONT_FILES = {
    "sans": "DejaVuSans.ttf",
    "sans-bold": "DejaVuSans-Bold.ttf",
    "serif": "DejaVuSerif.ttf",
    "serif-bold": "DejaVuSerif-Bold.ttf",
    "mono": "DejaVuSansMono.ttf",
}


@lru_cache(maxsize=None)
def font_path(style: str) -> str:
    import matplotlib

    if style not in FONT_FILES:
        raise DatasetError(f"unknown font style {style!r}", hint=f"use one of {', '.join(FONT_FILES)}")
    path = os.path.join(matplotlib.get_data_path(), "fonts", "ttf", FONT_FILES[style])
    if not os.path.exists(path):
        raise DatasetError(f"the font {path} that matplotlib ships is missing",
                           hint="reinstall matplotlib in the suite's environment (pip install --force-reinstall matplotlib)")
    return path


@lru_cache(maxsize=256)
def load_font(style: str, size_px: int) -> ImageFont.FreeTypeFont:
    if style.startswith(NOTO_PREFIX):  # "noto-Cyrillic": the Noto font of that script (fonts.py)
        from strings_bench.datasets.synthetic.fonts import load_noto

        return load_noto(style[len(NOTO_PREFIX):], int(round(size_px)))
    return ImageFont.truetype(font_path(style), size=max(4, int(round(size_px))))


NOTO_PREFIX = "noto-"


def text_direction(style: str) -> str | None:
    """"rtl" for the fonts of right-to-left scripts (Arabic is laid out right to left by raqm), else None."""
    from strings_bench.core.scripts import RTL_SCRIPTS

    return "rtl" if style.startswith(NOTO_PREFIX) and style[len(NOTO_PREFIX):] in RTL_SCRIPTS else None


def _check_glyphs(style: str, text: str) -> None:
    if style.startswith(NOTO_PREFIX):
        from strings_bench.datasets.synthetic.fonts import check_glyphs

        check_glyphs(style[len(NOTO_PREFIX):], text)


@dataclass(frozen=True)
class WordBox:
    """One drawn word: its text and the 4 corners of its box in texture pixels, in reading order."""

    text: str
    corners: np.ndarray  # (4, 2) float: TL, TR, BR, BL of the text as read; x right, y down


def noise_field(rng: np.random.Generator, h: int, w: int, octaves: tuple[int, ...] = (4, 16, 64)) -> np.ndarray:
    """Smooth multi-scale value noise in [0, 1], (h, w) float32: blotches SIFT can latch onto."""
    out = np.zeros((h, w), np.float32)
    total = 0.0
    for k, cells in enumerate(octaves):
        ch, cw = max(2, int(round(cells * h / max(h, w)))), max(2, cells)
        grid = rng.random((ch, cw)).astype(np.float32)
        img = Image.fromarray((grid * 255).astype(np.uint8)).resize((w, h), Image.Resampling.BICUBIC)
        amp = 0.5 ** k
        out += amp * np.asarray(img, np.float32) / 255.0
        total += amp
    out /= total
    lo, hi = float(out.min()), float(out.max())
    return (out - lo) / (hi - lo + 1e-6)


def tinted_noise(rng: np.random.Generator, h: int, w: int, color, amplitude: float = 0.12,
                 octaves: tuple[int, ...] = (4, 16, 64)) -> np.ndarray:
    """(h, w, 3) uint8: a base colour modulated by noise (paper, cloth, painted metal)."""
    n = noise_field(rng, h, w, octaves)[..., None]
    base = np.asarray(color, np.float32)[None, None, :]
    img = base * (1.0 - amplitude + 2 * amplitude * n)
    return np.clip(img, 0, 255).astype(np.uint8)


def wood(rng: np.random.Generator, h: int, w: int, light=(176, 126, 80), dark=(110, 70, 40)) -> np.ndarray:
    """(h, w, 3) uint8 wood grain running along x: rings from a warped sine plus fine streaks."""
    y = np.arange(h, dtype=np.float32)[:, None]
    x = np.arange(w, dtype=np.float32)[None, :]
    warp = noise_field(rng, h, w, (3, 9)) * 25.0
    rings = 0.5 + 0.5 * np.sin((y + warp) * (2 * np.pi / max(6.0, h / 14.0)) + 0.002 * x)
    streak = noise_field(rng, h, w, (2, 200))
    t = np.clip(0.65 * rings + 0.35 * streak, 0, 1)[..., None]
    img = np.asarray(dark, np.float32) * (1 - t) + np.asarray(light, np.float32) * t
    return np.clip(img, 0, 255).astype(np.uint8)


def tiles(rng: np.random.Generator, h: int, w: int, n_x: int, n_y: int) -> np.ndarray:
    """(h, w, 3) uint8 floor tiles: irregular grey-beige squares with grout and speckle."""
    img = np.zeros((h, w, 3), np.float32)
    ys = np.linspace(0, h, n_y + 1).astype(int)
    xs = np.linspace(0, w, n_x + 1).astype(int)
    for i in range(n_y):
        for j in range(n_x):
            c = np.array([150, 140, 125], np.float32) * (0.75 + 0.5 * rng.random()) + rng.normal(0, 10, 3)
            img[ys[i]:ys[i + 1], xs[j]:xs[j + 1]] = c
    img *= 0.75 + 0.5 * noise_field(rng, h, w, (8, 48, 160, 400))[..., None]
    grout = np.zeros((h, w), bool)
    gw = max(1, h // (n_y * 20))
    for yv in ys:
        grout[max(0, yv - gw):yv + gw] = True
    for xv in xs:
        grout[:, max(0, xv - gw):xv + gw] = True
    img[grout] = (70, 66, 60)
    return np.clip(img, 0, 255).astype(np.uint8)


def blobs(rng: np.random.Generator, h: int, w: int, palette, n: int) -> np.ndarray:
    """(h, w, 3) uint8 a wall/backdrop: soft noise ground with scattered coloured ellipses (no text)."""
    base = tinted_noise(rng, h, w, palette[0], amplitude=0.25, octaves=(6, 24, 96, 384))
    im = Image.fromarray(base)
    draw = ImageDraw.Draw(im)
    for k in range(n):
        cx, cy = rng.random() * w, rng.random() * h
        scale = 1.0 if k < n // 3 else 0.35  # a few large blobs, many small ones
        rx, ry = scale * (0.01 + 0.03 * rng.random()) * w, scale * (0.03 + 0.1 * rng.random()) * h
        col = tuple(int(v) for v in np.clip(np.asarray(palette[1 + rng.integers(len(palette) - 1)]) + rng.normal(0, 15, 3), 0, 255))
        draw.ellipse([cx - rx, cy - ry, cx + rx, cy + ry], fill=col)
    return np.asarray(im)


class Canvas:
    """A texture being painted: background image, words drawn one at a time with recorded boxes."""

    def __init__(self, image: np.ndarray):
        self.image = Image.fromarray(np.asarray(image, np.uint8)).convert("RGB")
        self.words: list[WordBox] = []
        self.lang: str | None = None  # language and script of its words, recorded in the annotations when set
        self.script: str | None = None

    @property
    def size(self) -> tuple[int, int]:
        return self.image.size

    def rect(self, box, fill) -> None:
        ImageDraw.Draw(self.image).rectangle([int(round(v)) for v in box], fill=tuple(int(c) for c in fill))

    def line_shape(self, xy, fill, width: int) -> None:
        ImageDraw.Draw(self.image).line([tuple(map(float, p)) for p in xy], fill=tuple(int(c) for c in fill), width=int(width))

    def word(self, text: str, x: float, y: float, size_px: float, fill=(0, 0, 0), style: str = "sans-bold",
             rotate: int = 0, stretch_x: float = 1.0, anchor: str = "lt") -> WordBox:
        """Draw one word; (x, y) is the top-left ("lt") or the centre ("mm") of its box in this canvas.

        rotate: 0 reads left to right; -90 reads top to bottom (clockwise, English book spines);
        90 reads bottom to top. stretch_x widens the glyphs (pre-compensates the squeeze near a
        sphere's poles). The box is the ink's bounding box plus a margin of 12 % of the size.
        """
        font = load_font(style, size_px)
        _check_glyphs(style, text)  # never a tofu box: every character must have a glyph in the font
        direction = text_direction(style)
        left, top, right, bottom = font.getbbox(text, direction=direction)
        pad = max(1, int(round(0.12 * size_px)))
        w, h = right - left + 2 * pad, bottom - top + 2 * pad
        label = Image.new("L", (w, h), 0)
        ImageDraw.Draw(label).text((pad - left, pad - top), text, font=font, fill=255, direction=direction)
        if stretch_x != 1.0:
            label = label.resize((max(1, int(round(w * stretch_x))), h), Image.Resampling.BICUBIC)
            w = label.size[0]
        # Corners of the label in its own frame, in reading order.
        local = np.array([[0, 0], [w, 0], [w, h], [0, h]], np.float64)
        if rotate == 0:
            corners = local
        elif rotate == -90:  # clockwise: reading direction points down, the glyph tops point right
            label = label.transpose(Image.Transpose.ROTATE_270)
            corners = np.stack([h - local[:, 1], local[:, 0]], axis=1)
        elif rotate == 90:  # anticlockwise: reading direction points up, the glyph tops point left
            label = label.transpose(Image.Transpose.ROTATE_90)
            corners = np.stack([local[:, 1], w - local[:, 0]], axis=1)
        else:
            raise ValueError(f"rotate must be 0, 90 or -90, not {rotate}")
        lw, lh = label.size
        if anchor == "mm":
            x, y = x - lw / 2, y - lh / 2
        elif anchor != "lt":
            raise ValueError(f"anchor must be 'lt' or 'mm', not {anchor!r}")
        ox, oy = int(round(x)), int(round(y))
        color = Image.new("RGB", label.size, tuple(int(c) for c in fill))
        self.image.paste(color, (ox, oy), label)
        box = WordBox(text, corners + np.array([ox, oy], np.float64))
        self.words.append(box)
        return box

    def text_line(self, text: str, x: float, y: float, size_px: float, fill=(0, 0, 0), style: str = "sans-bold",
                  rotate: int = 0, stretch_x: float = 1.0, anchor: str = "lt") -> list[WordBox]:
        """Draw space-separated words as one line (each word gets its own box).

        anchor "lt": (x, y) is where the line starts (top-left as read); "mm": the line's centre.
        The words are drawn, and their boxes recorded, in reading order.
        """
        font = load_font(style, size_px)
        words = text.split()
        direction = text_direction(style)
        space = font.getlength(" ") * stretch_x
        pad = max(1, int(round(0.12 * size_px)))
        bboxes = [font.getbbox(w, direction=direction) for w in words]
        widths = [(b[2] - b[0] + 2 * pad) * stretch_x for b in bboxes]
        height = max(b[3] - b[1] for b in bboxes) + 2 * pad
        total = sum(widths) + space * (len(words) - 1)
        # Reading direction and "down" (towards the glyph bottoms) in canvas coordinates. Right-to-left
        # scripts (Arabic) read leftwards: the first word is the rightmost, (x, y) of "lt" its top-right.
        along, down = {0: ((1, 0), (0, 1)), -90: ((0, 1), (-1, 0)), 90: ((0, -1), (1, 0))}[rotate]
        if direction == "rtl":
            if rotate != 0:
                raise ValueError("right-to-left text is drawn horizontally only (rotate=0)")
            along = (-1, 0)
        along, down = np.array(along, float), np.array(down, float)
        start = np.array([x, y], float)
        if anchor == "mm":
            start = start - along * total / 2 - down * height / 2
        out = []
        pos = 0.0
        for word, w in zip(words, widths):
            tl = start + along * pos  # top-left as read
            corners = np.array([tl, tl + along * w, tl + along * w + down * height, tl + down * height])
            x0, y0 = corners.min(0)
            out.append(self.word(word, x0, y0, size_px, fill, style, rotate, stretch_x))
            pos += w + space
        return out

    def array(self) -> np.ndarray:
        return np.asarray(self.image, np.uint8)
