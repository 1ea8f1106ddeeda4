"""A small numpy ray caster for analytic primitives (quads, discs, cylinders, spheres).

Each primitive carries a texture image and the boxes (in its texture's uv) where words are printed.
`render` casts s x s rays per pixel (supersampling), finds the nearest hit per ray, shades it with a
Lambert term (two-sided, one directional light plus ambient) and averages the subsamples. The text
mask of a pixel is true when at least half of its subsamples hit a word box.

Speed comes from screen-space culling: a primitive is intersected only with the rays inside the
screen rectangle its bounding corners project to, and one-sided quads facing away are skipped.

Conventions: rays use the COLMAP camera (x right, y down, z forward, pixel centres at +0.5). Ray
directions are not normalised: d = R^T [(u - cx)/fx, (v - cy)/fy, 1], so the ray parameter t of a
hit is its camera-space depth. Texture coordinates: u runs along the texture's x (right, as seen
from the front / outside), v along its y (down); (0, 0) is the texture's top-left corner.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from strings_bench.core import vec3
from strings_bench.scene.camera import Camera

EPS_T = 1e-6


@dataclass
class Material:
    texture: np.ndarray  # (H, W, 3) float32 in [0, 1]
    word_boxes: np.ndarray = field(default_factory=lambda: np.zeros((0, 4)))  # (K, 4) u0, v0, u1, v1
    tile: tuple[float, float] = (1.0, 1.0)  # texture repeats (background surfaces)

    def __post_init__(self):
        tex = np.asarray(self.texture)
        if tex.dtype == np.uint8:
            tex = tex.astype(np.float32) / 255.0
        self.texture = np.ascontiguousarray(tex, dtype=np.float32)
        self.word_boxes = np.asarray(self.word_boxes, np.float64).reshape(-1, 4)

    def sample(self, uv: np.ndarray) -> np.ndarray:
        """Bilinear texture lookup at uv (N, 2) -> (N, 3); wraps when tiled, clamps otherwise."""
        h, w = self.texture.shape[:2]
        x = uv[:, 0] * (w * self.tile[0]) - 0.5
        y = uv[:, 1] * (h * self.tile[1]) - 0.5
        x0, y0 = np.floor(x), np.floor(y)
        fx, fy = (x - x0)[:, None].astype(np.float32), (y - y0)[:, None].astype(np.float32)
        x0, y0 = x0.astype(np.int64), y0.astype(np.int64)
        if self.tile != (1.0, 1.0):
            xa, xb, ya, yb = x0 % w, (x0 + 1) % w, y0 % h, (y0 + 1) % h
        else:
            xa, xb = np.clip(x0, 0, w - 1), np.clip(x0 + 1, 0, w - 1)
            ya, yb = np.clip(y0, 0, h - 1), np.clip(y0 + 1, 0, h - 1)
        t = self.texture
        top = t[ya, xa] * (1 - fx) + t[ya, xb] * fx
        bot = t[yb, xa] * (1 - fx) + t[yb, xb] * fx
        return top * (1 - fy) + bot * fy

    def in_words(self, uv: np.ndarray) -> np.ndarray:
        inside = np.zeros(len(uv), bool)
        for u0, v0, u1, v1 in self.word_boxes:
            inside |= (uv[:, 0] >= u0) & (uv[:, 0] <= u1) & (uv[:, 1] >= v0) & (uv[:, 1] <= v1)
        return inside


def _dot(d: np.ndarray, v: np.ndarray) -> np.ndarray:
    """d . v over the last axis in d's dtype (no BLAS: core/vec3.py)."""
    return vec3.dot(d, np.asarray(v, d.dtype))


class Primitive:
    material: Material
    one_sided = False

    def corners(self) -> np.ndarray:  # (K, 3) points whose convex hull contains the primitive
        raise NotImplementedError

    def intersect(self, o: np.ndarray, d: np.ndarray) -> np.ndarray:  # t (...) with inf = miss
        raise NotImplementedError

    def surface(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:  # uv (N, 2), normal (N, 3)
        raise NotImplementedError

    def point(self, uv: np.ndarray) -> np.ndarray:  # (N, 2) -> (N, 3) points on the surface
        raise NotImplementedError

    def faces_away(self, o: np.ndarray) -> bool:
        return False


class Quad(Primitive):
    """A parallelogram p0 + a*eu + b*ev, a, b in [0, 1]; p0 is the texture's top-left corner.

    The front normal is ev x eu (seen from the front, eu points right and ev down).
    """

    def __init__(self, p0, eu, ev, material: Material, one_sided: bool = False):
        self.p0, self.eu, self.ev = (np.asarray(v, np.float64) for v in (p0, eu, ev))
        n = np.cross(self.ev, self.eu)
        self.n = vec3.unit(n)
        self.material = material
        self.one_sided = one_sided
        self._iu, self._iv = 1.0 / vec3.dot(self.eu, self.eu), 1.0 / vec3.dot(self.ev, self.ev)

    def corners(self):
        return np.array([self.p0, self.p0 + self.eu, self.p0 + self.ev, self.p0 + self.eu + self.ev])

    def faces_away(self, o):
        return self.one_sided and float(vec3.dot(self.n, o - self.p0)) <= 0

    def intersect(self, o, d):
        dn = _dot(d, self.n)
        w = o - self.p0
        with np.errstate(divide="ignore", invalid="ignore"):
            t = -vec3.dot(w, self.n) / dn
            a = (vec3.dot(w, self.eu) + t * _dot(d, self.eu)) * self._iu
            b = (vec3.dot(w, self.ev) + t * _dot(d, self.ev)) * self._iv
        ok = (t > EPS_T) & (a >= 0) & (a <= 1) & (b >= 0) & (b <= 1)
        return np.where(ok, t, np.inf)

    def surface(self, p):
        w = p - self.p0
        uv = np.stack([vec3.dot(w, self.eu) * self._iu, vec3.dot(w, self.ev) * self._iv], axis=1)
        return uv, np.broadcast_to(self.n, p.shape)

    def point(self, uv):
        uv = np.asarray(uv, np.float64).reshape(-1, 2)
        return self.p0 + uv[:, :1] * self.eu + uv[:, 1:] * self.ev


class Disc(Primitive):
    """A disc (centre c, normal n, radius r); texture spans its bounding square, u along e1, v along -e2."""

    def __init__(self, c, n, r, material: Material, e1=None):
        self.c = np.asarray(c, np.float64)
        self.n = vec3.unit(n)
        self.r = float(r)
        self.e1, self.e2 = _frame(self.n, e1)
        self.material = material

    def corners(self):
        r = self.r
        return np.array([self.c + sa * r * self.e1 + sb * r * self.e2 for sa in (-1, 1) for sb in (-1, 1)])

    def intersect(self, o, d):
        dn = _dot(d, self.n)
        w = o - self.c
        with np.errstate(divide="ignore", invalid="ignore"):
            t = -vec3.dot(w, self.n) / dn
            x = vec3.dot(w, self.e1) + t * _dot(d, self.e1)
            y = vec3.dot(w, self.e2) + t * _dot(d, self.e2)
        ok = (t > EPS_T) & (x * x + y * y <= self.r * self.r)
        return np.where(ok, t, np.inf)

    def surface(self, p):
        w = p - self.c
        uv = np.stack([0.5 + 0.5 * vec3.dot(w, self.e1) / self.r, 0.5 - 0.5 * vec3.dot(w, self.e2) / self.r], axis=1)
        return uv, np.broadcast_to(self.n, p.shape)

    def point(self, uv):
        uv = np.asarray(uv, np.float64).reshape(-1, 2)
        return self.c + (2 * uv[:, :1] - 1) * self.r * self.e1 + (1 - 2 * uv[:, 1:]) * self.r * self.e2


class Cylinder(Primitive):
    """The side of a finite cylinder: base centre c, unit axis a, radius r, height h.

    u = angle / 2pi measured from e1 towards e2 = a x e1 (increasing to the right seen from
    outside with a pointing up); v = 1 - height / h (0 at the top rim). Rays from outside hit the
    near side, rays from inside (a backdrop wall) the far side.
    """

    def __init__(self, c, a, r, h, material: Material, e1=None):
        self.c = np.asarray(c, np.float64)
        self.a = vec3.unit(a)
        self.r, self.h = float(r), float(h)
        self.e1, self.e2 = _frame(self.a, e1)
        self.material = material

    def corners(self):
        return np.array([self.c + z * self.h * self.a + sa * self.r * self.e1 + sb * self.r * self.e2
                         for z in (0, 1) for sa in (-1, 1) for sb in (-1, 1)])

    def intersect(self, o, d):
        w = o - self.c
        da = _dot(d, self.a)
        wa = float(vec3.dot(w, self.a))
        dp = d - da[..., None] * self.a.astype(d.dtype)
        wp = w - wa * self.a
        A = vec3.dot(dp, dp)
        B = 2 * _dot(dp, wp)
        C = float(vec3.dot(wp, wp)) - self.r ** 2
        return _nearest_root(A, B, C, lambda t: (wa + t * da >= 0) & (wa + t * da <= self.h))

    def surface(self, p):
        w = p - self.c
        z = vec3.dot(w, self.a)
        radial = w - z[:, None] * self.a
        n = radial / vec3.norm(radial)[:, None].clip(1e-12)
        phi = np.mod(np.arctan2(vec3.dot(radial, self.e2), vec3.dot(radial, self.e1)), 2 * np.pi)
        return np.stack([phi / (2 * np.pi), 1 - z / self.h], axis=1), n

    def point(self, uv):
        uv = np.asarray(uv, np.float64).reshape(-1, 2)
        phi = 2 * np.pi * uv[:, :1]
        return (self.c + self.r * (np.cos(phi) * self.e1 + np.sin(phi) * self.e2)
                + (1 - uv[:, 1:]) * self.h * self.a)


class Sphere(Primitive):
    """A sphere (centre c, radius r, polar axis a): u = longitude / 2pi from e1 towards e2 = a x e1,
    v = colatitude / pi (0 at the north pole): an equirectangular texture."""

    def __init__(self, c, r, material: Material, a=(0, 0, 1), e1=None):
        self.c = np.asarray(c, np.float64)
        self.r = float(r)
        self.a = vec3.unit(a)
        self.e1, self.e2 = _frame(self.a, e1)
        self.material = material

    def corners(self):
        return np.array([self.c + self.r * np.array([sx, sy, sz]) for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)])

    def intersect(self, o, d):
        w = o - self.c
        A = vec3.dot(d, d)
        B = 2 * _dot(d, w)
        C = float(vec3.dot(w, w)) - self.r ** 2
        return _nearest_root(A, B, C, None)

    def surface(self, p):
        w = (p - self.c) / self.r
        n = w / vec3.norm(w)[:, None].clip(1e-12)
        lat = np.arcsin(np.clip(vec3.dot(n, self.a), -1, 1))
        phi = np.mod(np.arctan2(vec3.dot(n, self.e2), vec3.dot(n, self.e1)), 2 * np.pi)
        return np.stack([phi / (2 * np.pi), (np.pi / 2 - lat) / np.pi], axis=1), n

    def point(self, uv):
        uv = np.asarray(uv, np.float64).reshape(-1, 2)
        phi, lat = 2 * np.pi * uv[:, :1], np.pi / 2 - np.pi * uv[:, 1:]
        return self.c + self.r * (np.cos(lat) * (np.cos(phi) * self.e1 + np.sin(phi) * self.e2) + np.sin(lat) * self.a)


def _frame(a: np.ndarray, e1=None) -> tuple[np.ndarray, np.ndarray]:
    """Unit e1 perpendicular to a (the given hint, projected) and e2 = a x e1."""
    if e1 is None:
        e1 = np.array([1.0, 0, 0]) if abs(a[0]) < 0.9 else np.array([0, 1.0, 0])
    e1 = np.asarray(e1, np.float64)
    e1 = e1 - vec3.dot(e1, a) * a
    e1 = vec3.unit(e1)
    return e1, np.cross(a, e1)


def _nearest_root(A, B, C, valid) -> np.ndarray:
    """Smallest t > 0 of A t^2 + B t + C = 0 accepted by `valid`; inf where none."""
    disc = B * B - 4 * A * C
    hit = disc >= 0
    s = np.sqrt(np.where(hit, disc, 0))
    with np.errstate(divide="ignore", invalid="ignore"):
        t1 = (-B - s) / (2 * A)
        t2 = (-B + s) / (2 * A)
    ok1 = hit & (t1 > EPS_T)
    ok2 = hit & (t2 > EPS_T)
    if valid is not None:
        ok1 &= valid(t1)
        ok2 &= valid(t2)
    return np.where(ok1, t1, np.where(ok2, t2, np.inf))


@dataclass
class RenderResult:
    rgb: np.ndarray  # (H, W, 3) uint8
    text_mask: np.ndarray  # (H, W) bool
    depth: np.ndarray  # (H, W) float64 camera-space depth of the centre-most subsample (inf = background)
    linear: np.ndarray | None = None  # (H, W, 3) float32 colour in [0, 1] before rounding (photometric.py starts here)
    photometry: object = None  # the ViewPhotometry applied to rgb by the generator, None for a clean render


@dataclass
class World:
    primitives: list[Primitive]
    light_dir: np.ndarray = field(default_factory=lambda: np.array([0.35, -0.45, 0.82]))  # towards the light
    ambient: float = 0.55
    diffuse: float = 0.5
    background: tuple[float, float, float] = (0.62, 0.66, 0.72)

    def __post_init__(self):
        self.light_dir = vec3.unit(self.light_dir)

    # ---- ray queries ---------------------------------------------------------------------
    def first_hit(self, o: np.ndarray, d: np.ndarray) -> np.ndarray:
        """Ray parameter of the nearest hit for rays o + t d (d: (N, 3)); inf where nothing is hit."""
        o = np.asarray(o, np.float64)
        d = np.asarray(d, np.float64).reshape(-1, 3)
        best = np.full(len(d), np.inf)
        for prim in self.primitives:
            if prim.faces_away(o):
                continue
            np.minimum(best, prim.intersect(o, d), out=best)
        return best

    def render(self, cam: Camera, supersample: int = 3) -> RenderResult:
        s = int(supersample)
        W, H = cam.width * s, cam.height * s
        o = cam.center
        # Subsample centres in pixel units: pixel x covers [x, x + 1), its s x s samples at (k + 0.5) / s.
        us = (np.arange(W) + 0.5) / s
        vs = (np.arange(H) + 0.5) / s
        xc = ((us - cam.cx) / cam.fx).astype(np.float32)
        yc = ((vs - cam.cy) / cam.fy).astype(np.float32)
        Rt = cam.R.T.astype(np.float32)
        d = (xc[None, :, None] * Rt[:, 0] + yc[:, None, None] * Rt[:, 1] + Rt[:, 2])  # (H, W, 3)
        tbuf = np.full((H, W), np.inf, np.float32)
        ibuf = np.full((H, W), -1, np.int32)
        for k, prim in enumerate(self.primitives):
            if prim.faces_away(o):
                continue
            rect = _screen_rect(cam, prim.corners(), s, W, H)
            if rect is None:
                continue
            y0, y1, x0, x1 = rect
            t = prim.intersect(o, d[y0:y1, x0:x1]).astype(np.float32)
            tb = tbuf[y0:y1, x0:x1]
            closer = t < tb
            tb[closer] = t[closer]
            ibuf[y0:y1, x0:x1][closer] = k

        color = np.empty((H * W, 3), np.float32)
        color[:] = self.background
        text = np.zeros(H * W, bool)
        ids = ibuf.ravel()
        order = np.argsort(ids, kind="stable")
        counts = np.bincount(ids + 1, minlength=len(self.primitives) + 1)
        starts = np.concatenate([[0], np.cumsum(counts)])
        dflat = d.reshape(-1, 3)
        tflat = tbuf.ravel()
        for k, prim in enumerate(self.primitives):
            sel = order[starts[k + 1]:starts[k + 2]]
            if len(sel) == 0:
                continue
            dd = dflat[sel].astype(np.float64)
            p = o + tflat[sel, None].astype(np.float64) * dd
            uv, n = prim.surface(p)
            # Two-sided shading: turn the normal towards the viewer.
            flip = vec3.dot(n, dd) > 0
            n = np.where(flip[:, None], -n, n)
            lambert = self.ambient + self.diffuse * np.clip(vec3.dot(n, self.light_dir), 0, None)
            color[sel] = prim.material.sample(uv) * lambert[:, None].astype(np.float32)
            if len(prim.material.word_boxes):
                text[sel] = prim.material.in_words(uv)

        rgb = color.reshape(cam.height, s, cam.width, s, 3).mean(axis=(1, 3))
        frac = text.reshape(cam.height, s, cam.width, s).mean(axis=(1, 3))
        depth = tbuf[s // 2::s, s // 2::s].astype(np.float64)
        return RenderResult(rgb=np.clip(np.rint(rgb * 255), 0, 255).astype(np.uint8), text_mask=frac >= 0.5, depth=depth,
                            linear=rgb)


def _screen_rect(cam: Camera, corners: np.ndarray, s: int, W: int, H: int):
    """Subsample-grid rectangle (y0, y1, x0, x1) covering the projected corners; whole frame when a
    corner is behind the camera; None when the primitive is off screen."""
    pc = cam.world_to_camera(corners)
    if np.any(pc[:, 2] <= 1e-6):
        return 0, H, 0, W
    u = (cam.fx * pc[:, 0] / pc[:, 2] + cam.cx) * s
    v = (cam.fy * pc[:, 1] / pc[:, 2] + cam.cy) * s
    x0, x1 = max(0, int(np.floor(u.min())) - 1), min(W, int(np.ceil(u.max())) + 1)
    y0, y1 = max(0, int(np.floor(v.min())) - 1), min(H, int(np.ceil(v.max())) + 1)
    if x0 >= x1 or y0 >= y1:
        return None
    return y0, y1, x0, x1
