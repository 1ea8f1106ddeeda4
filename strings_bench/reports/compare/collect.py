"""Collecting a comparison's cells: every fully evaluated cell of the run folders, by method, checkpoint, seed and
scene (`collect`), held to the scenes every method has (`common_scenes`)."""

from __future__ import annotations

import math
from pathlib import Path

from strings_bench.core.errors import StringsBenchError
from strings_bench.store import cell_row, iter_cells

VALUES = ("cer", "cer_known", "word_cer", "psnr", "ssim", "lpips", "gaussians", "train_seconds", "train_cpu_seconds")
TIMES = ("train_seconds", "train_cpu_seconds")  # differ between two trainings of one cell


def cell_seed(rec: dict) -> int:
    """The trainer seed a cell was made with (its method settings' `seed`, else the default 0)."""
    settings = ((rec.get("config") or {}).get("method") or {}).get("settings") or {}
    return int(settings.get("seed", 0))


def collect(run_dirs: list[Path], dataset: str | None = None, methods: list[str] | None = None,
            scenes: list[str] | None = None) -> dict:
    """{(method, label): {seed: {scene: {value: float, "iteration": int}}}} from the fully evaluated cells of the
    folders (of `dataset`, of `methods` and of `scenes` only, each when given). A name in `methods` or `scenes`
    that no cell of the folders has is an error (a typo would otherwise narrow the comparison in silence)."""
    out: dict = {}
    found: dict = {"methods": set(), "scenes": set()}
    seen: dict = {}
    datasets: dict = {}  # (method, seed, scene, label) -> the dataset it came from
    for run_dir in map(Path, run_dirs):
        if not run_dir.is_dir():
            raise StringsBenchError(f"no run folder {run_dir}", hint="give folders made by strings-bench run or calibrate")
        for rec in iter_cells(run_dir):
            row = cell_row(rec)
            if row["evaluation"] != "full" or (dataset and row["dataset"] != dataset):
                continue
            found["methods"].add(row["method"])
            found["scenes"].add(row["scene"])
            if (methods and row["method"] not in methods) or (scenes and row["scene"] not in scenes):
                continue
            seed = cell_seed(rec)
            key = (row["method"], seed, row["dataset"], row["scene"], row["label"])
            vals = {k: float(row[k]) if row[k] != "" else math.nan for k in VALUES}
            vals["iteration"] = int(row["iteration"])
            if key in seen:
                # the same cell trained in two folders (a 7K-only seed run and a 30K one): the CPU engine is
                # deterministic, so it must have the same figures; it then counts once
                first_dir, first = seen[key]
                same = all(first[k] == vals[k] or (math.isnan(first[k]) and math.isnan(vals[k]))
                           for k in VALUES if k not in TIMES)
                if not same:
                    raise StringsBenchError(f"{key} is in both {first_dir} and {run_dir}, with different figures",
                                            hint="give each seed's folder once (or --dataset to pick one dataset)")
                continue
            seen[key] = (run_dir, vals)
            other = datasets.setdefault((row["method"], seed, row["scene"], row["label"]), row["dataset"])
            if other != row["dataset"]:
                # cells are keyed by scene name: two datasets' "pantry" would overwrite each other
                raise StringsBenchError(f"{row['method']} {row['label']} seed {seed}: scene {row['scene']!r} is in "
                                        f"datasets {other} and {row['dataset']}",
                                        hint="compare one dataset at a time (--dataset); draws of a room are scenes "
                                             "ROOM@N of one dataset (docs/guide/datasets.md, 'Scene draws')")
            out.setdefault((row["method"], row["label"]), {}).setdefault(seed, {})[row["scene"]] = vals
    for what, wanted in (("methods", methods), ("scenes", scenes)):
        unknown = sorted(set(wanted or ()) - found[what])
        if unknown:
            raise StringsBenchError(f"no fully evaluated cell of {what} {', '.join(unknown)} in "
                                    + ", ".join(map(str, run_dirs)),
                                    hint=f"the folders' {what}: {', '.join(sorted(found[what])) or 'none'}")
    return out



def common_scenes(data: dict) -> tuple[dict, dict, set]:
    """`data` ({(method, label): {seed: {scene: ...}}}) held to the scenes every method has at each checkpoint (in
    any of its seeds), {(method, label): {seed: [scenes left out]}}, and the checkpoints whose methods share no
    scene (nothing is held back there). Means over different scenes would rank methods on different rooms and
    draws (a draw trained for some methods only): a draw moves known-text CER more than a seed does."""
    have: dict = {}
    for (m, label), per_seed in data.items():
        scenes = set().union(*(set(by_scene) for by_scene in per_seed.values()))
        have[label] = scenes if label not in have else have[label] & scenes
    unshared = {label for label, scenes in have.items() if not scenes}
    kept, dropped = {}, {}
    for (m, label), per_seed in data.items():
        if label in unshared:  # each method keeps its own (`left_out` says so)
            kept[(m, label)] = per_seed
            continue
        common = have[label]
        kept[(m, label)] = {seed: {sc: v for sc, v in by_scene.items() if sc in common}
                            for seed, by_scene in per_seed.items() if common & set(by_scene)}
        out = {seed: sorted(set(by_scene) - common) for seed, by_scene in per_seed.items()}
        if any(out.values()):
            dropped[(m, label)] = {seed: sc for seed, sc in out.items() if sc}
    return kept, dropped, unshared
