"""The tables of `strings-bench calibrate` (cli/calibrate.py): per setting, scene and checkpoint, then the means
against the paper's 3DGS figures; with scene draws (core/draws.py), the mean over the rooms of each draw, then over
the draws with the draws' range, and per room the mean over its draws with their range."""

from __future__ import annotations

import io
import math

from strings_bench.core.draws import split_draw

PAPER_3DGS = {"7K": 0.736, "30K": 0.148}  # 3DGS's OCR-CER on STRinGS-360 (the paper's Table 1)
TOLERANCE = 0.1
# The metrics averaged over rooms and draws in the tables (text_points: SfM points on the text, a scene's own).
MEAN_KEYS = ("cer", "cer_known", "word_cer", "text_nll", "text_points")


def as_float(x) -> float:
    try:
        return float(x)
    except (TypeError, ValueError):
        return math.nan


def _fmt(x, spec="{:.3f}") -> str:
    return "-" if isinstance(x, float) and math.isnan(x) else spec.format(x)


TARGET_NAMES = {"cer": "OCR-CER", "cer_known": "known-text CER"}


def _with_draw(r: dict) -> dict:
    """A row with its room, draw and group (the setting its draws share): from the row when given (run() sets them:
    a grid's seed axis makes draws of one setting), else from the scene name (ROOM@N)."""
    room, draw = split_draw(r["scene"])
    return {"room": room, "draw": draw, "group": r["setting"], **r}


def _mean(vals) -> float:
    vals = [v for v in vals if not (isinstance(v, float) and math.isnan(v))]
    return sum(vals) / len(vals) if vals else math.nan


def over_draws(rs: list[dict], key: str) -> dict:
    """The mean of `key` over the rooms of each draw, then over the draws: {"mean", "min", "max", "draws", "rooms",
    "per_draw"}. Only the rooms every draw has count (a draw still training would otherwise be a mean over other
    rooms); rows without a value are left out (NaN when nothing is left)."""
    by_draw: dict[int, dict[str, list[float]]] = {}
    for r in rs:
        v = as_float(r.get(key))
        if not math.isnan(v):
            by_draw.setdefault(r["draw"], {}).setdefault(r["room"], []).append(v)
    rooms = set.intersection(*(set(by_room) for by_room in by_draw.values())) if by_draw else set()
    per = {d: _mean(_mean(by_room[room]) for room in sorted(rooms)) for d, by_room in sorted(by_draw.items())}
    if not rooms:
        return {"mean": math.nan, "min": math.nan, "max": math.nan, "draws": 0, "rooms": 0, "per_draw": {}}
    return {"mean": _mean(per.values()), "min": min(per.values()), "max": max(per.values()), "draws": len(per),
            "rooms": len(rooms), "per_draw": per}


def _fmt_range(s: dict, spec: str = "{:.3f}") -> str:
    """'mean (min-max)' over draws; the mean alone for one draw."""
    if s["draws"] < 2:
        return _fmt(s["mean"], spec)
    return f"{_fmt(s['mean'], spec)} ({_fmt(s['min'], spec)}-{_fmt(s['max'], spec)})"


def tables(rows: list[dict], scenes: list[str], target: str = "cer", expected: dict | None = None) -> str:
    """The markdown: one row per setting, scene and checkpoint, then the means over scenes against the paper
    (`target`: the metric held against the paper's 3DGS figures, cer or cer_known). With several draws, the means
    are over the rooms of each draw, then over the draws, with the draws' range, and a table per room follows.
    `expected`: the scenes each group should have (default: len(scenes))."""
    rows = [_with_draw(r) for r in rows]
    out = io.StringIO()
    out.write("| setting | scene | ckpt | OCR-CER | known-text CER | word_cer | GT word_cer | text_nll | PSNR | Gaussians "
              "| train s | SfM text pts |\n")
    out.write("|---|---|---|---|---|---|---|---|---|---|---|---|\n")
    for r in rows:
        out.write(f"| {r['setting']} | {r['scene']} | {r['label']} | {_fmt(r['cer'])} | {_fmt(r['cer_known'])} | "
                  f"{_fmt(r['word_cer'])} | {_fmt(r.get('word_cer_gt', math.nan))} | {_fmt(r['text_nll'], '{:.2f}')} | "
                  f"{_fmt(r['psnr'], '{:.2f}')} | "
                  f"{r['gaussians']} | {_fmt(r['train_seconds'], '{:.0f}')} | "
                  f"{_fmt(as_float(r.get('text_points')), '{:.0f}')} |\n")
    groups: dict[tuple, list[dict]] = {}
    for r in rows:
        groups.setdefault((r["group"], r["label"], r["iteration"]), []).append(r)
    several = any(len({r["draw"] for r in rs}) > 1 for rs in groups.values())
    what = ("Mean over the rooms of each draw (the rooms every draw has), then over the draws, the draws' range in "
            "brackets" if several else "Mean over scenes")
    out.write(f"\n{what} (3DGS on STRinGS-360 in the paper: OCR-CER 0.736 at 7K, 0.148 at 30K; "
              f"calibrated = the mean {TARGET_NAMES[target]} within +-{TOLERANCE} of those):\n\n")
    out.write("| setting | ckpt | scenes |" + (" draws |" if several else "")
              + " OCR-CER | known-text CER | word_cer | text_nll | SfM text pts | paper | within |\n")
    out.write("|---|---|---|" + ("---|" if several else "") + "---|---|---|---|---|---|---|\n")
    for (group, label, _), rs in groups.items():
        s = {k: over_draws(rs, k) for k in MEAN_KEYS}
        cer = s[target]["mean"]
        paper = PAPER_3DGS.get(label)
        within = "-" if paper is None or math.isnan(cer) else ("yes" if abs(cer - paper) <= TOLERANCE else "no")
        n = (expected or {}).get(group, len(scenes))
        out.write(f"| {group} | {label} | {len(rs)}/{n} |" + (f" {s['cer']['draws']} |" if several else "")
                  + f" {_fmt_range(s['cer'])} | {_fmt_range(s['cer_known'])} | {_fmt_range(s['word_cer'])} | "
                  f"{_fmt_range(s['text_nll'], '{:.2f}')} | {_fmt_range(s['text_points'], '{:.0f}')} | "
                  f"{'-' if paper is None else paper} | {within} |\n")
    if several:
        out.write("\nPer room: the mean over its draws, the draws' range in brackets:\n\n")
        out.write("| setting | ckpt | room | draws | OCR-CER | known-text CER | word_cer | text_nll | SfM text pts |\n")
        out.write("|---|---|---|---|---|---|---|---|---|\n")
        for (group, label, _), rs in groups.items():
            for room in dict.fromkeys(r["room"] for r in rs):
                s = {k: over_draws([r for r in rs if r["room"] == room], k) for k in MEAN_KEYS}
                out.write(f"| {group} | {label} | {room} | {s['cer']['draws']} | {_fmt_range(s['cer'])} | "
                          f"{_fmt_range(s['cer_known'])} | {_fmt_range(s['word_cer'])} | "
                          f"{_fmt_range(s['text_nll'], '{:.2f}')} | {_fmt_range(s['text_points'], '{:.0f}')} |\n")
    return out.getvalue()
