"""CLI: `strings-bench ocr check|read`: OCR backends, and OCR of images into a results JSON for `cer`."""

from __future__ import annotations

import argparse
import json
import logging
import math
import time
from pathlib import Path
from typing import Any

from strings_bench.cli import command_help
from strings_bench.core.errors import StringsBenchError

log = logging.getLogger(__name__)

IMAGE_SUFFIXES = {".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".webp"}


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    ocr = subparsers.add_parser("ocr", help=command_help("ocr"))
    ocr_sub = ocr.add_subparsers(dest="ocr_command", metavar="ACTION")

    check = ocr_sub.add_parser("check", help="list available OCR backends and read a bundled sample")
    check.add_argument("--backend", action="append", help="backend(s) to try on the sample (default: rapidocr)")
    check.add_argument("--all", action="store_true", help="try every available backend (gcv is billed by Google)")
    check.set_defaults(func=_cmd_check)

    read = ocr_sub.add_parser("read", help="OCR images (optionally masked) into a results JSON for `cer`")
    read.add_argument("images", nargs="+", type=Path, help="image files or folders of images")
    read.add_argument("-o", "--out", type=Path, required=True, help="results JSON to write")
    read.add_argument("--backend", default="rapidocr")
    read.add_argument("--masks", type=Path, help="folder of text masks, matched to images by file stem")
    read.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="backend setting (JSON value)")
    read.add_argument("--no-cache", action="store_true", help="do not use or fill the OCR cache")
    read.set_defaults(func=_cmd_read)

    ocr.set_defaults(func=run, command_parser=ocr)
    return ocr


def run(args: argparse.Namespace) -> int:
    """`strings-bench ocr` without an action prints its help (exit status 2)."""
    args.command_parser.print_help()
    return 2


# --------------------------------------------------------------------------- ocr check
def _cmd_check(args: argparse.Namespace) -> int:
    from strings_bench.eval.cer import known_text_cer
    from strings_bench.eval.ocr import available_backends, get_backend
    from strings_bench.eval.ocr.sample import sample_image

    statuses = available_backends()
    print("OCR backends:")
    for name, st in statuses.items():
        print(f"  {name:<10} {'available' if st.available else 'unavailable':<12} {st.detail}")
    print_languages(statuses)
    if args.all:
        names = [n for n, st in statuses.items() if st.available]
    else:
        names = args.backend or ["rapidocr"]
    image, known = sample_image()
    print(f"\nsample: {image.shape[1]}x{image.shape[0]} px, known words: {' '.join(w.text for w in known)}")
    rc = 0
    for name in names:
        print(f"\n[{name}]")
        try:
            backend = get_backend(name, cache=False)
            print(f"  version: {backend.version}")
            t0 = time.perf_counter()
            backend.read(image)
            t1 = time.perf_counter()
            words = backend.read(image)
            t2 = time.perf_counter()
        except StringsBenchError as exc:
            print(f"  FAILED: {exc}")
            rc = 1
            continue
        for w in words:
            x0, y0 = w.polygon.min(axis=0)
            x1, y1 = w.polygon.max(axis=0)
            conf = "  n/a" if math.isnan(w.confidence) else f"{w.confidence:.3f}"
            print(f"  {w.text!r:<20} conf {conf}  box ({x0:.0f},{y0:.0f})-({x1:.0f},{y1:.0f})")
        res = known_text_cer(known, words)
        print(f"  first read {t1 - t0:.2f} s (includes loading), second read {t2 - t1:.2f} s")
        print(f"  known-text CER {res.cer:.3f} ({res.errors} errors / {res.chars} chars)")
    return rc


def print_languages(statuses) -> None:
    """The languages and scripts each available backend reads here (docs/ocr.md, "Other scripts")."""
    from strings_bench.core.scripts import LANGUAGES
    from strings_bench.eval.ocr.languages import (RAPIDOCR_MEASURED_UNREADABLE, rapidocr_scripts, rapidocr_supported_scripts,
                                                   tesseract_languages)

    print("\nLanguages and scripts:")
    if statuses.get("tesseract") and statuses["tesseract"].available:
        installed = tesseract_languages()
        print(f"  tesseract  installed languages (set with lang=..., e.g. --ocr tesseract:lang=rus): {' '.join(installed) or 'none'}")
        for code, lang in LANGUAGES.items():
            state = "installed" if code in installed else f"missing (apt-get install {lang.debian_package})"
            print(f"    {code:<8} {lang.name:<19} {lang.script:<11} {lang.direction}  {state}")
    else:
        print("  tesseract  not installed")
    if statuses.get("rapidocr") and statuses["rapidocr"].available:
        try:
            cover = rapidocr_scripts()
        except StringsBenchError as exc:
            print(f"  rapidocr   cannot read its dictionary: {exc.message}")
        else:
            reads = sorted(rapidocr_supported_scripts())
            shares = ", ".join(f"{s} {100 * v:.0f}%" for s, v in cover.items())
            print(f"  rapidocr   reads {', '.join(reads)} (letters of each script in its recogniser's dictionary: {shares}); "
                  f"refuses scenes in other scripts" + "".join(f"; {k}: {v}" for k, v in RAPIDOCR_MEASURED_UNREADABLE.items()))
    print("  gcv        every script (Google Cloud Vision; billed)")


# --------------------------------------------------------------------------- ocr read
def _parse_settings(items: list[str]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for item in items:
        if "=" not in item:
            raise StringsBenchError(f"--set {item!r} is not KEY=VALUE", hint="e.g. --set text_score=0.6")
        key, value = item.split("=", 1)
        try:
            out[key.strip()] = json.loads(value)
        except json.JSONDecodeError:
            out[key.strip()] = value
    return out


def _collect_images(paths: list[Path]) -> list[tuple[str, Path]]:
    found: list[tuple[str, Path]] = []
    for p in paths:
        if p.is_dir():
            found += [(f.relative_to(p).as_posix(), f) for f in sorted(p.rglob("*")) if f.suffix.lower() in IMAGE_SUFFIXES]
        elif p.is_file():
            found.append((p.name, p))
        else:
            raise StringsBenchError(f"image {p} does not exist", hint="give image files or folders")
    if not found:
        raise StringsBenchError("no images found", hint=f"image suffixes: {', '.join(sorted(IMAGE_SUFFIXES))}")
    return found


def _cmd_read(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from strings_bench.eval.ocr import OCRError, get_backend
    from strings_bench.eval.ocr.results import save_ocr_results

    backend = get_backend(args.backend, cache=not args.no_cache, **_parse_settings(args.set))
    images = _collect_images(args.images)
    masks: dict[str, Path] = {}
    if args.masks:
        if not args.masks.is_dir():
            raise StringsBenchError(f"mask folder {args.masks} does not exist", hint="give the folder of text masks")
        masks = {f.stem: f for f in args.masks.rglob("*") if f.suffix.lower() in IMAGE_SUFFIXES}
    results: dict[str, Any] = {}
    failures = 0
    for name, path in tqdm(images, desc=f"OCR ({backend.name})", unit="img"):
        mask = None
        if args.masks:
            mask = masks.get(path.stem)
            if mask is None:
                raise StringsBenchError(f"no mask for image {path} in {args.masks}", hint="masks are matched by file stem")
        try:
            results[name] = backend.read(path, mask=mask)
        except OCRError as exc:
            failures += 1
            results[name] = exc.message
            log.warning("OCR failed on %s: %s", path, exc.message)
    save_ocr_results(args.out, results, backend.describe())
    print(f"wrote {args.out}: {len(images)} images, {failures} OCR failures ({backend.name})")
    return 0
