"""Evaluation as its own protocol: ground truth, renders, masks and known text in; per-view and aggregate
results out. It writes no files.

The runner (bench/runner.py) and `strings-bench evaluate` (bench/evaluate.py) both call it, so a run's
cell and the evaluation of that cell's saved renders are the same computation. The split follows
nerfbaselines' `EvaluationProtocol` (render / evaluate / accumulate_metrics): whoever renders hands
over images, this module judges them.

    views = scene_views(scene, downscale)              # or EvalView(...) built from any folder of images
    evaluator = Evaluator(views, get_backend("rapidocr"))
    result = evaluator.evaluate("3dgs", {"view_000.png": render, ...})
    result["cer"]["cer"], result["metrics"]["psnr"], result["readability"]

What is scored is the 8-bit image (`to_uint8`, the rounding 3DGS' `save_image` uses): 3DGS' render.py
saves PNGs and its metrics.py reads them back, and a render folder scored later holds the same bytes.

Per view: PSNR, SSIM, LPIPS (eval/metrics.py), the text-region metrics on the mask, the OCR words of GT
and render (eval/ocr, read through the view's mask as the authors do: image x mask), and the word
crops (eval/readability.py). Per cell: the authors' recall-based OCR-CER (eval/cer.py, summed over
views), the known-text CER where the view's text is known, the means of the image metrics, and any
further OCR engine's reading with its agreement with the first.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Iterable, Mapping, Sequence

import numpy as np

from strings_bench.core.errors import OCRError, StringsBenchError
from strings_bench.eval.floors import gt_floor

if TYPE_CHECKING:
    from strings_bench.scene.scene import Scene

log = logging.getLogger(__name__)

WHOLE_IMAGE = "whole image"
SCENE_MASK = "dilated text mask"  # the scene's text mask (eval/text_masks.py), as the runner has always recorded it
GIVEN_MASK = "given mask (> 127), not dilated"  # a mask file beside the renders, read as the release's metrics_ocr does


def to_uint8(img: np.ndarray) -> np.ndarray:
    """The 8-bit image that is saved and scored: clip to [0, 1], x255, +0.5, truncate (torchvision's
    save_image, which 3DGS' render.py uses). uint8 input is returned as it is."""
    arr = np.asarray(img)
    if arr.dtype == np.uint8:
        return arr
    return (np.clip(arr.astype(np.float32, copy=False), 0, 1) * 255.0 + 0.5).astype(np.uint8)


def scored_image(img: np.ndarray) -> np.ndarray:
    """(H, W, 3) float32 in [0, 1] on the 8-bit grid: what every metric of this module sees."""
    return to_uint8(img).astype(np.float32) / 255.0


@dataclass(frozen=True)
class EvalView:
    """One test view to score against.

    name: the view's image name; renders are matched to views by it.
    gt: (H, W, 3) ground truth, float32 in [0, 1] (or uint8).
    mask: (H, W) bool text mask OCR reads through (image x mask), or None for the whole image.
    known_words: the view's known text at this resolution, objects with `.text` and `.polygon`
        (synthetic scenes), or None when the text is unknown (known-text CER is then n/a, never 0).
    mask_kind: what the mask is, as recorded in result.json.
    """

    name: str
    gt: np.ndarray
    mask: np.ndarray | None = None
    known_words: tuple | None = None
    mask_kind: str = SCENE_MASK

    def __post_init__(self):
        gt = np.asarray(self.gt)
        if gt.ndim != 3 or gt.shape[2] != 3:
            raise StringsBenchError(f"ground truth of view {self.name} has shape {gt.shape}, expected (H, W, 3)",
                                    hint="give RGB images")
        if self.mask is not None and np.asarray(self.mask).shape != gt.shape[:2]:
            raise StringsBenchError(
                f"mask of view {self.name} is {np.asarray(self.mask).shape[1]}x{np.asarray(self.mask).shape[0]}, "
                f"its ground truth is {gt.shape[1]}x{gt.shape[0]}", hint="a mask must be the size of its image")


def render_problems(renders: Mapping[str, np.ndarray], shapes: Mapping[str, tuple], missing: Iterable[str] = (),
                    strict: bool = False, constant_ptp: float = 1e-4) -> list[str]:
    """What is wrong with a set of renders, one sentence each (empty: nothing): a view of `shapes` with no
    render (unless in `missing`), a render of another shape, non-finite values. `strict` (the conformance
    check of `methods check`) also asks for floats within [0, 1] that are not constant. The runner and
    `strings-bench evaluate` refuse on the first problem; `methods check` reports it."""
    missing = set(missing)
    absent = [n for n in shapes if n not in renders and n not in missing]
    if absent:
        return [f"no render of test view(s) {', '.join(absent[:5])}{f' ... ({len(absent)} in all)' if len(absent) > 5 else ''}"
                f" (got {', '.join(map(str, list(renders)[:5])) or 'none'})"]
    problems = []
    for n, shape in shapes.items():
        if n not in renders:
            continue
        r = np.asarray(renders[n])
        if r.shape != tuple(shape):
            problems.append(f"render of {n} has shape {r.shape}, expected {tuple(shape)} (H, W, 3)")
            continue
        if strict and r.dtype.kind != "f":
            problems.append(f"render of {n} has dtype {r.dtype}, expected float values in [0, 1]")
            continue
        bad = 0 if r.dtype == np.uint8 else int((~np.isfinite(r)).sum())
        if bad:
            problems.append(f"render of {n} has {bad} NaN/Inf value(s) of {r.size}")
            continue
        if strict and (r.min() < -1e-6 or r.max() > 1 + 1e-6):
            problems.append(f"render of {n} spans [{r.min():.4g}, {r.max():.4g}], outside [0, 1]")
        elif strict and np.ptp(r) < constant_ptp:
            problems.append(f"render of {n} is constant ({float(r.flat[0]):.4g} everywhere)")
    return problems


def scene_views(scene: "Scene", downscale: float, mask_settings: Mapping | None | str = "auto") -> list[EvalView]:
    """The test views of `scene` at `downscale`: GT image, the evaluation text mask (eval/text_masks.py,
    `eval_mask_settings` unless `mask_settings` is given) and the known words."""
    from strings_bench.eval.text_masks import eval_mask, eval_mask_settings

    settings = eval_mask_settings(scene) if mask_settings == "auto" else mask_settings
    views = []
    for i in scene.test_idx:
        known = scene.known_words(i, downscale)
        views.append(EvalView(name=scene.names[i], gt=scene.load_image(i, downscale),
                              mask=eval_mask(scene, i, downscale, settings),
                              known_words=None if known is None else tuple(known)))
    return views


def known_text_scripts(views: Sequence[EvalView]) -> tuple[list[str], list[str]]:
    """(scripts, languages) of the views' known words: scripts by their characters (core.scripts), most
    frequent first; languages as annotated (`lang` of the words, synthetic-multi scenes)."""
    from strings_bench.core.scripts import scripts_of

    words = [k for v in views for k in (v.known_words or ())]
    langs = list(dict.fromkeys(lang for k in words if (lang := getattr(k, "lang", None))))
    return scripts_of(str(k.text) for k in words), langs


class Evaluator:
    """Scores renders of a fixed set of test views. GT-side work (GT OCR, LPIPS features, GT word crops) is
    done once and reused for every checkpoint and method.

    `ocr_backend` is one OCR backend or a list of them (`--ocr rapidocr,tesseract`): the first is the
    primary engine (`cer`, `cer_known`, the word-crop readability); each further one is scored the same way
    and compared with the primary (`ocr_engines` in the result). GT OCR is kept per engine.
    `mask_settings` is recorded in the result (how the masks were made; None: whole images or given masks).
    `with_readability` False leaves out the word-crop metrics (their recogniser takes seconds to load).
    """

    def __init__(self, views: Sequence[EvalView], ocr_backend, *, with_lpips: bool = True, cer_profile: str = "paper",
                 device: str = "cpu", ocr_workers: int | None = None, mask_settings: dict | None = None,
                 with_readability: bool = True, min_gt_chars: int | None = None):
        # OCR-CER is reported as not scored (cer None, with the reason) when the GT reads fewer characters than this
        # on the test views (a scene's `min_gt_chars` setting; the captures dataset sets it); None: no floor.
        self.min_gt_chars, self._floor_warned = (None if min_gt_chars is None else int(min_gt_chars)), False
        self.ocr_workers = ocr_workers  # reads at once per engine (None: the engine's default_workers)
        self.device = device  # where LPIPS runs
        self.cer_profile = cer_profile
        self.engines = list(ocr_backend) if isinstance(ocr_backend, (list, tuple)) else [ocr_backend]
        if not self.engines:
            raise StringsBenchError("no OCR engine given", hint="e.g. --ocr rapidocr")
        names = [e.name for e in self.engines]
        if len(set(names)) != len(names):
            raise StringsBenchError(f"OCR engines {names} name one engine twice", hint="name each engine once")
        self.ocr = self.engines[0]
        self.with_lpips = with_lpips
        self.mask_settings = mask_settings
        self.views = {v.name: v for v in views}
        if len(self.views) != len(views):
            raise StringsBenchError("two test views share a name", hint="view names must be unique")
        self.names = [v.name for v in views]
        self._gt = {v.name: scored_image(v.gt) for v in views}
        self._gt_ocr: dict[tuple[str, str], list | None] = {}  # (engine, view) -> GT words (None: OCR failed)
        self._gt_ocr_error: dict[tuple[str, str], str] = {}
        self._lpips_ref: dict[str, tuple] = {}  # view -> (GT features, (text crop box, its features) or None)
        self._readability = None if with_readability else False  # eval.readability.SceneReadability, made once
        self.known_scripts, self.known_languages = known_text_scripts(views)
        # An engine set to read "the scene's languages" (tesseract lang=auto) is resolved to them here.
        self.engines = [e.for_languages(self.known_languages) if hasattr(e, "for_languages") else e for e in self.engines]
        self.ocr = self.engines[0]
        if self._readability is None and self.known_scripts:
            # The word-crop readability runs RapidOCR's recogniser: not on text in scripts it cannot read.
            from strings_bench.eval.ocr.languages import rapidocr_supported_scripts

            try:
                unread = [sc for sc in self.known_scripts if sc not in rapidocr_supported_scripts()]
            except OCRError:  # no recogniser: readability() says so itself
                unread = []
            if unread:
                log.info("word-crop readability is not computed: its recogniser (RapidOCR) does not read %s",
                         ", ".join(unread))
                self._readability = False
        for engine in self.engines:  # an engine that cannot read the scene's script refuses it, naming who can
            check = getattr(engine, "require_scripts", None)
            if check is not None and self.known_scripts:
                check(self.known_scripts, f"these test views (known text in {', '.join(self.known_scripts)})")

    @classmethod
    def for_scene(cls, scene: "Scene", ocr_backend, downscale: float, **kwargs) -> "Evaluator":
        """An Evaluator of `scene`'s test views at `downscale` (`scene_views`), recording its mask settings."""
        from strings_bench.eval.text_masks import eval_mask_settings

        settings = eval_mask_settings(scene)
        views = scene_views(scene, downscale, settings)
        kwargs.setdefault("min_gt_chars", gt_floor(scene.settings, views))
        return cls(views, ocr_backend, mask_settings=settings, **kwargs)

    def floored(self, scene_cer: dict) -> dict:
        """A scene CER's dict with the floor on GT characters applied: below it, `cer` is None and `not_scored`
        says why (errors and characters are kept)."""
        floor = self.min_gt_chars
        if floor is None or scene_cer.get("chars", 0) >= floor:
            return scene_cer
        why = (f"the GT reads {scene_cer.get('chars', 0)} characters on the test views, below this scene's floor of "
               f"{floor} (min_gt_chars): too few for a CER")
        if not self._floor_warned:  # once per scene's evaluator, not per checkpoint
            self._floor_warned = True
            log.warning("OCR-CER not scored: %s; the run goes on, its cer is left empty (docs/guide/datasets.md, "
                        "'Too little text for a CER')", why)
        return {**scene_cer, "cer": None, "not_scored": why}

    # ---- ground-truth side ---------------------------------------------------------------------
    def gt(self, name: str) -> np.ndarray:
        """View `name`'s ground truth as scored: (H, W, 3) float32 on the 8-bit grid."""
        return self._gt[name]

    def mask(self, name: str) -> np.ndarray | None:
        return self.views[name].mask

    def gt_words(self, name: str, engine=None):
        """The OCR words of view `name`'s ground truth by `engine` (default the primary), read once."""
        engine = engine or self.ocr
        key = (engine.name, name)
        if key not in self._gt_ocr:
            try:
                self._gt_ocr[key] = engine.read(to_uint8(self.gt(name)), mask=self.mask(name))
            except OCRError as exc:
                self._gt_ocr[key] = None
                self._gt_ocr_error[key] = str(exc)
        return self._gt_ocr[key]

    def lpips_refs(self, name: str) -> tuple:
        """View `name`'s GT LPIPS features and its text crop's (metrics.text_lpips_reference), made once."""
        import strings_bench.eval.metrics as metrics

        if name not in self._lpips_ref:
            whole = metrics.lpips_reference(self.gt(name), device=self.device)
            self._lpips_ref[name] = (whole, metrics.text_lpips_reference(self.gt(name), self.mask(name), self.device, whole))
        return self._lpips_ref[name]

    # ---- renders -------------------------------------------------------------------------------
    def read_views(self, renders: Mapping[str, np.ndarray], engine=None, names: Iterable[str] | None = None) -> dict[str, tuple]:
        """`engine`'s (default the primary's) reading of the renders of `names` (default every view), and of
        the GT views not read yet (kept for gt_words), in one read_many pool: name -> (words or None, error)."""
        from strings_bench.eval.ocr.base import read_many

        engine = engine or self.ocr
        names = self.names if names is None else list(names)
        gt_todo = [n for n in self.names if (engine.name, n) not in self._gt_ocr]
        images = [to_uint8(self.gt(n)) for n in gt_todo] + [to_uint8(renders[n]) for n in names]
        masks = [self.mask(n) for n in gt_todo] + [self.mask(n) for n in names]
        results = read_many(engine, images, masks, workers=self.ocr_workers)
        for n, res in zip(gt_todo, results):
            failed = isinstance(res, OCRError)
            self._gt_ocr[(engine.name, n)] = None if failed else res
            if failed:
                self._gt_ocr_error[(engine.name, n)] = str(res)
        return {n: ((None, str(res)) if isinstance(res, OCRError) else (res, None))
                for n, res in zip(names, results[len(gt_todo):])}

    def check_renders(self, method: str, renders: Mapping[str, np.ndarray], missing: Iterable[str] = ()) -> None:
        """A clear error for a render that is absent (unless listed in `missing`), of another size, or not
        finite (`render_problems`)."""
        problems = render_problems(renders, {n: self.gt(n).shape for n in self.names}, missing)
        if problems:
            raise StringsBenchError(f"method {method}: {problems[0]}",
                                    hint="render every test view, keyed by image name, at the test camera's size "
                                         "(NaN/Inf: training diverged; run with -v for details)")

    def readability(self, views: dict) -> dict | None:
        """Word-crop readability of a cell (eval.readability); None, logged, when the recogniser cannot load."""
        import strings_bench.eval.readability as readability

        if self._readability is None:
            try:
                self._readability = readability.SceneReadability()
            except OCRError as exc:
                log.warning("word-crop readability is not computed: %s", exc)
                self._readability = False
        return self._readability.evaluate(views) if self._readability else None

    def evaluate(self, method: str, renders: Mapping[str, np.ndarray], with_lpips: bool | None = None,
                 missing: Iterable[str] = ()) -> dict:
        """Everything about one checkpoint: {"metrics", "readability", "ocr", "cer", "cer_known"[, "ocr_engines",
        "missing_renders"]}. `renders` maps view names to (H, W, 3) images (float in [0, 1] or uint8).

        `missing` lists views with no render that are scored as unread (no words: every GT character is an
        error) and have no image metrics; any other absent render is an error."""
        import strings_bench.eval.cer as cer
        import strings_bench.eval.metrics as metrics

        with_lpips = self.with_lpips if with_lpips is None else with_lpips
        missing = [n for n in self.names if n in set(missing) and n not in renders]
        self.check_renders(method, renders, missing)
        scored = {n: scored_image(renders[n]) for n in self.names if n not in missing}
        per_view: dict[str, dict] = {}
        ocr_views: dict[str, dict] = {}
        pairs: dict[str, tuple] = {}
        known_pairs: dict[str, tuple] = {}
        read_views: dict[str, tuple] = {}  # word-crop readability inputs: (render, gt, known words, GT OCR words)
        render_reads = self.read_views(scored, names=[n for n in self.names if n not in missing])
        for name in self.names:
            view, gt = self.views[name], self.gt(name)
            r = scored.get(name)
            if r is not None:
                # image_metrics + text_region_metrics in one pass (the same values: tests/eval/test_eval_speed.py)
                whole, text = self.lpips_refs(name) if with_lpips else (None, None)
                per_view[name] = metrics.view_metrics(r, gt, view.mask, with_lpips=with_lpips, gt_reference=whole,
                                                      device=self.device, text_reference=text)
            gt_words = self.gt_words(name)
            render_words, render_err = render_reads.get(name, ([], None))  # a missing render reads nothing
            pairs[name] = (gt_words, render_words)
            ocr_views[name] = {
                "mask": WHOLE_IMAGE if view.mask is None else view.mask_kind,
                "gt_words": None if gt_words is None else [w.to_dict() for w in gt_words],
                "render_words": None if render_words is None else [w.to_dict() for w in render_words],
                "gt_error": self._gt_ocr_error.get((self.ocr.name, name)),
                "render_error": render_err,
                **({"render_missing": True} if r is None else {}),
            }
            known = None if view.known_words is None else list(view.known_words)
            if r is not None:
                read_views[name] = (r, gt, known, gt_words)
            if known:
                known_pairs[name] = ([(k.text, k.polygon) for k in known], render_words)
                ocr_views[name]["known_words"] = [{"text": k.text, "polygon": np.asarray(k.polygon).tolist()} for k in known]
        scene_cer = cer.scene_cer(pairs, profile=self.cer_profile)
        # Known-text CER leaves out words too small for any OCR (cer.KNOWN_TEXT_MIN_HEIGHT_PX); the result's
        # `legibility` records the threshold and the excluded counts. The paper-protocol CER above is untouched.
        known_cer = cer.known_scene_cer(known_pairs, profile=self.cer_profile) if known_pairs else None

        readability = self.readability(read_views)
        engines = {e.name: self.second_opinion(e, scored, pairs, missing) for e in self.engines[1:]}

        def mean(key):
            vals = [v[key] for v in per_view.values() if not math.isnan(v[key])]
            return float(np.mean(vals)) if vals else math.nan

        return {
            "metrics": {"psnr": mean("psnr"), "ssim": mean("ssim"), "lpips": mean("lpips"),
                        **{k: mean(k) for k in metrics.TEXT_METRICS}, "per_view": per_view},
            "readability": readability,
            "ocr": {"backend": self.ocr.describe(), "mask_settings": self.mask_settings, "views": ocr_views},
            "cer": self.floored(scene_cer.to_dict()),
            "cer_known": None if known_cer is None else known_cer.to_dict(),
            "text": self.text_scripts(pairs),
            **({"ocr_engines": engines} if engines else {}),
            **({"missing_renders": missing} if missing else {}),
        }

    def evaluate_words(self, method: str, renders: Mapping[str, np.ndarray], missing: Iterable[str] = ()) -> dict:
        """The cheap evaluation of a dense checkpoint (`run --checkpoints every:N`): the word-crop readability (its
        GT side, the GT views' OCR included, is made once per Evaluator and reused) and PSNR/SSIM over the image
        and the text region; no OCR of the renders, no LPIPS. The keys of `evaluate`, with `cer` and `cer_known`
        None and no OCR views."""
        import strings_bench.eval.metrics as metrics

        missing = [n for n in self.names if n in set(missing) and n not in renders]
        self.check_renders(method, renders, missing)
        per_view: dict[str, dict] = {}
        read_views: dict[str, tuple] = {}
        for name in self.names:
            if name in missing:
                continue
            view, gt, r = self.views[name], self.gt(name), scored_image(renders[name])
            per_view[name] = metrics.view_metrics(r, gt, view.mask, with_lpips=False, device=self.device)
            known = None if view.known_words is None else list(view.known_words)
            read_views[name] = (r, gt, known, self.gt_words(name))

        def mean(key):
            vals = [v[key] for v in per_view.values() if not math.isnan(v[key])]
            return float(np.mean(vals)) if vals else math.nan

        return {
            "metrics": {"psnr": mean("psnr"), "ssim": mean("ssim"), "lpips": math.nan,
                        **{k: mean(k) for k in metrics.TEXT_METRICS}, "per_view": per_view},
            "readability": self.readability(read_views),
            "ocr": {"backend": self.ocr.describe(), "mask_settings": self.mask_settings, "views": {}},
            "cer": None,
            "cer_known": None,
            **({"missing_renders": missing} if missing else {}),
        }

    def text_scripts(self, pairs: Mapping[str, tuple]) -> dict:
        """The scripts (and languages, where annotated) of the scene's text: from the known words when
        the views have them, else from the primary engine's GT reading. Recorded as the result's `text`."""
        from strings_bench.core.scripts import scripts_of

        if self.known_scripts:
            return {"scripts": list(self.known_scripts), "languages": list(self.known_languages), "from": "known text"}
        texts = [w.text for gt, _ in pairs.values() if gt for w in gt]
        try:  # the languages the engine was told to read (Tesseract's lang), where it has them
            langs = list(self.ocr.languages()) if callable(getattr(self.ocr, "languages", None)) else []
        except OCRError:
            langs = []
        return {"scripts": scripts_of(texts), "languages": langs, "from": f"GT OCR ({self.ocr.name})"}

    def second_opinion(self, engine, renders: Mapping[str, np.ndarray], primary_pairs: dict, missing=()) -> dict:
        """A further OCR engine's reading of a cell: its words on every GT and render view, its CER and
        known-text CER (same rules as the primary's), and its agreement with the primary engine
        (`cer.word_agreement`) on the render views and on the GT views, summed over the views both
        engines read without failing."""
        import strings_bench.eval.cer as cer

        pairs: dict[str, tuple] = {}
        known_pairs: dict[str, tuple] = {}
        views: dict[str, dict] = {}
        agree_render = agree_gt = cer.WordAgreement()
        render_reads = self.read_views(renders, engine, names=[n for n in self.names if n not in missing])
        for name in self.names:
            gt_words = self.gt_words(name, engine)
            render_words, render_err = render_reads.get(name, ([], None))
            pairs[name] = (gt_words, render_words)
            views[name] = {"gt_words": None if gt_words is None else [w.to_dict() for w in gt_words],
                           "render_words": None if render_words is None else [w.to_dict() for w in render_words],
                           "gt_error": self._gt_ocr_error.get((engine.name, name)), "render_error": render_err}
            known = self.views[name].known_words
            if known:
                known_pairs[name] = ([(k.text, k.polygon) for k in known], render_words)
            primary_gt, primary_render = primary_pairs[name]
            if primary_render is not None and render_words is not None:
                agree_render = agree_render + cer.word_agreement(primary_render, render_words, self.cer_profile)
            if primary_gt is not None and gt_words is not None:
                agree_gt = agree_gt + cer.word_agreement(primary_gt, gt_words, self.cer_profile)
        scene_cer = cer.scene_cer(pairs, profile=self.cer_profile)
        known_cer = cer.known_scene_cer(known_pairs, profile=self.cer_profile) if known_pairs else None
        return {"backend": engine.describe(), "views": views, "cer": self.floored(scene_cer.to_dict()),
                "cer_known": None if known_cer is None else known_cer.to_dict(),
                "agreement": {"with": self.ocr.name, "renders": agree_render.to_dict(), "gt": agree_gt.to_dict(),
                              "iou_threshold": cer.IOU_THRESHOLD,
                              "rule": "text regions (IoU >= 0.1 components of both engines' words) read identically "
                                      "after the CER profile's normalisation (cer.word_agreement)"}}
