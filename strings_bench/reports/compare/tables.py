"""A comparison's tables: the CER table, the time and image-quality table, the ablations (`comparison_tables`) and,
with several scene draws, the CER over draws (`draws_tables`)."""

from __future__ import annotations

import math

from strings_bench.core.errors import StringsBenchError
from strings_bench.reports.compare.statistics import CER_VALUES, Comparison, mean_of, room_draw
from strings_bench.reports.table_model import Column, Table, dataset_title, label_value

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
              "figures (grey, never ranked) are from each method's spec (the STRinGS paper, Table 1).")
DRAWS_NOTE = (" Mean over the rooms of each seed and scene draw, then over the seeds of each draw, then over the draws; "
              "the range over every seed and draw in brackets. The paper's figures (grey, never ranked) are from each "
              "method's spec (the STRinGS paper, Table 1).")


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
    return {room: {d: mean_of(v) for d, v in sorted(by_draw.items())} for room, by_draw in out.items()}


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
                    values[m] = mean_of(per)
                    suffix[m] = f" ({min(per):.3f}-{max(per):.3f}, {len(per)} draws)" if len(per) > 1 else " (1 draw)"
                sub = f"{room or 'all rooms'}"
                cols.append(Column(f"{name} {label}", sub, sub, True, ".3f", values, suffix=suffix))
        if cols:
            tables.append(Table(f"compare_draws_{value}", "Method", "Method", cols, c.methods,
                                f"{name} over scene draws: per room, the mean over its draws of the mean over the seeds "
                                "of each draw, the draws' range and count in brackets; all rooms: the same over the "
                                "mean of the rooms every seed and draw has.", heading=f"{name} over draws"))
    return tables
