"""`strings-bench datasets ...`: list datasets and prepare (build or locate) their scenes.

Extending this command group (for other modules, e.g. `datasets add` / `datasets check`):
call `register_subcommand(name, help, setup_fn)` at import time of your module, and add your module's
dotted name to `EXTRA_SUBCOMMAND_MODULES` below (one line). `setup_fn(parser)` receives the new
subcommand's argparse parser; it adds arguments and must set `parser.set_defaults(func=...)` where
func(args) returns an exit code. Registered subcommands appear after `list` and `prepare`.
"""

from __future__ import annotations

import argparse
import importlib
import time
from dataclasses import dataclass
from typing import Callable

# Modules imported before the `datasets` parser is built; each calls register_subcommand().
EXTRA_SUBCOMMAND_MODULES: list[str] = ["strings_bench.cli.prepare"]


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


def add_cli(subparsers) -> None:
    p = subparsers.add_parser("datasets", help="list datasets, prepare scenes (build synthetic ones)",
                              description="Dataset registry: synthetic scenes are generated into the cache; "
                                          "real datasets are located through their cards and your dataset index.")
    p.set_defaults(func=lambda args: (p.print_help(), 2)[1])
    sub = p.add_subparsers(dest="datasets_command", metavar="SUBCOMMAND")

    lp = sub.add_parser("list", help="dataset ids, their scenes, and whether local copies/caches exist")
    lp.set_defaults(func=cmd_list)

    pp = sub.add_parser("prepare", help="build (synthetic) or locate scenes and print their statistics",
                        description="SPEC is a dataset id (all its scenes) or DATASET/SCENE, e.g. synthetic/books.")
    pp.add_argument("specs", nargs="*", metavar="SPEC", help="e.g. synthetic/books or synthetic")
    pp.add_argument("--all", action="store_true", help="every scene of the synthetic benchmark")
    pp.add_argument("--force", action="store_true", help="rebuild synthetic scenes even when cached")
    g = pp.add_argument_group("synthetic scenes (non-default settings build a separate cache entry)")
    g.add_argument("--width", type=int, help="image width (default 320)")
    g.add_argument("--height", type=int, help="image height (default 240)")
    g.add_argument("--views", type=int, dest="n_views", help="views on the orbit (default 48)")
    g.add_argument("--seed", type=int, help="generator seed (default 0)")
    g.add_argument("--supersample", type=int, help="s x s rays per pixel (default 2)")
    pp.set_defaults(func=cmd_prepare)

    for module in EXTRA_SUBCOMMAND_MODULES:
        importlib.import_module(module)
    for extra in EXTRA_SUBCOMMANDS:
        extra.setup(sub.add_parser(extra.name, help=extra.help))


# ---- list ----------------------------------------------------------------------------------------
def _scene_status(card, scene: str) -> str:
    from strings_bench.core.errors import DatasetError
    from strings_bench.datasets.registry import local_root

    if card.id == "synthetic":
        from strings_bench.datasets.synthetic import is_built, scene_dir

        return f"cached at {scene_dir(scene)}" if is_built(scene) else "not built (built on first use)"
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
    return 0


# ---- prepare -------------------------------------------------------------------------------------
def cmd_prepare(args) -> int:
    from tqdm.auto import tqdm

    from strings_bench.core.errors import DatasetError
    from strings_bench.datasets.registry import get_dataset, locate_scene
    from strings_bench.datasets.synthetic import SCENE_NAMES, build_scene, settings_with

    specs = list(args.specs)
    if args.all:
        specs += [f"synthetic/{s}" for s in SCENE_NAMES]
    if not specs:
        raise DatasetError("nothing to prepare", hint="name scenes (e.g. synthetic/books) or pass --all")
    settings = settings_with(width=args.width, height=args.height, n_views=args.n_views, seed=args.seed,
                             supersample=args.supersample)
    todo = []
    for spec in specs:
        dataset_id, _, scene = spec.partition("/")
        card = get_dataset(dataset_id)
        for sc in ([card.scene(scene)] if scene else card.scenes):
            if (dataset_id, sc.name) not in [(d, s) for d, s, _ in todo]:
                todo.append((dataset_id, sc.name, card))
    rows = []
    for dataset_id, scene, card in tqdm(todo, desc="scenes", unit="scene", disable=len(todo) < 2):
        t0 = time.perf_counter()
        if dataset_id == "synthetic":
            path = build_scene(scene, settings, force=args.force, progress=True)
        else:
            path = locate_scene(card, scene)
        rows.append(_stats(f"{dataset_id}/{scene}", path, time.perf_counter() - t0))
        tqdm.write(_format(rows[-1]))
    return 0


def _stats(scene_id: str, path, seconds: float) -> dict:
    from strings_bench.scene.scene import Scene
    from strings_bench.datasets.synthetic import read_meta
    from strings_bench.datasets.synthetic.generate import META_FILE, count_text_points

    scene = Scene.load(path)
    row = {"id": scene_id, "path": str(path), "views": scene.num_views, "points": scene.model.num_points,
           "seconds": seconds, "text_points": None, "build_seconds": None, "fallback": None}
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
    return (f"{row['id']}: {row['path']}\n  views {row['views']}, points {row['points']}, points in text masks {text}, "
            f"{row['seconds']:.1f} s{build}{warn}")
