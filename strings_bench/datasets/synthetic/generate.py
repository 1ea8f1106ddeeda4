"""Generate a synthetic scene folder: rendered views, GT text masks and polygons, and a sparse
point cloud triangulated by pycolmap from SIFT matches on the rendered images with the known poses.

Size (~540 lines): one pipeline in data-path order (render views, masks and polygons, SfM, write, the record of rho); its SfM step is sfm.py.

Layout written (COLMAP style, loadable with `Scene.load`):

    <cache_root>/synthetic/<scene>-<key>/
      images/view_000.png ...      rendered views (PNG)
      masks/view_000.png ...       GT text masks (255 = a ray of the pixel's majority hits a word box)
      sparse/0/                    COLMAP binary model, one PINHOLE camera per view, all registered
      text_annotations.json        per view: visible words and their 4-corner polygons (full-res px)
      scene_meta.json              generator version, settings, seed, timings, point counts, fallback

`key` hashes the generator version and every setting, so changing either builds a new folder.
The scene is built in a hidden sibling folder and renamed into place: an interrupted build never
leaves a half-written cache. scene_meta.json, written last, lists every file with its size; a cached
scene whose files do not match (a copy cut short, a file lost) is rebuilt, and the build folders of
killed processes are removed (`core.io.sweep_stale_temps`).
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import shutil
import time
import uuid
from dataclasses import asdict, dataclass, fields, replace
from pathlib import Path

import numpy as np
from PIL import Image
from tqdm.auto import tqdm

from strings_bench.core import vec3
from strings_bench.scene.camera import Camera
from strings_bench.scene.colmap import write_model
from strings_bench.core.errors import DatasetError
from strings_bench.core.io import atomic_write_json, cache_root, sweep_stale_temps, writer_tag
from strings_bench.scene.scene import KnownWord, write_annotations
from strings_bench.datasets.synthetic.photometric import apply_photometry, draw_view_photometry
from strings_bench.datasets.synthetic.rho import rendered_difficulty
from strings_bench.datasets.synthetic.scenes import BUILDERS, SceneSpec
from strings_bench.datasets.synthetic.multiscript import (MULTISCRIPT_VERSION, SCENE_NAMES_MULTI, WORDS, build_multi,
                                                         check_fonts, scene_script)
from strings_bench.datasets.synthetic.scenes360 import BUILDERS_360, DEFAULT_TEXT_PX, RoomParams
from strings_bench.datasets.synthetic.sfm import count_text_points, depth_sample_points, triangulate_with_known_poses

log = logging.getLogger(__name__)

# Bump whenever rendering, scene content or SfM settings change what a build produces.
GENERATOR_VERSION = "4"  # 3: the scene build without BLAS (core/vec3.py), SfM in canonical order; 4: SfM matching on one thread
SCENE_NAMES = tuple(BUILDERS)  # the `synthetic` dataset (easy: object-centred, clean images)
SCENE_NAMES_360 = tuple(BUILDERS_360)  # the `synthetic360` dataset (room-scale)
# SCENE_NAMES_MULTI: the `synthetic-multi` dataset (one scene per script; multiscript.py)
META_FILE = "scene_meta.json"


@dataclass(frozen=True)
class SyntheticSettings:
    width: int = 320
    height: int = 240
    n_views: int = 48  # views on the camera path (the paper's captures have 150-300)
    seed: int = 0
    supersample: int = 2  # s x s rays per pixel (3 is ~3x slower)
    max_features: int = 2048  # SIFT keypoints per image
    match_overlap: int = 8  # each view is matched with the next `match_overlap` views around the orbit
    min_points: int = 300  # fewer triangulated points than this triggers the relaxed retry, then the fallback
    min_word_px: float = 4.0  # words whose projected box is shorter than this are not annotated
    min_facing_cos: float = 0.2  # words seen more obliquely than ~78 degrees are not annotated
    # Difficulty controls (docs/synthetic.md, "Difficulty controls"). At their defaults every image is
    # the one generator version 2 made (version 3: the same rooms computed without BLAS, the same pixels on every
    # CPU); the scene content ones apply to synthetic360 scenes only.
    room_scale: float = 1.0  # synthetic360: multiplies the room, the clutter ring and the orbit radius (text shrinks ~1/x)
    text_px: tuple[float, float] | None = None  # synthetic360: word box heights (lo, hi) in pixels at room_scale 1; None: (6, 16) x width/320
    bg_frequency: float = 1.0  # synthetic360: multiplies the spatial frequency of floor, wall and clutter textures
    clutter: int = 10  # synthetic360: textured objects without text around the room
    exposure_sd: float = 0.0  # per-view exposure: sd of the gain in stops (gain 2 ** N(0, sd))
    white_balance_sd: float = 0.0  # per-view white balance: sd of the log gain of red and of blue (green fixed)
    vignetting: float = 0.0  # gain 1 - v r^2 with r = 1 at the image corners (0.3: corners 30 % darker)
    noise_sigma: float = 0.0  # additive Gaussian sensor noise, sd in 8-bit levels
    defocus_px: float = 0.0  # Gaussian defocus blur of every view, sd in pixels
    motion_blur_px: float = 0.0  # linear motion blur, length uniform in [0, this] pixels per view, random direction

    def __post_init__(self):
        if self.width < 32 or self.height < 24:
            raise DatasetError(f"synthetic image size {self.width}x{self.height} is too small", hint="use at least 32x24")
        if not 8 <= self.n_views <= 400:
            raise DatasetError(f"n_views={self.n_views} is out of range", hint="use 8..400 views (default 48)")
        if self.supersample < 1:
            raise DatasetError("supersample must be >= 1", hint="use 2 or 3")
        if not 0.5 <= self.room_scale <= 6:
            raise DatasetError(f"room_scale={self.room_scale} is out of range", hint="use 0.5..6 (1: the default room)")
        if self.text_px is not None:
            tp = tuple(float(v) for v in self.text_px)
            if len(tp) != 2 or not (2 <= tp[0] <= tp[1] <= self.width / 4):
                raise DatasetError(f"text_px={self.text_px} is not a (lo, hi) pair with 2 <= lo <= hi <= width/4",
                                   hint="e.g. text_px=(7, 20) at 320 px width")
            object.__setattr__(self, "text_px", tp)
        if not 0.1 <= self.bg_frequency <= 10:
            raise DatasetError(f"bg_frequency={self.bg_frequency} is out of range", hint="use 0.1..10 (1: default)")
        if not 0 <= self.clutter <= 60:
            raise DatasetError(f"clutter={self.clutter} is out of range", hint="use 0..60 objects (default 10)")
        for name in ("exposure_sd", "white_balance_sd", "noise_sigma", "defocus_px", "motion_blur_px"):
            if not getattr(self, name) >= 0:
                raise DatasetError(f"{name}={getattr(self, name)} must be >= 0", hint="0 turns the effect off")
        if not 0 <= self.vignetting < 1:
            raise DatasetError(f"vignetting={self.vignetting} is out of range", hint="use 0..0.9 (0: none)")

    def key(self, scene: str) -> str:
        # Difficulty controls at their defaults are left out, so scenes built before they existed keep their key.
        fields = asdict(self)
        for name in DIFFICULTY_FIELDS:
            if fields[name] == _DEFAULTS[name]:
                del fields[name]
        extra = {"multiscript_version": MULTISCRIPT_VERSION} if scene in SCENE_NAMES_MULTI else {}
        blob = json.dumps({"version": GENERATOR_VERSION, "scene": scene, **extra, **fields}, sort_keys=True)
        return hashlib.sha256(blob.encode()).hexdigest()[:12]

    def photometric(self) -> bool:
        """Whether any per-view photometric or sensor effect is on."""
        return any(getattr(self, n) != _DEFAULTS[n] for n in PHOTOMETRIC_FIELDS)

    def room_params(self) -> RoomParams:
        """The synthetic360 scene parameters these settings ask for."""
        text_px = self.text_px if self.text_px is not None else tuple(v * self.width / 320 for v in DEFAULT_TEXT_PX)
        return RoomParams(room_scale=self.room_scale, text_px=text_px, width=self.width, bg_frequency=self.bg_frequency,
                          clutter=self.clutter)


CONTENT_FIELDS = ("room_scale", "text_px", "bg_frequency", "clutter")
PHOTOMETRIC_FIELDS = ("exposure_sd", "white_balance_sd", "vignetting", "noise_sigma", "defocus_px", "motion_blur_px")
DIFFICULTY_FIELDS = CONTENT_FIELDS + PHOTOMETRIC_FIELDS
_DEFAULTS = {f.name: f.default for f in fields(SyntheticSettings)}


def check_scene_name(scene: str) -> None:
    if scene not in BUILDERS and scene not in BUILDERS_360 and scene not in SCENE_NAMES_MULTI:
        raise DatasetError(f"unknown synthetic scene {scene!r}",
                           hint=f"synthetic scenes: {', '.join(SCENE_NAMES)}; synthetic360: {', '.join(SCENE_NAMES_360)}; "
                                f"synthetic-multi: {', '.join(SCENE_NAMES_MULTI)}")


def scene_dir(scene: str, settings: SyntheticSettings | None = None) -> Path:
    """Where the scene's cache folder is (whether or not it has been built)."""
    check_scene_name(scene)
    settings = settings or SyntheticSettings()
    return cache_root() / "synthetic" / f"{scene}-{settings.key(scene)}"


def is_built(scene: str, settings: SyntheticSettings | None = None) -> bool:
    """Whether the scene's cache folder is complete (its meta file, and every file it lists at its size)."""
    return intact_problem(scene_dir(scene, settings)) is None


def _file_sizes(folder: Path) -> dict[str, int]:
    return {str(p.relative_to(folder)): p.stat().st_size for p in sorted(folder.rglob("*"))
            if p.is_file() and p.name != META_FILE}


def intact_problem(folder: Path) -> str | None:
    """None when `folder` is a complete scene build, else what is wrong with it."""
    meta_path = Path(folder) / META_FILE
    if not meta_path.is_file():
        return f"{meta_path} is missing (the build did not finish)"
    try:
        files = json.loads(meta_path.read_text(encoding="utf-8")).get("files")
    except (OSError, ValueError, AttributeError) as exc:
        return f"{meta_path} is unreadable: {exc}"
    if files is None:
        return None  # built before the file list was recorded: trusted as before
    if not isinstance(files, dict):
        return f"{meta_path} has a malformed file list"
    for rel, size in files.items():
        p = Path(folder) / rel
        if not p.is_file():
            return f"{p} is missing"
        if p.stat().st_size != size:
            return f"{p} has {p.stat().st_size} bytes, the build wrote {size}"
    return None


def read_meta(path: str | Path) -> dict:
    p = Path(path) / META_FILE
    try:
        return json.loads(p.read_text())
    except (OSError, ValueError) as exc:
        raise DatasetError(f"cannot read {p}: {exc}", hint="delete the folder and run `strings-bench datasets prepare` again") from exc


def build_scene(scene: str, settings: SyntheticSettings | None = None, force: bool = False,
                progress: bool = True) -> Path:
    """Build (or reuse from the cache) one synthetic scene and return its folder."""
    settings = settings or SyntheticSettings()
    final = scene_dir(scene, settings)
    sweep_stale_temps(final.parent)  # build folders of killed processes
    if final.exists() and not force:
        problem = intact_problem(final)
        if problem is None:
            _record_rho(final, scene, settings, only_if_missing=True)  # a record of an older measurement is redone
            return final
        log.warning("synthetic/%s: the cached scene is incomplete (%s); rebuilding it", scene, problem)
        shutil.rmtree(final, ignore_errors=True)  # not ours to trust
    tmp = final.parent / f".build-{final.name}-~{writer_tag()}-{uuid.uuid4().hex[:6]}"
    tmp.mkdir(parents=True)
    try:
        _build_into(scene, settings, tmp, progress)
        _record_rho(tmp, scene, settings)
        if final.exists():
            if not force:  # another process finished first: keep its copy
                shutil.rmtree(tmp, ignore_errors=True)
                return final
            shutil.rmtree(final)
        os.rename(tmp, final)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return final


def _record_rho(folder: Path, scene: str, settings: SyntheticSettings, only_if_missing: bool = False) -> None:
    """Keep the built scene's rho in its record (difficulty.json; scene/difficulty.py), its strokes measured on the
    words rendered again finer (`rho.rendered_difficulty`). The scene itself is complete without it: a failed
    measurement is logged and left to the next use."""
    from strings_bench.scene.difficulty import read_difficulty, write_difficulty
    from strings_bench.scene.scene import Scene

    if only_if_missing and read_difficulty(folder) is not None:
        return
    try:
        write_difficulty(folder, synthetic_difficulty(scene, settings, Scene.load(folder).extent))
    except Exception as exc:  # a property for the record: never worth a failed build
        log.warning("rho of synthetic/%s not measured: %s", scene, exc)


def ensure_rho_record(folder: Path) -> None:
    """For a synthetic scene folder of the suite's cache named directly (`run --datasets FOLDER`, a room built with
    other settings): its record of rho as `build_scene` keeps it (the settings read from its scene_meta.json).
    Anything else is left to the scene layer's measurement on the images."""
    folder = Path(folder)
    try:
        folder.resolve().relative_to(cache_root().resolve())
        meta = json.loads((folder / META_FILE).read_text())
        if str(meta["generator_version"]) != str(GENERATOR_VERSION):
            return  # built by another generator: this one would render another world
        settings = meta["settings"]
        settings = SyntheticSettings(**{**settings, "text_px": None if settings.get("text_px") is None
                                        else tuple(settings["text_px"])})
        scene = meta["scene"]
    except (ValueError, OSError, KeyError, TypeError, DatasetError):
        return
    _record_rho(folder, scene, settings, only_if_missing=True)


def synthetic_difficulty(scene: str, settings: SyntheticSettings, extent: float, views=None):
    """rho of synthetic `scene` built with `settings`, its words re-rendered finer (`rho.rendered_difficulty`) over
    `views` (default: every view); `extent` the built scene's."""
    spec = make_spec(scene, settings.seed, settings)
    cams = orbit_cameras(spec, settings, np.random.default_rng([settings.seed, 2]))
    return rendered_difficulty(spec, cams, lambda cam: visible_words(spec, cam, settings), settings.supersample,
                               extent, views)


# ---- cameras -------------------------------------------------------------------------------
def look_at(center: np.ndarray, target: np.ndarray, up=(0.0, 0.0, 1.0)) -> tuple[np.ndarray, np.ndarray]:
    """World-to-camera (R, t) for a camera at `center` looking at `target` (x right, y down, z forward)."""
    f = np.asarray(target, np.float64) - center
    f = vec3.unit(f)
    r = vec3.unit(np.cross(f, up))
    down = np.cross(f, r)
    R = np.stack([r, down, f])
    return R, -vec3.matvec(R, center)


def orbit_cameras(spec: SceneSpec, settings: SyntheticSettings, rng: np.random.Generator) -> list[Camera]:
    """A full orbit with gently varying elevation and distance, small jitter from the seed."""
    n, w, h = settings.n_views, settings.width, settings.height
    fx = 0.5 * w / np.tan(np.deg2rad(spec.fov_x) / 2)
    az0 = rng.uniform(0, 2 * np.pi)
    ph_e, ph_r = rng.uniform(0, 2 * np.pi, size=2)
    e_lo, e_hi = np.deg2rad(spec.elevation[0]), np.deg2rad(spec.elevation[1])
    cams = []
    for i in range(n):
        az = az0 + 2 * np.pi * i / n + rng.uniform(-0.2, 0.2) * 2 * np.pi / n
        el = e_lo + (e_hi - e_lo) * (0.5 + 0.5 * np.sin(4 * np.pi * i / n + ph_e))
        rad = spec.radius * (1 + 0.06 * np.sin(6 * np.pi * i / n + ph_r))
        center = spec.target + rad * np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
        target = spec.target + rng.normal(0, spec.target_jitter, 3)
        R, t = look_at(center, target)
        cams.append(Camera(fx, fx, w / 2, h / 2, w, h, R, t, name=f"view_{i:03d}.png"))
    return cams


# ---- ground-truth text -------------------------------------------------------------------------
SAMPLE_FRACTIONS = (0.1, 0.5, 0.9)


def word_corners_3d(spec: SceneSpec) -> list[np.ndarray]:
    """(4, 3) world corners of every word's box (TL, TR, BR, BL as read), on its surface."""
    return [spec.world.primitives[w.prim].point(w.uv) for w in spec.words]


def _bilinear(corners: np.ndarray, a: float, b: float) -> np.ndarray:
    tl, tr, br, bl = corners
    return (1 - b) * ((1 - a) * tl + a * tr) + b * ((1 - a) * bl + a * br)


def visible_words(spec: SceneSpec, cam: Camera, settings: SyntheticSettings) -> list[KnownWord]:
    """Words of the scene that this camera sees whole: all 4 corners in the frame, the surface
    facing the camera at 9 sample points of the box, none of them occluded (a ray from the camera
    to each sample must not hit anything first), and a projected height >= min_word_px."""
    world = spec.world
    C = cam.center
    candidates, sample_pts = [], []
    for word in spec.words:
        prim = world.primitives[word.prim]
        corners = prim.point(word.uv)
        px, z = cam.project(corners)
        if not np.all(np.isfinite(px)) or np.any(z <= 0):
            continue
        if np.any(px[:, 0] < 0) or np.any(px[:, 0] > cam.width) or np.any(px[:, 1] < 0) or np.any(px[:, 1] > cam.height):
            continue
        height = 0.5 * (vec3.norm_2d(px[0] - px[3]) + vec3.norm_2d(px[1] - px[2]))
        if height < settings.min_word_px:
            continue
        suv = np.array([_bilinear(word.uv, a, b) for b in SAMPLE_FRACTIONS for a in SAMPLE_FRACTIONS])
        pts = prim.point(suv)
        _, normals = prim.surface(pts)
        to_cam = C - pts
        cos = vec3.dot(normals, to_cam) / vec3.norm(to_cam)
        if np.any(cos < settings.min_facing_cos):
            continue
        # The viewing angle and distance at the word's centre (the middle sample): recorded with the word.
        centre = prim.point(np.asarray([_bilinear(word.uv, 0.5, 0.5)]))
        _, n_c = prim.surface(centre)
        v = C - centre[0]
        dist = float(vec3.norm(v))
        angle = float(np.degrees(np.arccos(np.clip(abs(float(vec3.dot(n_c[0], v))) / (vec3.norm(n_c[0]) * dist), 0.0, 1.0))))
        candidates.append((word, px, angle, dist))
        sample_pts.append(pts)
    if not candidates:
        return []
    pts = np.concatenate(sample_pts)
    t = world.first_hit(C, pts - C)  # t = 1 at the sample itself
    free = (t >= 1 - 1e-4).reshape(len(candidates), -1).all(axis=1)
    return [KnownWord(w.text, px, angle, dist, w.lang, w.script)
            for (w, px, angle, dist), ok in zip(candidates, free) if ok]


# ---- the build -------------------------------------------------------------------------------
def make_spec(scene: str, seed: int, settings: SyntheticSettings | None = None) -> SceneSpec:
    """The scene's content (geometry, textures, words) for `seed`; synthetic360 scenes also read the
    content controls of `settings` (room_scale, text_px, bg_frequency, clutter)."""
    check_scene_name(scene)
    settings = settings or SyntheticSettings()
    # The scene content and the orbit draw from separate streams of the same seed.
    rng = np.random.default_rng([seed, 1])
    if scene in BUILDERS_360:
        return BUILDERS_360[scene](rng, settings.room_params())
    changed = [n for n in CONTENT_FIELDS if getattr(settings, n) != _DEFAULTS[n]]
    if changed:
        raise DatasetError(f"{'synthetic-multi' if scene in SCENE_NAMES_MULTI else 'synthetic'}/{scene} has no setting "
                           f"{', '.join(changed)}",
                           hint=f"room size, text height, background frequency and clutter are controls of the "
                                f"synthetic360 scenes ({', '.join(SCENE_NAMES_360)}); the photometric ones apply to all")
    if scene in SCENE_NAMES_MULTI:
        check_fonts(scene)
        return build_multi(scene, rng)
    return BUILDERS[scene](rng)


def render_views(spec: SceneSpec, settings: SyntheticSettings, progress: bool = False, workers: int = 1):
    """Yield (camera, RenderResult, visible words) for every view of the orbit, in orbit order.

    With photometric controls on, RenderResult.rgb is the degraded photo and RenderResult.photometry
    the parameters drawn for the view; masks and words stay those of the clean render.

    workers > 1 renders views in that many fresh processes at once. Each worker rebuilds the scene
    with make_spec(spec.name, settings.seed, settings) (the content is a function of those), so give
    only specs made by make_spec; every view's pixels are the same as with one worker (each view's
    camera effects come from its own random stream)."""
    cams = orbit_cameras(spec, settings, np.random.default_rng([settings.seed, 2]))
    bar = tqdm(total=len(cams), desc=f"render {spec.name}", unit="view", disable=not progress, leave=False)
    try:
        if workers <= 1 or len(cams) < 2:
            for i, cam in enumerate(cams):
                res = _render_view(spec, settings, cam, i)
                bar.update(1)
                yield cam, res, visible_words(spec, cam, settings)
            return
        import multiprocessing
        from concurrent.futures import ProcessPoolExecutor

        # spawn: a fresh interpreter, so no thread pool of the parent (torch, numba, BLAS) is forked.
        pool = ProcessPoolExecutor(max_workers=min(workers, len(cams)), mp_context=multiprocessing.get_context("spawn"),
                                   initializer=_worker_init, initargs=(spec.name, settings))
        try:
            futures = [pool.submit(_worker_render, i) for i in range(len(cams))]
            for i, cam in enumerate(cams):
                res = futures[i].result()
                futures[i] = None  # the result is the caller's now: do not keep it here too
                bar.update(1)
                yield cam, res, visible_words(spec, cam, settings)
        finally:  # a caller that stops early (or an error) does not wait for the views not started
            pool.shutdown(wait=True, cancel_futures=True)
    finally:
        bar.close()


def _render_view(spec: SceneSpec, settings: SyntheticSettings, cam: Camera, i: int):
    res = spec.world.render(cam, settings.supersample)
    if settings.photometric():
        # Each view's camera effects from its own stream: the content and the path never move.
        rng = np.random.default_rng([settings.seed, 4, i])
        view = draw_view_photometry(settings, rng)
        res.rgb = apply_photometry(res.linear, view, rng)
        res.photometry = view
    return res


_WORKER: dict = {}  # in a render worker process: the scene, its settings and cameras


def _worker_init(scene: str, settings: SyntheticSettings) -> None:
    spec = make_spec(scene, settings.seed, settings)
    _WORKER.update(spec=spec, settings=settings,
                   cams=orbit_cameras(spec, settings, np.random.default_rng([settings.seed, 2])))


def _worker_render(i: int):
    res = _render_view(_WORKER["spec"], _WORKER["settings"], _WORKER["cams"][i], i)
    res.linear = None  # the build does not use it: 4 bytes a channel less to send back
    return res


# Rays per view from which views are rendered in parallel: below it, starting the workers (a fresh
# interpreter each, which rebuilds the scene's textures) costs more than it saves.
PARALLEL_RENDER_MIN_RAYS = 640 * 480 * 4
RENDER_WORKERS_ENV = "STRINGS_BENCH_RENDER_WORKERS"


def render_workers(settings: SyntheticSettings) -> int:
    """Processes that render a build's views: STRINGS_BENCH_RENDER_WORKERS when set, else the usable
    cores for views of at least PARALLEL_RENDER_MIN_RAYS rays (640x480 at 2x2 samples), else 1."""
    from strings_bench.core.cpus import usable_cores

    env = os.environ.get(RENDER_WORKERS_ENV, "").strip()
    if env:
        if not env.isdigit() or int(env) < 1:
            raise DatasetError(f"{RENDER_WORKERS_ENV}={env!r} is not a positive whole number",
                               hint="e.g. 8; unset it to use every core for large views")
        return int(env)
    rays = settings.width * settings.height * settings.supersample ** 2
    return usable_cores() if rays >= PARALLEL_RENDER_MIN_RAYS else 1


def _build_into(scene: str, settings: SyntheticSettings, out: Path, progress: bool) -> None:
    t_start = time.perf_counter()
    spec = make_spec(scene, settings.seed, settings)
    images_dir, masks_dir = out / "images", out / "masks"
    images_dir.mkdir()
    masks_dir.mkdir()
    cameras, depths, images, annotations, masks, photometry = [], [], [], {}, {}, {}
    t0 = time.perf_counter()
    for cam, res, words in render_views(spec, settings, progress, workers=render_workers(settings)):
        if res.photometry is not None:
            photometry[cam.name] = res.photometry.as_dict()
        Image.fromarray(res.rgb).save(images_dir / cam.name)
        stem = Path(cam.name).stem
        Image.fromarray((res.text_mask * 255).astype(np.uint8)).save(masks_dir / f"{stem}.png")
        cameras.append(cam)
        depths.append(res.depth)
        images.append(res.rgb)
        masks[cam.name] = res.text_mask
        annotations[cam.name] = words
    render_s = time.perf_counter() - t0
    write_annotations(out / "text_annotations.json", annotations)

    attempts = []
    fallback = None
    model = None
    bar = tqdm(total=2, desc=f"sfm {scene}", unit="attempt", disable=not progress, leave=False)
    for relaxed in (False, True):
        try:
            model, timings = triangulate_with_known_poses(images_dir, out / "_sfm", cameras, settings, relaxed=relaxed)
            attempts.append({"relaxed": relaxed, "points": model.num_points, **timings})
        except DatasetError:
            raise
        except Exception as exc:  # pycolmap raises RuntimeError/ValueError on failed stages
            attempts.append({"relaxed": relaxed, "error": f"{type(exc).__name__}: {exc}"})
            model = None
        bar.update(1)
        if model is not None and model.num_points >= settings.min_points:
            break
    bar.close()
    if model is None or model.num_points < settings.min_points:
        got = 0 if model is None else model.num_points
        log.warning("synthetic/%s: SfM triangulated only %d points (< %d) even with relaxed settings; FALLING BACK to "
                    "points sampled from the rendered depth maps. This scene's point cloud is not SfM-like; see "
                    "scene_meta.json", scene, got, settings.min_points)
        fallback = "depth_samples"
        model = depth_sample_points(cameras, depths, images, max(4 * settings.min_points, 2000),
                                    np.random.default_rng([settings.seed, 3]))
    shutil.rmtree(out / "_sfm", ignore_errors=True)
    write_model(model, out / "sparse" / "0")
    n_text = count_text_points(model, masks)
    sfm_s = sum(a.get("features_s", 0) + a.get("matching_s", 0) + a.get("triangulation_s", 0) for a in attempts)
    counts = model.visibility_counts()
    n_words = [len(v) for v in annotations.values()]
    heights = [0.5 * (vec3.norm_2d(w.polygon[0] - w.polygon[3]) + vec3.norm_2d(w.polygon[1] - w.polygon[2]))
               for v in annotations.values() for w in v]
    meta = {
        "generator_version": GENERATOR_VERSION,
        "scene": scene,
        "description": spec.description,
        "settings": asdict(settings),
        "key": settings.key(scene),
        "views": len(cameras),
        "registered_views": len(model.cameras),
        "points": model.num_points,
        "text_points": n_text,
        "mean_track_length": float(counts.mean()) if len(counts) else 0.0,
        "words_in_scene": len(spec.words),
        "visible_words_per_view": {"mean": float(np.mean(n_words)), "min": int(np.min(n_words)), "max": int(np.max(n_words))},
        "text_pixel_fraction": float(np.mean([m.mean() for m in masks.values()])),
        "word_height_px": ({"p10": float(np.percentile(heights, 10)), "median": float(np.median(heights)),
                            "p90": float(np.percentile(heights, 90))} if heights else None),
        "text_px": list(settings.room_params().text_px) if scene in BUILDERS_360 else None,
        **({"language": WORDS[scene].lang, "script": scene_script(scene)} if scene in SCENE_NAMES_MULTI else {}),
        "photometry": photometry or None,
        "fallback": fallback,
        "sfm_attempts": attempts,
        "timings_s": {"render": render_s, "sfm": sfm_s, "total": time.perf_counter() - t_start},
        "cpu_count": os.cpu_count(),
        "files": _file_sizes(out),  # checked on reuse (intact_problem)
    }
    atomic_write_json(out / META_FILE, meta)


def settings_with(**overrides) -> SyntheticSettings:
    """Default settings with some fields replaced (None values are ignored)."""
    return replace(SyntheticSettings(), **{k: v for k, v in overrides.items() if v is not None})
