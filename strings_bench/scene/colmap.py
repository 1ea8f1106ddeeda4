"""COLMAP models in and out, through pycolmap.

Reading gives plain arrays (cameras per image, points, tracks) so that the rest of the suite never
touches pycolmap objects. PINHOLE and SIMPLE_PINHOLE cameras are used directly; distorted models
are refused with the command that undistorts them (`strings-bench prepare` or COLMAP's
image_undistorter). Writing, and the canonical order of points and tracks that makes an SfM result the same file
from build to build.

Size (~460 lines): one file format both ways, with the diagnosis of broken binary files record by record.
"""

from __future__ import annotations

import logging
import shutil
import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from strings_bench.scene.camera import Camera
from strings_bench.core.errors import DatasetError

log = logging.getLogger(__name__)

PINHOLE_MODELS = ("PINHOLE", "SIMPLE_PINHOLE")
MODEL_FILES = ("cameras", "images", "points3D")


@dataclass
class ColmapModel:
    """A COLMAP reconstruction as arrays.

    Views are sorted by image name. Tracks are stored compressed: the observations of point i are
    `track_view[track_ptr[i]:track_ptr[i+1]]` (indices into `cameras`) with pixel positions
    `track_xy[...]` at full resolution.
    """

    cameras: list[Camera]  # one per registered image, sorted by name; Camera.name = image name
    xyz: np.ndarray  # (M, 3) float64
    rgb: np.ndarray  # (M, 3) uint8
    track_ptr: np.ndarray  # (M + 1,) int64
    track_view: np.ndarray  # (T,) int32
    track_xy: np.ndarray  # (T, 2) float64
    point_ids: np.ndarray  # (M,) int64, COLMAP point3D ids

    @property
    def names(self) -> list[str]:
        return [c.name for c in self.cameras]

    @property
    def num_points(self) -> int:
        return int(self.xyz.shape[0])

    def visibility_counts(self) -> np.ndarray:
        return np.diff(self.track_ptr)


def in_canonical_order(model: ColmapModel) -> ColmapModel:
    """The same points and tracks in an order that does not depend on how SfM ran: COLMAP's multi-threaded
    triangulation stores a track's observations, and numbers its points, in the order its threads finished.
    Each track is sorted by (view, x, y) and the points by their sorted tracks (then by xyz); the points are
    numbered 1..M in that order. The cameras are kept as they are (sorted by name)."""
    n = model.num_points
    ptr, views, xy = model.track_ptr, model.track_view.tolist(), model.track_xy.tolist()
    tracks = [sorted(zip(views[ptr[i]:ptr[i + 1]], xy[ptr[i]:ptr[i + 1]])) for i in range(n)]
    xyz = model.xyz.tolist()
    order = sorted(range(n), key=lambda i: (tracks[i], xyz[i]))
    lengths = [len(tracks[i]) for i in order]
    return ColmapModel(
        cameras=model.cameras,
        xyz=model.xyz[order].reshape(n, 3),
        rgb=model.rgb[order].reshape(n, 3),
        track_ptr=np.concatenate([[0], np.cumsum(lengths, dtype=np.int64)]).astype(np.int64),
        track_view=np.array([v for i in order for v, _ in tracks[i]], np.int32),
        track_xy=np.array([p for i in order for _, p in tracks[i]], np.float64).reshape(-1, 2),
        point_ids=np.arange(1, n + 1, dtype=np.int64),
    )


def find_model_dir(path: str | Path) -> Path:
    """Accept a scene folder (with sparse/0 or sparse/) or the model folder itself."""
    path = Path(path)
    for cand in (path, path / "sparse" / "0", path / "sparse"):
        if cand.is_dir() and any((cand / f"{n}{ext}").exists() for n in MODEL_FILES for ext in (".bin", ".txt")):
            return cand
    raise DatasetError(
        f"no COLMAP model found in {path} (looked for cameras/images/points3D .bin or .txt in "
        f"{path}, {path / 'sparse' / '0'} and {path / 'sparse'})",
        hint="a scene folder needs images/ and sparse/0/; run `strings-bench prepare PHOTOS_DIR --name NAME` "
        "to make one from photos",
    )


def _check_model_files(model_dir: Path) -> None:
    for ext in (".bin", ".txt"):
        present = [n for n in MODEL_FILES if (model_dir / f"{n}{ext}").exists()]
        if len(present) == len(MODEL_FILES):
            return
        if present:
            missing = [f"{n}{ext}" for n in MODEL_FILES if n not in present]
            raise DatasetError(
                f"COLMAP model in {model_dir} is incomplete: missing {', '.join(missing)}",
                hint="copy the complete sparse/0 folder written by COLMAP",
            )
    raise DatasetError(f"no COLMAP model files in {model_dir}", hint="expected cameras, images and points3D (.bin or .txt)")


def _camera_intrinsics(cam, model_dir: Path) -> tuple[float, float, float, float]:
    model = cam.model.name
    p = np.asarray(cam.params, dtype=np.float64)
    if model == "PINHOLE":
        return float(p[0]), float(p[1]), float(p[2]), float(p[3])
    if model == "SIMPLE_PINHOLE":
        return float(p[0]), float(p[0]), float(p[1]), float(p[2])
    raise DatasetError(
        f"camera {cam.camera_id} in {model_dir} uses the distorted model {model}; the suite needs "
        f"undistorted PINHOLE or SIMPLE_PINHOLE cameras",
        hint="undistort first: `strings-bench prepare` does it, or run `colmap image_undistorter "
        "--image_path images --input_path sparse/0 --output_path undistorted --output_type COLMAP`",
    )


def read_model(path: str | Path) -> ColmapModel:
    """Read a binary or text COLMAP model (scene folder or model folder)."""
    import pycolmap

    model_dir = find_model_dir(path)
    _check_model_files(model_dir)
    # pycolmap can spend minutes on a truncated .bin before failing without naming the file;
    # a record-by-record walk of the binary layout names the file and the record at once.
    problems = diagnose_binary_model(model_dir) or diagnose_text_model(model_dir)
    if problems:
        raise DatasetError("corrupt COLMAP model: " + "; ".join(problems),
                           hint="re-export the model from COLMAP, or re-run `strings-bench prepare`; your files were not modified")
    try:
        rec = pycolmap.Reconstruction(str(model_dir))
    except Exception as exc:  # pycolmap raises ValueError/IndexError/MemoryError on corrupt files
        raise DatasetError(
            f"cannot read the COLMAP model in {model_dir}: {type(exc).__name__}: {exc} "
            f"(a file is truncated or corrupt)",
            hint="re-export the model from COLMAP, or re-run `strings-bench prepare`; your files were not modified",
        ) from exc

    problems = value_problems(rec, model_dir)
    if problems:
        raise DatasetError("invalid values in the COLMAP model: " + "; ".join(problems),
                           hint="re-export the model from COLMAP, or re-run `strings-bench prepare`; your files were not modified")
    reg = [im for im in rec.images.values() if im.has_pose]
    if not reg:
        raise DatasetError(f"the COLMAP model in {model_dir} has no registered images", hint="SfM failed; check the photos")
    reg.sort(key=lambda im: im.name)
    view_of_image = {}
    cameras = []
    for idx, im in enumerate(reg):
        cam = rec.cameras[im.camera_id]
        fx, fy, cx, cy = _camera_intrinsics(cam, model_dir)
        pose = im.cam_from_world()
        R = np.asarray(pose.rotation.matrix(), dtype=np.float64)
        t = np.asarray(pose.translation, dtype=np.float64)
        cameras.append(Camera(fx, fy, cx, cy, int(cam.width), int(cam.height), R, t, name=im.name))
        view_of_image[im.image_id] = idx

    point_ids = np.array(sorted(rec.points3D.keys()), dtype=np.int64)
    m = len(point_ids)
    xyz = np.zeros((m, 3))
    rgb = np.zeros((m, 3), dtype=np.uint8)
    ptr = np.zeros(m + 1, dtype=np.int64)
    views: list[int] = []
    xys: list[np.ndarray] = []
    for i, pid in enumerate(point_ids):
        p = rec.points3D[int(pid)]
        xyz[i] = p.xyz
        rgb[i] = p.color
        n = 0
        for el in p.track.elements:
            v = view_of_image.get(el.image_id)
            if v is None:
                continue
            views.append(v)
            xys.append(np.asarray(rec.images[el.image_id].points2D[el.point2D_idx].xy, dtype=np.float64))
            n += 1
        ptr[i + 1] = ptr[i] + n
    return ColmapModel(
        cameras=cameras,
        xyz=xyz,
        rgb=rgb,
        track_ptr=ptr,
        track_view=np.asarray(views, dtype=np.int32),
        track_xy=np.asarray(xys, dtype=np.float64).reshape(-1, 2),
        point_ids=point_ids,
    )


def model_file(model_dir: Path, stem: str) -> Path:
    """The file of `stem` (cameras, images, points3D) that pycolmap reads in `model_dir`: .bin when present."""
    binary = Path(model_dir) / f"{stem}.bin"
    return binary if binary.exists() else Path(model_dir) / f"{stem}.txt"


def _list_ids(ids: list, n: int = 5) -> str:
    return ", ".join(str(i) for i in ids[:n]) + (f" ... ({len(ids)} in all)" if len(ids) > n else "")


def value_problems(rec, model_dir: Path) -> list[str]:
    """Values no scene can use, each naming its file: non-finite or non-positive intrinsics and image
    sizes of the cameras registered images use, non-finite poses of registered images, non-finite point coordinates (a NaN would reach every
    Gaussian through the scene extent and the initial model)."""
    model_dir = Path(model_dir)
    problems = []
    bad_cams = []
    used = {im.camera_id for im in rec.images.values() if im.has_pose}  # COLMAP keeps cameras of dropped images
    for cam_id, cam in sorted(rec.cameras.items()):
        if cam_id not in used:
            continue
        params = np.asarray(cam.params, dtype=np.float64)
        if not np.all(np.isfinite(params)) or int(cam.width) <= 0 or int(cam.height) <= 0:
            bad_cams.append(cam_id)
        elif cam.model.name in PINHOLE_MODELS and np.any(params[: 2 if cam.model.name == "PINHOLE" else 1] <= 0):
            bad_cams.append(cam_id)
    if bad_cams:
        problems.append(f"{model_file(model_dir, 'cameras')}: camera(s) {_list_ids(bad_cams)} have a non-finite or "
                        f"non-positive focal length, principal point or image size")
    bad_poses = []
    for image_id, im in sorted(rec.images.items()):
        if not im.has_pose:
            continue
        pose = im.cam_from_world()
        values = np.concatenate([np.asarray(pose.rotation.quat, dtype=np.float64).ravel(),
                                 np.asarray(pose.translation, dtype=np.float64).ravel()])
        if not np.all(np.isfinite(values)) or not np.any(values[:4]):
            bad_poses.append(im.name)
    if bad_poses:
        problems.append(f"{model_file(model_dir, 'images')}: image(s) {_list_ids(bad_poses)} have a non-finite pose "
                        f"(NaN or Inf rotation or translation)")
    bad_points = [pid for pid, p in rec.points3D.items() if not np.all(np.isfinite(np.asarray(p.xyz, dtype=np.float64)))]
    if bad_points:
        problems.append(f"{model_file(model_dir, 'points3D')}: point(s) {_list_ids(sorted(bad_points))} have NaN or Inf "
                        f"coordinates")
    return problems


def write_model(model: ColmapModel, out_dir: str | Path, binary: bool = True) -> Path:
    """Write cameras, images and points3D (with 2D observations) as a COLMAP model.

    One PINHOLE camera per image, so that per-image intrinsics survive. The folder is written to
    a temporary sibling and renamed, so a crash never leaves half a model.
    """
    import pycolmap

    out_dir = Path(out_dir)
    tmp = out_dir.with_name(out_dir.name + ".tmp-write")
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir(parents=True)

    rec = pycolmap.Reconstruction()
    counts = model.visibility_counts()
    # Observations per view, in point order, give each image its points2D list.
    # Keyed by track element k: COLMAP tracks may observe a point twice in one image.
    obs_of_view: list[list[tuple[int, np.ndarray]]] = [[] for _ in model.cameras]
    for k in range(len(model.track_view)):
        obs_of_view[model.track_view[k]].append((k, model.track_xy[k]))

    point2d_index: dict[int, int] = {}
    for v, cam in enumerate(model.cameras):
        cam_id = image_id = v + 1
        rec.add_camera_with_trivial_rig(
            pycolmap.Camera(
                camera_id=cam_id,
                model="PINHOLE",
                width=cam.width,
                height=cam.height,
                params=[cam.fx, cam.fy, cam.cx, cam.cy],
            )
        )
        kps = np.array([xy for _, xy in obs_of_view[v]], dtype=np.float64).reshape(-1, 2)
        image = pycolmap.Image(name=cam.name, keypoints=kps, camera_id=cam_id, image_id=image_id)
        pose = pycolmap.Rigid3d(np.hstack([cam.R, cam.t[:, None]]))
        rec.add_image_with_trivial_frame(image, pose)
        for j, (k, _) in enumerate(obs_of_view[v]):
            point2d_index[k] = j

    for i in range(model.num_points):
        if counts[i] == 0:
            continue
        track = pycolmap.Track(
            [
                pycolmap.TrackElement(int(model.track_view[k]) + 1, point2d_index[k])
                for k in range(model.track_ptr[i], model.track_ptr[i + 1])
            ]
        )
        rec.add_point3D(model.xyz[i], track, model.rgb[i])

    if binary:
        rec.write_binary(str(tmp))
    else:
        rec.write_text(str(tmp))
    if out_dir.exists():
        shutil.rmtree(out_dir)
    tmp.rename(out_dir)
    return out_dir


# ---- binary model diagnosis -------------------------------------------------------------------
def _camera_param_counts() -> dict[int, int]:
    import pycolmap

    counts = {}
    for model_id in pycolmap.CameraModelId.__members__.values():
        if int(model_id) < 0:
            continue
        try:
            counts[int(model_id)] = len(pycolmap.Camera.create_from_model_id(0, model_id, 1.0, 1, 1).params)
        except Exception:  # noqa: BLE001 - a model pycolmap cannot instantiate simply is not counted
            pass
    return counts


class _Reader:
    def __init__(self, path: Path):
        self.path = path
        self.data = path.read_bytes()
        self.pos = 0

    def take(self, fmt: str):
        size = struct.calcsize(fmt)
        if self.pos + size > len(self.data):
            raise EOFError
        out = struct.unpack_from(fmt, self.data, self.pos)
        self.pos += size
        return out

    def skip(self, n: int) -> None:
        if self.pos + n > len(self.data):
            raise EOFError
        self.pos += n

    def cstring(self) -> None:
        end = self.data.find(b"\0", self.pos)
        if end < 0:
            raise EOFError
        self.pos = end + 1


def diagnose_binary_model(model_dir: Path) -> list[str]:
    """Walk cameras.bin, images.bin and points3D.bin record by record (COLMAP's binary layout) and
    say which file is truncated or malformed, and where. Returns one message per bad file."""
    found = []
    param_counts = None
    for stem in MODEL_FILES:
        path = model_dir / f"{stem}.bin"
        if not path.exists():
            continue
        r = _Reader(path)
        k = total = 0
        try:
            (total,) = r.take("<Q")
            for k in range(total):
                if stem == "cameras":
                    _, model_id, _, _ = r.take("<iiQQ")
                    if param_counts is None:
                        param_counts = _camera_param_counts()
                    if model_id not in param_counts:
                        found.append(f"{path}: camera record {k + 1} of {total} has an unknown camera model id "
                                     f"{model_id} (corrupt file)")
                        break
                    r.skip(8 * param_counts[model_id])
                elif stem == "images":
                    r.skip(4 + 8 * 7 + 4)
                    r.cstring()
                    (n2d,) = r.take("<Q")
                    r.skip(24 * n2d)
                else:
                    r.skip(8 + 24 + 3 + 8)
                    (n_track,) = r.take("<Q")
                    r.skip(8 * n_track)
            else:
                if r.pos != len(r.data):
                    found.append(f"{path}: {len(r.data) - r.pos} unexpected bytes after the last of {total} records")
        except EOFError:
            found.append(f"{path} is truncated: it ends ({len(r.data)} bytes) inside record {k + 1} of {total}")
    return found


# ---- text model diagnosis ---------------------------------------------------------------------
def _camera_param_counts_by_name() -> dict[str, int]:
    import pycolmap

    by_id = _camera_param_counts()
    return {name: by_id[int(mid)] for name, mid in pycolmap.CameraModelId.__members__.items() if int(mid) in by_id}


def _numbers(tokens: list[str], kinds: str) -> str | None:
    """None when each token parses as its kind ('i' integer, 'f' float), else the first bad token."""
    for tok, kind in zip(tokens, kinds):
        try:
            int(tok) if kind == "i" else float(tok)
        except ValueError:
            return tok
    return None


def diagnose_text_model(model_dir: Path) -> list[str]:
    """Check cameras.txt, images.txt and points3D.txt line by line (COLMAP's text layout: token counts,
    numbers, camera models) and say which file and line is malformed. Returns one message per bad file.
    pycolmap's own errors on these files name a line of its C++ source, not of the file."""
    found = []
    model_dir = Path(model_dir)
    if any((model_dir / f"{n}.bin").exists() for n in MODEL_FILES):
        return found  # pycolmap reads the binary model
    counts = None
    for stem in MODEL_FILES:
        path = model_dir / f"{stem}.txt"
        if not path.exists():
            continue
        try:
            lines = path.read_text(encoding="utf-8").splitlines()
        except (OSError, UnicodeDecodeError) as exc:
            found.append(f"{path} cannot be read as text: {exc}")
            continue
        problem = None
        k = 0
        while k < len(lines) and problem is None:
            line = lines[k].strip()
            k += 1
            if not line or line.startswith("#"):
                continue
            tok = line.split()
            where = f"{path} line {k}"
            if stem == "cameras":
                if counts is None:
                    counts = _camera_param_counts_by_name()
                if len(tok) < 4:
                    problem = f"{where} has {len(tok)} values; a camera needs ID MODEL WIDTH HEIGHT PARAMS"
                elif tok[1] not in counts:
                    problem = f"{where} names an unknown camera model {tok[1]!r}"
                elif len(tok) != 4 + counts[tok[1]]:
                    problem = f"{where}: model {tok[1]} takes {counts[tok[1]]} parameters, the line has {len(tok) - 4}"
                elif (bad := _numbers([tok[0], tok[2], tok[3]] + tok[4:], "iii" + "f" * (len(tok) - 4))) is not None:
                    problem = f"{where}: {bad!r} is not a number"
            elif stem == "images":
                if len(tok) < 10:
                    problem = f"{where} has {len(tok)} values; an image needs ID QW QX QY QZ TX TY TZ CAMERA_ID NAME"
                elif (bad := _numbers(tok[:9], "ifffffffi")) is not None:
                    problem = f"{where}: {bad!r} is not a number"
                else:
                    # The next line lists the image's 2D points as X Y POINT3D_ID triples (it may be empty).
                    points = lines[k].split() if k < len(lines) else None
                    k += 1
                    if points is None:
                        problem = f"{path} ends after line {k - 1}: the 2D points line of image {tok[9]!r} is missing"
                    elif len(points) % 3:
                        problem = f"{path} line {k}: {len(points)} values, not X Y POINT3D_ID triples"
                    elif (bad := _numbers(points, "ffi" * (len(points) // 3))) is not None:
                        problem = f"{path} line {k}: {bad!r} is not a number"
            else:
                if len(tok) < 8 or (len(tok) - 8) % 2:
                    problem = (f"{where} has {len(tok)} values; a point needs ID X Y Z R G B ERROR and "
                               f"IMAGE_ID POINT2D_IDX pairs")
                elif (bad := _numbers(tok, "ifffiiif" + "ii" * ((len(tok) - 8) // 2))) is not None:
                    problem = f"{where}: {bad!r} is not a number"
        if problem:
            found.append(problem)
    return found
