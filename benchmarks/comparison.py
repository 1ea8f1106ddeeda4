"""The paper's tables from one or more run folders, with the spread over seeds (issue 27).

Each run folder holds one seed (`benchmarks/calibrate.py --seed N` or `strings-bench run --set seed=N`);
the seed of a cell is read from its own settings (0 when none was given). For each method this prints,
in the paper's layout:

- CER at 7K and 30K (its Table "OCR-CER"): OCR-CER, and the known-text CER the CPU regime is judged by
  (issue 27: OCR-CER saturates at 320x240), each the mean over the scenes of one seed, then the mean
  over seeds with the seeds' range;
- training time in minutes at 7K and 30K (its Table "Training Time"), measured in each run as it ran
  (folders measured under different load are not comparable: say so beside the table);
- PSNR, SSIM and Gaussians at 30K (its appendix table);
- the two ablations (its Table "Ablations"): without text densification at 7K, without the zero
  position LR at 3K, each beside STRinGS.

Only fully evaluated checkpoints count (the word-crop-only ones of `--checkpoints every:N` do not).
A method is averaged over the scenes every seed of it has; a (method, seed) missing a scene the
others have is reported, not averaged.

    python benchmarks/comparison.py runs/s360cpu-compare runs/s360cpu-seed1 runs/s360cpu-seed2
    python benchmarks/comparison.py runs/s360cpu-compare --json      # the numbers, for scripts
    python benchmarks/comparison.py runs/s360cpu-compare runs/s360cpu-seed1 --per-scene cer_known   # every cell
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

# the paper's order (its tables), then anything else a run holds
METHOD_ORDER = ["3dgs", "mip-splatting", "mcmc", "absgs", "edc-absgs", "strings", "strings-no-densify",
                "strings-pos-lr"]
VALUES = ("cer", "cer_known", "word_cer", "psnr", "ssim", "gaussians", "train_seconds")


def method_order(methods) -> list[str]:
    """The methods in the paper's order (METHOD_ORDER), any others after them by name."""
    return sorted(set(methods), key=lambda m: (METHOD_ORDER.index(m) if m in METHOD_ORDER else len(METHOD_ORDER), m))


def cell_seed(rec: dict) -> int:
    """The trainer seed a cell was made with (its method settings' `seed`, else the default 0)."""
    settings = ((rec.get("config") or {}).get("method") or {}).get("settings") or {}
    return int(settings.get("seed", 0))


def collect(run_dirs: list[Path], dataset: str | None = None) -> dict:
    """{(method, label): {seed: {scene: {value: float}}}} from the fully evaluated cells of the folders.
    The same (method, seed, scene, label) in two folders counts once when its figures agree (training time
    aside) and is an error when they differ: a seed must not count twice."""
    from strings_bench.core.errors import StringsBenchError
    from strings_bench.reports.results import cell_row, iter_cells

    out: dict = {}
    seen: dict = {}
    for run_dir in run_dirs:
        if not run_dir.is_dir():
            raise StringsBenchError(f"no run folder {run_dir}", hint="give folders made by strings-bench run or calibrate.py")
        for rec in iter_cells(run_dir):
            row = cell_row(rec)
            if row["evaluation"] != "full" or (dataset and row["dataset"] != dataset):
                continue
            seed = cell_seed(rec)
            key = (row["method"], seed, row["dataset"], row["scene"], row["label"])
            vals = {k: float(row[k]) if row[k] != "" else math.nan for k in VALUES}
            vals["iteration"] = int(row["iteration"])
            if key in seen:
                # the same cell trained in two folders (e.g. a 7K-only seed run and a 30K one): the CPU engine is
                # deterministic, so it must have given the same figures; it then counts once
                first_dir, first = seen[key]
                same = all(first[k] == vals[k] or (math.isnan(first[k]) and math.isnan(vals[k]))
                           for k in VALUES if k != "train_seconds")
                if not same:
                    raise StringsBenchError(f"{key} is in both {first_dir} and {run_dir}, with different figures",
                                            hint="give each seed's folder once (or --dataset to pick one dataset)")
                continue
            seen[key] = (run_dir, vals)
            out.setdefault((row["method"], row["label"]), {}).setdefault(seed, {})[row["scene"]] = vals
    return out


def summarise(per_seed: dict, value: str) -> dict | None:
    """Mean over scenes per seed, over the scenes every seed has; then mean, min and max over seeds."""
    scenes = set.intersection(*(set(s) for s in per_seed.values())) if per_seed else set()
    if not scenes:
        return None
    means = []
    for seed in sorted(per_seed):
        vals = [per_seed[seed][s][value] for s in sorted(scenes)]
        if any(math.isnan(v) for v in vals):
            continue
        means.append(sum(vals) / len(vals))
    if not means:
        return None
    missing = {seed: sorted(set(sc) - scenes) for seed, sc in per_seed.items() if set(sc) - scenes}
    return {"mean": sum(means) / len(means), "min": min(means), "max": max(means), "seeds": len(means),
            "scenes": len(scenes), "per_seed": means, "left_out": missing}


def fmt(s: dict | None, spec: str = "{:.3f}", scale: float = 1.0) -> str:
    if s is None:
        return "-"
    text = spec.format(s["mean"] * scale)
    if s["seeds"] > 1:
        text += f" ({spec.format(s['min'] * scale)}-{spec.format(s['max'] * scale)})"
    return text


def tables(data: dict) -> tuple[str, dict]:
    """The markdown and the numbers ({method: {label: {value: summary}}})."""
    methods = method_order(m for m, _ in data)
    numbers = {m: {label: {v: summarise(data[(m, label)], v) for v in VALUES}
                   for (mm, label) in data if mm == m} for m in methods}

    def get(m, label, v):
        return (numbers.get(m) or {}).get(label, {}).get(v)

    def seeds_scenes(m):
        s = [get(m, lab, "cer") for lab in ("30K", "7K", "3K")]
        s = next((x for x in s if x), None)
        return "-" if s is None else f"{s['seeds']} / {s['scenes']}"

    lines = ["Mean over scenes, then over seeds (range of the seeds' means in brackets).", "",
             "| method | seeds / scenes | OCR-CER 7K | OCR-CER 30K | known-text CER 7K | known-text CER 30K | "
             "word CER 30K |", "|---|---|---|---|---|---|---|"]
    for m in methods:
        lines.append(f"| {m} | {seeds_scenes(m)} | {fmt(get(m, '7K', 'cer'))} | {fmt(get(m, '30K', 'cer'))} | "
                     f"{fmt(get(m, '7K', 'cer_known'))} | {fmt(get(m, '30K', 'cer_known'))} | "
                     f"{fmt(get(m, '30K', 'word_cer'))} |")
    lines += ["", "| method | training time 7K (min) | training time 30K (min) | PSNR 30K | SSIM 30K | Gaussians 30K |",
              "|---|---|---|---|---|---|"]
    for m in methods:
        lines.append(f"| {m} | {fmt(get(m, '7K', 'train_seconds'), '{:.2f}', 1 / 60)} | "
                     f"{fmt(get(m, '30K', 'train_seconds'), '{:.2f}', 1 / 60)} | {fmt(get(m, '30K', 'psnr'), '{:.2f}')} | "
                     f"{fmt(get(m, '30K', 'ssim'), '{:.4f}')} | {fmt(get(m, '30K', 'gaussians'), '{:.0f}')} |")
    ablations = [("text densification (7K)", "strings-no-densify", "7K"),
                 ("zero position LR in phase 1 (3K)", "strings-pos-lr", "3K")]
    if any(m in methods for _, m, _ in ablations):
        lines += ["", "| ablation | checkpoint | w/o: OCR-CER | STRinGS: OCR-CER | w/o: known-text CER | "
                  "STRinGS: known-text CER |", "|---|---|---|---|---|---|"]
        for name, m, label in ablations:
            if m in methods:
                lines.append(f"| {name} | {label} | {fmt(get(m, label, 'cer'))} | {fmt(get('strings', label, 'cer'))} | "
                             f"{fmt(get(m, label, 'cer_known'))} | {fmt(get('strings', label, 'cer_known'))} |")
    left = [f"{m} {lab}: seed {seed} also has {', '.join(sc)} (left out of the means)"
            for m in methods for lab, vs in numbers[m].items() for seed, sc in ((vs.get("cer") or {}).get("left_out") or {}).items()]
    if left:
        lines += ["", *sorted(set(left))]
    return "\n".join(lines) + "\n", numbers


def per_scene_table(data: dict, value: str = "cer_known") -> str:
    """One row per method and checkpoint: `value` per scene, the seeds' figures joined with '/' (seed order)."""
    methods = method_order(m for m, _ in data)
    scenes = sorted({sc for per_seed in data.values() for by_scene in per_seed.values() for sc in by_scene})
    first_iteration: dict = {}  # label -> the smallest iteration trained for it (checkpoint order)
    for (_, label), per_seed in data.items():
        for by_scene in per_seed.values():
            for v in by_scene.values():
                first_iteration[label] = min(first_iteration.get(label, v["iteration"]), v["iteration"])
    labels = sorted(first_iteration, key=first_iteration.get)
    lines = [f"{value} per scene; several seeds as seed0 / seed1 / ... (seeds: the cells' own)", "",
             "| method | ckpt | " + " | ".join(scenes) + " |", "|---|---|" + "---|" * len(scenes)]
    for label in labels:
        for m in methods:
            per_seed = data.get((m, label))
            if not per_seed:
                continue
            cells = []
            for sc in scenes:
                vals = [f"{per_seed[seed][sc][value]:.3f}" for seed in sorted(per_seed) if sc in per_seed[seed]]
                cells.append(" / ".join(vals) or "-")
            lines.append(f"| {m} | {label} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("run_dirs", nargs="+", type=Path, help="run folders, one seed each")
    ap.add_argument("--dataset", default=None, help="only this dataset's cells (e.g. synthetic360-cpu)")
    ap.add_argument("--json", action="store_true", help="print the numbers as JSON instead of markdown")
    ap.add_argument("--per-scene", metavar="VALUE", default=None,
                    help="also print VALUE (cer, cer_known, word_cer, ...) per method, checkpoint and scene, every seed")
    args = ap.parse_args(argv)
    from strings_bench.core.errors import StringsBenchError

    try:
        data = collect(args.run_dirs, args.dataset)
    except StringsBenchError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    if not data:
        print("error: no fully evaluated cells in " + ", ".join(map(str, args.run_dirs)), file=sys.stderr)
        return 1
    md, numbers = tables(data)
    print(json.dumps(numbers, indent=1) if args.json else md)
    if args.per_scene:
        if args.per_scene not in VALUES:
            print(f"error: --per-scene {args.per_scene}: one of {', '.join(VALUES)}", file=sys.stderr)
            return 1
        print(per_scene_table(data, args.per_scene))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
