"""`strings-bench ocr check|read` and `strings-bench cer GT PRED`."""

from __future__ import annotations

import argparse
import json
import logging
import math
import sys
import time
from pathlib import Path
from typing import Any

from strings_bench.core.errors import StringsBenchError

log = logging.getLogger(__name__)

IMAGE_SUFFIXES = {".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".webp"}


def add_cli(subparsers: argparse._SubParsersAction) -> None:
    ocr = subparsers.add_parser("ocr", help="OCR backends: check them, read images")
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

    ocr.set_defaults(func=lambda args: (ocr.print_help(), 2)[1])

    cer = subparsers.add_parser(
        "cer",
        help="OCR-CER of predicted OCR results against GT OCR results",
        description="Score OCR results made anywhere (see docs/ocr.md for the JSON format).",
    )
    cer.add_argument("gt", type=Path, help="OCR of the ground-truth views: results JSON or folder")
    cer.add_argument("pred", type=Path, help="OCR of the rendered views: results JSON or folder")
    cer.add_argument("--json", action="store_true", help="print one JSON object instead of a table")
    cer.add_argument("--cer-profile", "--profile", dest="profile", default="paper",
                     help="CER profile: paper (default; the authors' rules exactly), robust (repairs invalid polygons, "
                          "NFC, all whitespace removed; a deviation), case-sensitive, nfkc-casefold; see docs/ocr.md. "
                          "--profile is the older name")
    cer.add_argument("--iou", type=float, default=0.1, help="IoU threshold of a GT-prediction match (default 0.1)")
    cer.add_argument("--out", type=Path, help="also write the JSON result to this file")
    cer.set_defaults(func=_cmd_cer)


# --------------------------------------------------------------------------- ocr check
def _cmd_check(args: argparse.Namespace) -> int:
    from strings_bench.eval.cer import known_text_cer
    from strings_bench.eval.ocr import available_backends, get_backend
    from strings_bench.eval.ocr.sample import sample_image

    statuses = available_backends()
    print("OCR backends:")
    for name, st in statuses.items():
        print(f"  {name:<10} {'available' if st.available else 'unavailable':<12} {st.detail}")
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


# --------------------------------------------------------------------------- cer
def _cmd_cer(args: argparse.Namespace) -> int:
    from strings_bench.eval.cer import get_profile, scene_cer
    from strings_bench.core.io import atomic_write_json
    from strings_bench.eval.ocr.results import load_ocr_results

    profile = get_profile(args.profile)
    if not args.iou > 0:
        raise StringsBenchError(f"--iou {args.iou} must be > 0", hint="the paper uses 0.1")
    gt, gt_meta = load_ocr_results(args.gt)
    pred, pred_meta = load_ocr_results(args.pred)
    if gt_meta["kind"] == "single" and pred_meta["kind"] == "single":
        pred = {next(iter(gt)): next(iter(pred.values()))}  # two single-image files: pair them by position
    missing = sorted(set(gt) - set(pred))
    no_gt = sorted(set(pred) - set(gt))
    if missing:
        print(f"warning: {len(missing)} GT image(s) have no prediction; counted as OCR failures: {', '.join(missing[:10])}"
              + (" ..." if len(missing) > 10 else ""), file=sys.stderr)
    if no_gt:
        print(f"warning: {len(no_gt)} predicted image(s) have no GT entry and are not scored: {', '.join(no_gt[:10])}"
              + (" ..." if len(no_gt) > 10 else ""), file=sys.stderr)
    per_image = {name: (gt[name], pred.get(name)) for name in gt}
    res = scene_cer(per_image, profile=profile, iou_threshold=args.iou)
    doc = res.to_dict()
    doc["ignored"]["missing_prediction"] = missing
    doc["ignored"]["no_gt"] = no_gt
    for side, meta in (("gt_backend", gt_meta), ("pred_backend", pred_meta)):
        if "backend" in meta:
            doc[side] = meta["backend"]
    if args.out:
        atomic_write_json(args.out, doc)
    if args.json:
        print(json.dumps(doc, indent=2, sort_keys=True))
        return 0
    width = max([len("image"), len("total")] + [len(n) for n in res.images])
    print(f"{'image':<{width}}  {'errors':>7}  {'chars':>7}  {'CER':>7}")
    for name, r in res.images.items():
        print(f"{name:<{width}}  {r.errors:>7}  {r.chars:>7}  {r.cer:>7.4f}")
    print(f"{'total':<{width}}  {res.errors:>7}  {res.chars:>7}  {res.cer:>7.4f}")
    print(f"scored {len(res.images)} image(s); ignored: {res.n_ignored_empty_gt} with no GT text, "
          f"{res.n_ignored_failed} OCR failure(s)")
    for label, names in (("no GT text", res.ignored_empty_gt), ("OCR failed", res.ignored_failed)):
        if names:
            print(f"  {label}: {', '.join(names)}")
    p = profile.to_dict()
    print(f"CER profile {p['name']} (Unicode {p['unicode_form']}, case {p['case']}, whitespace removed: {p['whitespace']}, "
          f"invalid polygons: {p['polygons']}); IoU >= {args.iou:g}")
    return 0
