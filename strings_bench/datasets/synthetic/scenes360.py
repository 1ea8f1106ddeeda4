"""The room-scale scenes of `synthetic360`, in the spirit of STRinGS-360's captures.

Size (~520 lines): the room builder and the three rooms built on it; the difficulty parameters are read in one place with the scenes that use them.

Each scene is a room (floor, four walls, ceiling, posters with text on the walls) with a cluster
of text-bearing objects in its middle and textured clutter (no text) around it; the cameras orbit
the cluster inside the room, so the far half of the room is behind the text in every view.

What sets difficulty (the `RoomParams`, from the generator settings; docs/synthetic.md):

- `room_scale` multiplies the room, the clutter ring and the orbit radius; the text objects keep
  their size, so they cover less of each view and their text shrinks in pixels (~1 / room_scale).
- `text_px` (lo, hi) is the distribution of word heights in pixels at room_scale 1: each line has
  a role (title, heading, body, fine print) and its box is lo * (hi / lo) ** rank pixels tall at
  the distance the cameras see it from (rank 1, 0.6, 0.3, 0). The carriers (labels, signs, box
  faces) have fixed physical sizes: text too long or too tall for its carrier is shrunk to fit.
- `bg_frequency` multiplies the spatial frequency (cycles per metre) of the floor, wall and clutter
  textures; `clutter` is the number of clutter objects around the room.

World frame as in scenes.py: z up, the floor at z = 0, 1 unit ~ 1 m. The word lists here share no
word with the five `synthetic` scenes (tests/datasets/test_synthetic360.py checks it).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from strings_bench.core import vec3
from strings_bench.datasets.synthetic.raycast import Cylinder, Disc, Material, Quad, Sphere
from strings_bench.datasets.synthetic.scenes import Builder, SceneSpec
from strings_bench.datasets.synthetic.textures import Canvas, blobs, load_font, tiles, tinted_noise, wood

FOV_X = 60.0  # horizontal field of view of every synthetic360 camera, degrees
ORBIT_RADIUS = 1.8  # camera orbit radius at room_scale 1, metres (horizontal distance ~ radius * cos(elevation))
ELEVATION = (6.0, 30.0)  # degrees, min and max over the orbit
TARGET_Z = 0.95  # height of the orbit's look-at point (the top of the cluster's table)
DEFAULT_TEXT_PX = (6.0, 16.0)  # word box heights at 320 px width; scaled with the width when not given
ROLE_RANK = {"title": 1.0, "heading": 0.6, "body": 0.3, "fine": 0.0}
TEXELS_PER_PIXEL = 5.0  # texture texels per image pixel at a carrier's nominal distance (2x2 rays per pixel)
BOX_PAD = 0.12  # the word box margin of textures.Canvas.word, as a fraction of the font size

Line = tuple  # (text, role, style, colour)


@dataclass(frozen=True)
class RoomParams:
    """The settings a room-scale scene is built from (see the module docstring)."""

    room_scale: float = 1.0
    text_px: tuple[float, float] = DEFAULT_TEXT_PX
    width: int = 320  # image width the text heights are meant at
    bg_frequency: float = 1.0
    clutter: int = 10

    @property
    def fx(self) -> float:
        return 0.5 * self.width / np.tan(np.deg2rad(FOV_X) / 2)

    @property
    def orbit_radius(self) -> float:
        return ORBIT_RADIUS * self.room_scale


def role_px(params: RoomParams, role: str) -> float:
    """Box height in pixels of a line of this role at its nominal distance (before any fit)."""
    lo, hi = params.text_px
    return float(lo * (hi / lo) ** ROLE_RANK[role])


def box_height_px(text: str, style: str, size: float) -> float:
    """Height of textures.Canvas.word's box for `text` at font size `size` (ink + margins)."""
    font = load_font(style, size)
    boxes = [font.getbbox(w) for w in text.split()]
    pad = max(1, int(round(BOX_PAD * size)))
    return max(b[3] - b[1] for b in boxes) + 2 * pad


def line_length_px(text: str, style: str, size: float) -> float:
    font = load_font(style, size)
    pad = max(1, int(round(BOX_PAD * size)))
    words = text.split()
    return sum(font.getbbox(w)[2] - font.getbbox(w)[0] + 2 * pad for w in words) + font.getlength(" ") * (len(words) - 1)


def size_for_box_height(text: str, style: str, box_h: float) -> float:
    """Font size whose word boxes are `box_h` texels tall (the ink's share measured at a large size)."""
    ref = 200.0
    ink = (box_height_px(text, style, ref) - 2 * round(BOX_PAD * ref)) / ref
    return max(4.0, box_h / (ink + 2 * BOX_PAD))


class RoomBuilder(Builder):
    """A Builder that sizes text in pixels at the distance the orbit sees each carrier from."""

    def __init__(self, rng: np.random.Generator, params: RoomParams):
        super().__init__(rng)
        self.params = params
        self.target = np.array([0.0, 0.0, TARGET_Z])
        self.fit_log: list[tuple[str, str, float]] = []  # (line, role, box height / the role's height): < 1 where shrunk

    # ---- text sizing ------------------------------------------------------------------------
    def nominal_distance(self, pos, normal) -> float:
        """Distance from a carrier at `pos` facing `normal` to the orbit camera that sees it head on,
        at room_scale 1 (mid elevation)."""
        pos, normal = np.asarray(pos, float), np.asarray(normal, float)
        nh = np.array([normal[0], normal[1], 0.0])
        if vec3.norm(nh) < 0.3:  # a top face: the camera on the carrier's side of the orbit
            nh = np.array([pos[0] - self.target[0], pos[1] - self.target[1], 0.0])
            if vec3.norm(nh) < 1e-6:
                nh = np.array([1.0, 0.0, 0.0])
        nh = vec3.unit(nh)
        el = np.deg2rad(np.mean(ELEVATION))
        cam = self.target + ORBIT_RADIUS * (np.cos(el) * nh + np.array([0, 0, np.sin(el)]))
        return float(vec3.norm(cam - pos))

    def density(self, pos, normal) -> float:
        """Texels per metre for a carrier: TEXELS_PER_PIXEL texels per image pixel at its nominal distance."""
        return float(np.clip(TEXELS_PER_PIXEL * self.params.fx / self.nominal_distance(pos, normal), 300, 12000))

    def label(self, cv: Canvas, rect, lines: list[Line], pos, normal, density: float, rotate: int = 0) -> None:
        """Draw `lines` centred in the canvas rectangle rect = (x0, y0, x1, y1) (texels), stacked in
        reading order, each sized by its role; shrunk to fit the rectangle."""
        d = self.nominal_distance(pos, normal)
        x0, y0, x1, y1 = rect
        # Along: the reading direction; across: the direction lines stack in.
        along, across = (x1 - x0, y1 - y0) if rotate == 0 else (y1 - y0, x1 - x0)
        sizes = []
        for text, role, style, _ in lines:
            box_h = role_px(self.params, role) * d / self.params.fx * density
            size = size_for_box_height(text, style, box_h)
            length = line_length_px(text, style, size)
            if length > 0.92 * along:
                size *= 0.92 * along / length
            sizes.append(size)
        gap = 0.35
        heights = [box_height_px(t, s, z) for (t, _, s, _), z in zip(lines, sizes)]
        total = sum(heights) * (1 + gap) - gap * heights[-1]
        if total > 0.92 * across:
            f = 0.92 * across / total
            sizes = [z * f for z in sizes]
            heights = [box_height_px(t, s, z) for (t, _, s, _), z in zip(lines, sizes)]
            total = sum(heights) * (1 + gap) - gap * heights[-1]
        for (text, role, style, _), size in zip(lines, sizes):
            target = role_px(self.params, role) * d / self.params.fx * density
            self.fit_log.append((text, role, box_height_px(text, style, size) / target))
        pos_across = -total / 2
        cx, cy = (x0 + x1) / 2, (y0 + y1) / 2
        for (text, _, style, color), size, h in zip(lines, sizes, heights):
            mid = pos_across + h / 2
            if rotate == 0:
                cv.text_line(text, cx, cy + mid, size, color, style, anchor="mm")
            else:  # -90: reads top to bottom, glyph tops to +x; the next line lies towards -x
                cv.text_line(text, cx - mid, cy, size, color, style, rotate=-90, anchor="mm")
            pos_across += h * (1 + gap)

    def canvas_m(self, w_m: float, h_m: float, density: float, color, amplitude: float = 0.06) -> Canvas:
        w, h = max(8, int(round(w_m * density))), max(8, int(round(h_m * density)))
        return Canvas(tinted_noise(self.rng, h, w, color, amplitude=amplitude, octaves=(3, 12, 48)))

    # ---- text-bearing objects --------------------------------------------------------------
    def jar(self, base, r: float, h: float, yaw_deg: float, color, front: list[Line], back: list[Line] | None,
            label_color=(244, 240, 228), cap=(40, 40, 40)) -> None:
        """A cylinder (jar, can, drum) with a paper label facing yaw (0: -y) and one facing away."""
        base = np.asarray(base, float)
        yaw = np.deg2rad(yaw_deg)
        e1 = np.array([np.cos(yaw), np.sin(yaw), 0.0])
        e2 = np.array([-np.sin(yaw), np.cos(yaw), 0.0])
        mid = base + [0, 0, h / 2]
        dens = max(self.density(mid - r * e2, -e2), self.density(mid + r * e2, e2))
        cv = self.canvas_m(2 * np.pi * r, h, dens, color)
        W, H = cv.size
        for uc, lines, normal in ((0.75, front, -e2), (0.25, back, e2)):
            if not lines:
                continue
            lw = 0.46 * W
            rect = (uc * W - lw / 2, 0.08 * H, uc * W + lw / 2, 0.94 * H)
            cv.rect(rect, label_color)
            self.label(cv, rect, lines, mid + r * normal, normal, dens)
        self.add(lambda m: Cylinder(base, (0, 0, 1), r, h, m, e1=e1), cv)
        self.add(lambda m: Cylinder(base + [0, 0, h], (0, 0, 1), 0.8 * r, 0.03, m), self.plain(cap, 0.15))
        self.add(lambda m: Disc(base + [0, 0, h + 0.03], (0, 0, 1), 0.8 * r, m), self.plain(cap, 0.1))

    def printed_box(self, center, size, yaw_deg: float, color, faces: dict[str, list[Line]],
                    panel=None) -> None:
        """A box with text on some faces ("-y", "+y", "-x", "+x"); panel: a paper panel behind the text."""
        c = np.asarray(center, float)
        yaw = np.deg2rad(yaw_deg)
        X = np.array([np.cos(yaw), np.sin(yaw), 0.0])
        Y = np.array([-np.sin(yaw), np.cos(yaw), 0.0])
        sx, sy, sz = size
        offsets = {"-y": (-Y, sy / 2, sx), "+y": (Y, sy / 2, sx), "-x": (-X, sx / 2, sy), "+x": (X, sx / 2, sy)}
        textured = {}
        for face, lines in faces.items():
            normal, off, fw = offsets[face]
            pos = c + off * normal
            dens = self.density(pos, normal)
            cv = self.canvas_m(fw, sz, dens, color, amplitude=0.1)
            W, H = cv.size
            rect = (0.06 * W, 0.08 * H, 0.94 * W, 0.92 * H)
            if panel is not None:
                cv.rect(rect, panel)
            self.label(cv, rect, lines, pos, normal, dens)
            textured[face] = cv
        self.box(c, size, yaw_deg, textured, self.plain(color, 0.12))

    def spine_row(self, start, yaw_deg: float, spines: list[tuple[str, str, tuple]], depth: float, z0: float,
                  thickness=(0.055, 0.075), height=(0.28, 0.32)) -> float:
        """Binders standing in a row along local +x from `start`, spines facing local -y, with the
        title and, on a paper label below it, a short code, both reading top to bottom. Returns the
        row's length."""
        yaw = np.deg2rad(yaw_deg)
        X = np.array([np.cos(yaw), np.sin(yaw), 0.0])
        Y = np.array([-np.sin(yaw), np.cos(yaw), 0.0])
        x = 0.0
        for title, code, color in spines:
            w = float(self.rng.uniform(*thickness))
            h = float(self.rng.uniform(*height))
            center = np.asarray(start, float) + (x + w / 2) * X + depth / 2 * Y + np.array([0, 0, z0 + h / 2])
            pos = center - depth / 2 * Y
            dens = self.density(pos, -Y)
            cv = self.canvas_m(w, h, dens, color, amplitude=0.08)
            W, H = cv.size
            ink = (25, 25, 30) if sum(color) > 420 else (245, 240, 225)
            self.label(cv, (0.1 * W, 0.05 * H, 0.9 * W, 0.64 * H), [(title, "body", "sans-bold", ink)], pos, -Y, dens,
                       rotate=-90)
            code_rect = (0.14 * W, 0.68 * H, 0.86 * W, 0.95 * H)
            cv.rect(code_rect, (240, 238, 230))
            self.label(cv, code_rect, [(code, "fine", "sans-bold", (20, 20, 20))], pos, -Y, dens, rotate=-90)
            self.box(center, (w, depth, h), yaw_deg, {"-y": cv}, self.plain(color, 0.1))
            x += w + 0.004
        return x

    def sign(self, center, w: float, h: float, yaw_deg: float, front: list[Line], back: list[Line] | None,
             board=(236, 236, 230), frame=(60, 60, 66), post: bool = True) -> None:
        """A thin double-sided board (front faces local -y) on a post."""
        faces = {"-y": front} if back is None else {"-y": front, "+y": back}
        self.printed_box(center, (w, 0.025, h), yaw_deg, frame, faces, panel=board)
        if post:
            c = np.asarray(center, float)
            self.add(lambda m: Cylinder((c[0], c[1], 0.0), (0, 0, 1), 0.02, c[2] - h / 2, m), self.plain((70, 70, 75), 0.2))

    def poster(self, wall_center, normal, w: float, h: float, lines: list[Line], color=(238, 234, 222)) -> None:
        """A poster flat on a wall (centre on the wall plane, `normal` pointing into the room)."""
        n = np.asarray(normal, float)
        pos = np.asarray(wall_center, float) + 0.01 * n
        dens = self.density(pos, n)
        cv = self.canvas_m(w, h, dens, color, amplitude=0.05)
        W, H = cv.size
        self.label(cv, (0.05 * W, 0.06 * H, 0.95 * W, 0.94 * H), lines, pos, n, dens)
        self.add(lambda m: vertical_quad(pos, n, w, h, m), cv)

    # ---- the room and clutter ------------------------------------------------------------------
    def room_shell(self, floor: str, palette) -> tuple[float, float, float]:
        """Floor, ceiling and four inward-facing walls sized by room_scale; returns (half x, half y, height)."""
        p, rng = self.params, self.rng
        R = p.orbit_radius
        lx, ly, hz = 2.0 * R, 1.8 * R, max(2.7, 1.9 * R)
        f = p.bg_frequency
        # Textures repeat once per `period` metres (times 1 / bg_frequency): the world frequency of the
        # pattern is fixed by bg_frequency, whatever the room's size.
        if floor == "wood":
            ftex, period = wood(rng, 512, 512, light=(186, 146, 104), dark=(112, 80, 50)), 1.2
        else:
            ftex, period = tiles(rng, 512, 512, 4, 4), 1.6
        self.add(lambda m: Quad((-lx, ly, 0), (2 * lx, 0, 0), (0, -2 * ly, 0), m, one_sided=True),
                 Material(ftex, tile=(2 * lx * f / period, 2 * ly * f / period)))
        self.add(lambda m: Quad((-lx, -ly, hz), (2 * lx, 0, 0), (0, 2 * ly, 0), m, one_sided=True),
                 Material(tinted_noise(rng, 128, 128, (225, 224, 218), 0.05), tile=(2, 2)))
        wtex = blobs(rng, 512, 1024, palette, 320)
        for normal, half_w, dist in (((1, 0, 0), ly, lx), ((-1, 0, 0), ly, lx), ((0, 1, 0), lx, ly), ((0, -1, 0), lx, ly)):
            n = np.array(normal, float)
            center = -n * dist + np.array([0, 0, hz / 2])
            self.add(lambda m, c=center, n=n, w=2 * half_w: vertical_quad(c, n, w, hz, m),
                     Material(wtex, tile=(2 * half_w * f / 2.0, hz * f / 1.0)))
        return lx, ly, hz

    def textured(self, kind: str, color) -> Material:
        """A texture-rich material for clutter; it repeats bg_frequency times per object."""
        rng, f = self.rng, self.params.bg_frequency
        if kind == "wood":
            tex = wood(rng, 256, 256, light=tuple(min(255, c + 40) for c in color), dark=color)
        elif kind == "blobs":
            tex = blobs(rng, 256, 256, [color, (220, 210, 190), (40, 60, 90), (150, 40, 40), (60, 120, 70)], 60)
        else:
            tex = tinted_noise(rng, 256, 256, color, amplitude=0.35, octaves=(4, 16, 64))
        return Material(tex, tile=(f, f))

    def clutter_ring(self, lx: float, ly: float, n: int) -> None:
        """`n` textured objects without text on the floor between the orbit and the walls."""
        rng = self.rng
        R = self.params.orbit_radius
        colors = [(120, 80, 50), (70, 90, 130), (150, 60, 50), (80, 110, 70), (170, 150, 110), (90, 80, 100)]
        angles = rng.uniform(0, 2 * np.pi) + np.linspace(0, 2 * np.pi, n, endpoint=False) + rng.uniform(-0.2, 0.2, n)
        for k, a in enumerate(angles):
            direction = np.array([np.cos(a), np.sin(a), 0.0])
            # Farthest the wall allows along this direction, keeping 0.35 m clear of it.
            wall = min(lx / max(abs(direction[0]), 1e-6), ly / max(abs(direction[1]), 1e-6)) - 0.35
            rad = float(rng.uniform(1.3 * R, max(1.3 * R, wall)))
            p = direction * rad
            color = colors[int(rng.integers(len(colors)))]
            kind = ("crate", "bin", "ball", "plant", "stack")[k % 5]
            if kind == "crate":
                s = rng.uniform(0.3, 0.5, 3)
                self.box((p[0], p[1], s[2] / 2), s, float(rng.uniform(0, 90)), {}, self.textured("wood", color))
            elif kind == "bin":
                r, h = float(rng.uniform(0.15, 0.22)), float(rng.uniform(0.35, 0.6))
                self.add(lambda m, p=p, r=r, h=h: Cylinder((p[0], p[1], 0), (0, 0, 1), r, h, m), self.textured("noise", color))
            elif kind == "ball":
                r = float(rng.uniform(0.12, 0.2))
                self.add(lambda m, p=p, r=r: Sphere((p[0], p[1], r), r, m), self.textured("blobs", color))
            elif kind == "plant":
                self.add(lambda m, p=p: Cylinder((p[0], p[1], 0), (0, 0, 1), 0.13, 0.3, m), self.textured("noise", (150, 80, 50)))
                self.add(lambda m, p=p: Sphere((p[0], p[1], 0.55), 0.28, m), self.textured("blobs", (50, 110, 50)))
            else:
                z = 0.0
                for _ in range(int(rng.integers(2, 4))):
                    s = rng.uniform(0.22, 0.4, 3) * np.array([1, 1, 0.6])
                    self.box((p[0], p[1], z + s[2] / 2), s, float(rng.uniform(0, 90)), {}, self.textured("noise", color))
                    z += s[2]

    def to_room_spec(self, name: str, description: str) -> SceneSpec:
        spec = self.to_spec(name, target=self.target, radius=self.params.orbit_radius, elevation=ELEVATION, fov_x=FOV_X,
                            description=description)
        spec.target_jitter = 0.05 * self.params.room_scale
        return spec


def vertical_quad(center, normal, w: float, h: float, material: Material) -> Quad:
    """A one-sided upright w x h rectangle centred at `center`, its front facing horizontal `normal`;
    its texture reads upright from the front."""
    n = np.asarray(normal, float)
    right = np.cross(-n, [0.0, 0.0, 1.0])  # the viewer's right when looking at the front
    p0 = np.asarray(center, float) - right * w / 2 + np.array([0, 0, h / 2])
    return Quad(p0, right * w, np.array([0.0, 0.0, -h]), material, one_sided=True)


# ---------------------------------------------------------------------------------------------
# pantry: a kitchen island with canisters (curved labels), two cereal boxes and a menu board above.
INK = (25, 25, 28)
RED, GREEN, BLUE = (170, 30, 30), (30, 100, 45), (30, 60, 140)
WHITE, CREAM = (250, 250, 245), (250, 240, 200)


def _l(title, heading, body, fine, title_color=INK, title_style="serif-bold") -> list[Line]:
    lines = [(title, "title", title_style, title_color), (heading, "heading", "sans-bold", INK),
             (body, "body", "sans", INK), (fine, "fine", "sans", INK)]
    return [ln for ln in lines if ln[0]]


# Each canister: its label (facing out of the island) and its colour. The island's inner side is
# hidden behind the other row, so nothing is printed there.
PANTRY_FRONT = [
    (_l("HONEY", "WILDFLOWER", "RAW COMB", "NET WT 340G", (140, 90, 10)), (200, 150, 40)),
    (_l("BEANS", "CHICKPEAS", "LOW SALT", "DRAINED 240G", GREEN, "sans-bold"), (190, 190, 200)),
    (_l("RICE", "BASMATI", "AGED GRAIN", "PACKED 2025", BLUE), (230, 225, 205)),
]
PANTRY_BACK = [
    (_l("OIL", "OLIVE", "EXTRA VIRGIN", "COLD PRESSED", GREEN), (90, 110, 40)),
    (_l("BREW", "ESPRESSO", "DARK ROAST", "KENYAN HIGHLANDS", (90, 50, 20), "sans-bold"), (60, 40, 30)),
    (_l("SPICE", "PAPRIKA", "SMOKED", "NET WT 75G", RED), (160, 40, 30)),
]


def build_pantry(rng: np.random.Generator, params: RoomParams) -> SceneSpec:
    b = RoomBuilder(rng, params)
    lx, ly, hz = b.room_shell("tiles", [(214, 206, 188), (180, 120, 80), (120, 150, 130), (200, 170, 90), (90, 90, 100)])
    top = 0.9
    b.box((0, 0, top / 2), (1.5, 0.76, top), 0, {"+z": Material(wood(rng, 256, 512), tile=(1, 1))},
          b.textured("noise", (200, 200, 195)))
    for side, row in ((-1, PANTRY_FRONT), (1, PANTRY_BACK)):
        yaw = 0 if side < 0 else 180
        for x, (front, color) in zip((-0.42, 0.0, 0.42), row):
            r, h = float(rng.uniform(0.115, 0.125)), float(rng.uniform(0.36, 0.4))
            b.jar((x * -side, side * 0.22, top), r, h, yaw, color, front, None)
    # Cereal boxes at the island's ends, printed on the face that looks out along x (a yaw-90 box's
    # "+y" face looks to -x, its "-y" face to +x).
    b.printed_box((-0.66, 0.0, top + 0.23), (0.36, 0.1, 0.46), 90, (220, 160, 40), {
        "+y": _l("OATS", "GRANOLA", "CLUSTERS", "SERVING 45G", RED, "sans-bold")}, panel=(245, 236, 210))
    b.printed_box((0.66, 0.0, top + 0.22), (0.36, 0.1, 0.44), 90, (60, 120, 170), {
        "-y": _l("BRAN", "FLAKES", "MALTED WHEAT", "LARGE PACK 750G", BLUE, "sans-bold")}, panel=(240, 240, 235))
    # A menu board on a pole above the island, chalk on both sides.
    b.sign((0.0, 0.0, top + 0.74), 0.9, 0.5, 0,
           [("TODAY", "title", "serif-bold", WHITE), ("LENTIL SOUP", "heading", "sans-bold", CREAM),
            ("SOURDOUGH", "body", "sans", WHITE), ("SERVED UNTIL NOON", "fine", "sans", WHITE)],
           [("DESSERT", "title", "serif-bold", WHITE), ("PLUM CAKE", "heading", "sans-bold", CREAM),
            ("WARM CUSTARD", "body", "sans", WHITE), ("ASK CHEF MARCO", "fine", "sans", WHITE)], board=(40, 55, 45))
    # A fruit bowl and a kettle between the rows: texture-rich, no text.
    for k in range(4):
        b.add(lambda m, k=k: Sphere((-0.2 + 0.08 * k, 0.03 * (k % 2), top + 0.045), 0.045, m),
              b.textured("noise", [(200, 60, 40), (230, 180, 40), (90, 150, 50), (200, 90, 30)][k]))
    b.add(lambda m: Cylinder((0.2, 0.0, top), (0, 0, 1), 0.07, 0.17, m), b.textured("blobs", (180, 180, 185)))
    _posters(b, lx, ly, hz, [
        [("RULES", "title", "serif-bold", RED), ("WASH HANDS", "heading", "sans-bold", INK),
         ("LABEL LEFTOVERS", "body", "sans", INK), ("CLEAN SPILLS QUICKLY", "fine", "sans", INK)],
        [("MENU", "title", "serif-bold", GREEN), ("MONDAY PASTA", "heading", "sans", INK),
         ("TUESDAY TACOS", "body", "sans", INK), ("WEDNESDAY CURRY", "fine", "sans", INK)],
        [("HERBS", "title", "serif-bold", GREEN), ("BASIL", "heading", "sans", INK),
         ("ROSEMARY", "body", "sans", INK), ("THYME PLUS SAGE", "fine", "sans", INK)],
        [("PANTRY", "title", "sans-bold", BLUE), ("RESTOCK FRIDAYS", "heading", "sans", INK),
         ("CHECK DATES", "body", "sans", INK), ("ROTATE OLDER STOCK", "fine", "sans", INK)],
    ])
    b.clutter_ring(lx, ly, params.clutter)
    return b.to_room_spec("pantry", "a kitchen room: island with labelled canisters (curved text), cereal boxes, a "
                                    "double-sided menu board, wall posters, textured clutter")


def _posters(b: RoomBuilder, lx: float, ly: float, hz: float, posters: list[list[Line]]) -> None:
    """One poster in the middle of each wall (+x, -x, +y, -y walls in that order), at eye height."""
    z = min(1.6, 0.55 * hz)
    for (normal, center), lines in zip((((-1, 0, 0), (lx, 0, z)), ((1, 0, 0), (-lx, 0, z)),
                                        ((0, -1, 0), (0, ly, z)), ((0, 1, 0), (0, -ly, z))), posters):
        b.poster(center, normal, 2.6, 1.5, lines)


# ---------------------------------------------------------------------------------------------
# office: a desk with two back-to-back rows of binders (vertical spine text), a nameplate,
# a whiteboard on a stand and a recycling bin.
BINDERS_A = [("INVOICES", "INV 23", (30, 60, 140)), ("PAYROLL", "HR 07", (170, 30, 30)),
             ("LEGAL", "LGL 12", (30, 100, 45)), ("TAXES", "FIN 24", (230, 225, 205)),
             ("BOARD", "Q3 26", (60, 60, 70)), ("BUDGET", "FY 25", (200, 150, 40))]
BINDERS_B = [("RECEIPTS", "ACC 19", (200, 90, 30)), ("POLICY", "INS 08", (40, 100, 110)),
             ("TRAINING", "HR 22", (230, 225, 205)), ("AUDITS", "EXT 31", (30, 60, 140)),
             ("MINUTES", "AGM 14", (90, 110, 130)), ("TENDERS", "BID 16", (170, 30, 30))]


def build_office(rng: np.random.Generator, params: RoomParams) -> SceneSpec:
    b = RoomBuilder(rng, params)
    lx, ly, hz = b.room_shell("wood", [(205, 205, 200), (90, 110, 150), (160, 160, 150), (70, 90, 80), (180, 130, 100)])
    top = 0.76
    b.box((0, 0, top / 2), (1.5, 0.8, top), 0, {"+z": Material(wood(rng, 256, 512, light=(120, 90, 60), dark=(80, 55, 35)))},
          b.textured("wood", (100, 70, 45)))
    depth = 0.26
    for side, binders in ((-1, BINDERS_A), (1, BINDERS_B)):
        yaw = 0 if side < 0 else 180
        yaw_r = np.deg2rad(yaw)
        X = np.array([np.cos(yaw_r), np.sin(yaw_r), 0.0])
        Y = np.array([-np.sin(yaw_r), np.cos(yaw_r), 0.0])
        # The row's back lies near y = 0: the spines face outwards, -y for the front row, +y for the back.
        b.spine_row(-0.62 * X - (depth + 0.01) * Y, yaw, binders, depth, top, thickness=(0.085, 0.1), height=(0.4, 0.44))
    # Nameplate at the desk's -x end, facing outwards (-x).
    b.printed_box((-0.66, 0.0, top + 0.07), (0.5, 0.04, 0.14), 90, (40, 40, 45), {
        "+y": [("ELENA VOSS", "heading", "serif-bold", (230, 200, 120)), ("CHIEF ARCHIVIST", "fine", "sans", (230, 230, 230))]})
    # Whiteboard on a pole at the +x end, written on both sides (they face +x and -x).
    b.sign((0.62, 0.0, top + 0.62), 0.78, 0.56, 90,
           [("SPRINT", "title", "sans-bold", BLUE), ("SHIP V4.2", "heading", "sans", INK),
            ("FIX LOGIN", "body", "sans", INK), ("DEMO THURSDAY", "fine", "sans", INK)],
           [("IDEAS", "title", "sans-bold", RED), ("DARK MODE", "heading", "sans", INK),
            ("EXPORT PDF", "body", "sans", INK), ("OFFLINE SYNC", "fine", "sans", INK)], board=(246, 247, 248))
    b.jar((0.1, 0.6, 0.0), 0.17, 0.46, 180, (40, 110, 60),
          [("PAPER", "title", "sans-bold", GREEN), ("RECYCLE", "heading", "sans-bold", INK),
           ("NO PLASTIC", "body", "sans", INK)], None, cap=(30, 80, 40))
    b.box((0.2, 0.0, top + 0.2), (0.5, 0.05, 0.32), 0, {}, b.textured("noise", (30, 30, 35)))  # a monitor, no text
    _posters(b, lx, ly, hz, [
        [("TARGETS", "title", "sans-bold", BLUE), ("REVENUE UP 8%", "heading", "sans", INK),
         ("CHURN BELOW 2%", "body", "sans", INK), ("HIRE THREE ENGINEERS", "fine", "sans", INK)],
        [("SAFETY", "title", "sans-bold", GREEN), ("KIT UNDER SINK", "heading", "sans", INK),
         ("CALL EXTENSION 4400", "body", "sans", INK), ("DEFIBRILLATOR BY LIFTS", "fine", "sans", INK)],
        [("QUIET", "title", "serif-bold", INK), ("PHONES SILENT", "heading", "sans", INK),
         ("THANK YOU", "body", "sans", INK), ("CALLS INSIDE BOOTHS", "fine", "sans", INK)],
        [("DESKS", "title", "serif-bold", RED), ("HOT DESKING", "heading", "sans", INK),
         ("BOOK ONLINE", "body", "sans", INK), ("CLEAR DESK POLICY", "fine", "sans", INK)],
    ])
    b.clutter_ring(lx, ly, params.clutter)
    return b.to_room_spec("office", "an office room: desk with back-to-back binder rows (vertical spine text), a "
                                    "nameplate, a double-sided whiteboard, a recycling bin, wall posters, clutter")


# ---------------------------------------------------------------------------------------------
# storeroom: a pallet of stencilled crates, an oil drum with curved hazard labels, a safety sign.
CRATES = [
    {"-y": _l("FRAGILE", "GLASSWARE", "CARRY GENTLY", "STACK MAX FOUR", RED, "sans-bold"),
     "+y": _l("UP", "THIS WAY", "CRATE 7731", "", INK, "sans-bold")},
    {"-y": _l("PARTS", "BEARINGS", "SPARES", "ORDER 90417", INK, "sans-bold"),
     "+y": _l("WET", "NO WATER", "HUMIDITY LIMIT", "", BLUE, "sans-bold")},
    {"-y": _l("CABLES", "BRASS", "FITTINGS", "GAUGE 14 AWG", INK, "sans-bold"),
     "+y": _l("HEAVY", "TEAM LIFT", "KILOS 38", "", RED, "sans-bold")},
    {"-y": _l("LAMPS", "LED TUBES", "WARM WHITE", "CARTON 3308", INK, "sans-bold"),
     "+y": _l("DOCK", "SHIPPING", "BAY SEVEN", "", INK, "sans-bold")},
]


def build_storeroom(rng: np.random.Generator, params: RoomParams) -> SceneSpec:
    b = RoomBuilder(rng, params)
    lx, ly, hz = b.room_shell("tiles", [(180, 180, 175), (200, 180, 60), (90, 90, 95), (120, 130, 140), (150, 110, 70)])
    b.box((0, 0, 0.07), (1.3, 0.96, 0.14), 0, {}, b.textured("wood", (150, 110, 70)))  # the pallet
    crate = (0.6, 0.44, 0.42)
    for (x, y), faces in zip([(-0.33, -0.24), (0.33, -0.24), (-0.33, 0.24), (0.33, 0.24)], CRATES):
        # Crates of the back row turn round, so their "-y" print faces +y (outwards).
        b.printed_box((x, y, 0.14 + crate[2] / 2), crate, 0 if y < 0 else 180, (176, 132, 84), faces)
    b.printed_box((0.0, -0.05, 0.56 + 0.16), (0.5, 0.4, 0.32), 3, (176, 132, 84), {
        "-y": _l("", "SAMPLES", "NOT FOR SALE", "", INK)})
    # An oil drum on the pallet's top crates: curved hazard labels front and back.
    b.jar((0.0, 0.12, 0.56 + 0.32), 0.2, 0.5, 0, (30, 70, 140),
          _l("DIESEL", "UN 1202", "STAY SEALED", "NET 200 LITRES", INK, "sans-bold"),
          _l("OIL", "LUBRICANT", "GRADE 15W40", "DRUM 0042", INK, "sans-bold"), label_color=(250, 240, 60), cap=(25, 50, 110))
    # A safety sign at the -x end, double-sided (faces -x and +x); a broom-like pole at +x.
    b.sign((-0.62, 0.0, 1.3), 0.7, 0.56, 90,
           [("DANGER", "title", "sans-bold", RED), ("FORKLIFTS", "heading", "sans-bold", INK),
            ("WORKING NEARBY", "body", "sans", INK), ("LOOK BOTH WAYS", "fine", "sans", INK)],
           [("HELMETS", "title", "sans-bold", BLUE), ("REQUIRED", "heading", "sans-bold", INK),
            ("BEYOND HERE", "body", "sans", INK), ("VISITORS REPORT", "fine", "sans", INK)], board=(250, 235, 80))
    _posters(b, lx, ly, hz, [
        [("EXIT", "title", "sans-bold", GREEN), ("ASSEMBLY POINT", "heading", "sans", INK),
         ("CAR PARK WEST", "body", "sans", INK), ("FOLLOW GREEN ARROWS", "fine", "sans", INK)],
        [("SMOKING", "title", "sans-bold", RED), ("STRICTLY BANNED", "heading", "sans", INK),
         ("FINE 800 EUROS", "body", "sans", INK), ("ANYWHERE ON SITE", "fine", "sans", INK)],
        [("LOADING", "title", "sans-bold", INK), ("DRIVERS REPORT", "heading", "sans", INK),
         ("WEAR VESTS", "body", "sans", INK), ("SPEED LIMIT 5 KMH", "fine", "sans", INK)],
        [("STOCK", "title", "sans-bold", BLUE), ("COUNT MONDAYS", "heading", "sans", INK),
         ("SCAN EACH ITEM", "body", "sans", INK), ("REPORT SHORTAGES", "fine", "sans", INK)],
    ])
    b.clutter_ring(lx, ly, params.clutter)
    return b.to_room_spec("storeroom", "a storeroom: pallet of stencilled crates, an oil drum with curved hazard "
                                       "labels, a double-sided safety sign, wall signs, clutter")


BUILDERS_360: dict[str, Callable[[np.random.Generator, RoomParams], SceneSpec]] = {
    "pantry": build_pantry,
    "office": build_office,
    "storeroom": build_storeroom,
}
