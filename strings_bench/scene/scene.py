"""The scene model every stage reads: cameras, lazily loaded images and masks, sparse points with
tracks, the train/test split, the scene extent, and (for synthetic scenes) the known text.

Folder layout (COLMAP style):

    SCENE/
      images/               photos (undistorted, pinhole)
      images_2/, images_4/  optional pre-downscaled copies (used when present)
      sparse/0/             COLMAP model (.bin or .txt)
      masks/                optional text masks, one PNG per image named <image stem>.png
      text_annotations.json optional known text: {"views": {image_name: [{"text", "polygon"[, "lang", "script"]}]}}
      split.json            optional split override: {"test": [names], "train": [names]}
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path

import numpy as np
from PIL import Image

from strings_bench.core import vec3
from strings_bench.scene.camera import Camera
from strings_bench.scene.colmap import ColmapModel, find_model_dir, model_file, read_model
from strings_bench.core.errors import DatasetError

IMAGE_EXTENSIONS = (".png", ".jpg", ".jpeg", ".JPG", ".JPEG", ".PNG")
ANNOTATION_FILE = "text_annotations.json"
SPLIT_FILE = "split.json"
TEST_EVERY = 8  # 3DGS protocol: every 8th image (sorted by name) is a test view


@dataclass(frozen=True)
class KnownWord:
    """A word whose text is known (synthetic scenes), with its polygon in full-resolution pixels."""

    text: str
    polygon: np.ndarray  # (K, 2)
    # Where the scene knows them (synthetic scenes): the angle in degrees between the surface normal and the
    # direction to the camera at the word's centre (0 = seen head-on), and the camera's distance to that centre
    # in scene units. None elsewhere.
    angle_deg: float | None = None
    distance: float | None = None
    # Where recorded (synthetic-multi scenes): the word's language (core.scripts codes: rus, ell, hin, ara,
    # chi_sim, eng) and script (core.scripts names: Cyrillic, Greek, Devanagari, Arabic, Han, Latin).
    lang: str | None = None
    script: str | None = None


def default_split(names: list[str], every: int = TEST_EVERY) -> tuple[list[int], list[int]]:
    """Indices (train, test) into `names` after sorting: index % every == 0 is a test view."""
    order = sorted(range(len(names)), key=lambda i: names[i])
    test = sorted(order[k] for k in range(0, len(order), every))
    test_set = set(test)
    train = [i for i in range(len(names)) if i not in test_set]
    return train, test


MIN_TEST_VIEWS = 3  # a sparse capture's split holds out at least this many views where it can (sparse_split)


def sparse_split(names: list[str], every: int = TEST_EVERY, min_test: int = MIN_TEST_VIEWS) -> tuple[list[str], int]:
    """The held-out views of a capture and the step used: every `every`-th view (sorted by name), unless that
    holds out fewer than `min_test`; then every k-th, k = max(3, n // min_test), which holds out `min_test` views
    or more from n >= 3 x min_test views and never more than a third of them (9 photos: views 0, 3, 6)."""
    order = sorted(names)
    if len(range(0, len(order), every)) < min_test:
        every = max(3, len(order) // min_test)
    return [order[k] for k in range(0, len(order), every)], every


def compute_extent(centers: np.ndarray) -> float:
    """3DGS scene extent: 1.1 x the largest distance of a camera centre from their mean."""
    centers = np.asarray(centers, dtype=np.float64).reshape(-1, 3)
    if len(centers) == 0:
        return 1.0
    radius = float(vec3.norm(centers - centers.mean(0)).max())
    # A single camera (or coincident ones) has radius 0: fall back to 1 so LRs stay non-zero.
    return 1.1 * radius if radius > 0 else 1.0


@dataclass
class Scene:
    """A scene on disk: its images, its COLMAP model (cameras and SfM points), text masks, known text and split.

    Build it with `Scene.load(folder)`. The folder holds `images/` and a COLMAP model (`sparse/0/` or
    `sparse/`, binary or text); optionally `masks/` (one text mask per view, named by the image's stem),
    `annotations.json` (the known text of synthetic scenes), `split.json` ({"test": [names], "train": [names]})
    and downscaled copies `images_2/`, `images_4/`. Views are indexed 0..num_views-1 in the model's image order.

    Attributes:
        root: the scene folder.
        name: the scene's name in tables (default: the folder's name).
        model: the COLMAP model: `model.cameras` (one `Camera` per view), `model.xyz` (P, 3) float SfM points in
            world units, `model.rgb` (P, 3) uint8 their colours.
        images_dir: the full-resolution images.
        masks_dir: the text masks, or None.
        known_text: image name -> the `KnownWord`s it shows, or None when the text is not known.
        train_idx: the training views' indices.
        test_idx: the test views' indices (split.json's, else every 8th view, as in 3DGS).
        settings: per-scene settings from a dataset card (e.g. STRinGS' n_max).

    Example:
        >>> from strings_bench.bench.check import tiny_scene
        >>> scene = Scene.load(tiny_scene())
        >>> scene.num_views, len(scene.train_idx) + len(scene.test_idx) == scene.num_views
        (8, True)
        >>> scene.load_image(scene.test_idx[0]).shape, scene.camera(0).width
        ((72, 96, 3), 96)
    """

    root: Path
    name: str
    model: ColmapModel
    images_dir: Path
    masks_dir: Path | None = None
    known_text: dict[str, list[KnownWord]] | None = None
    train_idx: list[int] = field(default_factory=list)
    test_idx: list[int] = field(default_factory=list)
    settings: dict = field(default_factory=dict)  # per-scene settings from a dataset card (e.g. n_max)

    # ---- construction -------------------------------------------------------------------
    @classmethod
    def load(cls, root: str | Path, name: str | None = None, images: str = "images", masks: str = "masks",
             settings: dict | None = None) -> "Scene":
        """Read the scene in folder `root` (nothing is decoded yet; images load on first use).

        Args:
            root: the scene folder.
            name: its name in tables (default: the folder's name).
            images: the images' sub-folder.
            masks: the text masks' sub-folder (absent: no masks).
            settings: per-scene settings (a dataset card's), kept in `settings`.
        Returns:
            the scene, with its train/test split.
        Raises:
            DatasetError: the folder, its images or its COLMAP model are missing, the model names an image that
                is not there, or split.json is malformed (each message says which, and how to fix it).
        """
        root = Path(root)
        if not root.is_dir():
            raise DatasetError(f"scene folder {root} does not exist", hint="check the path, or `strings-bench datasets list`")
        images_dir = root / images
        if not images_dir.is_dir():
            raise DatasetError(f"scene {root} has no {images}/ folder", hint="a scene folder needs images/ and sparse/0/")
        if not any(p.suffix in IMAGE_EXTENSIONS for p in images_dir.iterdir()):
            raise DatasetError(f"the images folder {images_dir} is empty", hint="copy the scene's photos into it")
        if not (root / "sparse").exists() and not any((root / f"cameras{e}").exists() for e in (".bin", ".txt")):
            raise DatasetError(
                f"scene {root} has no sparse/ folder (COLMAP model)",
                hint="run `strings-bench prepare PHOTOS_DIR --name NAME` to run SfM, or copy sparse/0 from COLMAP",
            )
        model = read_model(root)
        missing = [c.name for c in model.cameras if not (images_dir / c.name).exists()]
        if missing:
            raise DatasetError(
                f"{len(missing)} image(s) listed in the COLMAP model of {root} "
                f"({model_file(find_model_dir(root), 'images')}) are missing from {images_dir}: "
                f"{', '.join(missing[:5])}{' ...' if len(missing) > 5 else ''}",
                hint="copy the missing photos, or re-run SfM on the photos you have",
            )
        masks_dir = root / masks if (root / masks).is_dir() else None
        known = _read_annotations(root / ANNOTATION_FILE) if (root / ANNOTATION_FILE).exists() else None
        scene = cls(root=root, name=name or root.name, model=model, images_dir=images_dir, masks_dir=masks_dir,
                    known_text=known, settings=dict(settings or {}))
        scene.train_idx, scene.test_idx = scene._split()
        return scene

    def _split(self) -> tuple[list[int], list[int]]:
        names = self.model.names
        split_file = self.root / SPLIT_FILE
        if not split_file.exists():
            return default_split(names)
        hint = 'expected {"test": [image names], "train": [image names] (optional)}; or delete split.json to use every 8th image'
        try:
            spec = json.loads(split_file.read_text(encoding="utf-8"))
        except (OSError, ValueError) as exc:
            raise DatasetError(f"cannot read {split_file}: {exc}", hint=hint) from exc
        if not isinstance(spec, dict) or "test" not in spec:
            raise DatasetError(f"{split_file} has no \"test\" list", hint=hint)
        lists = {}
        for key in ("test", "train"):
            value = spec.get(key)
            if value is None and key == "train":
                continue
            if not isinstance(value, list) or not all(isinstance(n, str) for n in value):
                raise DatasetError(f"{split_file}: \"{key}\" must be a list of image names, got {json.dumps(value)[:80]}",
                                   hint=hint)
            lists[key] = value
        index = {n: i for i, n in enumerate(names)}
        unknown = [n for n in lists["test"] + lists.get("train", []) if n not in index]
        if unknown:
            raise DatasetError(f"{split_file} names images that are not in the model: {unknown[:5]}",
                               hint="fix the names, or delete split.json to use every 8th image")
        test = sorted({index[n] for n in lists["test"]})
        train_names = lists.get("train")
        train = sorted({index[n] for n in train_names}) if train_names else [i for i in range(len(names)) if i not in set(test)]
        both = sorted(set(train) & set(test))
        if both:
            raise DatasetError(f"{split_file} puts {len(both)} view(s) in both train and test: "
                               f"{[names[i] for i in both][:5]}", hint="a test view must not be trained on")
        if not test or not train:
            raise DatasetError(f"{split_file} leaves no {'test' if not test else 'training'} view "
                               f"({len(test)} test, {len(train)} train of {len(names)})", hint=hint)
        return train, test

    # ---- geometry -------------------------------------------------------------------------
    @property
    def num_views(self) -> int:
        """Views (registered images) in the model."""
        return len(self.model.cameras)

    @property
    def names(self) -> list[str]:
        """The views' image names, by view index."""
        return self.model.names

    def camera(self, i: int, downscale: float = 1) -> Camera:
        """View `i`'s pinhole camera (intrinsics in pixels, world -> camera pose) at the image size for
        `downscale` (2 = half width and height)."""
        cam = self.model.cameras[i]
        if downscale == 1:
            return cam
        w, h = self._image_size(i, downscale)
        return cam.resized(w, h) if (w, h) != (cam.width, cam.height) else cam

    @property
    def extent(self) -> float:
        """The scene's size in world units: 1.1 x the largest distance of a training camera from their mean
        (3DGS' `cameras_extent`); learning rates and size thresholds are multiples of it."""
        idx = self.train_idx or list(range(self.num_views))
        return compute_extent(np.stack([self.model.cameras[i].center for i in idx]))

    # ---- pixels ---------------------------------------------------------------------------
    def _image_size(self, i: int, downscale: float) -> tuple[int, int]:
        cam = self.model.cameras[i]
        return max(1, int(round(cam.width / downscale))), max(1, int(round(cam.height / downscale)))

    def image_path(self, i: int, downscale: float = 1) -> Path:
        """The file view `i` is read from: the `images_<downscale>/` copy when there is one, else the original."""
        name = self.model.cameras[i].name
        if downscale != 1 and float(downscale).is_integer():
            pre = self.root / f"{self.images_dir.name}_{int(downscale)}" / name
            if pre.exists():
                return pre
        return self.images_dir / name

    def load_image(self, i: int, downscale: float = 1) -> np.ndarray:
        """RGB float32 in [0, 1], (H, W, 3), at the camera's size for `downscale`."""
        return _load_rgb(str(self.image_path(i, downscale)), self._image_size(i, downscale))

    def mask_path(self, i: int) -> Path | None:
        """View `i`'s text mask file (masks/<stem>.png or .jpg), or None."""
        if self.masks_dir is None:
            return None
        stem = Path(self.model.cameras[i].name).stem
        for ext in (".png", ".jpg", ".PNG"):
            p = self.masks_dir / f"{stem}{ext}"
            if p.exists():
                return p
        return None

    def load_mask(self, i: int, downscale: float = 1) -> np.ndarray | None:
        """Boolean text mask (H, W) or None if the scene has no mask for this view.

        Masks may be stored at any resolution with the image's aspect ratio; other sizes are refused.
        """
        p = self.mask_path(i)
        if p is None:
            return None
        cam = self.model.cameras[i]
        return _load_mask(str(p), (cam.width, cam.height), self._image_size(i, downscale))

    def known_words(self, i: int, downscale: float = 1) -> list[KnownWord] | None:
        """Known words of view i with polygons scaled to `downscale`, or None when text is unknown."""
        if self.known_text is None:
            return None
        cam = self.model.cameras[i]
        w, h = self._image_size(i, downscale)
        s = np.array([w / cam.width, h / cam.height])
        return [KnownWord(k.text, k.polygon * s, k.angle_deg, k.distance, k.lang, k.script)
                for k in self.known_text.get(cam.name, [])]


def _to_8bit(im: Image.Image, mode: str) -> Image.Image:
    """`im` in 8-bit `mode` ("RGB", "L"). 16-bit and 32-bit grayscale is scaled to 8 bit first: PIL's
    convert clips those values at 255, which turns a 16-bit photo white."""
    if im.mode in ("I;16", "I;16B", "I;16L", "I", "F"):
        arr = np.asarray(im, dtype=np.float64)
        peak = 65535.0 if im.mode.startswith("I;16") or arr.max(initial=0) > 255 else 255.0
        im = Image.fromarray(np.clip(arr / peak * 255.0 + 0.5, 0, 255).astype(np.uint8), mode="L")
    return im.convert(mode)


def clear_image_cache() -> None:
    """Forget every decoded image: the next read of each decodes it again (a benchmark that times a run as it
    runs, first decodes included)."""
    _load_rgb.cache_clear()


@lru_cache(maxsize=256)
def _load_rgb(path: str, size: tuple[int, int]) -> np.ndarray:
    try:
        with Image.open(path) as im:
            (iw, ih), (tw, th) = im.size, size
            if abs(iw * th - ih * tw) > max(iw, ih, tw, th):
                # Another resolution of the same picture is resized below; another aspect is another picture.
                raise DatasetError(
                    f"image {path} is {iw}x{ih} but its camera is {tw}x{th} at this resolution (different aspect ratio)",
                    hint="the images and sparse/0 come from different runs (or the photo was cropped); keep them together")
            im = _to_8bit(im, "RGB")
            if im.size != size:
                im = im.resize(size, Image.Resampling.LANCZOS)
            arr = np.asarray(im, dtype=np.float32) / 255.0
    except (OSError, ValueError, SyntaxError, Image.DecompressionBombError) as exc:
        raise DatasetError(f"cannot read image {path}: {exc}", hint="the file is missing or corrupt; replace it") from exc
    arr.setflags(write=False)
    return arr


@lru_cache(maxsize=256)
def _load_mask(path: str, full_size: tuple[int, int], size: tuple[int, int]) -> np.ndarray:
    try:
        with Image.open(path) as im:
            im = _to_8bit(im, "L")
            msize = im.size
            if msize != size:
                # Same aspect ratio (within a pixel of rounding) means the mask is just another resolution.
                fw, fh = full_size
                if abs(msize[0] * fh - msize[1] * fw) > max(fw, fh):
                    raise DatasetError(
                        f"mask {path} is {msize[0]}x{msize[1]} but its image is {fw}x{fh} (different aspect ratio)",
                        hint="masks must be made from the undistorted images of this scene; regenerate them",
                    )
                im = im.resize(size, Image.Resampling.NEAREST)
            arr = np.asarray(im) > 127
    except (OSError, ValueError, SyntaxError, Image.DecompressionBombError) as exc:
        raise DatasetError(f"cannot read mask {path}: {exc}", hint="the file is corrupt; regenerate the masks") from exc
    arr.setflags(write=False)
    return arr


def _read_annotations(path: Path) -> dict[str, list[KnownWord]]:
    hint = 'expected {"views": {image_name: [{"text": ..., "polygon": [[x, y], ...]}]}}'
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:  # UnicodeDecodeError is a ValueError
        raise DatasetError(f"cannot read text annotations {path}: {exc}", hint=hint) from exc
    views = data.get("views") if isinstance(data, dict) else None
    if not isinstance(views, dict):
        raise DatasetError(f"text annotations {path} hold no \"views\" object (got {type(data).__name__})", hint=hint)
    out: dict[str, list[KnownWord]] = {}
    for name, words in views.items():
        if not isinstance(words, list) or not all(isinstance(w, dict) and "text" in w and "polygon" in w for w in words):
            raise DatasetError(f"text annotations {path}: view {name!r} is not a list of {{\"text\", \"polygon\"}} words",
                               hint=hint)
        kept = []
        for w in words:
            try:
                poly = np.asarray(w["polygon"], dtype=np.float64)
            except (ValueError, TypeError) as exc:
                raise DatasetError(f"text annotations {path}: a polygon of view {name!r} is not numbers: {exc}",
                                   hint=hint) from exc
            if poly.ndim != 2 or poly.shape[1] != 2 or len(poly) < 3 or not np.all(np.isfinite(poly)):
                raise DatasetError(f"text annotations {path}: a polygon of view {name!r} is not >= 3 finite [x, y] "
                                   f"points (shape {poly.shape})", hint=hint)
            geo = {}
            for key in ("angle_deg", "distance"):  # optional (synthetic scenes of older builds lack them)
                v = w.get(key)
                if v is not None and not (isinstance(v, (int, float)) and not isinstance(v, bool) and np.isfinite(v)):
                    raise DatasetError(f"text annotations {path}: {key} of a word of view {name!r} is not a finite "
                                       f"number ({v!r})", hint=hint)
                geo[key] = None if v is None else float(v)
            kept.append(KnownWord(str(w["text"]), poly, **geo, lang=w.get("lang"), script=w.get("script")))
        out[str(name)] = kept
    return out


def write_annotations(path: str | Path, views: dict[str, list[KnownWord]]) -> None:
    from strings_bench.core.io import atomic_write_json

    def word(w: KnownWord) -> dict:
        d = {"text": w.text, "polygon": np.asarray(w.polygon).tolist()}
        d.update({k: float(v) for k, v in (("angle_deg", w.angle_deg), ("distance", w.distance)) if v is not None})
        d.update({k: v for k, v in (("lang", w.lang), ("script", w.script)) if v is not None})
        return d

    atomic_write_json(path, {"views": {n: [word(w) for w in ws] for n, ws in views.items()}})
