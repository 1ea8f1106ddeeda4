"""CLI: `strings-bench prepare PHOTOS_DIR --name NAME`, and the real-data `datasets` subcommands
`add`, `check` and `download` (wired into the `datasets` group of strings_bench.cli.datasets).
"""

from __future__ import annotations

import argparse
import re
from pathlib import Path

from strings_bench.core.errors import DatasetError

NAME_RE = re.compile(r"^[A-Za-z0-9_.-]+$")


def _valid_name(name: str) -> str:
    if not NAME_RE.match(name):
        raise DatasetError(f"dataset name {name!r} may only hold letters, digits, '_', '-' and '.'",
                           hint="'/' separates dataset and scene in --datasets, so it cannot be part of a name")
    return name


# ---- prepare ----------------------------------------------------------------------------------
def add_cli(subparsers) -> None:
    p = subparsers.add_parser(
        "prepare",
        help="make a scene from your photos: SfM (pycolmap), undistortion, downscaled copies, OCR text masks",
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
    p.add_argument("--ocr", default="rapidocr", help="OCR backend for the text masks (default rapidocr)")
    p.add_argument("--threads", type=int, default=-1, help="threads for SfM (default: all cores)")
    p.add_argument("--overwrite", action="store_true", help="rebuild the scene folder if it exists")
    p.set_defaults(func=_run_prepare)


def _run_prepare(args: argparse.Namespace) -> int:
    from strings_bench.datasets.sfm import prepare_scene

    name = _valid_name(args.name)
    result = prepare_scene(args.photos_dir, name, out=args.out, max_size=args.max_size, masks=not args.no_masks,
                           matcher=args.matcher, num_threads=args.threads, overwrite=args.overwrite,
                           ocr_backend=args.ocr)
    print(result.summary())
    print(f"registered as {name!r}: use `--datasets {name}`")
    return 0


# ---- datasets add / check / download ----------------------------------------------------------
def _setup_add(p: argparse.ArgumentParser) -> None:
    p.description = ("Check PATH (read-only) and record it in the dataset index. NAME is a built-in dataset id "
                     "(strings360, tandt, dl3dv: PATH holds its scene folders) or a new name for your own scene "
                     "folder or folder of scenes.")
    p.add_argument("name")
    p.add_argument("path", type=Path)
    p.add_argument("--force", action="store_true", help="register even if the check finds errors")
    p.set_defaults(func=_run_add)


def _setup_check(p: argparse.ArgumentParser) -> None:
    p.description = "Validate scenes without modifying any file; exit status 1 when a scene has errors."
    p.add_argument("target", nargs="?", default=None,
                   help="registered NAME (or NAME/SCENE) or a PATH; default: every registered local copy")
    p.set_defaults(func=_run_check)


def _setup_download(p: argparse.ArgumentParser) -> None:
    p.description = ("Download a dataset that has a direct URL (resumable, hash printed or verified, safe "
                     "unpacking), then check and register it; for the others print the exact steps.")
    p.add_argument("name")
    p.add_argument("--dest", type=Path, default=None, help="where to unpack (default: CACHE/datasets/NAME)")
    p.set_defaults(func=_run_download)


SUBCOMMANDS = (
    ("add", "validate a local copy of a dataset or scene and register it under NAME", _setup_add),
    ("check", "validate a registered dataset or a scene folder (never modifies files)", _setup_check),
    ("download", "download a dataset with a direct URL, or print the steps to get it", _setup_download),
)


def add_dataset_subcommands(sub) -> None:
    """Add `add`, `check` and `download` to a `datasets` subparsers object (tests, other front ends)."""
    for name, help_text, setup in SUBCOMMANDS:
        setup(sub.add_parser(name, help=help_text))


def _register_with_datasets_group() -> None:
    try:
        from strings_bench.cli.datasets import register_subcommand
    except ImportError:  # the `datasets` group is not there: add_dataset_subcommands still works
        return
    for name, help_text, setup in SUBCOMMANDS:
        register_subcommand(name, help_text, setup)


def add_local_copy(name: str, path: Path, force: bool = False, echo=print) -> list:
    """Check then register; returns the scene reports. Raises DatasetError when the check fails."""
    from strings_bench.datasets.cards import BUILTIN_REAL_CARDS
    from strings_bench.datasets.check import check_card_copy, check_path, format_reports
    from strings_bench.datasets.registry import _REGISTRY, list_datasets, read_index, register_local_copies, write_index

    name = _valid_name(name)
    path = Path(path).expanduser()
    if not path.is_dir():
        raise DatasetError(f"{path} does not exist or is not a folder", hint="pass the folder of your local copy")
    path = path.resolve()
    builtin_real = {c.id for c in BUILTIN_REAL_CARDS}
    list_datasets()  # load every built-in card
    if name in builtin_real:
        reports = check_card_copy(name, path)
        present = [r for r in reports if r.found]
        if not present:
            raise DatasetError(f"none of the scenes of {name} are in {path}",
                               hint=f"PATH must hold the scene folders ({', '.join(s.name for s in _REGISTRY[name].scenes)})")
        missing = len(reports) - len(present)
        reports = present
        if missing:
            echo(f"note: {missing} scene(s) of {name} are not in {path}; the others are checked")
    else:
        existing = _REGISTRY.get(name)
        if existing is not None and existing.notes != "registered with `datasets add` or `prepare`":
            raise DatasetError(f"{name!r} is a built-in dataset that is not stored on disk by the user",
                               hint="choose another name for your copy")
        reports = check_path(path)
    echo(format_reports(reports))
    if not all(r.ok for r in reports) and not force:
        raise DatasetError(f"{path} has errors (above); not registered as {name!r}",
                           hint="fix them and re-run, or pass --force to register anyway")
    index = read_index()
    index[name] = str(path)
    write_index(index)
    register_local_copies()
    echo(f"registered {name!r} -> {path}")
    return reports


def _run_add(args: argparse.Namespace) -> int:
    add_local_copy(args.name, args.path, force=args.force)
    return 0


def _run_check(args: argparse.Namespace) -> int:
    from strings_bench.datasets.check import check_target, format_reports
    from strings_bench.datasets.registry import read_index

    targets = [args.target] if args.target else list(read_index())
    if not targets:
        print("no local copies registered; `strings-bench datasets add NAME PATH` registers one")
        return 0
    reports = []
    for t in targets:
        reports.extend(check_target(t))
    print(format_reports(reports))
    return 0 if all(r.ok for r in reports) else 1


def _run_download(args: argparse.Namespace) -> int:
    from strings_bench.datasets.download import download_dataset

    download_dataset(args.name, dest=args.dest)
    return 0


_register_with_datasets_group()
