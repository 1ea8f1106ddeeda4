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

import json
import logging
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from strings_bench.bench.predictions import (OURS_DIR, Checkpoint, Predictions, PredictionsError,  # noqa: F401
                                             detect_layout, image_files, match_renders, open_predictions, shown,
                                             read_mask, read_rgb)
from strings_bench.core.io import atomic_write_json
from strings_bench.core.results import RESULT_FILE, CellKey, is_finished, safe_name

log = logging.getLogger(__name__)

MANIFEST = "evaluate.json"


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
    """How `evaluate` scores a predictions folder; `strings-bench evaluate`'s options, one field each.

    Attributes:
        scene: the ground truth as a scene of the suite: a registry id ("synthetic/books") or a scene folder; its
            masks, known text and test split are used. Give `scene` or `gt`, not both.
        gt: a folder of ground-truth images named like the renders (when the predictions hold none).
        masks: a folder of text masks (<view stem>.png), over the scene's or the layout's own.
        out: the output run folder (default: runs/evaluate/<predictions' name>).
        method, dataset, scene_name, iteration: the names the cells get (defaults: from the predictions).
        downscale: the renders' downscale against the scene's images (default: from the sizes).
        ocr: engine name(s), comma-separated ("rapidocr", "rapidocr,tesseract"), or an `OCRBackend` object.
        cer_profile: how text is normalised before CER ("paper": the authors' protocol).
        with_lpips: compute LPIPS (needs the LPIPS-VGG weights).
        allow_missing: score a test view without a render as unread (CER 1) instead of refusing.
        min_gt_chars: the floor on GT characters below which a scene's OCR-CER is left empty (None: the scene's
            own `min_gt_chars`, else eval/floors.py MIN_GT_CHARS when the views have no known text, else none;
            0: no floor, the CER is kept however little text the GT reads).
        train_seconds: the training time to record with the cells (None: not known).
        report: write report/ (tables, figures, index.html).
        progress: show progress bars.
    """

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
    min_gt_chars: int | None = None
    train_seconds: float | None = None
    report: bool = True
    progress: bool = True


def default_out(pred: Path) -> Path:
    return Path("runs") / "evaluate" / safe_name(Path(pred).name.split(".")[0] or "predictions")


def evaluate(pred: str | Path, opts: EvaluateOptions, say=print) -> Path:
    """Score the renders at `pred` with the suite's OCR-CER, word-crop and image metrics, into a run folder.

    Args:
        pred: a predictions folder or archive in one of the layouts (`inria`, `nerfbaselines`, `folder`: the
            module's docstring; docs/guide/evaluate.md).
        opts: the options (`EvaluateOptions`).
        say: where progress lines go (default: print).
    Returns:
        the output folder: results.csv, cells/<method>/<dataset>/<scene>/<iteration>/result.json and, unless
        `opts.report` is False, report/. A checkpoint already scored there is skipped (the run resumes).
    Raises:
        PredictionsError: the layout is not recognised, a render is missing (without `allow_missing`) or not the
            size of its ground truth, both `scene` and `gt` are given, or the folder was evaluated before with
            other options.
        OCRError: an unknown OCR engine (before anything is read).
    """
    from strings_bench.bench.records import versions, write_gt_pngs, write_run_report
    from strings_bench.eval.ocr import get_engines
    from strings_bench.store import CellConfig, CellRecord, iteration_label, write_cell, write_results_csv
    from strings_bench.eval.cer import get_profile
    from strings_bench.eval.metrics import describe as metrics_describe
    from strings_bench.eval.protocol import Evaluator, scene_views

    pred = Path(pred)
    get_profile(opts.cer_profile)
    if opts.scene and opts.gt:
        raise PredictionsError("give --scene or --gt, not both", hint="--scene: a scene of the suite; --gt: a folder of GT images")
    out = Path(opts.out) if opts.out else default_out(pred)
    engines = get_engines(opts.ocr)  # an unknown engine fails before anything is read
    with open_predictions(pred, progress=opts.progress) as root:
        preds = detect_layout(root)
        say(f"layout: {preds.layout} ({len(preds.checkpoints)} checkpoint(s): "
            f"{', '.join(str(c.iteration) for c in preds.checkpoints)})")
        given_masks = image_files(Path(opts.masks), recursive=True) if opts.masks else None
        if opts.masks and not given_masks:
            raise PredictionsError(f"mask folder {opts.masks} has no images", hint="one <view stem>.png per view")
        source = _source(preds, opts, pred)
        if isinstance(opts.ocr, str):  # a scene that names its own GT engine is read by it first (eval.ocr.scene_engines)
            from strings_bench.eval.ocr import scene_engines

            spec, note = scene_engines(opts.ocr, source.settings if isinstance(source.settings, dict) else None)
            if note:
                say(f"{source.scene}: {note}")
                engines = get_engines(spec)
        method = opts.method or _default_method(preds, pred)
        manifest = {"predictions": str(pred.resolve()), "layout": preds.layout, "method": method,
                    "dataset": source.dataset, "scene": source.scene, "ground_truth": _describe_source(source),
                    "masks": str(Path(opts.masks).resolve()) if opts.masks else None,
                    "ocr": [e.name for e in engines], "cer_profile": opts.cer_profile, "downscale": opts.downscale,
                    "allow_missing": opts.allow_missing}
        if opts.min_gt_chars is not None:  # recorded when given, so that a folder made without it still resumes
            manifest["min_gt_chars"] = int(opts.min_gt_chars)
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
                    f"checkpoint {ck.iteration}: no render for {len(missing)} of {len(views)} test view(s): {shown(missing)}",
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
                                                    cer_profile=opts.cer_profile, mask_settings=mask_settings,
                                                    min_gt_chars=_floor(opts, source, views))
            evaluator = evaluator_cache[ev_key]
            result = evaluator.evaluate(method, renders, missing=missing)
            train = opts.train_seconds
            record = CellRecord(
                method=method, dataset=source.dataset, scene=source.scene, iteration=ck.iteration,
                label=ck.label or iteration_label(ck.iteration),
                config=CellConfig(evaluate={**manifest, "checkpoint": ck.iteration}, schedule=None, downscale=ds,
                                  cer_profile=opts.cer_profile,
                                  scene={"settings": source.settings, "test_views": evaluator.names},
                                  versions=versions(), metrics=metrics_describe()),
                timings={"train_seconds": train, "preprocess_seconds": None if train is None else 0.0,
                         "total_seconds": train, "train_cpu_seconds": None, "eval_seconds": time.perf_counter() - t0},
                extra={"layout": preds.layout}, scores=result)
            write_gt_pngs(out, source.dataset, source.scene, evaluator)
            _write_manifest(out, manifest)
            write_cell(key.path(out), record, {n: renders[n] for n in evaluator.names if n in renders})
            written.append(key)
            c = result["cer"]["cer"]
            say(f"  {ck.iteration}: OCR-CER {c if c is None else f'{c:.3f}'}, PSNR {result['metrics']['psnr']:.2f}"
                + (f", {len(missing)} render(s) missing, scored as unread" if missing else ""))
    write_results_csv(out)
    if opts.report:
        write_run_report(out)
    return out


def _floor(opts: EvaluateOptions, source: Source, views: dict) -> int | None:
    """The GT-character floor of this evaluation: the option when given (0: none), else the scene's rule."""
    from strings_bench.eval.floors import gt_floor

    if opts.min_gt_chars is not None:
        if int(opts.min_gt_chars) < 0:
            raise PredictionsError(f"min_gt_chars must be 0 (no floor) or more, got {opts.min_gt_chars}")
        return int(opts.min_gt_chars) or None
    return gt_floor(source.settings, list(views.values()))


def _default_method(preds: Predictions, pred: Path) -> str:
    if preds.layout == "nerfbaselines" and isinstance(preds.info.get("method"), str):
        return preds.info["method"]
    name = pred.name.split(".")[0]
    if preds.layout == "inria":
        # MODEL/test/ours_N or MODEL/test: the model folder's name
        p = pred
        while OURS_DIR.match(p.name) or p.name == "test":
            p = p.parent
        name = p.name
    return safe_name(name or "external")


def _source(preds: Predictions, opts: EvaluateOptions, pred: Path) -> Source:
    if opts.scene:
        from strings_bench.core.progress import progress_bars
        from strings_bench.datasets.registry import resolve_scenes

        with progress_bars(opts.progress):  # a scene built on first use: its bars only when evaluate shows its own
            refs = resolve_scenes([opts.scene])
        if len(refs) != 1:
            raise PredictionsError(f"--scene {opts.scene} names {len(refs)} scenes", hint="give one scene, e.g. synthetic/books")
        ref = refs[0]
        scene = ref.load()
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
            raise PredictionsError(f"no render for the test views of {source.scene}", hint="see docs/guide/evaluate.md")
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
    gt_files = image_files(source.gt_dir, recursive=True) if source.gt_dir else ck.gt
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
