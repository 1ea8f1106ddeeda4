"""Validate a local copy of a scene (or a dataset of scenes) without touching it.

`check_scene(path)` reports, each with a message naming the file and a hint:
  - missing folders (images/, sparse/0/) and incomplete or unreadable COLMAP models (a truncated
    .bin is pinned to the file and record where it breaks);
  - images on disk without a pose, and poses (registered images) whose photo is missing;
  - cameras that need undistortion (any model other than PINHOLE / SIMPLE_PINHOLE);
  - images whose size disagrees with their camera;
  - masks: present or absent, missing per image, orphaned, and their size (same as the image,
    another resolution with the same aspect, or a wrong aspect);
  - anything else `Scene.load` refuses (split.json, text_annotations.json).

Everything here only reads: files are opened read-only, nothing is created next to the data.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from PIL import Image

from strings_bench.scene.colmap import (MODEL_FILES, PINHOLE_MODELS, diagnose_binary_model, diagnose_text_model,
                                       model_file, value_problems)
from strings_bench.core.errors import DatasetError, StringsBenchError

IMAGE_SUFFIXES = {".png", ".jpg", ".jpeg"}
MASK_SUFFIXES = (".png", ".jpg", ".PNG")
ERROR, WARNING, INFO = "error", "warning", "info"
UNDISTORT_HINT = ("undistort first: `strings-bench prepare` does it for photos, or run `colmap image_undistorter "
                  "--image_path images --input_path sparse/0 --output_path undistorted --output_type COLMAP`")


@dataclass
class Problem:
    level: str  # "error" (the scene cannot be used), "warning" (usable, but look), "info"
    path: str  # the file or folder concerned
    message: str
    hint: str = ""

    def __str__(self) -> str:
        return f"{self.level}: {self.message}" + (f"\n    hint: {self.hint}" if self.hint else "")


@dataclass
class SceneReport:
    path: Path
    name: str = ""
    problems: list[Problem] = field(default_factory=list)
    stats: dict = field(default_factory=dict)
    found: bool = True  # False: the scene folder of a card is not in the copy at all

    @property
    def ok(self) -> bool:
        return not any(p.level == ERROR for p in self.problems)

    def errors(self) -> list[Problem]:
        return [p for p in self.problems if p.level == ERROR]

    def add(self, level: str, path: Path | str, message: str, hint: str = "") -> None:
        self.problems.append(Problem(level, str(path), message, hint))

    def format(self) -> str:
        head = f"{self.name or self.path.name}: {'OK' if self.ok else 'PROBLEMS'} ({self.path})"
        stats = ", ".join(f"{k} {v}" for k, v in self.stats.items())
        lines = [head] + ([f"  {stats}"] if stats else [])
        for p in self.problems:
            lines.extend("  " + ln for ln in str(p).splitlines())
        return "\n".join(lines)


def _list(names: list[str], n: int = 5) -> str:
    return ", ".join(names[:n]) + (f" ... ({len(names)} in all)" if len(names) > n else "")


# ---- the scene check --------------------------------------------------------------------------
def _find_model_dir(root: Path) -> Path | None:
    for cand in (root / "sparse" / "0", root / "sparse", root):
        if cand.is_dir() and any((cand / f"{n}{e}").exists() for n in MODEL_FILES for e in (".bin", ".txt")):
            return cand
    return None


def _same_aspect(a: tuple[int, int], b: tuple[int, int]) -> bool:
    # Within a pixel of rounding, as Scene.load_mask accepts.
    return abs(a[0] * b[1] - a[1] * b[0]) <= max(b)


def _image_size(path: Path) -> tuple[int, int] | None:
    """The image's size, or None when it cannot be decoded. The whole file is decoded: a photo cut short
    by a broken copy has a valid header and would otherwise pass until training reads it."""
    try:
        with Image.open(path) as im:
            im.load()
            return im.size
    except (OSError, ValueError, SyntaxError, Image.DecompressionBombError):
        return None


def check_scene(path: str | Path, name: str = "", try_load: bool = True) -> SceneReport:
    import pycolmap

    root = Path(path)
    rep = SceneReport(path=root, name=name or root.name)
    if not root.is_dir():
        rep.add(ERROR, root, f"scene folder {root} does not exist", "check the path")
        return rep

    # images/
    images_dir = root / "images"
    on_disk: dict[str, Path] = {}
    if not images_dir.is_dir():
        rep.add(ERROR, images_dir, f"missing folder images/ in {root}",
                "a scene folder holds images/ (undistorted photos) and sparse/0/ (COLMAP model)")
    else:
        on_disk = {p.name: p for p in sorted(images_dir.iterdir()) if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES}
        if not on_disk:
            rep.add(ERROR, images_dir, f"the images folder {images_dir} is empty (no .jpg/.png files)",
                    "copy the scene's photos into it")
    rep.stats["images on disk"] = len(on_disk)

    # sparse/0
    model_dir = _find_model_dir(root)
    rec = None
    if model_dir is None:
        rep.add(ERROR, root / "sparse" / "0", f"missing folder sparse/0/ (COLMAP model) in {root}",
                "copy sparse/0 from COLMAP, or run `strings-bench prepare PHOTOS_DIR --name NAME` to make one")
    else:
        complete = [e for e in (".bin", ".txt") if all((model_dir / f"{n}{e}").exists() for n in MODEL_FILES)]
        if not complete:
            have = sorted(p.name for p in model_dir.iterdir() if p.stem in MODEL_FILES)
            missing = [f"{n}.bin" for n in MODEL_FILES if not (model_dir / f"{n}.bin").exists()]
            rep.add(ERROR, model_dir, f"the COLMAP model in {model_dir} is incomplete: has {_list(have) or 'nothing'}, "
                    f"missing {_list(missing)}", "copy the complete sparse/0 folder written by COLMAP")
        else:
            # Walk the binary files first: pycolmap can spend minutes on a cut-off points3D.bin
            # (a garbage track length read past the end), and its errors do not name the file.
            where = diagnose_binary_model(model_dir) if complete[0] == ".bin" else diagnose_text_model(model_dir)
            if where:
                rep.add(ERROR, model_dir, f"cannot read the COLMAP model in {model_dir}: {'; '.join(where)}",
                        "re-copy or re-export the model (the file was cut short or damaged)")
            else:
                try:
                    rec = pycolmap.Reconstruction(str(model_dir))
                except Exception as exc:  # noqa: BLE001 - pycolmap raises ValueError/IndexError on corrupt files
                    rep.add(ERROR, model_dir, f"cannot read the COLMAP model in {model_dir}: {type(exc).__name__}: "
                            f"{exc}", "re-copy or re-export the model (a file is damaged)")

    registered = {}
    if rec is not None:
        bad_values = value_problems(rec, model_dir)
        if bad_values:
            rep.add(ERROR, model_dir, f"invalid values in the COLMAP model: {'; '.join(bad_values)}",
                    "re-copy or re-export the model (the file was damaged or written by a broken tool)")
        for im in rec.images.values():
            if im.has_pose:
                registered[im.name] = im
        unposed_in_model = sorted(im.name for im in rec.images.values() if not im.has_pose)
        rep.stats.update({"registered images": len(registered), "points": rec.num_points3D()})
        if not registered:
            rep.add(ERROR, model_dir, f"the COLMAP model in {model_dir} has no registered images",
                    "SfM failed on these photos; re-run it")
        if unposed_in_model:
            rep.add(WARNING, model_dir, f"{len(unposed_in_model)} image(s) are listed in the model without a pose "
                    f"and will be left out: {_list(unposed_in_model)}")

        # Cameras that need undistortion.
        models_used: dict[int, list[str]] = {}
        for im in registered.values():
            models_used.setdefault(im.camera_id, []).append(im.name)
        distorted = []
        for cam_id, names in sorted(models_used.items()):
            cam = rec.cameras[cam_id]
            if cam.model.name not in PINHOLE_MODELS:
                distorted.append(f"camera {cam_id} ({cam.model.name}, {len(names)} image(s))")
        rep.stats["camera models"] = ",".join(sorted({rec.cameras[c].model.name for c in models_used})) or "-"
        if distorted:
            rep.add(ERROR, model_dir / "cameras", "cameras need undistortion (the suite reads PINHOLE or "
                    f"SIMPLE_PINHOLE only): {_list(distorted)}", UNDISTORT_HINT)

        if images_dir.is_dir():
            # Poses without images, images without poses.
            no_image = sorted(n for n in registered if n not in on_disk and not (images_dir / n).exists())
            if no_image:
                rep.add(ERROR, images_dir, f"{len(no_image)} image(s) have a pose in the model but no file in "
                        f"{images_dir}: {_list(no_image)} (listed in {model_file(model_dir, 'images')})",
                        "copy the missing photos, or re-run SfM on the photos you have")
            no_pose = sorted(n for n in on_disk if n not in registered)
            if no_pose:
                rep.add(WARNING, images_dir, f"{len(no_pose)} image(s) in {images_dir} have no pose in the model "
                        f"and will be ignored: {_list(no_pose)}",
                        "fine if SfM could not register them; otherwise re-run SfM")
            # Image size vs camera size.
            wrong_aspect, other_res, unreadable = [], [], []
            for n, im in registered.items():
                p = images_dir / n
                if not p.exists():
                    continue
                size = _image_size(p)
                cam = rec.cameras[im.camera_id]
                want = (int(cam.width), int(cam.height))
                if size is None:
                    unreadable.append(n)
                elif size != want:
                    (other_res if _same_aspect(size, want) else wrong_aspect).append(
                        f"{n} is {size[0]}x{size[1]}, camera {want[0]}x{want[1]}")
            if unreadable:
                rep.add(ERROR, images_dir, f"{len(unreadable)} image(s) cannot be read: {_list(unreadable)}",
                        "the files are corrupt or not images; replace them")
            if wrong_aspect:
                rep.add(ERROR, images_dir, f"{len(wrong_aspect)} image(s) do not match their camera's aspect ratio: "
                        f"{_list(wrong_aspect, 3)}", "the images and sparse/0 come from different runs; keep them together")
            if other_res:
                rep.add(WARNING, images_dir, f"{len(other_res)} image(s) are stored at another resolution than "
                        f"their camera (same aspect; resized when loaded): {_list(other_res, 3)}")

    _check_masks(root, rep, registered, on_disk, rec)

    if try_load and rep.ok:
        from strings_bench.scene.scene import Scene

        try:
            Scene.load(root)
        except StringsBenchError as exc:
            rep.add(ERROR, root, f"the scene does not load: {exc.message}", exc.hint or "")
    return rep


def _check_masks(root: Path, rep: SceneReport, registered: dict, on_disk: dict, rec) -> None:
    masks_dir = root / "masks"
    if not masks_dir.is_dir():
        rep.stats["masks"] = "absent"
        rep.add(INFO, masks_dir, "no masks/ folder: STRinGS needs text masks (make them with `strings-bench prepare`'s "
                "OCR masks, the 'ocr' mask source, or bring Hi-SAM masks; see docs/guide/datasets.md)")
        return
    masks = {p.stem: p for p in sorted(masks_dir.iterdir()) if p.is_file() and p.suffix in MASK_SUFFIXES}
    rep.stats["masks"] = len(masks)
    names = list(registered) or list(on_disk)
    stems = {Path(n).stem: n for n in names}
    without = sorted(n for s, n in stems.items() if s not in masks)
    orphans = sorted(p.name for s, p in masks.items() if s not in stems)
    if not masks:
        rep.add(WARNING, masks_dir, f"the masks folder {masks_dir} is empty", "remove it, or fill it with <image stem>.png masks")
        return
    if without:
        rep.add(WARNING, masks_dir, f"{len(without)} image(s) have no mask in {masks_dir}: {_list(without)}",
                "masks are named <image stem>.png; STRinGS with the 'dataset' mask source refuses a view without "
                "one, so give text-free views an all-black mask")
    if orphans:
        rep.add(WARNING, masks_dir, f"{len(orphans)} mask(s) match no image: {_list(orphans)}",
                "masks are named <image stem>.png after the images in images/")
    wrong, other_res, unreadable = [], [], []
    for stem, mpath in masks.items():
        if stem not in stems:
            continue
        n = stems[stem]
        if rec is not None and n in registered:
            cam = rec.cameras[registered[n].camera_id]
            want = (int(cam.width), int(cam.height))
        elif n in on_disk:
            want = _image_size(on_disk[n])
            if want is None:
                continue
        else:
            continue
        size = _image_size(mpath)
        if size is None:
            unreadable.append(mpath.name)
        elif size != want:
            (other_res if _same_aspect(size, want) else wrong).append(f"{mpath.name} is {size[0]}x{size[1]}, "
                                                                       f"image {want[0]}x{want[1]}")
    if unreadable:
        rep.add(ERROR, masks_dir, f"{len(unreadable)} mask(s) cannot be read: {_list(unreadable)}", "regenerate them")
    if wrong:
        rep.add(ERROR, masks_dir, f"{len(wrong)} mask(s) have the wrong size (different aspect ratio from their image): "
                f"{_list(wrong, 3)}", "masks must be made from this scene's undistorted images; regenerate them")
    if other_res:
        rep.add(INFO, masks_dir, f"{len(other_res)} mask(s) are at another resolution with the image's aspect "
                f"(resized when loaded): {_list(other_res, 3)}")


# ---- datasets and paths -----------------------------------------------------------------------
def _scene_dirs(path: Path) -> list[Path]:
    if (path / "sparse").exists() or (path / "images").exists():
        return [path]
    return sorted(p for p in path.iterdir() if p.is_dir() and ((p / "sparse").exists() or (p / "images").exists()))


def check_path(path: str | Path) -> list[SceneReport]:
    """A scene folder, or a folder of scene folders."""
    path = Path(path)
    if not path.is_dir():
        rep = SceneReport(path=path)
        rep.add(ERROR, path, f"{path} does not exist or is not a folder", "check the path")
        return [rep]
    dirs = _scene_dirs(path)
    if not dirs:
        # Not recognisably a scene: check it as one anyway, which names each missing folder.
        rep = check_scene(path)
        rep.add(INFO, path, f"{path} is neither a scene folder (images/, sparse/0/) nor a folder of scene folders",
                "point at the folder that holds images/ and sparse/0/, or at their parent")
        return [rep]
    return [check_scene(d) for d in dirs]


def check_card_copy(dataset_id: str, root: str | Path) -> list[SceneReport]:
    """Check a copy of a built-in real dataset at ROOT: every scene of its card."""
    from strings_bench.datasets.cards import find_scene_folder
    from strings_bench.datasets.registry import get_dataset

    card = get_dataset(dataset_id)
    reports = []
    for sc in card.scenes:
        try:
            folder = find_scene_folder(Path(root), sc.name, card.id)
        except DatasetError as exc:
            rep = SceneReport(path=Path(root) / sc.name, name=f"{card.id}/{sc.name}", found=False)
            rep.add(ERROR, Path(root) / sc.name, exc.message, exc.hint or "")
            reports.append(rep)
            continue
        rep = check_scene(folder, name=f"{card.id}/{sc.name}")
        reports.append(rep)
    return reports


def check_target(target: str) -> list[SceneReport]:
    """`datasets check` argument: a path, or the name of a registered dataset."""
    from strings_bench.datasets.cards import BUILTIN_REAL_CARDS
    from strings_bench.datasets.registry import locate_scene, read_index, select_scenes

    if Path(target).exists():
        return check_path(target)
    index = read_index()
    dataset_id, _, scene = target.partition("/")
    if dataset_id in {c.id for c in BUILTIN_REAL_CARDS}:
        if dataset_id not in index:
            raise DatasetError(f"dataset {dataset_id!r} has no local copy registered",
                               hint=f"`strings-bench datasets download {dataset_id}` says how to get it; then "
                               f"`strings-bench datasets add {dataset_id} PATH`")
        reports = check_card_copy(dataset_id, index[dataset_id])
        return [r for r in reports if not scene or r.name == f"{dataset_id}/{scene}"]
    card, scenes = select_scenes(target)
    if not scenes and dataset_id in index:
        return check_path(index[dataset_id])
    return [check_scene(locate_scene(card, sc.name), name=f"{card.id}/{sc.name}") for sc in scenes]


def format_reports(reports: list[SceneReport]) -> str:
    bad = sum(not r.ok for r in reports)
    tail = f"{len(reports)} scene(s) checked: {len(reports) - bad} OK, {bad} with errors"
    return "\n".join([r.format() for r in reports] + [tail])
