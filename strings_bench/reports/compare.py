"""The paper's tables over run folders of several seeds (`strings-bench compare RUN_DIR...`; issue 27).

Size (~570 lines): one comparison from its cells to its numbers (seeds and scene draws), its tables and its four
renderings (Markdown, LaTeX, CSV, HTML); the renderings share the numbers and the decided rows, so they stay together.

Each run folder holds one seed (`strings-bench calibrate --seed N`, or `run --set seed=N`); a cell's seed is read
from its own settings (0 when none was given). For each method, in the registry's (the paper's) order:

- CER at 7K and 30K (the paper's Table "OCR-CER"): OCR-CER, the known-text CER the CPU regime is judged by
  (OCR-CER saturates at 320x240) and the word CER, each the mean over the scenes of one seed, then the mean over
  the seeds with the seeds' range; the paper's own OCR-CER beside, from the method's spec (`PaperFigures`);
- training time in minutes at 7K and 30K (the paper's Table "Training Time"), with the paper's minutes beside
  (folders measured under different load are not comparable: say so beside the table);
- PSNR, SSIM, LPIPS and Gaussians at 30K (the paper's appendix table);
- the ablations (its Table "Ablations"): every method whose spec names `ablation_of`, beside that method, at the
  checkpoint the spec names (`ablation_at`), or the last both have where the folders lack it (the caption says so);
- "decided / not decided": each method against STRinGS (the spec of group "ours") where both have several seeds:
  decided when the seeds' ranges do not overlap. Beside it, the (seed, draw) replicates in which the method is below STRinGS
  (`paired_lower`), which never changes the verdict.

Scene draws (core/draws.py, issue 40) count like seeds: a cell of scene `pantry@1` is room pantry at draw 1, and
a (seed, draw) pair is one *replicate*. Each replicate's figure is the mean over the rooms every replicate has; a
method's mean is the mean over the draws of the mean over the seeds of each draw (= the mean over seeds when there
is one draw, today's figure), and its range, the one "decided" reads, is over every replicate (seeds and draws).
With several draws the comparison adds, per CER value, the mean over draws with the draws' range per room and
over all rooms (`draws_tables`); the per-scene rows stay (`per_scene_table`).

`methods` and `scenes` (`--methods`, `--scenes`) choose the cells before anything else.
Only fully evaluated checkpoints count (not the word-crop-only ones of `--checkpoints every:N`). Every method is
held to the scenes all methods have at that checkpoint (`common_scenes`: a folder still filling, or a draw trained
for some methods only, would otherwise rank methods on different rooms). Within a method, a ragged coverage keeps
the replicates that have every room or every replicate over the rooms they all have, whichever keeps more cells.
What is held back is listed, not averaged. The same cell in two folders counts once when its figures agree and is an error when they differ.
Written as Markdown, LaTeX, CSV and an HTML page in the run report's style (`write_comparison`).
"""

from __future__ import annotations

import csv
import io
import math
from dataclasses import dataclass
from pathlib import Path

from strings_bench.core.draws import split_draw
from strings_bench.core.errors import DatasetError, StringsBenchError
from strings_bench.core.io import atomic_write_text
from strings_bench.reports.results import cell_row, iter_cells, iteration_label
from strings_bench.reports.results import read_manifest
from strings_bench.reports.table_model import PREAMBLE, Column, MethodNames, Table, dataset_title, label_value

VALUES = ("cer", "cer_known", "word_cer", "psnr", "ssim", "lpips", "gaussians", "train_seconds")
CER_VALUES = (("cer", "OCR-CER"), ("cer_known", "known-text CER"), ("word_cer", "word CER"))
DECIDED_CAPTION = ("Decided: both methods have several seeds (or scene draws) and the ranges of their means per seed "
                   "and draw do not overlap; not decided: they overlap. Lower in (paired): in how many of the (seed, "
                   "draw) replicates both have the method's mean is below the reference's (beside the verdict, not "
                   "part of it).")
PAPER_DATASET = "strings360"  # the paper's dataset a synthetic360 comparison stands beside


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
                           for k in VALUES if k != "train_seconds")
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
                                             "ROOM@N of one dataset (docs/datasets.md, 'Scene draws')")
            out.setdefault((row["method"], row["label"]), {}).setdefault(seed, {})[row["scene"]] = vals
    for what, wanted in (("methods", methods), ("scenes", scenes)):
        unknown = sorted(set(wanted or ()) - found[what])
        if unknown:
            raise StringsBenchError(f"no fully evaluated cell of {what} {', '.join(unknown)} in "
                                    + ", ".join(map(str, run_dirs)),
                                    hint=f"the folders' {what}: {', '.join(sorted(found[what])) or 'none'}")
    return out


def room_draw(scene: str) -> tuple[str, int]:
    """(room, draw) of a cell's scene name ('pantry@2' -> ('pantry', 2)); a name that is no draw is draw 0 of itself."""
    try:
        return split_draw(scene)
    except DatasetError:
        return scene, 0


def _mean(xs) -> float:
    xs = list(xs)
    return sum(xs) / len(xs)


def summarise(per_seed: dict, value: str) -> dict | None:
    """Per replicate (seed, draw): the mean over the rooms every replicate has; then the mean over the seeds of each
    draw, and over the draws ("mean"), with the range over the replicates ("min", "max"). One draw: the mean over
    the scenes every seed has, per seed, then the mean, min and max over the seeds."""
    reps: dict = {}
    for seed, by_scene in per_seed.items():
        for scene, vals in by_scene.items():
            room, draw = room_draw(scene)
            reps.setdefault((seed, draw), {})[room] = vals
    if not reps:
        return None
    # A ragged coverage (draw 1 of one room only) keeps either the replicates that have every room, or every
    # replicate over the rooms all of them have: whichever keeps more cells (a tie keeps every replicate).
    every_room = set.union(*(set(r) for r in reps.values()))
    rooms = set.intersection(*(set(r) for r in reps.values()))
    complete = {rep: r for rep, r in reps.items() if set(r) == every_room}
    if len(complete) * len(every_room) > len(reps) * len(rooms):
        reps, rooms = complete, every_room
    if not rooms:
        return None
    means = {}
    for rep in sorted(reps):
        vals = [reps[rep][room][value] for room in sorted(rooms)]
        if any(math.isnan(v) for v in vals):
            continue
        means[rep] = sum(vals) / len(vals)
    if not means:
        return None
    seeds = sorted({seed for seed, _ in means})
    draws = sorted({draw for _, draw in means})
    per_draw = {d: _mean(m for (_, dd), m in means.items() if dd == d) for d in draws}
    # the scenes of a seed outside the replicates and rooms averaged (reported, not averaged)
    def used(seed, scene):
        room, draw = room_draw(scene)
        return (seed, draw) in reps and room in rooms
    missing = {seed: sorted(sc for sc in by_scene if not used(seed, sc))
               for seed, by_scene in per_seed.items() if not all(used(seed, sc) for sc in by_scene)}
    return {"mean": _mean(per_draw.values()), "min": min(means.values()), "max": max(means.values()),
            "seeds": len(seeds), "draws": len(draws), "replicates": len(means), "scenes": len(rooms),
            "per_seed": [_mean(m for (s, _), m in means.items() if s == seed) for seed in seeds],
            "per_draw": per_draw, "per_replicate": [[s, d, m] for (s, d), m in sorted(means.items())],
            "left_out": missing}


def decided(a: dict | None, b: dict | None) -> str:
    """Whether two methods' summaries separate them: "decided" when both have several replicates (seeds x draws)
    and their ranges do not overlap, "not decided" when they overlap, "one seed" when either has a single seed of a
    single draw, "" when either is missing."""
    if a is None or b is None:
        return ""
    if a["replicates"] < 2 or b["replicates"] < 2:
        return "one seed"
    return "decided" if a["max"] < b["min"] or b["max"] < a["min"] else "not decided"


def common_scenes(data: dict) -> tuple[dict, dict, set]:
    """`data` ({(method, label): {seed: {scene: ...}}}) held to the scenes every method has at each checkpoint (in
    any of its seeds), {(method, label): {seed: [scenes left out]}}, and the checkpoints whose methods share no
    scene (nothing is held back there). Means over different scenes would rank methods on different rooms and
    draws (a draw trained for some methods only): a draw moves known-text CER more than a seed does (issue 40)."""
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


@dataclass
class Comparison:
    """The numbers of a comparison: {method: {label: {value: summary}}}, in the registry's order. `data` holds the
    cells averaged (the scenes every method has, `common_scenes`), `cells` every cell of the folders (the per-scene
    rows), `not_common` the cells held back for that."""

    data: dict
    numbers: dict
    methods: list[str]
    run_dirs: list[Path]
    names: MethodNames  # as the folders' run.json recorded the methods, then as their specs do
    paper_dataset: str = PAPER_DATASET
    cells: dict | None = None
    not_common: dict | None = None
    unshared: set | None = None  # checkpoints whose methods share no scene
    against: str | None = None  # the reference `decided_rows` holds the others against; None: STRinGS

    def get(self, method: str, label: str, value: str) -> dict | None:
        return (self.numbers.get(method) or {}).get(label, {}).get(value)

    @property
    def reference(self) -> str | None:
        """The method the others are held against: `against` where given, else the one of group "ours" (STRinGS)."""
        if self.against:
            return self.against
        return next((m for m in self.methods if self.names.info(m)["group"] == "ours"), None)

    def ablations(self) -> list[tuple[str, str, str, str]]:
        """(ablation, the method it ablates, checkpoint label, the label its spec names) for every ablation both
        of which are compared: at the spec's checkpoint (`ablation_at`) where both have a CER there, else at the
        last checkpoint both have (a folder trained to 7K and 30K has no 3K: n/a would hide the ablation)."""
        out = []
        for m in self.methods:
            info = self.names.info(m)
            if info["group"] == "ablation" and info["ablation_of"] in self.methods:
                of, named = info["ablation_of"], iteration_label(int(info["ablation_at"]))
                both = [lab for lab in self.numbers.get(m, {}) if self.get(m, lab, "cer") and self.get(of, lab, "cer")]
                label = named if named in both or not both else max(both, key=label_value)
                out.append((m, of, label, named))
        return out

    def left_out(self) -> list[str]:
        within = {f"{m} {lab}: seed {seed} also has {', '.join(sc)} (left out of the means)"
                  for m in self.methods for lab, vs in self.numbers[m].items()
                  for seed, sc in ((vs.get("cer") or {}).get("left_out") or {}).items()}
        across = {f"{m} {lab}: seed {seed} also has {', '.join(sc)} (left out of the means: not every method has it)"
                  for (m, lab), per_seed in (self.not_common or {}).items() for seed, sc in per_seed.items()}
        apart = {f"{lab}: the methods share no scene; each method's mean is over its own (not comparable)"
                 for lab in self.unshared or ()}
        return sorted(within | across | apart)


def compare(run_dirs: list[Path], dataset: str | None = None, paper_dataset: str = PAPER_DATASET,
            methods: list[str] | None = None, scenes: list[str] | None = None,
            against: str | None = None) -> Comparison:
    """The comparison of the fully evaluated cells of `run_dirs` (one seed each), of `methods` and `scenes` only
    when given: the scenes all methods share are found after that choice, so a method left out does not narrow
    the others. `against`: the method every other is held against in "Decided or not" (default: STRinGS)."""
    # Seeds are averaged: folders of different equal-Gaussian budgets (run --budget; none is one of them) are
    # different conditions, never seeds of one.
    budgets = {str(d): (read_manifest(d) or {}).get("budget") for d in run_dirs}
    if len(set(map(str, budgets.values()))) > 1:
        raise StringsBenchError("the run folders were made under different Gaussian budgets: " + ", ".join(
            f"{d}: {'no budget' if b is None else f'--budget {b}'}" for d, b in budgets.items()),
            hint="compare folders of one budget at a time (run --budget, docs/running.md)")
    cells = collect(run_dirs, dataset, methods, scenes)
    data, not_common, unshared = common_scenes(cells)
    if not data:
        raise StringsBenchError("no fully evaluated cells in " + ", ".join(map(str, run_dirs)),
                                hint="give run folders with finished cells (strings-bench run or calibrate)")
    recorded: dict = {}
    for d in run_dirs:
        recorded.update((read_manifest(d) or {}).get("methods") or {})
    names = MethodNames.of({"methods": recorded})
    methods = names.order(m for m, _ in data)
    numbers = {m: {label: {v: summarise(data[(m, label)], v) for v in VALUES} for (mm, label) in data if mm == m}
               for m in methods}
    if against is not None and against not in methods:
        raise StringsBenchError(f"--against {against}: no fully evaluated cells of {against} among the compared",
                                hint="give one of " + ", ".join(methods))
    return Comparison(data, numbers, methods, [Path(d) for d in run_dirs], names, paper_dataset, cells, not_common,
                      unshared, against)


# ---- tables --------------------------------------------------------------------------------------------
def _column(c: Comparison, group: str, sub: str, label: str, value: str, lower: bool, fmt: str,
            scale: float = 1.0, methods=None) -> Column:
    """The seeds' mean of `value` at `label` per method, with the seeds' range after it."""
    values, suffix = {}, {}
    for m in methods or c.methods:
        s = c.get(m, label, value)
        if s is None:
            continue
        values[m] = s["mean"] * scale
        if s["replicates"] > 1:
            suffix[m] = f" ({format(s['min'] * scale, fmt)}-{format(s['max'] * scale, fmt)})"
    return Column(group, sub, sub, lower, fmt, values, suffix=suffix)


def _paper_column(c: Comparison, what: str, label: str, sub: str, fmt: str) -> Column | None:
    """The paper's own figure (the methods' specs) as a greyed, unranked column; None when no method has one."""
    from strings_bench.methods.registry import get_method

    values = {}
    for m in c.methods:
        try:
            figures = get_method(m).paper_results.get(c.paper_dataset, {}).get(what, {})
        except StringsBenchError:  # a method of an old folder that is no longer registered
            continue
        if int(label_value(label)) in figures:
            values[m] = figures[int(label_value(label))]
    if not values:
        return None
    return Column(f"paper ({dataset_title(c.paper_dataset)})", sub, sub, True, fmt, values, greyed=True)


SEEDS_NOTE = (" Mean over the scenes of each seed, then over the seeds; the seeds' range in brackets. The paper's "
              "figures (grey, never ranked) are from each method's spec (REFERENCE.md section 5).")
DRAWS_NOTE = (" Mean over the rooms of each seed and scene draw, then over the seeds of each draw, then over the draws; "
              "the range over every seed and draw in brackets. The paper's figures (grey, never ranked) are from each "
              "method's spec (REFERENCE.md section 5).")


def has_draws(c: "Comparison") -> bool:
    """Whether any method of the comparison has several scene draws."""
    return any(s["draws"] > 1 for m in c.methods for lab in c.numbers[m] for s in c.numbers[m][lab].values() if s)


def comparison_tables(c: Comparison) -> list[Table]:
    """The CER table, the time and image-quality table and, where the comparison has them, the ablations."""
    main = [m for m in c.methods if not c.names.is_ablation(m)] or c.methods
    drawn = has_draws(c)
    note = DRAWS_NOTE if drawn else SEEDS_NOTE
    # the most seeds (x draws) a method has at any checkpoint, and the scenes (rooms) averaged there
    most = {m: max((s for lab in c.numbers[m] if (s := c.get(m, lab, "cer"))),
                   key=lambda s: (s["replicates"], s["scenes"]), default=None) for m in c.methods}
    cer_cols = [Column("", what, what, True, ".0f", {m: s[what] for m, s in most.items() if s}, greyed=True)
                for what in (("seeds", "draws", "scenes") if drawn else ("seeds", "scenes"))]
    cer_cols += [_column(c, "", f"{name} {label}", label, value, True, ".3f")
                for value, name in CER_VALUES for label in ("7K", "30K") if (value, label) != ("word_cer", "7K")]
    cer_cols += [p for label in ("7K", "30K") if (p := _paper_column(c, "cer", label, f"OCR-CER {label}", ".3f"))]
    tables = [Table("compare_cer", r"Method", "Method", cer_cols, c.methods,
                    "CER at 7K and 30K: OCR-CER (the paper's metric), known-text CER and word CER." + note,
                    heading="CER over seeds and draws" if drawn else "CER over seeds")]
    time_cols = [_column(c, "", f"training time {label} (min)", label, "train_seconds", True, ".2f", 1 / 60, main)
                 for label in ("7K", "30K")]
    time_cols += [p for label in ("7K", "30K")
                  if (p := _paper_column(c, "minutes", label, f"training time {label} (min)", ".1f"))]
    time_cols += [_column(c, "", f"{name} 30K", "30K", value, lower, fmt, methods=main)
                  for value, name, lower, fmt in (("psnr", "PSNR", False, ".2f"), ("ssim", "SSIM", False, ".4f"),
                                                  ("lpips", "LPIPS", True, ".4f"), ("gaussians", "Gaussians", True, ".0f"))]
    tables.append(Table("compare_time_quality", "Method", "Method", time_cols, main,
                        "Training time (optimisation, minutes; only comparable between folders measured under the same "
                        "load) and image quality at 30K." + note, heading="Training time and image quality"))
    ablations = c.ablations()
    if ablations:
        rows = [m for m, _, _, _ in ablations]
        cols = [Column("", "checkpoint", "checkpoint", True, "K", {m: label_value(lab) for m, _, lab, _ in ablations})]
        moved = [f"{c.names.title(m)} at {lab} (its spec names {named}, which this comparison lacks)"
                 for m, _, lab, named in ablations if lab != named]
        for value, name in CER_VALUES[:2]:
            wo, full = {}, {}
            for m, of, label, _ in ablations:
                for target, src in ((wo, m), (full, of)):
                    s = c.get(src, label, value)
                    if s is not None:
                        target[m] = s["mean"]
            cols += [Column("", f"w/o: {name}", f"w/o: {name}", True, ".3f", wo),
                     Column("", f"full method: {name}", f"full method: {name}", True, ".3f", full)]
        tables.append(Table("compare_ablations", "Ablation", "Ablation", cols, rows,
                            "Each ablation beside the method it ablates (its spec's ablation_of), at the checkpoint its "
                            "spec names (ablation_at)" + (f"; {'; '.join(moved)}" if moved else "") + "." + note,
                            shade=False, heading="Ablations"))
    if drawn:
        tables += draws_tables(c)
    for t in tables:
        t.names = c.names
    return tables


def _room_draw_means(c: Comparison, method: str, label: str, value: str) -> dict:
    """{room: {draw: the mean over the seeds of that draw}} of one method and checkpoint (NaN figures left out)."""
    out: dict = {}
    for by_scene in (c.data.get((method, label)) or {}).values():
        for scene, vals in by_scene.items():
            if not math.isnan(vals[value]):
                room, draw = room_draw(scene)
                out.setdefault(room, {}).setdefault(draw, []).append(vals[value])
    return {room: {d: _mean(v) for d, v in sorted(by_draw.items())} for room, by_draw in out.items()}


def draws_tables(c: Comparison, labels=("7K", "30K")) -> list[Table]:
    """Per CER value: each method's mean over the scene draws with the draws' range, per room (each draw's figure
    the mean over its seeds) and over all rooms (each draw's figure the mean over its seeds of the mean over the
    rooms every replicate has: the summary's per_draw)."""
    tables = []
    for value, name in CER_VALUES:
        cols = []
        for label in labels:
            per_room = {m: _room_draw_means(c, m, label, value) for m in c.methods}
            rooms = sorted({room for rs in per_room.values() for room in rs})
            if not rooms:
                continue
            for room in [*rooms, None]:
                values, suffix = {}, {}
                for m in c.methods:
                    if room is None:
                        s = c.get(m, label, value)
                        per = list(s["per_draw"].values()) if s else []
                    else:
                        per = list(per_room[m].get(room, {}).values())
                    if not per:
                        continue
                    values[m] = _mean(per)
                    suffix[m] = f" ({min(per):.3f}-{max(per):.3f}, {len(per)} draws)" if len(per) > 1 else " (1 draw)"
                sub = f"{room or 'all rooms'}"
                cols.append(Column(f"{name} {label}", sub, sub, True, ".3f", values, suffix=suffix))
        if cols:
            tables.append(Table(f"compare_draws_{value}", "Method", "Method", cols, c.methods,
                                f"{name} over scene draws: per room, the mean over its draws of the mean over the seeds "
                                "of each draw, the draws' range and count in brackets; all rooms: the same over the "
                                "mean of the rooms every seed and draw has.", heading=f"{name} over draws"))
    return tables


def decided_rows(c: Comparison) -> list[dict]:
    """Each method against the reference (`Comparison.reference`: STRinGS unless `against` names another) per CER
    value and checkpoint: the difference of the seeds' means and whether the seeds' ranges separate them."""
    ref = c.reference
    rows = []
    if ref is None:
        return rows
    for m in c.methods:
        if m == ref:
            continue
        for value, name in CER_VALUES:
            for label in ("7K", "30K"):
                a, b = c.get(m, label, value), c.get(ref, label, value)
                verdict = decided(a, b)
                if verdict:
                    both = (a, b)
                    seeds = " / ".join(f"{x['seeds']}" if x["draws"] == 1 else f"{x['seeds']}x{x['draws']} draws"
                                       for x in both)
                    rows.append({"method": m, "against": ref, "value": value, "label": label,
                                 "difference": a["mean"] - b["mean"], "seeds": seeds, "verdict": verdict,
                                 "paired": paired_lower(a, b)})
    return rows


def paired_lower(a: dict, b: dict) -> str:
    """In how many of the replicates (seed, draw) both summaries have, `a`'s mean is below `b`'s: "3 of 3". Shown
    beside the verdict, never deciding it: a draw moves every method together (one room build is harder for all),
    so two methods whose ranges over draws overlap can still be in the same order on every draw."""
    pa = {(seed, draw): v for seed, draw, v in a["per_replicate"]}
    pb = {(seed, draw): v for seed, draw, v in b["per_replicate"]}
    shared = sorted(pa.keys() & pb.keys())
    return f"{sum(pa[k] < pb[k] for k in shared)} of {len(shared)}"


def _shown(rows: list[dict]) -> tuple[list[dict], str]:
    """The pairs both sides of which have several seeds (or draws), and a sentence on those left out."""
    shown = [r for r in rows if r["verdict"] != "one seed"]
    n = len(rows) - len(shown)
    return shown, (f" {n} pair(s) with a single seed (of a single draw) on one side are not listed." if n else "")


def _decided_markdown(c: Comparison, rows: list[dict]) -> str:
    lines = ["| method | against | CER | checkpoint | difference of means | seeds | verdict | lower in (paired) |",
             "|---|---|---|---|---|---|---|---|"]
    cer_names = dict(CER_VALUES)
    for r in rows:
        lines.append(f"| {c.names.title(r['method'])} | {c.names.title(r['against'])} | {cer_names[r['value']]} | {r['label']} | "
                     f"{r['difference']:+.3f} | {r['seeds']} | {r['verdict']} | {r['paired']} |")
    return "\n".join(lines) + "\n"


def per_scene_table(c: Comparison, value: str = "cer_known") -> str:
    """One row per method and checkpoint: `value` per scene, the seeds' figures joined with '/' (seed order)."""
    if value not in VALUES:
        raise StringsBenchError(f"--per-scene {value}: not a compared value", hint=f"one of: {', '.join(VALUES)}")
    cells = c.cells if c.cells is not None else c.data
    scenes = sorted({sc for per_seed in cells.values() for by_scene in per_seed.values() for sc in by_scene},
                    key=lambda sc: (room_draw(sc)[0], room_draw(sc)[1], sc))  # a room's draws side by side
    first: dict = {}  # label -> the smallest iteration trained for it (checkpoint order)
    for (_, label), per_seed in cells.items():
        for by_scene in per_seed.values():
            for v in by_scene.values():
                first[label] = min(first.get(label, v["iteration"]), v["iteration"])
    lines = [f"{value} per scene; several seeds as seed0 / seed1 / ... (seeds: the cells' own)", "",
             "| method | ckpt | " + " | ".join(scenes) + " |", "|---|---|" + "---|" * len(scenes)]
    for label in sorted(first, key=first.get):
        for m in c.methods:
            per_seed = cells.get((m, label))
            if not per_seed:
                continue
            row = [" / ".join(f"{per_seed[seed][sc][value]:.3f}" for seed in sorted(per_seed) if sc in per_seed[seed])
                     or "-" for sc in scenes]
            lines.append(f"| {c.names.title(m)} | {label} | " + " | ".join(row) + " |")
    return "\n".join(lines) + "\n"


def comparison_markdown(c: Comparison, per_scene: str | None = None) -> str:
    over = "seeds and scene draws" if has_draws(c) else "seeds"
    parts = [f"# Comparison over {over}: {', '.join(str(d) for d in c.run_dirs)}", ""]
    for t in comparison_tables(c):
        parts += [f"## {t.title}", "", t.markdown(), t.caption, ""]
    rows, left = _shown(decided_rows(c))
    if rows or left:
        parts += ["## Decided or not" + ("" if c.against is None else f", against {c.names.title(c.reference)}"), "",
                  _decided_markdown(c, rows),
                  DECIDED_CAPTION + left, ""]
    if c.left_out():
        parts += c.left_out() + [""]
    if per_scene:
        parts += ["## Per scene", "", per_scene_table(c, per_scene)]
    return "\n".join(parts)


def comparison_csv(c: Comparison) -> str:
    """Every summary as a row: method, checkpoint, value, mean, min, max, seeds, scenes, the seeds' means."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["method", "label", "value", "mean", "min", "max", "seeds", "scenes", "per_seed", "draws", "per_draw",
                "draw_min", "draw_max"])
    for m in c.methods:
        for label in sorted(c.numbers[m], key=label_value):
            for value, s in c.numbers[m][label].items():
                if s is not None:
                    per_draw = list(s["per_draw"].values())
                    w.writerow([m, label, value, repr(s["mean"]), repr(s["min"]), repr(s["max"]), s["seeds"], s["scenes"],
                                " ".join(repr(x) for x in s["per_seed"]), s["draws"],
                                " ".join(f"{d}:{x!r}" for d, x in s["per_draw"].items()), repr(min(per_draw)),
                                repr(max(per_draw))])
    return buf.getvalue()


def comparison_html(c: Comparison, tables: list[Table]) -> str:
    from strings_bench.reports.html import esc, html_page, table_html

    title = "strings-bench comparison over seeds" + (" and scene draws" if has_draws(c) else "")
    parts = [f"<header><h1>{esc(title)}</h1><p>Run folders: {esc(', '.join(str(d) for d in c.run_dirs))}</p></header>"
             "<main>", '<p class="legend"><span style="background:var(--first)">first</span><span style="background:'
             'var(--second)">second</span><span style="background:var(--third)">third</span>best of each column by the '
             "seeds' mean (the paper's figures, in grey, never rank). Click a header to sort.</p>"]
    for t in tables:
        parts.append(f"<h2>{esc(t.title)}</h2>{table_html(t)}<p class=\"caption\">{esc(t.caption)}</p>")
    rows, left = _shown(decided_rows(c))
    if rows or left:
        cer_names = dict(CER_VALUES)
        body = "".join(
            f'<tr><td class="name">{esc(c.names.title(r["method"]))}</td><td>{esc(cer_names[r["value"]])}</td>'
            f'<td>{esc(r["label"])}</td><td data-v="{r["difference"]!r}">{r["difference"]:+.3f}</td>'
            f'<td>{esc(r["seeds"])}</td><td class="{"decided" if r["verdict"] == "decided" else "undecided"}">'
            f'{esc(r["verdict"])}</td><td>{esc(r["paired"])}</td></tr>' for r in rows)
        parts.append(f"<h2>Decided or not, against {esc(c.names.title(c.reference))}</h2>"
                     '<table class="data" id="table-decided"><thead><tr>'
                     '<th class="name" data-col="0" data-type="text">method</th><th data-col="1" data-type="text">CER</th>'
                     '<th data-col="2" data-type="text">checkpoint</th><th data-col="3" data-type="num">difference</th>'
                     '<th data-col="4" data-type="text">seeds</th><th data-col="5" data-type="text">verdict</th>'
                     '<th data-col="6" data-type="text">lower in (paired)</th>'
                     f"</tr></thead><tbody>{body}</tbody></table>"
                     f'<p class="caption">{esc(DECIDED_CAPTION + left)}</p>')
    for line in c.left_out():
        parts.append(f'<p class="note">{esc(line)}</p>')
    return html_page(title, "\n".join(parts) + "</main>")


def write_comparison(c: Comparison, out: str | Path, per_scene: str | None = None) -> dict[str, Path]:
    """Write comparison.md, comparison.tex (with tables' preamble.tex), comparison.csv and index.html into `out`."""
    out = Path(out)
    tables = comparison_tables(c)
    tex = "\n".join(t.latex() for t in tables)
    doc = "\n".join([r"\documentclass{article}", r"\usepackage[margin=1.5cm]{geometry}", PREAMBLE,
                     r"\begin{document}", tex, r"\end{document}"]) + "\n"
    return {"md": atomic_write_text(out / "comparison.md", comparison_markdown(c, per_scene)),
            "tex": atomic_write_text(out / "comparison.tex", doc),
            "csv": atomic_write_text(out / "comparison.csv", comparison_csv(c)),
            "html": atomic_write_text(out / "index.html", comparison_html(c, tables))}
