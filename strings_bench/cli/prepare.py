"""CLI: `strings-bench prepare PHOTOS_DIR --name NAME`: a scene folder made from your photos
(`strings-bench datasets add` registers a folder you already have)."""

from __future__ import annotations

import argparse
from pathlib import Path

from strings_bench.cli import command_help
from strings_bench.cli.datasets import valid_name


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "prepare",
        help=command_help("prepare"),
        description="Run structure from motion on a folder of photos and write a scene folder "
        "(images/, images_2/, images_4/, sparse/0/, masks/) registered under NAME, so that "
        "`strings-bench run --datasets NAME` uses it.",
    )
    p.add_argument("photos_dir", type=Path, help="folder with the photos (.jpg/.png)")
    p.add_argument("--name", required=True, help="name to register the scene under")
    p.add_argument("--out", type=Path, default=None, help="scene folder (default: CACHE/scenes/NAME)")
    p.add_argument("--max-size", type=int, default=1600,
                   help="downscale photos so the long side is at most this many pixels before SfM (default 1600; 0 = keep)")
    p.add_argument("--no-masks", action="store_true", help="skip the OCR text masks")
    p.add_argument("--matcher", choices=["auto", "exhaustive", "sequential"], default="auto",
                   help="feature matching: exhaustive for small sets (auto: up to 80 photos), sequential for video-like order")
    p.add_argument("--ocr", default="rapidocr",
                   help="OCR backend for the text masks (default rapidocr), with settings as in `run --ocr`, e.g. "
                        "tesseract:lang=rus")
    p.add_argument("--threads", type=int, default=-1,
                   help="threads for SfM (default: all cores; 1 makes the seeded SfM repeatable)")
    p.add_argument("--intrinsics", type=_intrinsics, default=None, metavar="FX,FY,CX,CY",
                   help="the photos' known calibration in pixels (OpenCV convention: the first pixel's centre is 0,0), "
                        "e.g. a sequence's published values: one PINHOLE camera that SfM keeps fixed; the photos must "
                        "share one size")
    p.add_argument("--overwrite", action="store_true", help="rebuild the scene folder if it exists")
    p.add_argument("--bundler", nargs="?", const="auto", default=None, metavar="FILE",
                   help="the cameras are given by a Bundler reconstruction in PHOTOS_DIR (bundle.out or cameras.out, "
                        "or FILE; images in PHOTOS_DIR/images, listed by list.txt or ordered_filenames.txt): convert "
                        "them and run no SfM (datasets/bundler.py)")
    p.set_defaults(func=run)
    return p


def _intrinsics(value: str) -> tuple[float, float, float, float]:
    try:
        fx, fy, cx, cy = (float(v) for v in value.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected FX,FY,CX,CY (four numbers, e.g. 535.4,539.2,320.1,247.6), "
                                         f"got {value!r}") from None
    return fx, fy, cx, cy


def run(args: argparse.Namespace) -> int:
    """`strings-bench prepare`: make the scene folder, register it and print a summary."""
    from strings_bench.datasets.sfm import prepare_scene

    name = valid_name(args.name)
    if args.bundler and args.intrinsics is not None:
        from strings_bench.core.errors import DatasetError

        raise DatasetError("--intrinsics and --bundler both give the cameras", hint="the Bundler file's cameras are used "
                           "as they are: leave out --intrinsics")
    if args.bundler:
        from strings_bench.datasets.bundler import prepare_bundler_scene

        result = prepare_bundler_scene(args.photos_dir, name, out=args.out,
                                       bundle_file=None if args.bundler == "auto" else args.bundler,
                                       max_size=args.max_size, masks=not args.no_masks, ocr_backend=args.ocr,
                                       overwrite=args.overwrite)
        print(result.summary())
        print(f"registered as {name!r}: use `--datasets {name}`")
        return 0
    result = prepare_scene(args.photos_dir, name, out=args.out, max_size=args.max_size, masks=not args.no_masks,
                           matcher=args.matcher, num_threads=args.threads, overwrite=args.overwrite,
                           ocr_backend=args.ocr, intrinsics=args.intrinsics)
    print(result.summary())
    print(f"registered as {name!r}: use `--datasets {name}`")
    return 0
