"""Deterministic text images with known words (for `ocr check`, tests and benchmarks).

Rendered with Pillow's bundled font (`ImageFont.load_default(size)`), so the output does not depend
on the fonts installed on the machine, only on the Pillow version.
"""

from __future__ import annotations

import numpy as np

from strings_bench.eval.ocr.base import Word

SAMPLE_LINES = [["STRinGS", "bench"], ["Gaussian", "Splatting", "2026"], ["Fire", "Extinguisher", "EXIT"]]

VOCABULARY = (
    "apple river stone garden window coffee market yellow purple silver orange bridge candle "
    "engine forest guitar harbor island jacket kitchen lemon marble number office pencil "
    "quartz rocket summer ticket umbrella velvet winter zebra museum station library bakery "
    "pharmacy theatre street avenue north south east west open closed sale exit entrance "
    "books globe shelf chemicals truck train 2024 1987 42 365 100"
).split()


def _font(size: int):
    from PIL import ImageFont

    return ImageFont.load_default(size=size)


def render_lines(
    lines: list[list[str]],
    font_size: int = 40,
    margin: int = 24,
    word_gap: float = 0.6,
    line_gap: float = 0.8,
    fg: tuple[int, int, int] = (0, 0, 0),
    bg: tuple[int, int, int] = (255, 255, 255),
    size: tuple[int, int] | None = None,
) -> tuple[np.ndarray, list[Word]]:
    """An RGB image of `lines` (each a list of words) and the known words with their ink boxes."""
    from PIL import Image, ImageDraw

    font = _font(font_size)
    probe = ImageDraw.Draw(Image.new("RGB", (1, 1)))
    gap_x, gap_y = int(word_gap * font_size), int(line_gap * font_size)
    placed: list[tuple[str, int, int]] = []
    y = margin
    width = 0
    for line in lines:
        x = margin
        for word in line:
            placed.append((word, x, y))
            x0, _, x1, _ = probe.textbbox((x, y), word, font=font)
            x = x1 + gap_x
        width = max(width, x - gap_x + margin)
        y += font_size + gap_y
    height = y - gap_y + margin
    w, h = size if size is not None else (width, height)
    img = Image.new("RGB", (int(w), int(h)), bg)
    draw = ImageDraw.Draw(img)
    words = []
    for word, x, yy in placed:
        draw.text((x, yy), word, fill=fg, font=font)
        x0, y0, x1, y1 = draw.textbbox((x, yy), word, font=font)
        words.append(Word.from_box(word, x0, y0, x1, y1))
    return np.asarray(img).copy(), words


def sample_image() -> tuple[np.ndarray, list[Word]]:
    """The fixed sample read by `strings-bench ocr check`."""
    return render_lines(SAMPLE_LINES, font_size=40)


def random_text_image(
    rng: np.random.Generator,
    n_lines: int = 3,
    words_per_line: tuple[int, int] = (1, 3),
    font_size: tuple[int, int] = (32, 56),
    size: tuple[int, int] | None = None,
) -> tuple[np.ndarray, list[Word]]:
    """Random vocabulary words in lines, dark on light or light on dark, with known boxes."""
    lines = [
        [str(rng.choice(VOCABULARY)) for _ in range(int(rng.integers(words_per_line[0], words_per_line[1] + 1)))]
        for _ in range(n_lines)
    ]
    dark = tuple(int(v) for v in rng.integers(0, 60, 3))
    light = tuple(int(v) for v in rng.integers(200, 256, 3))
    fg, bg = (dark, light) if rng.random() < 0.7 else (light, dark)
    return render_lines(lines, font_size=int(rng.integers(font_size[0], font_size[1] + 1)), fg=fg, bg=bg, size=size)
