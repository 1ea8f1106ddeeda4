"""CLI: `strings-bench cer GT PRED`: OCR-CER of OCR results made anywhere (see docs/ocr.md)."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from strings_bench.cli import command_help
from strings_bench.core.errors import StringsBenchError


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    cer = subparsers.add_parser(
        "cer",
        help=command_help("cer"),
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
    cer.set_defaults(func=run)
    return cer


# --------------------------------------------------------------------------- cer
def run(args: argparse.Namespace) -> int:
    """`strings-bench cer GT PRED`: score, print a table (or JSON), optionally write the JSON."""
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
