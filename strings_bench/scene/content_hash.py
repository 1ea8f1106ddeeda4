"""A scene folder's content hash: one SHA-256 over what a training and its evaluation read from the folder,
so that two machines compare a scene in one line (`strings-bench datasets show` prints it).

What is hashed, in this order, each part also hashed on its own (`parts`), so that where two hashes differ
the part that differs is named:

- ``images``: every image under images/, images_2/, images_4/ (file name, then the decoded pixels: shape,
  dtype, bytes), sorted by folder and name. Decoded, not the files' bytes: two PNG encoders may write the
  same pixels differently;
- ``masks``: the same for masks/ (and masks_2/, masks_4/ where present);
- ``cameras``: per registered view, sorted by name: name, width, height, fx, fy, cx, cy, R and t (float64), as
  `read_model` gives them;
- ``points``: the SfM points in the model's order: xyz (float64), rgb (uint8), and each point's track (view
  index and the observed pixel, float64) in the order stored. The order is content: it is the order of the
  initial Gaussians;
- ``text``: text_annotations.json and split.json as bytes, where present.

Not hashed: the record files (scene_meta.json, prepare.json, capture.json), which hold timings and paths.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
from PIL import Image

from strings_bench.scene.colmap import read_model

IMAGE_FOLDERS = ("images", "images_2", "images_4")
MASK_FOLDERS = ("masks", "masks_2", "masks_4")
TEXT_FILES = ("text_annotations.json", "split.json")
IMAGE_SUFFIXES = {".png", ".jpg", ".jpeg"}
HASH_CHARS = 16  # the hash as printed: 64 bits of the SHA-256, plenty to tell scenes apart


def _add_array(h, a: np.ndarray) -> None:
    a = np.ascontiguousarray(a)
    h.update(f"{a.dtype.str}{a.shape}".encode())
    h.update(a.tobytes())


def _hash_pictures(root: Path, folders: tuple[str, ...]) -> str:
    h = hashlib.sha256()
    for folder in folders:
        d = root / folder
        if not d.is_dir():
            continue
        for p in sorted(d.iterdir()):
            if p.suffix.lower() not in IMAGE_SUFFIXES:
                continue
            h.update(f"{folder}/{p.name}\0".encode())
            with Image.open(p) as im:
                _add_array(h, np.asarray(im))
    return h.hexdigest()


def _hash_cameras(model) -> str:
    h = hashlib.sha256()
    for c in model.cameras:
        h.update(f"{c.name}\0{int(c.width)}x{int(c.height)}\0".encode())
        _add_array(h, np.array([c.fx, c.fy, c.cx, c.cy], "<f8"))
        _add_array(h, np.asarray(c.R, "<f8"))
        _add_array(h, np.asarray(c.t, "<f8"))
    return h.hexdigest()


def _hash_points(model) -> str:
    h = hashlib.sha256()
    _add_array(h, np.asarray(model.xyz, "<f8"))
    _add_array(h, np.asarray(model.rgb, np.uint8))
    _add_array(h, np.asarray(model.track_ptr, "<i8"))
    _add_array(h, np.asarray(model.track_view, "<i4"))
    _add_array(h, np.asarray(model.track_xy, "<f8"))
    return h.hexdigest()


def _hash_text(root: Path) -> str:
    h = hashlib.sha256()
    for name in TEXT_FILES:
        p = root / name
        if p.is_file():
            h.update(f"{name}\0".encode())
            h.update(p.read_bytes())
    return h.hexdigest()


def scene_content_hash(root: str | Path) -> dict:
    """{"hash": 16 hex digits over every part, "parts": {part: 16 hex digits}} of the scene folder `root`
    (DatasetError from read_model when its COLMAP model cannot be read)."""
    root = Path(root)
    model = read_model(root)
    parts = {"images": _hash_pictures(root, IMAGE_FOLDERS), "masks": _hash_pictures(root, MASK_FOLDERS),
             "cameras": _hash_cameras(model), "points": _hash_points(model), "text": _hash_text(root)}
    total = hashlib.sha256("".join(f"{k}={v}\n" for k, v in parts.items()).encode()).hexdigest()
    return {"hash": total[:HASH_CHARS], "parts": {k: v[:HASH_CHARS] for k, v in parts.items()}}
