"""`strings-ocr`: an evaluation protocol for nerfbaselines, so that `nerfbaselines evaluate` reports OCR-CER.

nerfbaselines discovers protocols through the `nerfbaselines.specs` entry points (its `_registry`); this
package registers `strings-ocr` there (pyproject.toml -> strings_bench/eval/nerfbaselines_spec.py). Use it
with predictions whose info.json names it, or override the protocol:

    nerfbaselines evaluate PREDICTIONS -o results.json --evaluation-protocol strings-ocr

Per image it returns nerfbaselines' own default metrics (psnr, ssim, mae, mse, lpips) plus this suite's
OCR reading of the GT and the render through the image's mask (image x (mask > 127), the STRinGS release's
metrics_ocr) scored with the authors' CER (eval/cer.py, profile `paper`): `ocr_cer_errors`, `ocr_cer_chars`,
`ocr_failed` and the image's `ocr_cer`. `accumulate_metrics` sums errors and characters over the images, so
`ocr_cer` of the whole set is the paper's scene CER (total errors / total GT characters), not a mean of
per-image ratios. The OCR engine is STRINGS_BENCH_OCR (default rapidocr).
"""

from __future__ import annotations

import os
from typing import Dict, Iterable, Union

import numpy as np

PROTOCOL_ID = "strings-ocr"
OCR_ENV = "STRINGS_BENCH_OCR"


class StringsOCRProtocol:
    """nerfbaselines' EvaluationProtocol (get_name / render / evaluate / accumulate_metrics) with OCR-CER."""

    _name = PROTOCOL_ID

    def __init__(self):
        from nerfbaselines.evaluation import DefaultEvaluationProtocol

        from strings_bench.eval.ocr import get_backend

        self._default = DefaultEvaluationProtocol()
        self._engine = get_backend(os.environ.get(OCR_ENV) or "rapidocr")

    def get_name(self) -> str:
        return self._name

    def render(self, method, dataset, *, options=None):
        return self._default.render(method, dataset, options=options)

    def evaluate(self, predictions, dataset) -> Dict[str, Union[float, int]]:
        from nerfbaselines.utils import image_to_srgb

        from strings_bench.eval.protocol import GIVEN_MASK, EvalView, Evaluator

        out = self._image_metrics(predictions, dataset)
        meta = dataset["metadata"]
        space, background = meta.get("color_space"), meta.get("background_color")
        gt = image_to_srgb(dataset["images"][0], np.uint8, color_space=space, background_color=background)
        pred = image_to_srgb(predictions["color"], np.uint8, color_space=space, background_color=background)
        mask = None
        if dataset.get("masks") is not None:
            m = np.asarray(dataset["masks"][0])
            mask = (m > 127) if m.dtype == np.uint8 else (m > 0.5)  # nerfbaselines' read_mask gives bool
            mask = mask.reshape(mask.shape[:2])
        name = str(dataset["image_paths"][0]) if dataset.get("image_paths") else "image"
        view = EvalView(name=name, gt=gt[..., :3], mask=mask, mask_kind=GIVEN_MASK)
        result = Evaluator([view], self._engine, with_lpips=False, with_readability=False).evaluate("nerfbaselines", {name: pred[..., :3]})
        c = result["cer"]
        failed = len((c.get("ignored") or {}).get("failed") or [])
        out.update({"ocr_cer_errors": int(c["errors"]), "ocr_cer_chars": int(c["chars"]), "ocr_failed": failed,
                    "ocr_cer": float(c["cer"]) if c.get("cer") is not None else float("nan")})
        return out

    def _image_metrics(self, predictions, dataset) -> dict:
        """nerfbaselines' default metrics. Its LPIPS (AlexNet) needs torchvision, which has no CPU build here;
        without it LPIPS is n/a (NaN) and the rest is computed by nerfbaselines' own functions, as its default
        protocol does. (An ImportError must not escape: `nerfbaselines evaluate` would take it for a missing
        torch and try to build a docker image.)"""
        try:
            return dict(self._default.evaluate(predictions, dataset))
        except ImportError:
            from nerfbaselines import metrics
            from nerfbaselines.utils import convert_image_dtype, image_to_srgb

            meta = dataset["metadata"]
            space, background = meta.get("color_space"), meta.get("background_color")
            gt = convert_image_dtype(image_to_srgb(dataset["images"][0], np.uint8, color_space=space,
                                                   background_color=background), np.float32)[None]
            pred = convert_image_dtype(image_to_srgb(predictions["color"], np.uint8, color_space=space,
                                                     background_color=background), np.float32)[None]
            pred = pred[..., : gt.shape[-1]]
            if dataset.get("masks") is not None:
                m = convert_image_dtype(dataset["masks"][0], np.float32)[..., None]
                pred, gt = pred * m, gt * m
            mse = metrics.mse(pred, gt)
            return {"psnr": metrics.psnr(mse).mean().item(), "ssim": metrics.ssim(gt, pred).mean().item(),
                    "mae": metrics.mae(gt, pred).mean().item(), "mse": mse.mean().item(), "lpips": float("nan")}

    def accumulate_metrics(self, metrics: Iterable[Dict[str, Union[float, int]]]) -> Dict[str, Union[float, int]]:
        metrics = list(metrics)
        counted = ("ocr_cer_errors", "ocr_cer_chars", "ocr_failed")
        acc = self._default.accumulate_metrics([{k: v for k, v in m.items() if k not in counted and k != "ocr_cer"}
                                                for m in metrics])
        for k in counted:
            acc[k] = int(sum(m.get(k, 0) for m in metrics))
        acc["ocr_cer"] = acc["ocr_cer_errors"] / acc["ocr_cer_chars"] if acc["ocr_cer_chars"] else float("nan")
        return acc
