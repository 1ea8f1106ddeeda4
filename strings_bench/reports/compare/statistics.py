"""A comparison's numbers: per method, checkpoint and value, the mean over the seeds (and scene draws) with their
range (`summarise`), whether two methods' ranges separate them (`decided`, `decided_rows`, `paired_lower`), and the
`Comparison` that holds them (`compare`)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

from strings_bench.core.draws import split_draw
from strings_bench.core.errors import DatasetError, StringsBenchError
from strings_bench.core.schedules import iteration_label
from strings_bench.reports.compare.collect import VALUES, collect, common_scenes
from strings_bench.reports.table_model import MethodNames, label_value
from strings_bench.store import read_manifest

CER_VALUES = (("cer", "OCR-CER"), ("cer_known", "known-text CER"), ("word_cer", "word CER"))
PAPER_DATASET = "strings360"  # the paper's dataset a synthetic360 comparison stands beside


def room_draw(scene: str) -> tuple[str, int]:
    """(room, draw) of a cell's scene name ('pantry@2' -> ('pantry', 2)); a name that is no draw is draw 0 of itself."""
    try:
        return split_draw(scene)
    except DatasetError:
        return scene, 0


def mean_of(xs) -> float:
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
    per_draw = {d: mean_of(m for (_, dd), m in means.items() if dd == d) for d in draws}
    # the scenes of a seed outside the replicates and rooms averaged (reported, not averaged)
    def used(seed, scene):
        room, draw = room_draw(scene)
        return (seed, draw) in reps and room in rooms
    missing = {seed: sorted(sc for sc in by_scene if not used(seed, sc))
               for seed, by_scene in per_seed.items() if not all(used(seed, sc) for sc in by_scene)}
    return {"mean": mean_of(per_draw.values()), "min": min(means.values()), "max": max(means.values()),
            "seeds": len(seeds), "draws": len(draws), "replicates": len(means), "scenes": len(rooms),
            "per_seed": [mean_of(m for (s, _), m in means.items() if s == seed) for seed in seeds],
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
            hint="compare folders of one budget at a time (run --budget, docs/guide/running.md)")
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
