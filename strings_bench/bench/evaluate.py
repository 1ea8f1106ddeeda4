"""`strings-bench evaluate`: the suite's readability metrics on renders made anywhere.

Reads a predictions folder in one of three layouts, matches its renders to ground-truth views, scores every
checkpoint with the evaluation protocol (eval/protocol.py, the same code `run` uses) and writes the cells of
a run folder, so that `strings-bench report` gives the same tables as for a run:

    OUT/evaluate.json                      what was evaluated: layout, sources, options (a re-run must match)
    OUT/results.csv                        one row per checkpoint
    OUT/cells/<method>/<dataset>/<scene>/<iteration>/result.json, renders/<view stem>.png
    OUT/gt/<dataset>/<scene>/<view stem>.png
    OUT/report/                            tables, figures, index.html with the word-crop gallery

Layouts (`detect_layout`):

- ``inria``: the output of the Inria 3DGS code (and of the STRinGS release's render.py): MODEL/test/ours_<N>/
  with renders/, gt/ and optionally masks/, files named by index (00000.png), the same name in all three.
  PRED may be MODEL, MODEL/test or one ours_<N>; every ours_<N> is a checkpoint labelled N. With masks/,
  OCR reads image x (mask > 127) with no further dilation: the release's metrics_ocr protocol.
- ``nerfbaselines``: `nerfbaselines render` predictions: color/, gt-color/, optional mask/ and info.json, as a
  folder or a .zip / .tar.gz archive.
- ``folder``: a plain folder of renders named after the test views (<stem>.png or .jpg); the ground truth comes
  from --scene or --gt.

With --scene, the ground truth, the evaluation masks and the known text come from the scene (as in `run`),
and the test split is the suite's; renders are matched by view name (index-named renders by position in
the split). Without a scene, OCR-CER needs only GT and render images (and masks when given); columns that
need known text are n/a, never 0.
"""

from __future__ import annotations

import contextlib
import json
import logging
import re
import shutil
import tarfile
import tempfile
import time
import zipfile
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath
from typing import Iterator

import numpy as np

from strings_bench.core.errors import StringsBenchError
from strings_bench.core.io import atomic_write_json
from strings_bench.core.results import RESULT_FILE, CellKey, is_finished, safe_name

log = logging.getLogger(__name__)

LAYOUTS = ("inria", "nerfbaselines", "folder")
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")
MANIFEST = "evaluate.json"
_OURS = re.compile(r"^ours_(\d+)$")


class PredictionsError(StringsBenchError):
    """The predictions (or the ground truth given with them) cannot be evaluated as they are."""


# ---- reading the predictions ----------------------------------------------------------------------
@dataclass
class Checkpoint:
    """One checkpoint's files: render key -> path; gt and masks keyed the same way (None: not in the layout)."""

    iteration: int
    renders: dict[str, Path]
    gt: dict[str, Path] | None = None
    masks: dict[str, Path] | None = None
    label: str | None = None


@dataclass
class Predictions:
    layout: str
    root: Path
    checkpoints: list[Checkpoint]
    info: dict = field(default_factory=dict)  # nerfbaselines' info.json
    index_named: bool = False  # render keys are positions in the test split (Inria's 00000.png)


def _image_files(folder: Path, recursive: bool = False) -> dict[str, Path]:
    """Image files of `folder` keyed by their path relative to it without the suffix."""
    if not folder.is_dir():
        return {}
    pattern = "**/*" if recursive else "*"
    out = {}
    for p in sorted(folder.glob(pattern)):
        if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES:
            key = p.relative_to(folder).with_suffix("").as_posix()
            if key in out:
                raise PredictionsError(f"{out[key]} and {p} name the same view",
                                       hint="keep one image per view name (.png or .jpg, not both)")
            out[key] = p
    return out


def _inria_checkpoint(folder: Path, n: int) -> Checkpoint:
    renders = _image_files(folder / "renders")
    if not renders:
        raise PredictionsError(f"{folder / 'renders'} has no images", hint="expected renders/00000.png, ...")
    gt = _image_files(folder / "gt") if (folder / "gt").is_dir() else None
    masks = _image_files(folder / "masks") if (folder / "masks").is_dir() else None
    return Checkpoint(n, renders, gt, masks)


def detect_layout(root: Path) -> Predictions:
    """The layout of the predictions folder `root` (see the module docstring); a clear error when none fits."""
    root = Path(root)
    if not root.exists():
        raise PredictionsError(f"predictions {root} do not exist", hint="give a folder of renders, an Inria 3DGS "
                               "model folder, or nerfbaselines predictions (folder, .zip or .tar.gz)")
    if not root.is_dir():
        raise PredictionsError(f"predictions {root} are a file, not a folder or a .zip / .tar.gz archive",
                               hint="give the folder that holds the renders")
    # Inria: MODEL/test/ours_N, MODEL/test, or ours_N itself
    for test_dir in (root / "test", root):
        ours = sorted((int(m.group(1)), p) for p in (test_dir.iterdir() if test_dir.is_dir() else [])
                      if p.is_dir() and (m := _OURS.match(p.name)))
        if ours:
            return Predictions("inria", root, [_inria_checkpoint(p, n) for n, p in ours], index_named=True)
    if (m := _OURS.match(root.name)) and (root / "renders").is_dir():
        return Predictions("inria", root, [_inria_checkpoint(root, int(m.group(1)))], index_named=True)
    if (root / "color").is_dir() and (root / "gt-color").is_dir():
        info = {}
        if (root / "info.json").exists():
            try:
                info = json.loads((root / "info.json").read_text(encoding="utf-8"))
            except (OSError, ValueError) as exc:
                raise PredictionsError(f"cannot read {root / 'info.json'}: {exc}",
                                       hint="nerfbaselines writes it with the predictions; restore or delete it") from exc
        renders = _image_files(root / "color", recursive=True)
        if not renders:
            raise PredictionsError(f"{root / 'color'} has no images", hint="nerfbaselines writes color/<image>.png")
        masks = _image_files(root / "mask", recursive=True) if (root / "mask").is_dir() else None
        it = info.get("num_iterations") if isinstance(info, dict) else None
        return Predictions("nerfbaselines", root,
                           [Checkpoint(int(it) if isinstance(it, int) and it >= 0 else 0, renders,
                                       _image_files(root / "gt-color", recursive=True), masks)], info=info or {})
    renders = _image_files(root)
    if renders:
        return Predictions("folder", root, [Checkpoint(0, renders)])
    raise PredictionsError(
        f"{root} holds no renders: no images, no test/ours_<N>/renders (Inria 3DGS), no color/ + gt-color/ "
        f"(nerfbaselines)", hint="point evaluate at the folder of renders (see docs/evaluate.md)")


def _safe_members(names: list[str], archive: Path) -> None:
    for name in names:
        p = PurePosixPath(name.replace("\\", "/"))
        if p.is_absolute() or ".." in p.parts or re.match(r"^[A-Za-z]:", name):
            raise PredictionsError(f"archive {archive} holds {name!r}, a path outside the archive",
                                   hint="refused: extracting it would write outside the folder; repack the predictions")


@contextlib.contextmanager
def open_predictions(path: Path) -> Iterator[Path]:
    """`path` as a folder: itself, or a .zip / .tar.gz extracted into a temporary folder (removed after).
    Members with absolute paths, `..`, or links are refused before anything is extracted."""
    path = Path(path)
    name = path.name.lower()
    if path.is_dir() or not path.exists():
        yield path
        return
    with tempfile.TemporaryDirectory(prefix="strings-bench-pred-") as tmp:
        try:
            if name.endswith(".zip"):
                with zipfile.ZipFile(path) as zf:
                    _safe_members(zf.namelist(), path)
                    zf.extractall(tmp)
            elif name.endswith((".tar.gz", ".tgz", ".tar")):
                with tarfile.open(path) as tf:
                    members = tf.getmembers()
                    _safe_members([m.name for m in members], path)
                    links = [m.name for m in members if m.issym() or m.islnk() or not (m.isfile() or m.isdir())]
                    if links:
                        raise PredictionsError(f"archive {path} holds links or special files ({', '.join(links[:3])})",
                                               hint="refused: predictions are plain image files; repack without links")
                    tf.extractall(tmp)
            else:
                raise PredictionsError(f"predictions {path} are a file, not a folder or a .zip / .tar.gz archive",
                                       hint="give the folder that holds the renders")
        except (zipfile.BadZipFile, tarfile.TarError, OSError, EOFError) as exc:
            raise PredictionsError(f"cannot read archive {path}: {exc}", hint="the archive is corrupt or truncated") from exc
        root = Path(tmp)
        entries = [p for p in root.iterdir()]
        # an archive of one folder (predictions/...) is read as that folder
        yield entries[0] if len(entries) == 1 and entries[0].is_dir() and not (root / "color").is_dir() else root


def read_rgb(path: Path) -> np.ndarray:
    """An image file as (H, W, 3) uint8; a clear error naming the file when it cannot be read."""
    from PIL import Image

    try:
        with Image.open(path) as im:
            im.load()
            if im.mode in ("RGBA", "LA") or (im.mode == "P" and "transparency" in im.info):
                # as nerfbaselines' image_to_srgb does: alpha blended onto black
                arr = np.asarray(im.convert("RGBA"), dtype=np.float32) / 255.0
                return (arr[..., :3] * arr[..., 3:] * 255.0 + 0.5).astype(np.uint8)
            return np.asarray(im.convert("RGB"), dtype=np.uint8).copy()
    except (OSError, ValueError, SyntaxError, Image.DecompressionBombError) as exc:
        raise PredictionsError(f"cannot read image {path}: {exc}", hint="the file is missing or corrupt; replace it") from exc


def read_mask(path: Path) -> np.ndarray:
    """A mask file as (H, W) bool: > 127 after conversion to 8-bit grey, as the release's metrics_ocr does."""
    from PIL import Image

    try:
        with Image.open(path) as im:
            return np.asarray(im.convert("L")) > 127
    except (OSError, ValueError, SyntaxError, Image.DecompressionBombError) as exc:
        raise PredictionsError(f"cannot read mask {path}: {exc}", hint="the file is missing or corrupt; replace it") from exc


# ---- matching renders to views ----------------------------------------------------------------------
def _shown(items, n: int = 5) -> str:
    items = list(items)
    return ", ".join(str(x) for x in items[:n]) + (f" ... ({len(items)} in all)" if len(items) > n else "")


def match_renders(view_names: list[str], renders: dict[str, Path], index_named: bool, where: Path) -> dict[str, Path]:
    """view name -> render file. Renders are matched by the view's stem (its path without the suffix), or, for
    index-named renders (00000, 00001, ...), by position in `view_names`. Renders matching no view are an error."""
    if index_named and all(k.isdigit() for k in renders):
        by_key = {f"{i:05d}": n for i, n in enumerate(view_names)}
    else:
        by_key = {str(PurePosixPath(n).with_suffix("")): n for n in view_names}
    stray = [renders[k].name for k in renders if k not in by_key]
    if stray and len(stray) == len(renders):
        raise PredictionsError(
            f"no render in {where} is named after a test view: renders {_shown(sorted(renders))}; "
            f"test views {_shown(view_names)}",
            hint="name each render after its test view (<view stem>.png), or index them 00000.png... in test-split order")
    if stray:
        raise PredictionsError(f"render(s) {_shown(sorted(stray))} in {where} match no test view",
                               hint=f"test views: {_shown(view_names)}; remove the extra files or fix their names")
    return {by_key[k]: p for k, p in renders.items()}


@dataclass
class Source:
    """Where the ground truth of an evaluation comes from: a scene (known text, the suite's masks) or images."""

    kind: str  # "scene" or "images"
    dataset: str
    scene: str
    scene_obj: object | None = None
    settings: dict = field(default_factory=dict)
    gt_dir: Path | None = None


def _views_from_images(gt_files: dict[str, Path], mask_files: dict[str, Path] | None, where: str):
    from strings_bench.eval.protocol import GIVEN_MASK, EvalView

    views = []
    for key in sorted(gt_files):
        mask = None
        if mask_files is not None:
            if key not in mask_files:
                raise PredictionsError(f"no mask for view {gt_files[key].name} in {where}",
                                       hint="give one mask per view, named like the view (<stem>.png)")
            mask = read_mask(mask_files[key])
        gt = read_rgb(gt_files[key])
        if mask is not None and mask.shape != gt.shape[:2]:
            raise PredictionsError(f"mask {mask_files[key]} is {mask.shape[1]}x{mask.shape[0]}, its view "
                                   f"{gt_files[key]} is {gt.shape[1]}x{gt.shape[0]}", hint="a mask must be the size of its image")
        views.append(EvalView(name=f"{key}{gt_files[key].suffix}", gt=gt, mask=mask, known_words=None, mask_kind=GIVEN_MASK))
    return views


def _scene_downscale(scene, render: np.ndarray, i: int, given: float | None) -> float:
    if given is not None:
        return float(given)
    cam = scene.model.cameras[i]
    return cam.width / render.shape[1]


# ---- the command ---------------------------------------------------------------------------------------
@dataclass
class EvaluateOptions:
    scene: str | None = None  # registry id (synthetic/books) or a scene folder
    gt: Path | None = None
    masks: Path | None = None
    out: Path | None = None
    method: str | None = None
    dataset: str | None = None
    scene_name: str | None = None
    iteration: int | None = None
    downscale: float | None = None
    ocr: object = "rapidocr"
    cer_profile: str = "paper"
    with_lpips: bool = True
    allow_missing: bool = False
    train_seconds: float | None = None
    report: bool = True
    progress: bool = True


def default_out(pred: Path) -> Path:
    return Path("runs") / "evaluate" / safe_name(Path(pred).name.split(".")[0] or "predictions")


def evaluate(pred: str | Path, opts: EvaluateOptions, say=print) -> Path:
    """Evaluate the predictions at `pred` (see the module docstring); returns the output folder."""
    from strings_bench.bench.runner import _get_ocr, _jsonable, _write_png, versions
    from strings_bench.eval.cer import get_profile
    from strings_bench.eval.metrics import describe as metrics_describe
    from strings_bench.eval.protocol import Evaluator, scene_views

    pred = Path(pred)
    get_profile(opts.cer_profile)
    if opts.scene and opts.gt:
        raise PredictionsError("give --scene or --gt, not both", hint="--scene: a scene of the suite; --gt: a folder of GT images")
    out = Path(opts.out) if opts.out else default_out(pred)
    engines = _get_ocr(opts.ocr)  # an unknown engine fails before anything is read
    with open_predictions(pred) as root:
        preds = detect_layout(root)
        say(f"layout: {preds.layout} ({len(preds.checkpoints)} checkpoint(s): "
            f"{', '.join(str(c.iteration) for c in preds.checkpoints)})")
        given_masks = _image_files(Path(opts.masks), recursive=True) if opts.masks else None
        if opts.masks and not given_masks:
            raise PredictionsError(f"mask folder {opts.masks} has no images", hint="one <view stem>.png per view")
        source = _source(preds, opts, pred)
        method = opts.method or _default_method(preds, pred)
        manifest = {"predictions": str(pred.resolve()), "layout": preds.layout, "method": method,
                    "dataset": source.dataset, "scene": source.scene, "ground_truth": _describe_source(source),
                    "masks": str(Path(opts.masks).resolve()) if opts.masks else None,
                    "ocr": [e.name for e in engines], "cer_profile": opts.cer_profile, "downscale": opts.downscale,
                    "allow_missing": opts.allow_missing}
        _check_manifest(out, manifest)
        evaluator_cache: dict = {}
        written = []
        for ck in preds.checkpoints:
            key = CellKey(method, source.dataset, source.scene, ck.iteration)
            if is_finished(out, key):
                say(f"  {ck.iteration}: already evaluated ({key.path(out) / RESULT_FILE})")
                continue
            t0 = time.perf_counter()
            renders_files, views, ds, mask_settings = _checkpoint_views(preds, ck, source, opts, given_masks, root,
                                                                         evaluator_cache, scene_views)
            missing = [n for n in views if n not in renders_files]
            if missing and not opts.allow_missing:
                raise PredictionsError(
                    f"checkpoint {ck.iteration}: no render for {len(missing)} of {len(views)} test view(s): {_shown(missing)}",
                    hint="render every test view, or pass --allow-missing to score the missing ones as unread (CER 1)")
            renders = {}
            for name, path in renders_files.items():
                img = read_rgb(path)
                gt = views[name].gt
                if img.shape != np.asarray(gt).shape:
                    raise PredictionsError(f"render {path} is {img.shape[1]}x{img.shape[0]}, its ground truth "
                                           f"({name}) is {np.asarray(gt).shape[1]}x{np.asarray(gt).shape[0]}",
                                           hint="renders must be at the ground truth's size (check --downscale)")
                renders[name] = img
            ev_key = (id(views), ds)
            if ev_key not in evaluator_cache:
                evaluator_cache[ev_key] = Evaluator(list(views.values()), engines, with_lpips=opts.with_lpips,
                                                    cer_profile=opts.cer_profile, mask_settings=mask_settings)
            evaluator = evaluator_cache[ev_key]
            result = evaluator.evaluate(method, renders, missing=missing)
            cell_dir = key.path(out)
            gt_dir = out / "gt" / safe_name(source.dataset) / safe_name(source.scene)
            for name in evaluator.names:
                stem = PurePosixPath(name).with_suffix("").as_posix().replace("/", "_")
                if name in renders:
                    _write_png(cell_dir / "renders" / f"{stem}.png", renders[name])
                if not (gt_dir / f"{stem}.png").exists():
                    _write_png(gt_dir / f"{stem}.png", evaluator.gt(name))
            from strings_bench.reports.results import iteration_label

            train = opts.train_seconds
            record = {
                "method": method, "dataset": source.dataset, "scene": source.scene, "iteration": ck.iteration,
                "label": ck.label or iteration_label(ck.iteration),
                "config": {"evaluate": {**manifest, "checkpoint": ck.iteration}, "preset": None, "downscale": ds,
                           "cer_profile": opts.cer_profile, "scene": {"settings": source.settings, "test_views": evaluator.names},
                           "versions": versions(), "metrics": metrics_describe()},
                "resumed_from_step": 0, "device": "", "gpu": None,
                "timings": {"train_seconds": train, "preprocess_seconds": None if train is None else 0.0,
                            "total_seconds": train, "eval_seconds": time.perf_counter() - t0},
                "gaussians": None, "peak_memory_mb": None, "extra": {"layout": preds.layout},
                **result,
            }
            _write_manifest(out, manifest)
            atomic_write_json(cell_dir / RESULT_FILE, _jsonable(record))
            written.append(key)
            c = result["cer"]["cer"]
            say(f"  {ck.iteration}: OCR-CER {c if c is None else f'{c:.3f}'}, PSNR {result['metrics']['psnr']:.2f}"
                + (f", {len(missing)} render(s) missing, scored as unread" if missing else ""))
    from strings_bench.reports.results import write_results_csv

    write_results_csv(out)
    if opts.report:
        from strings_bench.reports import write_report

        write_report(out)
    return out


def _default_method(preds: Predictions, pred: Path) -> str:
    if preds.layout == "nerfbaselines" and isinstance(preds.info.get("method"), str):
        return preds.info["method"]
    name = pred.name.split(".")[0]
    if preds.layout == "inria":
        # MODEL/test/ours_N or MODEL/test: the model folder's name
        p = pred
        while _OURS.match(p.name) or p.name == "test":
            p = p.parent
        name = p.name
    return safe_name(name or "external")


def _source(preds: Predictions, opts: EvaluateOptions, pred: Path) -> Source:
    if opts.scene:
        from strings_bench.datasets.registry import resolve_scenes
        from strings_bench.scene.scene import Scene

        refs = resolve_scenes([opts.scene])
        if len(refs) != 1:
            raise PredictionsError(f"--scene {opts.scene} names {len(refs)} scenes", hint="give one scene, e.g. synthetic/books")
        ref = refs[0]
        scene = Scene.load(ref.path, name=ref.scene, settings=dict(ref.settings))
        return Source("scene", opts.dataset or ref.dataset, opts.scene_name or ref.scene, scene, dict(ref.settings))
    if opts.gt is None and not all(ck.gt for ck in preds.checkpoints):
        raise PredictionsError(f"the {preds.layout} predictions at {pred} carry no ground truth",
                               hint="give --scene SCENE (a scene of the suite) or --gt GT_DIR (a folder of GT images)")
    name = opts.scene_name or safe_name(pred.name.split(".")[0] or "scene")
    return Source("images", opts.dataset or "external", name, gt_dir=Path(opts.gt) if opts.gt else None)


def _describe_source(source: Source) -> dict:
    if source.kind == "scene":
        return {"scene": str(source.scene_obj.root), "settings": source.settings}
    return {"images": str(source.gt_dir.resolve()) if source.gt_dir else "beside the renders"}


def _checkpoint_views(preds, ck: Checkpoint, source: Source, opts: EvaluateOptions, given_masks, root, cache, scene_views):
    """(render files by view name, views by name, downscale, mask settings) of one checkpoint."""
    masks = given_masks if given_masks is not None else ck.masks
    if source.kind == "scene":
        scene = source.scene_obj
        names = [scene.names[i] for i in scene.test_idx]
        files = match_renders(names, ck.renders, preds.index_named, root)
        if not files:
            raise PredictionsError(f"no render for the test views of {source.scene}", hint="see docs/evaluate.md")
        first = next(iter(files))
        ds = _scene_downscale(scene, read_rgb(files[first]), scene.test_idx[names.index(first)], opts.downscale)
        ck_key = ("scene", ds, None if masks is None else id(masks))
        if ck_key not in cache:
            from strings_bench.eval.protocol import GIVEN_MASK, EvalView
            from strings_bench.eval.text_masks import eval_mask_settings

            if masks is None:
                settings = eval_mask_settings(scene)
                views = scene_views(scene, ds, settings)
            else:  # given masks (release render.py's masks/, --masks): used as they are, keyed like the renders
                settings = None
                keyed = match_renders(names, masks, preds.index_named, root)
                views = []
                for v in scene_views(scene, ds, None):
                    if v.name not in keyed:
                        raise PredictionsError(f"no mask for test view {v.name}", hint="give one mask per view")
                    m = read_mask(keyed[v.name])
                    if m.shape != np.asarray(v.gt).shape[:2]:
                        raise PredictionsError(f"mask {keyed[v.name]} is {m.shape[1]}x{m.shape[0]}, the view is "
                                               f"{np.asarray(v.gt).shape[1]}x{np.asarray(v.gt).shape[0]}",
                                               hint="a mask must be the size of its image")
                    views.append(EvalView(v.name, v.gt, m, v.known_words, GIVEN_MASK))
            cache[ck_key] = ({v.name: v for v in views}, settings)
        views, settings = cache[ck_key]
        return files, views, ds, settings
    # ground truth from images: --gt, or the layout's gt/ (gt-color/)
    gt_files = _image_files(source.gt_dir, recursive=True) if source.gt_dir else ck.gt
    if not gt_files:
        raise PredictionsError(f"no ground-truth images in {source.gt_dir or root}", hint="one image per test view")
    ck_key = ("images", id(gt_files) if source.gt_dir is None else str(source.gt_dir), None if masks is None else id(masks))
    if ck_key not in cache:
        if source.gt_dir is not None:
            gt_files = cache.setdefault(("gt_files", str(source.gt_dir)), gt_files)
        cache[ck_key] = ({v.name: v for v in _views_from_images(gt_files, masks, str(root))}, None)
    views, settings = cache[ck_key]
    names = list(views)
    files = match_renders(names, ck.renders, False, root)  # GT and renders carry the same names
    return files, views, opts.downscale, settings


def _check_manifest(out: Path, manifest: dict) -> None:
    path = out / MANIFEST
    if path.exists():
        try:
            old = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, ValueError) as exc:
            raise PredictionsError(f"cannot read {path}: {exc}", hint="delete it, or use another --out folder") from exc
        differ = [k for k in manifest if old.get(k) != manifest[k]]
        if differ:
            raise PredictionsError(f"{out} holds an evaluation with other {', '.join(differ)}",
                                   hint="use another --out folder, or delete that one to evaluate afresh")
        return
    if (out / "cells").exists() and not path.exists():
        raise PredictionsError(f"{out} holds cells but no {MANIFEST}: it is a run folder, not an evaluation",
                               hint="use another --out folder")


def _write_manifest(out: Path, manifest: dict) -> None:
    """Written with the first cell, so that refused input leaves no folder behind that refuses the next try."""
    if not (out / MANIFEST).exists():
        atomic_write_json(out / MANIFEST, manifest)
