"""The multilingual synthetic scenes (`synthetic-multi/<script>`): one scene per script, in Russian
(Cyrillic), Greek, Hindi (Devanagari), Arabic (right to left) and Simplified Chinese (Han).

Every scene has the same objects as the `synthetic` scenes' geometry families, with real words of its
language that fit them:

- book spines (boxes): two stacks of lying books, one on each side of a plinth, with horizontal
  titles of well-known books of the language and their authors (the `books`/`shelf` family);
- labelled jars (cylinders, curved text): a food word per jar (milk, water, honey, salt, sugar, oil
  or its local counterpart), a label on each side (the `chemicals`/`extinguisher` family);
- a double-sided sign board (planes): public signs (exit, library, pharmacy).

Words are drawn with the script's Noto font (fonts.py; Debian fonts-noto-core / fonts-noto-cjk) and
shaped by libraqm; every character is checked against the font's cmap before it is drawn. Each
annotated word records its language and script (`lang`, `script` in text_annotations.json). Reading
order follows the script: the words of a line are listed (and placed) in reading order, right to left
for Arabic; a word's polygon is its upright box (top-left, top-right, bottom-right, bottom-left on the
page), whatever the direction.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from strings_bench.core.scripts import LANGUAGES
from strings_bench.datasets.synthetic.raycast import Quad
from strings_bench.datasets.synthetic.scenes import TEXEL, Builder, SceneSpec, fit_size, room
from strings_bench.datasets.synthetic.textures import NOTO_PREFIX, Canvas


@dataclass(frozen=True)
class Words:
    lang: str
    books: tuple[tuple[str, str], ...]  # (title, author), 6
    jars: tuple[str, ...]  # 4 food words
    signs: tuple[str, ...]  # 2 public signs (front, back)


WORDS: dict[str, Words] = {
    "cyrillic": Words(
        "rus",
        books=(("ВОЙНА И МИР", "ТОЛСТОЙ"), ("МЁРТВЫЕ ДУШИ", "ГОГОЛЬ"), ("ИДИОТ", "ДОСТОЕВСКИЙ"),
               ("ОБЛОМОВ", "ГОНЧАРОВ"), ("ОТЦЫ И ДЕТИ", "ТУРГЕНЕВ"), ("ВИШНЁВЫЙ САД", "ЧЕХОВ")),
        jars=("МОЛОКО", "МЁД", "СОЛЬ", "САХАР"),
        signs=("ВЫХОД", "АПТЕКА"),
    ),
    "greek": Words(
        "ell",
        books=(("ΟΔΥΣΣΕΙΑ", "ΟΜΗΡΟΣ"), ("ΙΛΙΑΔΑ", "ΟΜΗΡΟΣ"), ("ΑΝΤΙΓΟΝΗ", "ΣΟΦΟΚΛΗΣ"),
               ("ΜΗΔΕΙΑ", "ΕΥΡΙΠΙΔΗΣ"), ("ΠΟΛΙΤΕΙΑ", "ΠΛΑΤΩΝ"), ("ΟΡΕΣΤΕΙΑ", "ΑΙΣΧΥΛΟΣ")),
        jars=("ΓΑΛΑ", "ΜΕΛΙ", "ΑΛΑΤΙ", "ΖΑΧΑΡΗ"),
        signs=("ΕΞΟΔΟΣ", "ΦΑΡΜΑΚΕΙΟ"),
    ),
    "devanagari": Words(
        "hin",
        books=(("गोदान", "प्रेमचंद"), ("रामायण", "वाल्मीकि"), ("महाभारत", "व्यास"),
               ("निर्मला", "प्रेमचंद"), ("पंचतंत्र", "विष्णु शर्मा"), ("मधुशाला", "बच्चन")),
        jars=("दूध", "शहद", "नमक", "चीनी"),
        signs=("निकास", "पुस्तकालय"),
    ),
    "arabic": Words(
        "ara",
        books=(("كليلة ودمنة", "ابن المقفع"), ("المقدمة", "ابن خلدون"), ("الأيام", "طه حسين"),
               ("ألف ليلة وليلة", "مجهول"), ("رسالة الغفران", "المعري"), ("زقاق المدق", "نجيب محفوظ")),
        jars=("حليب", "عسل", "ملح", "سكر"),
        signs=("مخرج", "صيدلية"),
    ),
    "chinese": Words(
        "chi_sim",
        books=(("红楼梦", "曹雪芹"), ("西游记", "吴承恩"), ("水浒传", "施耐庵"),
               ("三国演义", "罗贯中"), ("论语", "孔子"), ("呐喊", "鲁迅")),
        jars=("牛奶", "蜂蜜", "食盐", "白糖"),
        signs=("出口", "图书馆"),
    ),
}
SCENE_NAMES_MULTI = tuple(WORDS)
MULTISCRIPT_VERSION = "1"  # bump when the content of these scenes changes (it is part of their cache key)
SPINE_COLORS = [(140, 30, 35), (25, 55, 110), (30, 90, 50), (60, 40, 30), (120, 60, 120), (20, 20, 25)]
JAR_COLORS = [(230, 230, 225), (200, 150, 60), (215, 220, 230), (245, 240, 235)]


def scene_script(scene: str) -> str:
    """The script (core.scripts name) of a synthetic-multi scene."""
    return LANGUAGES[WORDS[scene].lang].script


def _canvas(b: Builder, w_units: float, h_units: float, color, lang: str) -> Canvas:
    cv = b.canvas(w_units, h_units, color)
    cv.lang, cv.script = lang, LANGUAGES[lang].script
    return cv


def _spine(b: Builder, length: float, thick: float, color, title: str, author: str, lang: str) -> Canvas:
    """A lying book's spine: the title in the first 60 % of it, the author in the rest, as the script
    reads (right-aligned start for Arabic)."""
    cv = _canvas(b, length, thick, color, lang)
    W, H = cv.size
    style = NOTO_PREFIX + LANGUAGES[lang].script
    ink = (245, 232, 190)
    rtl = LANGUAGES[lang].direction == "rtl"
    t_size = fit_size(title, style, 0.56 * W, 0.55 * H)
    a_size = fit_size(author, style, 0.32 * W, 0.4 * H)
    title_c, author_c = (0.68 * W, 0.2 * W) if rtl else (0.32 * W, 0.8 * W)
    cv.text_line(title, title_c, H / 2, t_size, ink, style, anchor="mm")
    cv.text_line(author, author_c, H / 2, a_size, ink, style, anchor="mm")
    return cv


def build_multi(scene: str, rng: np.random.Generator) -> SceneSpec:
    words = WORDS[scene]
    lang = words.lang
    style = NOTO_PREFIX + LANGUAGES[lang].script
    b = Builder(rng)
    room(b, "wood")
    b.box((0, 0, 0.04), (1.3, 0.62, 0.08), 0, {}, b.plain((70, 50, 35), 0.2))
    # Two stacks of three lying books, spines facing -y (front) and +y (back).
    depth, length = 0.24, 0.5
    for side, titles in ((-1, words.books[:3]), (1, words.books[3:])):
        yaw = 0 if side < 0 else 180
        z = 0.08
        for k, (title, author) in enumerate(titles):
            th = float(rng.uniform(0.085, 0.1))
            color = SPINE_COLORS[(k + 3 * (side > 0)) % len(SPINE_COLORS)]
            spine = _spine(b, length - 0.02 * k, th, color, title, author, lang)
            center = (-0.15 * side, side * (0.02 + depth / 2), z + th / 2)
            b.box(center, (length - 0.02 * k, depth - 0.02 * k, th), yaw, {"-y": spine, "+z": b.plain(color, 0.12)},
                  b.plain((235, 228, 205), 0.05))
            z += th
    # Four jars with a label on each side (u = 0.75 faces -y, u = 0.25 faces +y).
    for k, (word, (x, y)) in enumerate(zip(words.jars, [(0.55, -0.14), (0.55, 0.14), (-0.55, 0.14), (-0.55, -0.14)])):
        r, h = 0.085, 0.22
        color = JAR_COLORS[k]
        cv = _canvas(b, 2 * np.pi * r, h, color, lang)
        W, H = cv.size
        for uc in (0.75, 0.25):
            lw = 0.36 * W
            x0 = uc * W - lw / 2
            cv.rect([x0, 0.2 * H, x0 + lw, 0.8 * H], (250, 248, 240))
            cv.rect([x0, 0.2 * H, x0 + lw, 0.2 * H + 8], (200, 40, 30) if k % 2 else (30, 60, 160))
            size = fit_size(word, style, 0.88 * lw, 0.06 * TEXEL)
            cv.text_line(word, uc * W, 0.53 * H, size, (20, 20, 20), style, anchor="mm")
        b.cylinder((x, y, 0.08), r, h, cv, top=b.plain((200, 190, 170), 0.1))
        b.cylinder((x, y, 0.08 + h), 0.6 * r, 0.03, b.plain((40, 40, 40), 0.15), top=b.plain((50, 50, 50), 0.15))
    # A double-sided sign on a post, above the books: one sign per face.
    sw, sh, zc = 0.5, 0.16, 0.66
    b.box((0, 0, 0.38), (0.03, 0.03, 0.6), 0, {}, b.plain((90, 90, 95), 0.1))
    for k, (text, normal) in enumerate(zip(words.signs, (-1, 1))):
        color = (20, 110, 50) if k == 0 else (30, 70, 150)
        cv = _canvas(b, sw, sh, color, lang)
        W, H = cv.size
        cv.rect([6, 6, W - 6, H - 6], (240, 240, 235))
        cv.rect([14, 14, W - 14, H - 14], color)
        cv.text_line(text, W / 2, H / 2, fit_size(text, style, 0.86 * W, 0.6 * H), (250, 250, 245), style, anchor="mm")
        # Quad(p0, eu, ev): p0 the texture's top-left, eu along its width, ev down; facing -y or +y.
        ex = np.array([1.0, 0, 0]) * (-normal)
        p0 = np.array([0, normal * 0.018, zc + sh / 2]) - ex * sw / 2
        b.add(lambda m, p0=p0, ex=ex: Quad(p0, sw * ex, np.array([0, 0, -sh]), m, one_sided=True), cv)
    return b.to_spec(f"{scene}", target=(0, 0, 0.36), radius=1.3, elevation=(8, 28), fov_x=60,
                     description=f"{LANGUAGES[lang].name} ({LANGUAGES[lang].script}) text: lying book spines, "
                                 "labelled jars (curved text) and a double-sided sign")


def check_fonts(scene: str) -> None:
    """DatasetError saying why the scene cannot be drawn here (its font is missing, or no shaping)."""
    from strings_bench.core.errors import DatasetError
    from strings_bench.datasets.synthetic.fonts import missing_fonts

    problems = missing_fonts([scene_script(scene)])
    if problems:
        raise DatasetError(f"synthetic-multi/{scene} is not built: {problems[scene_script(scene)]}",
                           hint="scripts/system_deps.sh installs fonts-noto-core and fonts-noto-cjk (apt, as root); "
                                "the scene is never drawn without its glyphs")
