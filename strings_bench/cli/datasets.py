"""CLI: `strings-bench datasets list|prepare|add|check|download`: the dataset registry, synthetic
scenes, and local copies of real datasets.

Another package can add a subcommand to this group: `register_subcommand(name, help, setup_fn)`
before the parser is built; `setup_fn(parser)` adds the arguments and must set
`parser.set_defaults(func=...)`, func(args) returning an exit code. Registered subcommands come
after the built-in ones.
"""

from __future__ import annotations

import argparse
import re
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from strings_bench.cli import command_help
from strings_bench.core.errors import DatasetError

NAME_RE = re.compile(r"^[A-Za-z0-9_.-]+$")


def valid_name(name: str) -> str:
    """`name` if it can name a dataset (letters, digits, '_', '-', '.'), else a DatasetError."""
    if not NAME_RE.match(name):
        raise DatasetError(f"dataset name {name!r} may only hold letters, digits, '_', '-' and '.'",
                           hint="'/' separates dataset and scene in --datasets, so it cannot be part of a name")
    return name


@dataclass(frozen=True)
class Subcommand:
    name: str
    help: str
    setup: Callable[[argparse.ArgumentParser], None]


EXTRA_SUBCOMMANDS: list[Subcommand] = []


def register_subcommand(name: str, help: str, setup_fn: Callable[[argparse.ArgumentParser], None]) -> None:
    """Add `strings-bench datasets NAME` (idempotent: a second registration of NAME replaces the first)."""
    EXTRA_SUBCOMMANDS[:] = [s for s in EXTRA_SUBCOMMANDS if s.name != name]
    EXTRA_SUBCOMMANDS.append(Subcommand(name, help, setup_fn))


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = subparsers.add_parser("datasets", help=command_help("datasets"),
                              description="Dataset registry: synthetic scenes are generated into the cache; "
                                          "real datasets are located through their cards and your dataset index.")
    p.set_defaults(func=run, command_parser=p)
    sub = p.add_subparsers(dest="datasets_command", metavar="SUBCOMMAND")

    lp = sub.add_parser("list", help="dataset ids, their scenes, and whether local copies/caches exist")
    lp.set_defaults(func=cmd_list)

    pp = sub.add_parser("prepare", help="build (synthetic) or locate scenes and print their statistics",
                        description="SPEC is a dataset id (all its scenes) or DATASET/SCENE, e.g. synthetic/books; on "
                                    "the synthetic360 datasets DATASET/SCENE@N is draw N of a room (generator seed N) "
                                    "and DATASET@N every room at draw N (docs/guide/datasets.md, 'Scene draws').")
    pp.add_argument("specs", nargs="*", metavar="SPEC",
                    help="e.g. synthetic/books, synthetic, synthetic360-cpu/pantry@1 or synthetic360-cpu@2")
    pp.add_argument("--all", action="store_true", help="every scene of the synthetic benchmark")
    pp.add_argument("--force", action="store_true", help="rebuild synthetic scenes even when cached")
    g = pp.add_argument_group("synthetic scenes (non-default settings build a separate cache entry)")
    g.add_argument("--width", type=int, help="image width (default 320)")
    g.add_argument("--height", type=int, help="image height (default 240)")
    g.add_argument("--views", type=int, dest="n_views", help="views on the orbit (default 48)")
    g.add_argument("--seed", type=int, help="generator seed (default 0; on synthetic360 scenes a draw, SCENE@N, "
                                            "names the same thing)")
    g.add_argument("--supersample", type=int, help="s x s rays per pixel (default 2)")
    d = pp.add_argument_group("difficulty controls (docs/synthetic.md; the first four: synthetic360 scenes only)")
    d.add_argument("--room-scale", type=float, help="multiplies the room, the clutter ring and the orbit radius (default 1)")
    d.add_argument("--text-px", type=_text_px, metavar="LO,HI",
                   help="word box heights in pixels at room scale 1 (default 6,16 x width/320)")
    d.add_argument("--bg-frequency", type=float, help="multiplies the spatial frequency of background textures (default 1)")
    d.add_argument("--clutter", type=int, help="textured objects without text around the room (default 10)")
    d.add_argument("--exposure-sd", type=float, help="per-view exposure, sd in stops (synthetic 0, synthetic360 0.15)")
    d.add_argument("--white-balance-sd", type=float, help="per-view sd of the log red and blue gains (0 / 0.03)")
    d.add_argument("--vignetting", type=float, help="corner darkening, gain 1 - v r^2 (0 / 0.15)")
    d.add_argument("--noise-sigma", type=float, help="Gaussian sensor noise, sd in 8-bit levels (0 / 1.5)")
    d.add_argument("--defocus-px", type=float, help="Gaussian defocus blur, sd in pixels (default 0)")
    d.add_argument("--motion-blur-px", type=float, help="motion blur, length up to this many pixels per view (default 0)")
    pp.set_defaults(func=cmd_prepare)

    add_dataset_subcommands(sub)
    for extra in EXTRA_SUBCOMMANDS:
        extra.setup(sub.add_parser(extra.name, help=extra.help))
    return p


def _text_px(value: str) -> tuple[float, float]:
    try:
        lo, hi = (float(v) for v in value.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected LO,HI (two numbers, e.g. 6,16), got {value!r}") from None
    return lo, hi


SYNTHETIC_IDS = ("synthetic", "synthetic360", "synthetic360-cpu")
OVERRIDE_FIELDS = ("width", "height", "n_views", "seed", "supersample", "room_scale", "text_px", "bg_frequency", "clutter",
                   "exposure_sd", "white_balance_sd", "vignetting", "noise_sigma", "defocus_px", "motion_blur_px")


def run(args: argparse.Namespace) -> int:
    """`strings-bench datasets` without a subcommand prints its help (exit status 2)."""
    args.command_parser.print_help()
    return 2


# ---- list ----------------------------------------------------------------------------------------
def _scene_status(card, scene: str) -> str:
    from strings_bench.core.errors import DatasetError
    from strings_bench.datasets.registry import local_root

    if card.id in SYNTHETIC_IDS:
        from strings_bench.core.draws import draw_name, split_draw
        from strings_bench.datasets.synthetic import default_settings, is_built, scene_dir

        room = split_draw(scene)[0]
        settings = default_settings(scene, card.id)
        status = f"cached at {scene_dir(room, settings)}" if is_built(room, settings) else "not built (built on first use)"
        others = [f"@{d}" for d in card.draws if d and is_built(room, default_settings(draw_name(room, d), card.id))]
        return status + (f"; draws cached: {', '.join(others)}" if others else "")
    if card.id == "captures":
        from strings_bench.datasets import captures

        if captures.is_built(scene):
            return f"built at {captures.scene_dir(scene)}"
        try:
            return f"not built (built on first use from {captures.capture_source(scene)})"
        except DatasetError as exc:
            return f"not built; {exc}"
    if card.locate is not None:
        return "located on demand"
    try:
        path = local_root(card.id) / scene
    except DatasetError:
        return "no local copy (`strings-bench datasets add`)"
    return f"local: {path}" if path.is_dir() else f"missing: {path}"


def cmd_list(args) -> int:
    from strings_bench.datasets.registry import list_datasets

    for card in list_datasets():
        print(f"{card.id}: {card.title}")
        for sc in card.scenes:
            settings = ", ".join(f"{k}={v}" for k, v in sorted(sc.settings.items()))
            print(f"  {card.id}/{sc.name:<14} [{settings}] {_scene_status(card, sc.name)}")
        if card.draws:
            print(f"  draws: registered {', '.join(f'@{d}' for d in card.draws)}; any N >= 0 works: "
                  f"{card.id}/SCENE@N is the scene at generator seed N (SCENE@0 = SCENE), {card.id}@N every scene at draw N")
    return 0


# ---- prepare -------------------------------------------------------------------------------------
def cmd_prepare(args) -> int:
    from tqdm.auto import tqdm

    from strings_bench.core.errors import DatasetError
    from strings_bench.datasets.registry import locate_scene, select_scenes
    from dataclasses import replace

    from strings_bench.core.draws import split_draw
    from strings_bench.datasets.synthetic import SCENE_NAMES, build_scene, default_settings, with_draw

    specs = list(args.specs)
    if args.all:
        specs += [f"synthetic/{s}" for s in SCENE_NAMES]
    if not specs:
        raise DatasetError("nothing to prepare", hint="name scenes (e.g. synthetic/books) or pass --all")
    overrides = {k: getattr(args, k) for k in OVERRIDE_FIELDS if getattr(args, k, None) is not None}
    todo = []
    for spec in specs:
        card, scenes = select_scenes(spec)
        dataset_id = card.id
        for sc in scenes:
            if (dataset_id, sc.name) not in [(d, s) for d, s, _ in todo]:
                todo.append((dataset_id, sc.name, card))
    rows = []
    for dataset_id, scene, card in tqdm(todo, desc="scenes", unit="scene", disable=len(todo) < 2):
        t0 = time.perf_counter()
        if dataset_id in SYNTHETIC_IDS:
            # Each scene's defaults (synthetic360 has camera variation on), with the options given; a draw
            # (pantry@N) then sets the generator seed.
            room = split_draw(scene)[0]
            room, settings = with_draw(scene, replace(default_settings(room, dataset_id), **overrides))
            path = build_scene(room, settings, force=args.force, progress=True)
        else:
            path = locate_scene(card, scene)
        rows.append(_stats(f"{dataset_id}/{scene}", path, time.perf_counter() - t0))
        tqdm.write(_format(rows[-1]))
    return 0


def _stats(scene_id: str, path, seconds: float) -> dict:
    from strings_bench.scene.scene import Scene
    from strings_bench.datasets.synthetic import read_meta
    from strings_bench.datasets.synthetic.generate import META_FILE
    from strings_bench.datasets.synthetic.sfm import count_text_points

    from strings_bench.scene.difficulty import recorded_difficulty

    scene = Scene.load(path)
    row = {"id": scene_id, "path": str(path), "views": scene.num_views, "points": scene.model.num_points,
           "seconds": seconds, "text_points": None, "build_seconds": None, "fallback": None,
           "difficulty": recorded_difficulty(scene)}
    if (path / META_FILE).exists():
        meta = read_meta(path)
        row.update(text_points=meta["text_points"], build_seconds=meta["timings_s"]["total"], fallback=meta["fallback"])
    elif scene.masks_dir is not None:
        masks = {scene.names[i]: m for i in range(scene.num_views) if (m := scene.load_mask(i)) is not None}
        row["text_points"] = count_text_points(scene.model, masks)
    return row


def _format(row: dict) -> str:
    text = "n/a (no masks)" if row["text_points"] is None else str(row["text_points"])
    build = "" if row["build_seconds"] is None else f", built in {row['build_seconds']:.1f} s"
    warn = f"  WARNING: fallback point cloud ({row['fallback']})" if row["fallback"] else ""
    d = row.get("difficulty")
    rho = ("\n  rho n/a (no known words and no text masks to measure strokes on)" if d is None or d.rho is None else
           f"\n  rho {d.rho:.3f} (one 3DGS position step = {100 * d.rho:.1f} % of a text stroke: extent {d.extent:.3g}, "
           f"median stroke {d.stroke_world:.3g} in world units, {d.stroke_px:.2f} px, {d.words} words{d.how_measured()})")
    return (f"{row['id']}: {row['path']}\n  views {row['views']}, points {row['points']}, points in text masks {text}, "
            f"{row['seconds']:.1f} s{build}{warn}{rho}")


# ---- add / check / download ----------------------------------------------------------------
def _setup_add(p: argparse.ArgumentParser) -> None:
    p.description = ("Check PATH (read-only) and record it in the dataset index. NAME is a built-in dataset id "
                     "(strings360, tandt, dl3dv: PATH holds its scene folders) or a new name for your own scene "
                     "folder or folder of scenes.")
    p.add_argument("name")
    p.add_argument("path", type=Path)
    p.add_argument("--force", action="store_true", help="register even if the check finds errors")
    p.set_defaults(func=_run_add)


def _setup_show(p: argparse.ArgumentParser) -> None:
    p.description = ("Print a scene's record: where it is, views and test views, photos left out by SfM, the GT "
                     "characters OCR reads on the test views (captures), rho (docs/difficulty.md) and the content hash "
                     "of its images, masks, cameras, points and text (docs/reproducibility.md). A scene that "
                     "is not built yet is only reported as such; --build builds it (SfM for a capture, the generator "
                     "for a synthetic room).")
    p.add_argument("spec", metavar="NAME[/SCENE]", help="a dataset id (every scene) or DATASET/SCENE, e.g. "
                                                        "captures/bundler_et")
    p.add_argument("--build", action="store_true", help="build the scene when it is not built yet")
    p.set_defaults(func=_run_show)


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
    ("show", "print a scene's record, rho included (built scenes; --build builds one)", _setup_show),
    ("check", "validate a registered dataset or a scene folder (never modifies files)", _setup_check),
    ("download", "download a dataset with a direct URL, or print the steps to get it", _setup_download),
)


def add_dataset_subcommands(sub) -> None:
    """Add `add`, `check` and `download` to a `datasets` subparsers object (tests, other front ends)."""
    for name, help_text, setup in SUBCOMMANDS:
        setup(sub.add_parser(name, help=help_text))


def add_local_copy(name: str, path: Path, force: bool = False, echo=print) -> list:
    """Check then register; returns the scene reports. Raises DatasetError when the check fails."""
    from strings_bench.datasets.cards import BUILTIN_REAL_CARDS
    from strings_bench.datasets.card import LOCAL_CARD_NOTES
    from strings_bench.datasets.registry import register_local_copies
    from strings_bench.datasets.check import check_card_copy, check_path, format_reports
    from strings_bench.datasets.registry import find_dataset, get_dataset, list_datasets, read_index, write_index

    name = valid_name(name)
    path = Path(path).expanduser()
    if not path.is_dir():
        raise DatasetError(f"{path} does not exist or is not a folder", hint="pass the folder of your local copy")
    path = path.resolve()
    if name == "captures":  # the photos of the captures dataset, built into scenes on first use
        from strings_bench.datasets.captures import check_data_root

        present = check_data_root(path)
        index = read_index()
        index[name] = str(path)
        write_index(index)
        echo(f"registered the captures' data folder {path} (captures found: {', '.join(present)}); their scenes are "
             "built on first use")
        return []
    builtin_real = {c.id for c in BUILTIN_REAL_CARDS}
    list_datasets()  # load every built-in card
    if name in builtin_real:
        reports = check_card_copy(name, path)
        present = [r for r in reports if r.found]
        if not present:
            raise DatasetError(f"none of the scenes of {name} are in {path}",
                               hint=f"PATH must hold the scene folders ({', '.join(s.name for s in get_dataset(name).scenes)})")
        missing = len(reports) - len(present)
        reports = present
        if missing:
            echo(f"note: {missing} scene(s) of {name} are not in {path}; the others are checked")
    else:
        existing = find_dataset(name)
        if existing is not None and existing.notes != LOCAL_CARD_NOTES:
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


def _run_show(args: argparse.Namespace) -> int:
    from strings_bench.datasets.record import format_record, scene_record
    from strings_bench.datasets.registry import select_scenes

    card, scenes = select_scenes(args.spec)
    for i, sc in enumerate(scenes):
        print(("\n" if i else "") + format_record(scene_record(card, sc, build=args.build)))
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
