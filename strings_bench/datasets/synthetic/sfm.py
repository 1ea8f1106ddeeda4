"""The synthetic scenes' SfM: pycolmap's SIFT features and matches on the rendered views, triangulated with the
known poses (`triangulate_with_known_poses`), points sampled from the rendered depth where SfM finds too few
(`depth_sample_points`), and the count of points on text (`count_text_points`). Step 3 of generate.py's pipeline.
"""

from __future__ import annotations

import logging
import time
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from strings_bench.core import vec3
from strings_bench.core.errors import DatasetError
from strings_bench.scene.camera import Camera
from strings_bench.scene.colmap import ColmapModel, in_canonical_order, read_model

# `settings` below is generate.py's SyntheticSettings (its SfM fields: max_features, match_overlap, seed, ...),
# named in annotations only: generate.py imports this module.

log = logging.getLogger(__name__)


@contextmanager
def _quiet_colmap():
    import pycolmap

    old = pycolmap.logging.minloglevel
    pycolmap.logging.minloglevel = 2  # errors only; COLMAP logs every image at INFO
    try:
        yield
    finally:
        pycolmap.logging.minloglevel = old


def _write_pairs(path: Path, names: list[str], overlap: int) -> int:
    """Circular sequential pairs: the orbit closes, so the last views are matched with the first."""
    n = len(names)
    pairs = {tuple(sorted((i, (i + k) % n))) for i in range(n) for k in range(1, min(overlap, n - 1) + 1)}
    path.write_text("".join(f"{names[i]} {names[j]}\n" for i, j in sorted(pairs)))
    return len(pairs)




def triangulate_with_known_poses(images_dir: Path, work: Path, cameras: list[Camera], settings: SyntheticSettings,
                                 relaxed: bool = False) -> tuple[ColmapModel, dict]:
    """SIFT features, matching and pycolmap.triangulate_points with the known cameras, each on one thread. Returns
    the triangulated model, its tracks and points in canonical order (scene/colmap.py, in_canonical_order), and stage
    timings.

    Why one thread everywhere: with the features extracted on two, or the triangulation run on two, the default
    run's room (3 304 points) came out with the same tracks but other last bits of coordinates (up to 7e-15, in 51
    points) from build to build. Matching on two threads gave the same 3 304 points on a loaded machine (load 8-26),
    but on an idle one (load 0.4) the same images gave 3 293 points (likely: the matches reach the database in the
    order the threads finish, and the triangulation follows that order; not traced further). On one thread the
    order is the pairs' own; it costs about 2 s of a room's build on 2 cores. The canonical order removes what is left; the thread count stays out of the cache
    key."""
    import pycolmap

    work.mkdir(parents=True, exist_ok=True)
    db = work / "database.db"
    db.unlink(missing_ok=True)
    names = [c.name for c in cameras]
    cam0 = cameras[0]
    timings = {}
    with _quiet_colmap():
        t0 = time.perf_counter()
        reader = pycolmap.ImageReaderOptions()
        reader.camera_model = "PINHOLE"
        reader.camera_params = f"{cam0.fx},{cam0.fy},{cam0.cx},{cam0.cy}"
        extraction = pycolmap.FeatureExtractionOptions()
        extraction.num_threads = 1  # see above: on two threads the points' last bits varied from build to build
        extraction.sift.max_num_features = settings.max_features * (2 if relaxed else 1)
        pycolmap.extract_features(db, images_dir, image_names=names, camera_mode=pycolmap.CameraMode.SINGLE,
                                  reader_options=reader, extraction_options=extraction, device=pycolmap.Device.cpu)
        timings["features_s"] = time.perf_counter() - t0

        t0 = time.perf_counter()
        pairs_file = work / "pairs.txt"
        n_pairs = _write_pairs(pairs_file, names, settings.match_overlap + (4 if relaxed else 0))
        matching = pycolmap.FeatureMatchingOptions()
        matching.num_threads = 1  # see above: on two threads an idle machine gave other points
        pairing = pycolmap.ImportedPairingOptions()
        pairing.match_list_path = str(pairs_file)
        verification = pycolmap.TwoViewGeometryOptions()
        verification.ransac.random_seed = settings.seed
        pycolmap.match_image_pairs(db, matching_options=matching, pairing_options=pairing,
                                   verification_options=verification, device=pycolmap.Device.cpu)
        timings["matching_s"] = time.perf_counter() - t0
        timings["pairs"] = n_pairs

        t0 = time.perf_counter()
        database = pycolmap.Database.open(str(db))
        try:
            db_images = {im.name: im for im in database.read_all_images()}
        finally:
            database.close()
        missing = [n for n in names if n not in db_images]
        if missing:
            raise DatasetError(f"pycolmap did not import {len(missing)} rendered image(s) ({missing[:3]})",
                               hint="the render or the PNG write failed; delete the cache folder and retry")
        rec = pycolmap.Reconstruction()
        for cam in cameras:
            im = db_images[cam.name]
            if im.camera_id not in rec.cameras:
                rec.add_camera_with_trivial_rig(pycolmap.Camera(
                    camera_id=im.camera_id, model="PINHOLE", width=cam.width, height=cam.height,
                    params=[cam.fx, cam.fy, cam.cx, cam.cy]))
            image = pycolmap.Image(name=cam.name, camera_id=im.camera_id, image_id=im.image_id)
            rec.add_image_with_trivial_frame(image, pycolmap.Rigid3d(np.hstack([cam.R, cam.t[:, None]])))
        options = pycolmap.IncrementalPipelineOptions()
        options.num_threads = 1  # see above: one thread, the same points from build to build
        options.random_seed = settings.seed
        if relaxed:
            options.triangulation.min_angle = 1.0
            options.triangulation.ignore_two_view_tracks = False
        out = work / "triangulated"
        out.mkdir(exist_ok=True)
        rec = pycolmap.triangulate_points(rec, db, images_dir, out, clear_points=True, options=options)
        timings["triangulation_s"] = time.perf_counter() - t0
    model = in_canonical_order(read_model(out))
    _check_poses_kept(model, cameras)
    return model, timings


def _check_poses_kept(model: ColmapModel, cameras: list[Camera]) -> None:
    by_name = {c.name: c for c in cameras}
    if len(model.cameras) != len(cameras):
        raise DatasetError(f"triangulation registered {len(model.cameras)} of {len(cameras)} views",
                           hint="this is a generator bug; report it with the scene name and settings")
    for cam in model.cameras:
        ref = by_name[cam.name]
        if not (np.allclose(cam.R, ref.R, atol=1e-6) and np.allclose(cam.t, ref.t, atol=1e-6)):
            raise DatasetError(f"triangulation moved the known pose of {cam.name}",
                               hint="this is a generator bug; report it with the scene name and settings")


def depth_sample_points(cameras: list[Camera], depths: list[np.ndarray], images: list[np.ndarray],
                        n_target: int, rng: np.random.Generator) -> ColmapModel:
    """FALLBACK ONLY (SfM failed): points sampled from the rendered depth maps, with tracks of the
    views where each point is in frame and not occluded (its depth agrees with that view's map)."""
    per_view = max(1, n_target // max(1, len(cameras) // 4))
    xyz, rgb = [], []
    for v in range(0, len(cameras), 4):
        cam, depth = cameras[v], depths[v]
        ys, xs = np.nonzero(np.isfinite(depth) & (depth < 6.0))  # not the far backdrop
        if len(ys) == 0:
            continue
        pick = rng.choice(len(ys), size=min(per_view, len(ys)), replace=False)
        ys, xs = ys[pick], xs[pick]
        z = depth[ys, xs]
        pc = np.stack([(xs + 0.5 - cam.cx) / cam.fx * z, (ys + 0.5 - cam.cy) / cam.fy * z, z], axis=1)
        xyz.append(vec3.vecmat(pc - cam.t, cam.R))  # R^T (x - t), as row vectors
        rgb.append(images[v][ys, xs])
    xyz = np.concatenate(xyz) if xyz else np.zeros((0, 3))
    rgb = np.concatenate(rgb) if rgb else np.zeros((0, 3), np.uint8)
    obs_view = [[] for _ in range(len(xyz))]
    obs_xy = [[] for _ in range(len(xyz))]
    for v, cam in enumerate(cameras):
        px, z = cam.project(xyz)
        ok = np.isfinite(px).all(1) & (px[:, 0] >= 0) & (px[:, 0] < cam.width) & (px[:, 1] >= 0) & (px[:, 1] < cam.height)
        idx = np.nonzero(ok)[0]
        d = depths[v][px[idx, 1].astype(int), px[idx, 0].astype(int)]
        for i in idx[np.abs(d - z[idx]) < 0.01 * z[idx]]:
            obs_view[i].append(v)
            obs_xy[i].append(px[i])
    keep = [i for i in range(len(xyz)) if len(obs_view[i]) >= 2]
    ptr = np.concatenate([[0], np.cumsum([len(obs_view[i]) for i in keep])]).astype(np.int64)
    return ColmapModel(
        cameras=cameras, xyz=xyz[keep], rgb=rgb[keep].astype(np.uint8), track_ptr=ptr,
        track_view=np.array([v for i in keep for v in obs_view[i]], np.int32),
        track_xy=np.array([p for i in keep for p in obs_xy[i]], np.float64).reshape(-1, 2),
        point_ids=np.arange(1, len(keep) + 1, dtype=np.int64))


def count_text_points(model: ColmapModel, masks: dict[str, np.ndarray]) -> int:
    """Points that project inside the GT text mask of at least one view of their track
    (Algorithm 1 of STRinGS with tau = 1, on the undilated GT masks)."""
    index = {c.name: i for i, c in enumerate(model.cameras)}
    hits = np.zeros(model.num_points, bool)
    point_of_obs = np.repeat(np.arange(model.num_points), np.diff(model.track_ptr))
    for name, mask in masks.items():
        v = index[name]
        sel = np.nonzero(model.track_view == v)[0]
        if len(sel) == 0:
            continue
        pts = point_of_obs[sel]
        cam = model.cameras[v]
        px, z = cam.project(model.xyz[pts])
        ok = np.isfinite(px).all(1) & (z > 0) & (px[:, 0] >= 0) & (px[:, 0] < cam.width) & (px[:, 1] >= 0) & (px[:, 1] < cam.height)
        pts, px = pts[ok], px[ok]
        inside = mask[px[:, 1].astype(int), px[:, 0].astype(int)]
        hits[pts[inside]] = True
    return int(hits.sum())
