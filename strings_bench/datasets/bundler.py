"""A scene from a Bundler reconstruction (`cameras.out` / `bundle.out`, Bundle file v0.3): the cameras and
points are given, so they are converted to a COLMAP model and no structure from motion is run.

Bundler's conventions (Snavely's Bundler manual): a camera is `f k1 k2`, a rotation R and a translation t;
a world point X is seen at P = R X + t, p = -P / P_z, p' = f (1 + k1 |p|^2 + k2 |p|^4) p, in pixels from
the image centre with y pointing up (the camera looks down -z). COLMAP's camera looks down +z with y
pointing down, so R_colmap = diag(1, -1, -1) R and t_colmap = diag(1, -1, -1) t, and the camera is
COLMAP's RADIAL model (f, cx, cy, k1, k2: the same distortion on p) with the principal point at the image
centre; a keypoint (x, y) is the pixel (x + w/2, h/2 - y). Cameras with f = 0 were not reconstructed and
are left out, with their images.

Bundler works on the stored pixels; photos whose EXIF orientation turns them are written upright and
their cameras turned with them (a 90-degree turn of the image is a turn of the camera about its axis),
so OCR and every method see upright text. Then the stages of `sfm.prepare_scene` after mapping follow:
undistortion to PINHOLE, images_2/ and images_4/, OCR text masks.
"""

from __future__ import annotations

import shutil
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np
from PIL import Image, ImageOps
from tqdm import tqdm

from strings_bench.core import vec3
from strings_bench.core.errors import DatasetError
from strings_bench.core.io import atomic_write_json

BUNDLER_TO_COLMAP = np.diag([1.0, -1.0, -1.0])


@dataclass
class BundlerModel:
    focal: np.ndarray  # (N,) f per camera (0: not reconstructed)
    k: np.ndarray  # (N, 2) k1, k2
    R: np.ndarray  # (N, 3, 3)
    t: np.ndarray  # (N, 3)
    xyz: np.ndarray  # (M, 3)
    rgb: np.ndarray  # (M, 3) uint8
    tracks: list[np.ndarray]  # per point: (K, 4) camera index, key index, x, y


def read_bundler(path: str | Path) -> BundlerModel:
    """Parse a Bundle v0.3 file (cameras.out / bundle.out)."""
    path = Path(path)
    try:
        lines = [ln for ln in path.read_text().splitlines() if ln.strip() and not ln.startswith("#")]
        n, m = (int(v) for v in lines[0].split())
        pos = 1
        focal, k, R, t = [], [], [], []
        for _ in range(n):
            f, k1, k2 = (float(v) for v in lines[pos].split())
            rot = np.array([[float(v) for v in lines[pos + j].split()] for j in (1, 2, 3)])
            tr = np.array([float(v) for v in lines[pos + 4].split()])
            focal.append(f), k.append((k1, k2)), R.append(rot), t.append(tr)
            pos += 5
        xyz, rgb, tracks = [], [], []
        for _ in range(m):
            xyz.append([float(v) for v in lines[pos].split()])
            rgb.append([int(v) for v in lines[pos + 1].split()])
            v = lines[pos + 2].split()
            tracks.append(np.array(v[1:], dtype=np.float64).reshape(int(v[0]), 4))
            pos += 3
    except (OSError, ValueError, IndexError) as exc:
        raise DatasetError(f"cannot read Bundler file {path}: {type(exc).__name__}: {exc}",
                           hint="expected a Bundle file v0.3 (header line, 'N M', N cameras of 5 lines, M points of 3)") from exc
    rot = np.array(R).reshape(-1, 3, 3)
    if rot.shape[0] != n or len(xyz) != m:
        raise DatasetError(f"Bundler file {path} holds {rot.shape[0]} cameras and {len(xyz)} points, its header says {n} and {m}",
                           hint="the file is truncated")
    return BundlerModel(np.array(focal), np.array(k).reshape(-1, 2), rot, np.array(t).reshape(-1, 3),
                        np.array(xyz).reshape(-1, 3), np.clip(np.array(rgb), 0, 255).astype(np.uint8).reshape(-1, 3), tracks)


def image_list(src: Path, n: int) -> list[str]:
    """The image file of each Bundler camera: list.txt (Bundler's own: 'path [0 f]' per line) or
    ordered_filenames.txt (optionally led by the count), names relative to images/ (or to the folder)."""
    for name in ("list.txt", "ordered_filenames.txt"):
        p = src / name
        if p.is_file():
            names = [ln.split()[0] for ln in p.read_text().splitlines() if ln.strip()]
            if names and names[0].isdigit() and int(names[0]) == len(names) - 1:
                names = names[1:]  # a count first (the PhotogrammetryCourse layout)
            break
    else:
        raise DatasetError(f"{src} has no list.txt or ordered_filenames.txt naming the image of each camera",
                           hint="Bundler's list.txt, one image path per camera in camera order")
    if len(names) != n:
        raise DatasetError(f"{p} names {len(names)} images for {n} cameras", hint="one image per camera, in camera order")
    return [Path(x).name for x in names]


# EXIF orientation -> (upright pixel of a stored pixel (u, v) in a w x h image, camera-frame rotation Q with
# x_upright = Q x_stored). PIL's exif_transpose: 3 turns 180 degrees, 6 clockwise (ROTATE_270), 8
# anticlockwise (ROTATE_90).
def _orient(orientation: int, w: float, h: float):
    if orientation in (0, 1):
        return (lambda u, v: (u, v)), np.eye(3), (w, h)
    if orientation == 3:
        return (lambda u, v: (w - u, h - v)), np.diag([-1.0, -1.0, 1.0]), (w, h)
    if orientation == 6:
        return (lambda u, v: (h - v, u)), np.array([[0.0, -1, 0], [1, 0, 0], [0, 0, 1]]), (h, w)
    if orientation == 8:
        return (lambda u, v: (v, w - u)), np.array([[0.0, 1, 0], [-1, 0, 0], [0, 0, 1]]), (h, w)
    raise DatasetError(f"EXIF orientation {orientation} (mirrored) is not supported", hint="store the photos unmirrored")


def bundler_reconstruction(model: BundlerModel, names: list[str], sizes: list[tuple[int, int]], orientations: list[int]):
    """A pycolmap.Reconstruction of the Bundler model, in the upright images' frame: one RADIAL camera per
    image, the given poses, the points with their tracks (observations of left-out cameras dropped; points
    seen fewer than twice dropped)."""
    import pycolmap

    rec = pycolmap.Reconstruction()
    keep: dict[int, int] = {}  # Bundler camera index -> COLMAP image id
    maps = {}
    for i, (name, (w, h), o) in enumerate(zip(names, sizes, orientations)):
        if not model.focal[i] > 0:
            continue
        to_upright, Q, (W, H) = _orient(o, w, h)
        cam_id = image_id = len(keep) + 1
        keep[i] = image_id
        f = float(model.focal[i])
        rec.add_camera_with_trivial_rig(pycolmap.Camera(camera_id=cam_id, model="RADIAL", width=int(W), height=int(H),
                                                        params=[f, W / 2, H / 2, *map(float, model.k[i])]))
        flip = vec3.matmul(Q, BUNDLER_TO_COLMAP)
        R = vec3.matmul(flip, model.R[i])
        t = vec3.matvec(flip, model.t[i])
        maps[i] = (to_upright, w, h, cam_id, image_id, R, t, name)
    kp: dict[int, list] = {i: [] for i in keep}
    point_obs = []
    for p, track in enumerate(model.tracks):
        els = []
        for cam, _key, x, y in track:
            cam = int(cam)
            if cam not in keep:
                continue
            to_upright, w, h = maps[cam][:3]
            u, v = to_upright(x + w / 2, h / 2 - y)
            els.append((cam, len(kp[cam])))
            kp[cam].append((u, v))
        point_obs.append(els)
    for i in keep:
        _, _, _, cam_id, image_id, R, t, name = maps[i]
        image = pycolmap.Image(name=name, keypoints=np.array(kp[i], np.float64).reshape(-1, 2), camera_id=cam_id,
                               image_id=image_id)
        rec.add_image_with_trivial_frame(image, pycolmap.Rigid3d(np.hstack([R, t[:, None]])))
    for p, els in enumerate(point_obs):
        if len({c for c, _ in els}) < 2:
            continue
        track = pycolmap.Track([pycolmap.TrackElement(keep[c], j) for c, j in els])
        rec.add_point3D(model.xyz[p], track, model.rgb[p])
    return rec, [names[i] for i in keep]


def prepare_bundler_scene(src: str | Path, name: str, out: str | Path | None = None, bundle_file: str | None = None,
                          max_size: int = 1600, masks: bool = True, ocr_backend: str = "rapidocr", overwrite: bool = False,
                          register: bool = True, progress: bool = True, echo: Callable[[str], None] = print):
    """`src` (a folder with images/, a Bundler file and its image list) -> a registered scene folder."""
    import pycolmap

    from strings_bench.datasets.sfm import (PrepareResult, save_like, default_scene_dir, finish_scene, numbered_stages,
                                            publish_scene, register_scene, write_sparse_split)

    src = Path(src)
    bundle = src / bundle_file if bundle_file else next((src / n for n in ("bundle.out", "cameras.out") if (src / n).is_file()), None)
    if bundle is None or not bundle.is_file():
        raise DatasetError(f"no Bundler file in {src}", hint="expected bundle.out or cameras.out (Bundle file v0.3)")
    model = read_bundler(bundle)
    names = image_list(src, len(model.focal))
    img_dir = src / "images" if (src / "images").is_dir() else src
    missing = [n for n in names if not (img_dir / n).is_file()]
    if missing:
        raise DatasetError(f"{len(missing)} image(s) of {bundle} are missing from {img_dir}: {', '.join(missing[:5])}",
                           hint="the image list names the photo of each camera")
    scene_dir = (Path(out) if out is not None else default_scene_dir(name)).resolve()
    if scene_dir.exists() and not overwrite:
        raise DatasetError(f"{scene_dir} already exists", hint="pass --overwrite to rebuild it, or --out elsewhere")
    work = scene_dir.with_name(f".{scene_dir.name}.prepare-tmp")
    shutil.rmtree(work, ignore_errors=True)
    work.mkdir(parents=True)
    stages: dict[str, float] = {}
    stage = numbered_stages(4 if masks else 3, stages, echo)

    try:
        t = stage(f"convert the Bundler cameras of {len(names)} photos (no SfM)")
        raw = work / "input"
        raw.mkdir()
        sizes, orientations = [], []
        for n in tqdm(names, desc="upright", unit="img", disable=not progress):
            with Image.open(img_dir / n) as im:
                sizes.append(im.size)
                orientations.append(int(im.getexif().get(0x0112, 1) or 1))
                save_like(ImageOps.exif_transpose(im).convert("RGB"), raw / n)
        rec, kept = bundler_reconstruction(model, names, sizes, orientations)
        model_dir = work / "sparse_raw"
        model_dir.mkdir()
        rec.write(str(model_dir))
        for n in names:
            if n not in kept:
                (raw / n).unlink()
        stages["convert"] = time.perf_counter() - t
        scene_tmp, num_masks, num_text = finish_scene(model_dir, raw, work, max_size, masks, ocr_backend, progress, stage,
                                                      stages)
        final = pycolmap.Reconstruction(str(scene_tmp / "sparse" / "0"))
        result = PrepareResult(scene_dir=scene_dir, num_photos=len(names), num_registered=len(kept),
                               num_points=final.num_points3D(), num_models=1, matcher="none (Bundler cameras)",
                               stage_seconds=stages, num_masks=num_masks, num_masks_with_text=num_text,
                               unregistered=sorted(set(names) - set(kept)))
        split = write_sparse_split(scene_tmp)
        atomic_write_json(scene_tmp / "prepare.json", {**result.to_dict(), "photos_dir": str(src.resolve()), "split": split,
                                                       "bundler_file": str(bundle.resolve()), "max_size": max_size,
                                                       "exif_orientations": sorted(set(orientations))})
        publish_scene(scene_tmp, scene_dir)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    if register:
        register_scene(name, scene_dir)
    return result
