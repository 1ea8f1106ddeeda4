"""CLI: `strings-bench calibrate`: calibrate `synthetic360` against the paper: 3DGS's OCR-CER at 3K, 7K and 30K over a grid of difficulty settings.

The paper's 3DGS row on its STRinGS-360 captures is OCR-CER 0.736 at 7K and 0.148 at 30K: text is
unreadable early and readable late. This script trains 3DGS with the paper's schedule on the
`synthetic360` scenes built at each point of a grid of generator settings (docs/synthetic.md,
"Difficulty controls"), through the suite's runner, and reports per scene and setting OCR-CER (the
paper's), known-text CER, the word-crop readability metrics (word_cer, text_nll), PSNR and the
Gaussian count, then the mean over the scenes next to the paper's figures (within +-0.1 or not).

    # the calibration itself: a CUDA GPU, the paper's schedule at ~1600 px (default grid: room scale 1, 2, 3)
    strings-bench calibrate --device cuda
    strings-bench calibrate --device cuda --grid room_scale=1.5,2 text_px=24:64,16:48 --views 150
    # a CPU smoke run (tiny scale; the figures mean nothing for the calibration)
    strings-bench calibrate --device cpu --width 160 --height 120 --views 16 --steps-scale 0.005 \
        --scenes pantry --grid room_scale=1,2
    # the CPU regime (docs/synthetic.md, "Calibration on the CPU"): 320x240, 48 views, schedule x0.05
    # (7K = 350 steps, 30K = 1500), device cpu, run folder runs/calibrate-cpu
    strings-bench calibrate --regime cpu --grid room_scale=0.7,1
    strings-bench calibrate --regime cpu --grid room_scale=0.7,1 --report-only   # tables only, no training
    # the frozen CPU configuration (dataset synthetic360-cpu), once the calibration chose it: every method
    strings-bench calibrate --regime cpu --dataset synthetic360-cpu --out runs/s360cpu-compare \
        --methods strings,3dgs,strings-no-densify,strings-pos-lr,absgs,mip-splatting,mcmc,edc-absgs

Draws: `--draws 0,1,2` trains every room of `--scenes` at each generator seed (scene draws
ROOM@N, docs/guide/datasets.md), at every grid point and on `--dataset`; draw 0 is the room itself (today's cells).
A grid axis `seed=0,1,2` is read the same way: its points are draws of one setting in the tables.

    # 3DGS on the three rooms of synthetic360-cpu at draws 0, 1, 2, schedule x0.1, checkpoints 3K and 7K
    strings-bench calibrate --regime cpu --dataset synthetic360-cpu --draws 0,1,2 --steps-scale 0.1 \
        --checkpoints 3K,7K --out runs/cal40-x0.1-draws

The tables give, per setting and checkpoint, the mean over the rooms of each draw, then the mean over the
draws with the draws' range (min-max), and per room the mean over its draws with their range, beside the
per-scene rows; every row carries the scene's SfM points and those on text (its scene_meta.json).

Grid: `KEY=V1,V2,...` per generator setting (any field of SyntheticSettings; text_px values as
LO:HI); the grid is their product, each point on top of `--base` (default: the synthetic360 card's
photometric settings) and `--width/--height/--views`. Each point becomes a dataset `s360-<label>`
in one run folder (resumable: run the same command again). Calibrate on 3DGS alone:
choose the settings before looking at STRinGS, then measure STRinGS once with `--methods strings`.

`--regime` picks the defaults of the size, views, schedule scale, device, grid and run folder:
`paper` (1600x1200, 150 views, the paper's schedule, CUDA) or `cpu` (REGIMES["cpu"]); every other named
schedule of core/schedules.py (SCHEDULES) is a regime too: the cpu regime at that schedule's scale, run
folder runs/calibrate-<name> (`regimes()`). An option given explicitly wins over its regime's value.
`--report-only` rebuilds the tables from the cells already in the run folder (same arguments as the run)
and trains nothing.

Writes calibration.csv and calibration.md into the run folder and prints the markdown.
"""

from __future__ import annotations

import argparse
import csv
import io
import itertools
import math
import sys
from pathlib import Path

from strings_bench.cli import command_help
# the tables (reports/calibration.py); `tables` and the paper's figures are re-exported: tests read them here
from strings_bench.reports.calibration import PAPER_3DGS, TARGET_NAMES, TOLERANCE, as_float, tables  # noqa: F401

DEFAULT_GRID = ["room_scale=1,2,3"]
# Defaults per regime (--regime); an option given on the command line wins. "cpu": one (3DGS, scene)
# cell to 30K-equivalent (1500 steps) costs ~15 min or less on 2 cores (docs/synthetic.md).
REGIMES = {
    "paper": {"device": "auto", "width": 1600, "height": 1200, "views": 150, "steps_scale": None,
              "grid": DEFAULT_GRID, "out": "runs/calibrate", "target": "cer"},
    "cpu": {"device": "cpu", "width": 320, "height": 240, "views": 48, "steps_scale": 0.05,
            "grid": ["room_scale=0.7,1"], "out": "runs/calibrate-cpu",
            # OCR-CER saturates at 320x240 (docs/synthetic.md): the CPU target is the known-text CER
            "target": "cer_known"},
}
COLUMNS = ["setting", "scene", "room", "draw", "label", "iteration", "cer", "cer_known", "word_cer", "word_cer_gt",
           "text_nll", "psnr", "gaussians", "train_seconds", "sfm_points", "text_points"]
ABBREVIATIONS = {"room_scale": "r", "text_px": "t", "bg_frequency": "f", "clutter": "c", "exposure_sd": "e",
                 "white_balance_sd": "wb", "vignetting": "v", "noise_sigma": "n", "defocus_px": "d",
                 "motion_blur_px": "m", "n_views": "views"}


def parse_value(key: str, text: str):
    """One grid value: text_px as LO:HI, ints for int fields, floats otherwise; 'none' for None."""
    if text.lower() == "none":
        return None
    if key == "text_px":
        lo, _, hi = text.partition(":")
        return (float(lo), float(hi))
    return int(text) if key in ("n_views", "clutter", "seed", "supersample") else float(text)


def parse_grid(items: list[str]) -> list[dict]:
    """['room_scale=1,2', 'noise_sigma=0,2'] -> the product as a list of {key: value} dicts."""
    from dataclasses import fields

    from strings_bench.core.errors import StringsBenchError
    from strings_bench.datasets.synthetic import SyntheticSettings

    names = {f.name for f in fields(SyntheticSettings)}
    axes = []
    for item in items:
        key, sep, values = item.partition("=")
        if not sep or key not in names or not values:
            raise StringsBenchError(f"grid entry {item!r} is not KEY=V1,V2 with KEY a generator setting",
                                    hint=f"settings: {', '.join(sorted(names))}")
        try:
            axes.append([(key, parse_value(key, v)) for v in values.split(",")])
        except ValueError as exc:
            raise StringsBenchError(f"grid entry {item!r}: {exc}", hint="numbers, text_px as LO:HI") from exc
    return [dict(point) for point in itertools.product(*axes)] if axes else [{}]


def point_label(point: dict) -> str:
    """A dataset id for a grid point, e.g. s360-r2-t24_64 (letters, digits, '_', '-', '.')."""
    parts = []
    for key, value in point.items():
        if isinstance(value, tuple):
            value = "_".join(f"{v:g}" for v in value)
        elif isinstance(value, float):
            value = f"{value:g}"
        parts.append(f"{ABBREVIATIONS.get(key, key)}{value}")
    return "s360-" + ("-".join(parts) if parts else "base")


def regimes() -> dict[str, dict]:
    """REGIMES, and a regime for every other named schedule (core/schedules.py SCHEDULES, e.g. a frozen `cpu-long`):
    the cpu regime (the paper regime for a scale >= 1) at that schedule's scale, run folder runs/calibrate-<name>. So
    freezing a schedule is one line in SCHEDULES, and `calibrate --regime NAME` trains at its scale."""
    from strings_bench.core.schedules import SCHEDULES

    out = {name: dict(r) for name, r in REGIMES.items()}
    for name, sched in SCHEDULES.items():
        if name not in out:
            base = REGIMES["cpu"] if sched.steps_scale < 1 else REGIMES["paper"]
            out[name] = {**base, "steps_scale": None if sched.steps_scale == 1 else sched.steps_scale,
                         "out": f"runs/calibrate-{name}"}
    return out


def expand_scenes(scenes: str, draws: str = "0") -> list[str]:
    """The scene names of `--scenes` at `--draws`, draw by draw (every room of draw 0, then of draw 1, ...: a draw
    is complete before the next starts); an entry ROOM@N is taken as it is. StringsBenchError for an unknown room
    or a malformed draw."""
    from strings_bench.core.draws import draw_name, parse_draws, split_draw
    from strings_bench.core.errors import StringsBenchError
    from strings_bench.datasets.synthetic import SCENE_NAMES_360

    entries = [s.strip() for s in scenes.split(",") if s.strip()]
    split = [split_draw(e) for e in entries]
    unknown = [room for room, _ in split if room not in SCENE_NAMES_360]
    if unknown or not entries:
        raise StringsBenchError(f"unknown synthetic360 scene(s) {', '.join(unknown) or '(none given)'}",
                                hint=f"scenes: {', '.join(SCENE_NAMES_360)} (ROOM@N: draw N of a room)")
    out: list[str] = []
    for n in parse_draws(draws):
        for e, (room, d) in zip(entries, split):
            name = draw_name(room, d) if "@" in e else draw_name(room, n)
            if name not in out:
                out.append(name)
    return out


def check_regime(device: str, width: int, steps_scale: float | None) -> str:
    """The device to train on; refuses the calibration without CUDA unless a small CPU smoke run is asked for."""
    import torch

    from strings_bench.core.errors import StringsBenchError

    if device in ("auto", "cuda") or device.startswith("cuda:"):
        if not torch.cuda.is_available():
            raise StringsBenchError(
                "the calibration needs a CUDA GPU (the paper's schedule, 30K steps at ~1600 px), and torch sees none",
                hint="on a CPU, run a smoke check: --device cpu --width 320 --height 240 --steps-scale 0.05 "
                     "(width <= 640 and steps scale < 1 on the CPU)")
        return "cuda" if device == "auto" else device
    if device == "cpu":
        if width > 640 or steps_scale is None or steps_scale >= 1:
            raise StringsBenchError(
                f"--device cpu runs only at a small scale (asked: width {width}, steps scale {steps_scale})",
                hint="give --width <= 640 and --steps-scale < 1 (e.g. 0.05); the calibration itself needs a GPU")
        return "cpu"
    raise StringsBenchError(f"unknown device {device!r}", hint="use cuda, cuda:N or cpu")


def scene_points(rec: dict, cache: dict) -> tuple[float, float]:
    """(SfM points, SfM points on text) of the scene a cell trained on, from its scene_meta.json (NaN when the
    cell's scene folder or its meta is gone)."""
    path = ((rec.get("config") or {}).get("scene") or {}).get("path")
    if not path:
        return math.nan, math.nan
    if path not in cache:
        from strings_bench.core.errors import DatasetError
        from strings_bench.datasets.synthetic import read_meta

        try:
            meta = read_meta(path)
            cache[path] = (as_float(meta.get("points")), as_float(meta.get("text_points")))
        except DatasetError:
            cache[path] = (math.nan, math.nan)
    return cache[path]


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    ap = subparsers.add_parser("calibrate", help=command_help("calibrate"), description=__doc__,
                               formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--regime", choices=sorted(regimes()), default="paper",
                    help="defaults for device, size, views, schedule scale, grid and run folder (default: paper; "
                         "cpu: REGIMES['cpu']; any other named schedule: the cpu regime at its scale)")
    ap.add_argument("--device", default=None, help="cuda (default when torch sees one), cuda:N, or cpu (small scale only)")
    ap.add_argument("--scenes", default="pantry,office,storeroom",
                    help="synthetic360 rooms (default all three); ROOM@N names one draw of a room")
    ap.add_argument("--draws", default="0",
                    help="scene draws (generator seeds) of every room, e.g. 0,1,2 (default 0: the rooms themselves); "
                         "applied at every grid point and to --dataset; the tables give the mean over draws with "
                         "their range")
    ap.add_argument("--grid", nargs="*", default=None, metavar="KEY=V1,V2",
                    help=f"difficulty grid (default: the regime's; paper: {' '.join(DEFAULT_GRID)}, "
                         f"cpu: {' '.join(REGIMES['cpu']['grid'])}); text_px values as LO:HI")
    ap.add_argument("--base", nargs="*", default=None, metavar="KEY=V",
                    help="settings every grid point starts from (default: the synthetic360 card's, SYNTHETIC360_DEFAULTS)")
    ap.add_argument("--width", type=int, default=None)
    ap.add_argument("--height", type=int, default=None)
    ap.add_argument("--views", type=int, default=None, help="views per scene (the paper's captures: 150-300)")
    ap.add_argument("--steps-scale", type=float, default=None, help="schedule scale (default: the regime's)")
    ap.add_argument("--checkpoints", default="3000,7000,30000",
                    help="paper iterations to evaluate; every:N adds word-crop-only checkpoints every N paper "
                         "iterations (time to legibility, docs/readability.md)")
    ap.add_argument("--seed", type=int, default=0,
                    help="the trainer's seed for every method (default 0, the methods' own); a seed other than 0 "
                         "needs its own run folder (default: the regime's folder with -seed<N>)")
    ap.add_argument("--methods", default="3dgs", help="3dgs to calibrate; strings once the settings are frozen")
    ap.add_argument("--ocr", default="rapidocr")
    ap.add_argument("--budget", default=None, metavar="N|METHOD",
                    help="hold every method to a Gaussian budget of N, or to the count METHOD (e.g. 3dgs, trained "
                         "first without a budget) reaches on the same scene at the last checkpoint; a budget needs its "
                         "own --out folder "
                         "(docs/guide/running.md, \"Equal Gaussian budget\")")
    ap.add_argument("--out", default=None, help="run folder (default: the regime's)")
    ap.add_argument("--target", choices=sorted(TARGET_NAMES), default=None,
                    help="the metric whose mean is held against the paper's 3DGS figures (paper: cer, cpu: cer_known)")
    ap.add_argument("--dataset", default=None,
                    help="train on a registered synthetic360 configuration (e.g. synthetic360-cpu, the frozen CPU "
                         "settings) instead of a grid; --grid, --base, --width, --height and --views are then unused")
    ap.add_argument("--report-only", action="store_true",
                    help="write calibration.csv/.md from the cells already in the run folder; train nothing")
    ap.set_defaults(func=run)
    return ap


def run(args: argparse.Namespace) -> int:
    """Train the grid (or the registered configuration) through the runner, then write calibration.csv/.md."""
    apply_regime(args)

    import strings_bench.bench as bench
    from strings_bench.store import cell_row, iter_cells
    from strings_bench.bench.plan import ALL_METHODS
    from strings_bench.cli.run import parse_checkpoints, split_checkpoints
    from strings_bench.core.errors import StringsBenchError
    from strings_bench.core.io import atomic_write_text
    from strings_bench.datasets.registry import register_dataset
    from strings_bench.core.draws import split_draw
    from strings_bench.datasets.synthetic import SYNTHETIC360_DEFAULTS, settings_with, synthetic360_card

    try:
        device = args.device if args.report_only else check_regime(args.device, args.width, args.steps_scale)
        scenes = expand_scenes(args.scenes, args.draws)
        base = dict(SYNTHETIC360_DEFAULTS)
        if args.base is not None:
            base = {}
            for item in args.base:
                key, _, value = item.partition("=")
                base[key] = parse_value(key, value)
        points = [] if args.dataset else parse_grid(args.grid)
        drawn = any(split_draw(s)[1] for s in scenes)
        if drawn and (base.get("seed") or any("seed" in p for p in points)):
            raise StringsBenchError("scene draws set the generator seed, and --base or --grid sets it too",
                                    hint="give the seeds once: --draws 0,1,2, or a grid axis seed=0,1,2")
        checkpoints, dense_every = split_checkpoints(parse_checkpoints(args.checkpoints))
        checkpoints = sorted(set(checkpoints)) if checkpoints else None
        # seed 0 is every method's default: recorded as no override, so folders made before --seed resume
        overrides = {ALL_METHODS: {"seed": args.seed}} if args.seed else {}
        specs, labels = [], {}
        if args.dataset:  # a registered (frozen) configuration, e.g. synthetic360-cpu: no grid
            from strings_bench.datasets.registry import get_dataset

            get_dataset(args.dataset)
            labels[args.dataset] = {}
            specs = [f"{args.dataset}/{s}" for s in scenes]
        for point in points:
            settings = settings_with(**{**base, "width": args.width, "height": args.height, "n_views": args.views, **point})
            label = point_label(point)
            labels[label] = point
            register_dataset(synthetic360_card(label, settings, title=f"synthetic360 at {point or 'the base settings'}"))
            specs += [f"{label}/{s}" for s in scenes]
        run_dir = Path(args.out)
        methods = [m.strip() for m in args.methods.split(",") if m.strip()]
        if args.report_only:
            if not run_dir.is_dir():
                raise StringsBenchError(f"--report-only: no run folder {run_dir}", hint="run without --report-only first")
        else:
            bench.run(methods, specs, run_dir=run_dir, schedule="paper", ocr=args.ocr, with_lpips=False,
                       write_report=False, steps_scale=args.steps_scale, checkpoints=checkpoints,
                       dense_every=dense_every, method_overrides=overrides, device=device, budget=args.budget)
    except StringsBenchError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1

    rows, metas = [], {}
    # a grid axis seed=0,1,2 makes draws of one setting: its points are grouped under the label without the seed
    groups = {label: point_label({k: v for k, v in point.items() if k != "seed"}) if "seed" in point else label
              for label, point in labels.items()}
    for rec in iter_cells(run_dir):
        r = cell_row(rec)
        if r["dataset"] not in labels or r["scene"] not in scenes or r["method"] not in methods:
            continue
        if r["evaluation"] != "full":  # every:N's word-crop-only checkpoints: docs/readability.md's analysis reads them
            continue
        room, draw = split_draw(r["scene"])
        sfm, text = scene_points(rec, metas)
        rows.append({"setting": r["dataset"], "scene": r["scene"], "room": room,
                     "draw": int(labels[r["dataset"]].get("seed", draw)), "group": groups[r["dataset"]],
                     "label": r["label"], "iteration": int(r["iteration"]),
                     **{k: as_float(r[k]) for k in ("cer", "cer_known", "word_cer", "word_cer_gt", "text_nll", "psnr",
                                                "train_seconds")},
                     "gaussians": r["gaussians"], "method": r["method"], "sfm_points": sfm, "text_points": text})
    order = list(labels)
    rows.sort(key=lambda r: (r["method"], order.index(r["setting"]), r["iteration"], scenes.index(r["scene"])))
    expected: dict[str, int] = {}
    for label in labels:
        expected[groups[label]] = expected.get(groups[label], 0) + len(scenes)
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=["method", *COLUMNS, *labels_keys(labels)], extrasaction="ignore")
    writer.writeheader()
    for r in rows:
        writer.writerow({**r, **{k: labels[r["setting"]].get(k, "") for k in labels_keys(labels)}})
    atomic_write_text(run_dir / "calibration.csv", buf.getvalue())
    schedule = "paper schedule" if args.steps_scale is None else f"schedule x{args.steps_scale:g}"
    draws = sorted({split_draw(s)[1] for s in scenes} | {int(p["seed"]) for p in labels.values() if "seed" in p})
    drawn_note = f"Draws (generator seeds): {', '.join(map(str, draws))}\n\n" if len(draws) > 1 else ""
    if args.dataset:
        md = (f"# synthetic360 calibration: {', '.join(methods)}, {schedule}, device {device}, regime {args.regime}\n\n"
              f"Dataset: {args.dataset} (its registered settings)\n\n{drawn_note}")
    else:
        md = (f"# synthetic360 calibration: {', '.join(methods)}, {schedule}, {args.width}x{args.height}, "
              f"{args.views} views, device {device}, regime {args.regime}\n\nBase settings: {base}\n\n{drawn_note}")
    for method in methods:
        md += (f"## {method}\n\n" + tables([r for r in rows if r["method"] == method], scenes, args.target, expected)
               + "\n")
    atomic_write_text(run_dir / "calibration.md", md)
    print(md)
    print(f"written: {run_dir / 'calibration.csv'}, {run_dir / 'calibration.md'}")
    return 0


def apply_regime(args) -> None:
    """Fill the options left unset (None) from --regime's defaults, in place (the default run folder of a
    seed other than 0 gets a -seed<N> suffix: a folder holds one seed)."""
    for key, value in regimes()[args.regime].items():
        if getattr(args, key) is None:
            if key == "out" and getattr(args, "seed", 0):
                value = f"{value}-seed{args.seed}"
            setattr(args, key, list(value) if isinstance(value, list) else value)


def labels_keys(labels: dict) -> list[str]:
    """The grid's setting names, in order of first appearance."""
    keys: list[str] = []
    for point in labels.values():
        keys += [k for k in point if k not in keys]
    return keys

