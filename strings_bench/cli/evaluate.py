"""CLI: `strings-bench evaluate PRED`: the suite's metrics on renders made anywhere (docs/guide/evaluate.md)."""

from __future__ import annotations

import argparse

from strings_bench.cli import command_help


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "evaluate", help=command_help("evaluate"),
        description="Scores the renders in PRED against ground truth with the same evaluation as `run` (OCR-CER, "
                    "known-text CER, word-crop readability, PSNR/SSIM/LPIPS) and writes a run-like folder: one cell per "
                    "checkpoint, results.csv and the report. Layouts, detected and named: a plain folder of renders "
                    "named after the test views; Inria 3DGS output (MODEL/test/ours_<N>/renders, gt, masks); "
                    "nerfbaselines predictions (color/, gt-color/, mask/, info.json; folder, .zip or .tar.gz). "
                    "See docs/guide/evaluate.md.")
    p.add_argument("pred", help="the predictions: a folder of renders, an Inria 3DGS model folder (or its test/ or "
                                "test/ours_<N>/), or nerfbaselines predictions (folder, .zip, .tar.gz)")
    src = p.add_mutually_exclusive_group()
    src.add_argument("--scene", default=None,
                     help="the scene the renders are of (synthetic/books, strings360/globe, or a scene folder): GT, "
                          "text masks and known text come from it, as in `run`")
    src.add_argument("--gt", default=None, help="a folder of ground-truth images named like the renders "
                                                "(default: the layout's gt/ or gt-color/)")
    p.add_argument("--masks", default=None, help="a folder of text masks named like the views; OCR reads "
                                                 "image x (mask > 127), no dilation (the STRinGS release's metrics_ocr)")
    p.add_argument("--out", default=None, help="output folder (default runs/evaluate/<PRED name>; the same folder resumes)")
    p.add_argument("--method", default=None, help="method name in the tables (default: from the predictions)")
    p.add_argument("--dataset", default=None, help="dataset name in the tables (default: the scene's, else external)")
    p.add_argument("--scene-name", default=None, help="scene name in the tables (default: the scene's, else PRED's)")
    p.add_argument("--downscale", type=float, default=None,
                   help="with --scene: the downscale the renders were made at (default: from their width)")
    p.add_argument("--ocr", default="rapidocr", help="OCR engine(s), as for `run` (default rapidocr)")
    p.add_argument("--cer-profile", default="paper", help="OCR-CER profile (default paper: the authors' rules)")
    p.add_argument("--no-lpips", action="store_true", help="skip LPIPS (a VGG pass per view; slow on a CPU)")
    p.add_argument("--allow-missing", action="store_true",
                   help="score test views without a render as unread (every GT character an error) instead of refusing")
    p.add_argument("--min-gt-chars", type=int, default=None, metavar="N",
                   help="leave OCR-CER empty when the GT reads fewer than N characters on the test views (default: "
                        "50 for views without known text, a scene's own floor where it sets one; 0: no floor)")
    p.add_argument("--train-seconds", type=float, default=None,
                   help="training time of the method, for the time columns and the scatter (default n/a)")
    p.add_argument("--no-report", action="store_true", help="write results.csv only, not the report")
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    from strings_bench.bench.evaluate import EvaluateOptions, evaluate

    opts = EvaluateOptions(scene=args.scene, gt=args.gt, masks=args.masks, out=args.out, method=args.method,
                           dataset=args.dataset, scene_name=args.scene_name, downscale=args.downscale, ocr=args.ocr,
                           cer_profile=args.cer_profile, with_lpips=not args.no_lpips, allow_missing=args.allow_missing,
                           min_gt_chars=args.min_gt_chars, train_seconds=args.train_seconds, report=not args.no_report)
    out = evaluate(args.pred, opts)
    print(f"results: {out / 'results.csv'}")
    if not args.no_report:
        print(f"html:    {(out / 'report' / 'index.html').resolve().as_uri()}")
    return 0
