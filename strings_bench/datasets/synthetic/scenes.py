"""The five synthetic scenes, mirroring the text configurations of STRinGS-360.

Size (~470 lines): the five scene builders side by side over the primitives they share; one file per scene would scatter the size choices that are meant to be compared.

World frame: z up, the floor at z = 0, the object(s) around the origin, 1 unit ~ 1 m. Each scene
builder returns a `SceneSpec`: the primitives to ray-cast, every printed word (primitive + its box
corners in texture uv, in reading order) and the orbit the cameras follow.

Text sizes are chosen in world units so that at the default 320x240 the large titles are ~10-14 px
tall, medium text ~7-9 px and the small print ~4-6 px (hard, sometimes unreadable).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
from PIL import Image

from strings_bench.datasets.synthetic.raycast import Cylinder, Disc, Material, Primitive, Quad, Sphere, World
from strings_bench.datasets.synthetic.textures import Canvas, blobs, load_font, noise_field, tiles, tinted_noise, wood

TEXEL = 1000  # texture pixels per world unit on text-bearing surfaces


@dataclass
class SceneWord:
    text: str
    prim: int  # index into world.primitives
    uv: np.ndarray  # (4, 2) box corners in texture uv, reading order TL, TR, BR, BL
    lang: str | None = None  # recorded in the annotations when set (multilingual scenes)
    script: str | None = None


@dataclass
class SceneSpec:
    name: str
    world: World
    words: list[SceneWord]
    target: np.ndarray  # orbit centre the cameras look at
    radius: float  # orbit radius (horizontal distance is radius * cos(elevation))
    elevation: tuple[float, float]  # degrees, min and max over the orbit
    fov_x: float  # horizontal field of view, degrees
    description: str = ""
    target_jitter: float = 0.02  # sd of the per-view look-at point jitter, world units


class Builder:
    """Collects primitives and the words printed on them."""

    def __init__(self, rng: np.random.Generator):
        self.rng = rng
        self.prims: list[Primitive] = []
        self.words: list[SceneWord] = []

    def add(self, prim_factory: Callable[[Material], Primitive], canvas_or_material) -> Primitive:
        if isinstance(canvas_or_material, Canvas):
            canvas = canvas_or_material
            w, h = canvas.size
            uvs = [wb.corners / np.array([w, h], np.float64) for wb in canvas.words]
            boxes = np.array([[c[:, 0].min(), c[:, 1].min(), c[:, 0].max(), c[:, 1].max()] for c in uvs]).reshape(-1, 4)
            material = Material(canvas.array(), word_boxes=boxes)
            for wb, uv in zip(canvas.words, uvs):
                self.words.append(SceneWord(wb.text, len(self.prims), uv, canvas.lang, canvas.script))
        else:
            material = canvas_or_material
        prim = prim_factory(material)
        self.prims.append(prim)
        return prim

    # ---- materials ---------------------------------------------------------------------------
    def plain(self, color, amplitude: float = 0.1, size: int = 96) -> Material:
        return Material(tinted_noise(self.rng, size, size, color, amplitude=amplitude))

    def canvas(self, w_units: float, h_units: float, color, amplitude: float = 0.08) -> Canvas:
        w, h = max(8, int(round(w_units * TEXEL))), max(8, int(round(h_units * TEXEL)))
        return Canvas(tinted_noise(self.rng, h, w, color, amplitude=amplitude, octaves=(3, 12, 48)))

    # ---- shapes --------------------------------------------------------------------------------
    def box(self, center, size, yaw_deg: float, faces: dict, default) -> None:
        """A closed box of one-sided quads. `faces` maps "-y", "+y", "-x", "+x", "+z", "-z" to a
        Canvas or Material (see `face_size` for each face's width x height); `default` fills the rest.
        In a face's texture, up is +z for the side faces and +y (local) for the top."""
        c = np.asarray(center, np.float64)
        yaw = np.deg2rad(yaw_deg)
        X = np.array([np.cos(yaw), np.sin(yaw), 0.0])
        Y = np.array([-np.sin(yaw), np.cos(yaw), 0.0])
        Z = np.array([0.0, 0.0, 1.0])
        hx, hy, hz = (0.5 * float(v) for v in size)
        geometry = {
            "-y": (c - hy * Y - hx * X + hz * Z, 2 * hx * X, -2 * hz * Z),
            "+y": (c + hy * Y + hx * X + hz * Z, -2 * hx * X, -2 * hz * Z),
            "+x": (c + hx * X - hy * Y + hz * Z, 2 * hy * Y, -2 * hz * Z),
            "-x": (c - hx * X + hy * Y + hz * Z, -2 * hy * Y, -2 * hz * Z),
            "+z": (c + hz * Z - hx * X + hy * Y, 2 * hx * X, -2 * hy * Y),
            "-z": (c - hz * Z - hx * X - hy * Y, 2 * hx * X, 2 * hy * Y),
        }
        for name, (p0, eu, ev) in geometry.items():
            mat = faces.get(name, default)
            self.add(lambda m, p0=p0, eu=eu, ev=ev: Quad(p0, eu, ev, m, one_sided=True), mat)

    def cylinder(self, base, r, h, side, top=None, bottom=False) -> Primitive:
        base = np.asarray(base, np.float64)
        prim = self.add(lambda m: Cylinder(base, (0, 0, 1), r, h, m), side)
        if top is not None:
            self.add(lambda m: Disc(base + [0, 0, h], (0, 0, 1), r, m), top)
        if bottom:
            self.add(lambda m: Disc(base, (0, 0, -1), r, m), top if top is not None else side)
        return prim

    def to_spec(self, name, target, radius, elevation, fov_x, description) -> SceneSpec:
        return SceneSpec(name, World(self.prims), self.words, np.asarray(target, np.float64), radius, elevation,
                         fov_x, description)


def face_size(size, face: str) -> tuple[float, float]:
    sx, sy, sz = size
    return {"-y": (sx, sz), "+y": (sx, sz), "-x": (sy, sz), "+x": (sy, sz), "+z": (sx, sy), "-z": (sx, sy)}[face]


def fit_size(text: str, style: str, max_len_px: float, max_size_px: float) -> float:
    """Largest font size (<= max_size_px) at which `text` is at most max_len_px long."""
    size = float(max_size_px)
    while size > 6:
        font = load_font(style, size)
        if font.getlength(text) + 0.24 * size <= max_len_px:
            return size
        size *= 0.93
    return size


def room(b: Builder, floor: str = "tiles", wall_palette=None) -> None:
    """Floor disc and a backdrop wall (inward-facing cylinder): textured, no text."""
    rng = b.rng
    if floor == "wood":
        ftex = wood(rng, 512, 512, light=(190, 150, 105), dark=(120, 84, 52))
        b.add(lambda m: Disc((0, 0, 0), (0, 0, 1), 7.0, m), Material(ftex, tile=(6, 6)))
    else:
        ftex = tiles(rng, 512, 512, 4, 4)
        b.add(lambda m: Disc((0, 0, 0), (0, 0, 1), 7.0, m), Material(ftex, tile=(5, 5)))
    palette = wall_palette or [(200, 196, 184), (120, 140, 170), (170, 110, 90), (90, 120, 90), (60, 60, 70)]
    wtex = blobs(rng, 512, 2048, palette, 600)
    b.add(lambda m: Cylinder((0, 0, 0), (0, 0, 1), 7.0, 4.0, m), Material(wtex, tile=(3, 1)))


# ---------------------------------------------------------------------------------------------
# books: two back-to-back rows of standing books (titles along the spines = vertical text), a
# small stack of lying books with horizontal spine text at the end of each row, and the covers of
# the end books facing sideways.

BOOKS_A = [
    ("MOBY DICK", "Herman Melville"), ("WAR AND PEACE", "Leo Tolstoy"), ("EMMA", "Jane Austen"),
    ("ULYSSES", "James Joyce"), ("DRACULA", "Bram Stoker"), ("HAMLET", "Shakespeare"),
    ("THE ODYSSEY", "Homer"), ("JANE EYRE", "Charlotte Bronte"), ("MIDDLEMARCH", "George Eliot"),
    ("WALDEN", "Thoreau"), ("CANDIDE", "Voltaire"),
]
BOOKS_B = [
    ("FRANKENSTEIN", "Mary Shelley"), ("THE IDIOT", "Dostoevsky"), ("PERSUASION", "Jane Austen"),
    ("IVANHOE", "Walter Scott"), ("KIDNAPPED", "Stevenson"), ("BEOWULF", "Anonymous"),
    ("OLIVER TWIST", "Dickens"), ("LITTLE WOMEN", "Louisa Alcott"), ("THE RAVEN", "Edgar Poe"),
    ("ROBINSON CRUSOE", "Daniel Defoe"), ("TIME MACHINE", "H G Wells"),
]
SPINE_COLORS = [(140, 30, 35), (25, 55, 110), (30, 90, 50), (200, 170, 90), (60, 40, 30), (120, 60, 120),
                (20, 20, 25), (180, 90, 30), (90, 110, 130), (230, 220, 200), (100, 20, 40), (40, 100, 110)]


def _ink_for(color) -> tuple[int, int, int]:
    return (25, 20, 15) if sum(color) > 420 else (245, 232, 190)


def standing_spine(b: Builder, w: float, h: float, color, title: str, author: str, publisher: str | None) -> Canvas:
    cv = b.canvas(w, h, color)
    W, H = cv.size
    ink = _ink_for(color)
    band = max(3, int(0.012 * TEXEL))
    cv.rect([0, int(0.05 * H), W, int(0.05 * H) + band], ink)
    cv.rect([0, int(0.95 * H) - band, W, int(0.95 * H)], ink)
    # Title along the spine (reads top to bottom), author below it, both vertical.
    t_size = fit_size(title, "serif-bold", 0.56 * H, 0.62 * W)
    cv.text_line(title, W / 2, 0.07 * H + 0.29 * H, t_size, ink, "serif-bold", rotate=-90, anchor="mm")
    a_size = fit_size(author, "sans", 0.26 * H, 0.36 * W)
    cv.text_line(author, W / 2, 0.66 * H + 0.14 * H, a_size, ink, "sans", rotate=-90, anchor="mm")
    if publisher:
        cv.text_line(publisher, W / 2, 0.9 * H, min(0.3 * W, 0.02 * TEXEL), ink, "sans-bold", anchor="mm")
    return cv


def lying_spine(b: Builder, length: float, thick: float, color, title: str, author: str) -> Canvas:
    cv = b.canvas(length, thick, color)
    W, H = cv.size
    ink = _ink_for(color)
    t_size = fit_size(title, "serif-bold", 0.62 * W, 0.62 * H)
    cv.text_line(title, 0.05 * W, H / 2 - 0.33 * H, t_size, ink, "serif-bold")
    a_size = fit_size(author, "sans", 0.28 * W, 0.38 * H)
    cv.text_line(author, 0.83 * W, H / 2, a_size, ink, "sans", anchor="mm")
    return cv


def build_books(rng: np.random.Generator) -> SceneSpec:
    b = Builder(rng)
    room(b, "wood")
    plinth = (1.3, 0.6, 0.08)
    b.box((0, 0, 0.04), plinth, 0, {}, b.plain((70, 50, 35), 0.2))
    depth = 0.26
    for side, titles in ((-1, BOOKS_A), (1, BOOKS_B)):
        yaw = 0 if side < 0 else 180
        # Local +x of a yaw-180 book points to world -x: walk along the row in local order.
        x = -0.6
        order = list(titles)
        rng.shuffle(order)
        placed = []
        for k, (title, author) in enumerate(order[:9]):
            w = float(rng.uniform(0.075, 0.105))
            h = float(rng.uniform(0.36, 0.48))
            color = SPINE_COLORS[int(rng.integers(len(SPINE_COLORS)))]
            publisher = ["PENGUIN", "VINTAGE", "OXFORD", None][k % 4]
            spine = standing_spine(b, w, h, color, title, author, publisher)
            cx_local = x + w / 2
            center = np.array([cx_local * (1 if side < 0 else -1), side * (0.01 + depth / 2), 0.08 + h / 2])
            placed.append((center, w, h, color))
            faces = {"-y": spine, "+z": b.plain((235, 228, 205), 0.05)}
            b.box(center, (w, depth, h), yaw, faces, b.plain(color, 0.12))
            x += w + 0.003
        # End of the row: a stack of lying books with horizontal spine text.
        stack_titles = [("ATLAS OF THE WORLD", "Collins"), ("FIELD GUIDE TO BIRDS", "Peterson"),
                        ("THE ART OF COOKING", "Escoffier")] if side < 0 else [
                        ("COSMOS", "Carl Sagan"), ("A BRIEF HISTORY OF TIME", "Hawking"),
                        ("ORIGIN OF SPECIES", "Darwin")]
        length = 0.58 - x - 0.02
        z = 0.08
        for k, (title, author) in enumerate(stack_titles):
            th = float(rng.uniform(0.06, 0.085))
            color = SPINE_COLORS[(3 * k + (side > 0) * 5) % len(SPINE_COLORS)]
            spine = lying_spine(b, length - 0.01 * k, th, color, title, author)
            cx_local = x + 0.02 + (length - 0.01 * k) / 2
            center = (cx_local * (1 if side < 0 else -1), side * (0.01 + depth / 2), z + th / 2)
            b.box(center, (length - 0.01 * k, depth - 0.02 * k, th), yaw,
                  {"-y": spine, "+z": b.plain(color, 0.12)}, b.plain((235, 228, 205), 0.05))
            z += th
        # The first book's front cover faces the row's open end (-x locally): a printed cover.
        center, w, h, color = placed[0]
        cover = b.canvas(depth, h, color)
        W, H = cover.size
        ink = _ink_for(color)
        cover_title = "CLASSIC TALES" if side < 0 else "COLLECTED POEMS"
        cover.text_line(cover_title, W / 2, 0.25 * H, fit_size(cover_title, "serif-bold", 0.9 * W, 0.07 * TEXEL), ink,
                        "serif-bold", anchor="mm")
        cover.text_line("Volume One", W / 2, 0.4 * H, 0.035 * TEXEL, ink, "serif", anchor="mm")
        cover.text_line("illustrated edition 1921", W / 2, 0.85 * H, 0.022 * TEXEL, ink, "sans", anchor="mm")
        # Paint the cover as a thin quad just outside the book's -x face (local), facing outwards.
        yaw_r = np.deg2rad(yaw)
        X = np.array([np.cos(yaw_r), np.sin(yaw_r), 0.0])
        Y = np.array([-np.sin(yaw_r), np.cos(yaw_r), 0.0])
        Z = np.array([0.0, 0.0, 1.0])
        c = center - (w / 2 + 0.0015) * X
        p0 = c + depth / 2 * Y + h / 2 * Z
        b.add(lambda m, p0=p0, Y=Y: Quad(p0, -depth * Y, -h * Z, m, one_sided=True), cover)
    return b.to_spec("books", target=(0, 0, 0.3), radius=1.55, elevation=(8, 30), fov_x=60,
                     description="two back-to-back rows of packed standing books (vertical spine titles and "
                                 "authors), stacks of lying books (horizontal spine text), printed end covers")


# ---------------------------------------------------------------------------------------------
def build_extinguisher(rng: np.random.Generator) -> SceneSpec:
    b = Builder(rng)
    room(b, "tiles")
    r, h = 0.17, 0.78
    circ = 2 * np.pi * r
    cv = b.canvas(circ, h, (190, 25, 25), amplitude=0.06)
    W, H = cv.size
    # Front label centred at u = 0.75 (faces -y), back label at u = 0.25 (faces +y).
    for uc, lines in (
        (0.75, [("FIRE", 0.07, "sans-bold"), ("EXTINGUISHER", 0.05, "sans-bold"), ("ABC DRY CHEMICAL", 0.032, "sans-bold"),
                ("1 PULL PIN", 0.027, "sans"), ("2 AIM AT BASE OF FIRE", 0.024, "sans"),
                ("3 SQUEEZE HANDLE", 0.024, "sans"), ("4 SWEEP SIDE TO SIDE", 0.024, "sans"),
                ("PRODUCT CODE 18060", 0.018, "sans-bold"), ("UL RATED 2A 10BC", 0.016, "sans")]),
        (0.25, [("INSPECT MONTHLY", 0.04, "sans-bold"), ("RECHARGE AFTER USE", 0.03, "sans-bold"),
                ("KEEP AWAY FROM HEAT", 0.026, "sans"), ("OPERATING TEMPERATURE", 0.02, "sans"),
                ("MINUS 40 TO 120 F", 0.02, "sans"), ("MODEL B402 SERIAL 77314", 0.016, "sans"),
                ("MADE IN USA", 0.022, "sans-bold")]),
    ):
        lw = 0.32 * W
        x0 = uc * W - lw / 2
        cv.rect([x0, 0.1 * H, x0 + lw, 0.93 * H], (238, 236, 228))
        cv.rect([x0 + 6, 0.1 * H + 6, x0 + lw - 6, 0.1 * H + 14], (190, 25, 25))
        y = 0.1 * H + 26
        for text, size_u, style in lines:
            size = fit_size(text, style, 0.9 * lw, size_u * TEXEL)
            color = (190, 25, 25) if size_u >= 0.05 else (20, 20, 20)
            cv.text_line(text, uc * W, y + size * 0.6, size, color, style, anchor="mm")
            y += size * 1.35
    b.cylinder((0, 0, 0), r, h, cv, top=b.plain((170, 20, 20), 0.1))
    # Valve head, handle and hose stub: plain dark parts (no text).
    b.cylinder((0, 0, h), 0.05, 0.12, b.plain((40, 40, 40), 0.2), top=b.plain((60, 60, 60), 0.1))
    b.box((0.06, 0, h + 0.13), (0.2, 0.04, 0.02), 20, {}, b.plain((30, 30, 30), 0.2))
    b.box((-0.04, -0.12, h + 0.03), (0.03, 0.16, 0.03), 0, {}, b.plain((15, 15, 15), 0.1))
    b.box((0.45, 0.3, 0.1), (0.3, 0.25, 0.2), 30, {}, b.plain((70, 90, 120), 0.25))  # a crate beside it
    return b.to_spec("extinguisher", target=(0, 0, 0.45), radius=1.25, elevation=(5, 28), fov_x=60,
                     description="red cylinder with instruction labels front and back (curved text), small "
                                 "print such as PRODUCT CODE 18060")


# ---------------------------------------------------------------------------------------------
PLACES = [
    # (name, longitude deg, latitude deg, size units, kind)
    ("PACIFIC", 200, 8, 0.06, "ocean"), ("OCEAN", 200, -6, 0.06, "ocean"),
    ("ATLANTIC", 325, 20, 0.055, "ocean"), ("INDIAN OCEAN", 75, -25, 0.045, "ocean"),
    ("AFRICA", 20, 5, 0.05, "land"), ("EUROPE", 15, 48, 0.04, "land"), ("ASIA", 95, 42, 0.055, "land"),
    ("AMERICA", 260, 38, 0.045, "land"),
    ("MINNEAPOLIS", 267, 45, 0.024, "city"), ("CHICAGO", 272, 34, 0.026, "city"), ("DENVER", 255, 28, 0.022, "city"),
    ("LIMA", 283, -12, 0.026, "city"), ("BOGOTA", 286, 4, 0.022, "city"), ("SAO PAULO", 313, -23, 0.024, "city"),
    ("LAGOS", 3, 7, 0.022, "city"), ("NAIROBI", 37, -1, 0.024, "city"), ("CAIRO", 31, 30, 0.026, "city"),
    ("MADRID", 356, 40, 0.022, "city"), ("OSLO", 11, 60, 0.022, "city"), ("MUMBAI", 73, 19, 0.026, "city"),
    ("TOKYO", 140, 36, 0.028, "city"), ("SEOUL", 127, 28, 0.022, "city"), ("PERTH", 116, -32, 0.024, "city"),
    ("SYDNEY", 151, -34, 0.026, "city"), ("JAKARTA", 107, -6, 0.022, "city"), ("HONOLULU", 202, 21, 0.022, "city"),
    ("ANCHORAGE", 210, 50, 0.02, "city"), ("SANTIAGO", 289, -33, 0.02, "city"),
]


def build_globe(rng: np.random.Generator) -> SceneSpec:
    b = Builder(rng)
    room(b, "wood")
    r = 0.42
    W, H = int(2 * np.pi * r * TEXEL), int(np.pi * r * TEXEL)
    # Oceans and continents from thresholded noise; a lat/long grid.
    n = noise_field(rng, H // 4, W // 4, (3, 8, 24))
    land = np.asarray(Image.fromarray((n > 0.55).astype(np.uint8) * 255).resize((W, H)), np.uint8) > 127
    ocean = tinted_noise(rng, H, W, (90, 140, 200), amplitude=0.08, octaves=(4, 16))
    ground = tinted_noise(rng, H, W, (200, 185, 130), amplitude=0.15, octaves=(6, 24, 96))
    img = np.where(land[..., None], ground, ocean)
    cv = Canvas(img)
    for k in range(1, 12):
        cv.line_shape([(k * W / 12, 0), (k * W / 12, H)], (60, 90, 140), 3)
    for k in range(1, 6):
        cv.line_shape([(0, k * H / 6), (W, k * H / 6)], (60, 90, 140), 3)
    for name, lon, lat, size_u, kind in PLACES:
        # u runs from e1 towards e2 (east); v = colatitude / pi.
        x, y = (lon % 360) / 360 * W, (90 - lat) / 180 * H
        stretch = 1 / np.cos(np.deg2rad(lat))  # the equirectangular map squeezes by cos(lat) on the sphere
        color = {"ocean": (20, 50, 110), "land": (110, 40, 20), "city": (15, 15, 15)}[kind]
        style = {"ocean": "serif-bold", "land": "serif-bold", "city": "sans-bold"}[kind]
        if kind == "city":
            cv.rect([x - 6, y - 6, x + 6, y + 6], (200, 20, 20))
            cv.text_line(name, x + 14 * stretch, y - size_u * TEXEL * 0.7, size_u * TEXEL, color, style, stretch_x=stretch)
        else:
            cv.text_line(name, x, y, size_u * TEXEL, color, style, stretch_x=stretch, anchor="mm")
    tilt = np.deg2rad(23.4)
    axis = (np.sin(tilt), 0.0, np.cos(tilt))
    b.add(lambda m: Sphere((0, 0, 0.92), r, m, a=axis, e1=(np.cos(tilt), 0, -np.sin(tilt))), cv)
    b.cylinder((0, 0, 0.0), 0.2, 0.04, b.plain((50, 40, 30), 0.2), top=b.plain((60, 48, 36), 0.2))
    b.cylinder((0, 0, 0.04), 0.025, 0.48, b.plain((150, 120, 60), 0.1))
    return b.to_spec("globe", target=(0, 0, 0.88), radius=1.6, elevation=(3, 25), fov_x=60,
                     description="a tilted globe with ocean, continent and city names on a sphere "
                                 "(e.g. MINNEAPOLIS), lat/long grid")


# ---------------------------------------------------------------------------------------------
CHEMICALS = [
    ("ACETAMINOPHEN", "C8H9NO2", "CAS 103-90-2", "500 g"), ("SODIUM CHLORIDE", "NaCl", "CAS 7647-14-5", "1 kg"),
    ("ETHANOL 95%", "C2H5OH", "FLAMMABLE", "1 L"), ("ACETONE", "C3H6O", "CAS 67-64-1", "500 mL"),
    ("HYDROCHLORIC ACID", "HCl 1M", "CORROSIVE", "1 L"), ("POTASSIUM NITRATE", "KNO3", "OXIDIZER", "250 g"),
    ("GLUCOSE", "C6H12O6", "LOT 4471", "1 kg"), ("COPPER SULFATE", "CuSO4", "TOXIC", "500 g"),
]
BOTTLE_COLORS = [(110, 60, 25), (200, 210, 215), (40, 80, 130), (120, 70, 30), (215, 220, 210), (50, 100, 60),
                 (230, 230, 235), (90, 50, 20)]


def build_chemicals(rng: np.random.Generator) -> SceneSpec:
    b = Builder(rng)
    room(b, "tiles")
    top_z = 0.42
    b.box((0, 0, top_z - 0.02), (1.2, 0.62, 0.04), 0, {}, Material(wood(rng, 256, 512), tile=(1, 1)))
    for sx in (-1, 1):
        for sy in (-1, 1):
            b.box((sx * 0.55, sy * 0.26, (top_z - 0.04) / 2), (0.04, 0.04, top_z - 0.04), 0, {}, b.plain((80, 60, 40), 0.2))
    slots = [(-0.42, -0.13), (-0.14, -0.15), (0.14, -0.13), (0.42, -0.15), (-0.42, 0.15), (-0.14, 0.13),
             (0.14, 0.15), (0.42, 0.13)]
    for k, ((bx, by), (name, formula, code, amount)) in enumerate(zip(slots, CHEMICALS)):
        r = float(rng.uniform(0.075, 0.1))
        h = float(rng.uniform(0.24, 0.32))
        color = BOTTLE_COLORS[k]
        cv = b.canvas(2 * np.pi * r, h, color, amplitude=0.06)
        W, H = cv.size
        # Labels facing -y (u = 0.75) and +y (u = 0.25): the same chemical, two layouts.
        for uc, big in ((0.75, True), (0.25, False)):
            lw = 0.4 * W
            x0 = uc * W - lw / 2
            cv.rect([x0, 0.22 * H, x0 + lw, 0.86 * H], (245, 244, 236))
            cv.rect([x0, 0.22 * H, x0 + lw, 0.22 * H + 10], (200, 40, 30) if k % 2 else (30, 60, 160))
            name_size = fit_size(name, "sans-bold", 0.92 * lw, (0.034 if big else 0.028) * TEXEL)
            y = 0.3 * H
            for word_line, size, style in ((name, name_size, "sans-bold"), (formula, 0.026 * TEXEL, "sans"),
                                           (code, 0.017 * TEXEL, "sans"), (amount, 0.022 * TEXEL, "sans-bold")):
                size = fit_size(word_line, style, 0.92 * lw, size)
                cv.text_line(word_line, uc * W, y + size * 0.6, size, (20, 20, 20), style, anchor="mm")
                y += size * 1.45
        b.cylinder((bx, by, top_z), r, h, cv, top=b.plain(color, 0.1))
        # Cap.
        b.cylinder((bx, by, top_z + h), 0.45 * r, 0.05, b.plain((30, 30, 30) if k % 3 else (200, 30, 30), 0.15),
                   top=b.plain((40, 40, 40), 0.15))
    return b.to_spec("chemicals", target=(0, 0, 0.56), radius=1.35, elevation=(10, 32), fov_x=60,
                     description="eight labelled bottles (names, formulas, CAS numbers, amounts) on a lab table")


# ---------------------------------------------------------------------------------------------
SHELF_TITLES = [
    ("INTRODUCTION TO ALGORITHMS", "CORMEN"), ("PATTERN RECOGNITION", "BISHOP"), ("LINEAR ALGEBRA", "STRANG"),
    ("COMPUTER VISION", "SZELISKI"), ("DEEP LEARNING", "GOODFELLOW"), ("OPTICS", "HECHT"),
    ("CALCULUS", "STEWART"), ("NUMERICAL RECIPES", "PRESS"), ("PROBABILITY THEORY", "JAYNES"),
    ("ROBOTICS", "CRAIG"),
]


def build_shelf(rng: np.random.Generator) -> SceneSpec:
    b = Builder(rng)
    room(b, "tiles")
    woodmat = Material(wood(rng, 256, 1024, light=(160, 115, 70), dark=(95, 62, 35)))
    depth = 0.56
    levels = (0.04, 0.44)
    for z in levels:
        b.box((0, 0, z - 0.02), (1.3, depth, 0.04), 0, {}, woodmat)
    b.box((0, 0, 0.86), (1.3, depth, 0.04), 0, {}, woodmat)
    for sx in (-1, 1):
        for sy in (-1, 1):
            b.box((sx * 0.63, sy * 0.26, 0.44), (0.04, 0.04, 0.88), 0, {}, woodmat)
    book_depth = 0.24
    for li, z0 in enumerate(levels):
        for side in (-1, 1):
            yaw = 0 if side < 0 else 180
            x = -0.56
            while x < 0.5:
                n_books = int(rng.integers(3, 6))
                length = float(rng.uniform(0.26, 0.34))
                if x + length > 0.6:
                    break
                z = z0
                for k in range(n_books):
                    # Repeated titles, as on library shelves: draw from a short list with replacement.
                    title, author = SHELF_TITLES[int(rng.integers(len(SHELF_TITLES)))]
                    th = float(rng.uniform(0.045, 0.07))
                    color = SPINE_COLORS[int(rng.integers(len(SPINE_COLORS)))]
                    spine = lying_spine(b, length, th, color, title, author)
                    jitter = float(rng.uniform(-0.01, 0.01))
                    cx = x + length / 2 + jitter
                    center = (cx * (1 if side < 0 else -1), side * (0.005 + book_depth / 2) + 0.0, z + th / 2)
                    b.box(center, (length, book_depth, th), yaw, {"-y": spine}, b.plain(color, 0.12))
                    z += th
                    if z > z0 + 0.34:
                        break
                x += length + 0.03
            # A book leaning upright in front of the stacks: partial occlusion.
            xo = float(rng.uniform(-0.3, 0.3))
            color = SPINE_COLORS[int(rng.integers(len(SPINE_COLORS)))]
            b.box((xo * (1 if side < 0 else -1), side * (0.27 + 0.01), z0 + 0.15), (0.22, 0.02, 0.3), yaw + 8,
                  {}, b.plain(color, 0.2))
    return b.to_spec("shelf", target=(0, 0, 0.44), radius=1.75, elevation=(5, 28), fov_x=60,
                     description="double-sided two-level shelf of stacked lying books with repeated titles, "
                                 "partly occluded by upright books and the shelf boards")


BUILDERS: dict[str, Callable[[np.random.Generator], SceneSpec]] = {
    "books": build_books,
    "extinguisher": build_extinguisher,
    "globe": build_globe,
    "chemicals": build_chemicals,
    "shelf": build_shelf,
}
