"""What shrinking the schedule does, and how well a miniature agrees with the full schedule.

    python studies/miniature/miniature.py motion RUN_DIR [RUN_DIR ...] [--csv FILE]
    python studies/miniature/miniature.py agreement --reference CSV_OR_RUN [...] CANDIDATE=CSV_OR_RUN [...] [--csv FILE]

`motion` reads run folders (any schedule scale and miniature) and prints, per method, scene and checkpoint: the
steps trained, Gaussians, the refinement rounds that changed the model's size, and the motion log
(strings_bench/engine/motion.py): the mean path of a Gaussian in early 3DGS position steps (1.6e-4 x extent) and
in the scene's text strokes (x rho, docs/difficulty.md), for all Gaussians and for STRinGS' text Gaussians.

`agreement` scores candidate miniatures against the full-schedule reference on the cells both have (same
method, scene and checkpoint label). For each checkpoint it compares every pair of methods on each scene: the
sign of their CER difference, a difference under --tie counting as a tie (a tie agrees only with a tie). It
prints, per candidate and checkpoint: pairs compared, the share of pairs ordered alike (known-text CER, and
OCR-CER), and the mean |CER difference| of the cells. **It never prints a CER or which method is ahead**, so a
miniature can be chosen on agreement without looking at the comparison it will run (`--show` lists the cells).

    python studies/miniature/miniature.py choose --reference CSV_OR_RUN [...] --baseline NAME CANDIDATE=CSV_OR_RUN [...]

`choose` applies the rule of docs/miniature.md ("The rule that picks it") to the same inputs: eligibility (every
reference cell present; training time at most --max-cost x the baseline candidate's on the same cells), the score
(mean of the four ordered-alike shares), level within --level of the best, then cost, then the mean known-text
difference. It prints each candidate's figures and the choice with its reason, and no CER either.

    python studies/miniature/miniature.py verdicts --reference CSV_OR_RUN [...] [--verdict-table CSV]

`verdicts` holds the paper's claims (the verdict table of docs/results/cpu-long.md) against the reference itself,
once the miniature is frozen (it prints CERs): per claim the reference can speak to (CER at 7K against 3DGS and
EDC-AbsGS, Gaussians at 7K, the lock at 3K and 7K), per room, `yes` when STRinGS is on the claimed side on every room
and CER, `no` when it is on the other side on every one, `mixed` otherwise; a CER difference under --tie, or a count
within 5 %, is level. One seed: the verdicts say what the seed-0 cells show, not what seeds decide.
`--verdict-table` sets that table's column REFERENCE_COLUMN.
"""

from __future__ import annotations

import argparse
import csv
import itertools
import json
import sys
from pathlib import Path

from strings_bench.reports.doc_tables import set_table_column, show_and_save

POSITION_STEP = 1.6e-4  # 3DGS' initial position LR, in scene extents (Kerbl et al. 2023, section 7.1)


def _rows(source: str) -> list[dict]:
    """results.csv rows of a run folder or of a CSV file."""
    path = Path(source)
    if path.is_dir():
        path = path / "results.csv"
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


def _rho(dataset: str, scene: str, cache: dict) -> float | None:
    key = (dataset, scene)
    if key not in cache:
        from strings_bench.scene.difficulty import recorded_difficulty
        from strings_bench.datasets.registry import resolve_scenes
        from strings_bench.scene.scene import Scene

        ref = resolve_scenes([f"{dataset}/{scene}"])[0]
        cache[key] = recorded_difficulty(Scene.load(ref.path, settings=ref.settings)).rho
    return cache[key]


def _cer(value) -> str:
    """A result.json CER entry ({"cer": x, ...}, a number, or None) as a table cell."""
    value = value.get("cer") if isinstance(value, dict) else value
    return "" if value is None else f"{float(value):.3f}"


def motion_rows(run_dirs: list[str]) -> list[dict]:
    rows, rhos = [], {}
    for run_dir in run_dirs:
        if not (Path(run_dir) / "run.json").is_file():
            print(f"{run_dir}: no run.json (not started yet), left out", file=sys.stderr)
            continue
        manifest = json.loads((Path(run_dir) / "run.json").read_text())
        sched = manifest["schedule"]
        for result in sorted(Path(run_dir).glob("cells/*/*/*/*/result.json")):
            rec = json.loads(result.read_text())
            extra = rec.get("extra") or {}
            if "position_path" not in extra:
                continue  # trained before the motion log existed
            rho = _rho(rec["dataset"], rec["scene"], rhos)
            steps = extra["position_path"] / POSITION_STEP
            text = extra.get("text_position_path")
            rows.append({
                "method": rec["method"], "scene": rec["scene"], "scale": sched["steps_scale"],
                "miniature": sched.get("miniature", "shrink"), "ckpt": rec["label"], "steps": rec["iteration"],
                "Gaussians": rec["gaussians"], "size changes": extra.get("count_changes", ""),
                "path (steps)": f"{steps:.1f}", "path (strokes)": "" if rho is None else f"{steps * rho:.2f}",
                "text path (steps)": "" if text is None else f"{text / POSITION_STEP:.1f}",
                "text path (strokes)": "" if text is None or rho is None else f"{text / POSITION_STEP * rho:.2f}",
                "logged from step": extra.get("motion_from_step", ""),
                "known-text CER": _cer(rec.get("cer_known")), "OCR-CER": _cer(rec.get("cer")),
            })
    return rows


def _sign(d: float, tie: float) -> int:
    return 0 if abs(d) < tie else (1 if d > 0 else -1)


CER_COLUMNS = (("cer_known", "known-text CER"), ("cer", "OCR-CER"))


def agreement_stats(reference: list[dict], candidate: list[dict], tie: float) -> list[tuple]:
    """(checkpoint label, cells, {column name: (pairs, pairs ordered alike, [|CER difference| per cell])}) per
    checkpoint label of the cells both sides have."""
    def table(rows):
        return {(r["method"], r["scene"], r["label"]): r for r in rows}

    ref, cand = table(reference), table(candidate)
    common = sorted(set(ref) & set(cand))
    out = []
    for label in sorted({k[2] for k in common}, key=lambda s: (len(s), s)):
        keys = [k for k in common if k[2] == label]
        stats = {}
        for col, name in CER_COLUMNS:
            pairs = agree = 0
            diffs = []
            for scene in sorted({k[1] for k in keys}):
                cells = [k for k in keys if k[1] == scene and ref[k].get(col) not in ("", None)
                         and cand[k].get(col) not in ("", None)]
                diffs += [abs(float(cand[k][col]) - float(ref[k][col])) for k in cells]
                for a, b in itertools.combinations(cells, 2):
                    s_ref = _sign(float(ref[a][col]) - float(ref[b][col]), tie)
                    s_cand = _sign(float(cand[a][col]) - float(cand[b][col]), tie)
                    pairs += 1
                    agree += s_ref == s_cand
            stats[name] = (pairs, agree, diffs)
        out.append((label, len(keys), stats))
    return out


def agreement(reference: list[dict], candidate: list[dict], tie: float) -> list[dict]:
    """Per checkpoint label: pairs compared, shares ordered alike, mean |CER difference| (module docstring)."""
    out = []
    for label, n_cells, stats in agreement_stats(reference, candidate, tie):
        row = {"ckpt": label, "cells": n_cells}
        for _, name in CER_COLUMNS:
            pairs, agree, diffs = stats[name]
            row[f"pairs ({name})"] = pairs
            row[f"ordered alike ({name})"] = "" if not pairs else f"{agree / pairs:.2f}"
            row[f"mean abs. difference ({name})"] = "" if not diffs else f"{sum(diffs) / len(diffs):.3f}"
        out.append(row)
    return out


def training_seconds(rows: list[dict], keys: set) -> float:
    """The training time of the (method, scene) cells in `keys`: each cell's time at its last checkpoint (a cell's
    train_seconds is cumulative over its checkpoints), summed."""
    last: dict = {}
    for r in rows:
        key = (r["method"], r["scene"])
        if key in keys and r.get("train_seconds") not in ("", None):
            it = int(r["iteration"])
            if key not in last or it > last[key][0]:
                last[key] = (it, float(r["train_seconds"]))
    return sum(t for _, t in last.values())


def choose(reference: list[dict], candidates: dict[str, list[dict]], baseline: str, tie: float = 0.02,
           max_cost: float = 2.0, level: float = 0.05) -> tuple[list[dict], str | None, str]:
    """The rule of docs/miniature.md: per candidate its coverage, cost (training seconds over the reference's
    (method, scene) cells, and as a multiple of the baseline's), score (mean of the ordered-alike shares over the
    checkpoints and both CERs) and mean known-text difference; then the choice and its reason. Returns (rows,
    chosen name or None, reason)."""
    ref_cells = {(r["method"], r["scene"], r["label"]) for r in reference}
    ref_pairs = {(m, sc) for m, sc, _ in ref_cells}
    if baseline not in candidates:
        raise SystemExit(f"the baseline {baseline!r} is not among the candidates {sorted(candidates)}")
    base_cost = training_seconds(candidates[baseline], ref_pairs)
    rows = []
    for name, cand in candidates.items():
        have = {(r["method"], r["scene"], r["label"]) for r in cand}
        missing = len(ref_cells - have)
        cost = training_seconds(cand, ref_pairs)
        shares, diffs = [], []
        for _, _, stats in agreement_stats(reference, cand, tie):
            for _, col in CER_COLUMNS:
                pairs, agree, _ = stats[col]
                if pairs:
                    shares.append(agree / pairs)
            known = stats["known-text CER"][2]
            if known:
                diffs.append(sum(known) / len(known))
        ratio = cost / base_cost if base_cost > 0 else float("nan")
        eligible = missing == 0 and ratio <= max_cost
        rows.append({"candidate": name, "reference cells missing": missing, "training s": f"{cost:.0f}",
                     "cost / baseline": f"{ratio:.2f}", "eligible": "yes" if eligible else "no",
                     "score": "" if not shares else f"{sum(shares) / len(shares):.3f}",
                     "mean abs. difference (known-text CER)": "" if not diffs else f"{sum(diffs) / len(diffs):.3f}",
                     "_score": sum(shares) / len(shares) if shares else None, "_cost": cost,
                     "_diff": sum(diffs) / len(diffs) if diffs else float("inf"), "_eligible": eligible})
    ok = [r for r in rows if r["_eligible"] and r["_score"] is not None]
    if not ok:
        reason = "no candidate is eligible yet (every reference cell present, cost within the limit)"
        chosen = None
    else:
        best = max(r["_score"] for r in ok)
        level_rows = [r for r in ok if r["_score"] >= best - level]
        pick = min(level_rows, key=lambda r: (r["_cost"], r["_diff"]))
        chosen = pick["candidate"]
        others = [r["candidate"] for r in level_rows if r is not pick]
        reason = (f"{chosen}: score {pick['score']} (best {best:.3f}, level within {level})"
                  + (f"; cheaper than the level candidates {', '.join(others)}" if others else "; no other candidate level"))
    for r in rows:
        for k in ("_score", "_cost", "_diff", "_eligible"):
            r.pop(k)
    return rows, chosen, reason


REFERENCE_COLUMN = "x1 (the paper's schedule; storeroom, pantry; seed 0)"
CLAIM_BASELINES = ("3dgs", "edc-absgs")  # the reference's baselines (STRinGS' ablation aside)
COUNT_TIE = 0.05  # Gaussian counts within 5 % are level


def _value(rows: list[dict], method: str, scene: str, label: str, key: str) -> float | None:
    for r in rows:
        if r["method"] == method and r["scene"] == scene and r["label"] == label and r.get(key) not in (None, ""):
            return float(r[key])
    return None


def _side(ours: float, others: list[float], tie: float, relative: bool = False) -> str:
    """"below" when `ours` is below every one of `others` by more than the tie, "above" when above some one by
    more than it, else "level"."""
    def apart(a, b):  # a below b by more than the tie
        return a < b * (1 - tie) if relative else a < b - tie
    if all(apart(ours, o) for o in others):
        return "below"
    if any(apart(o, ours) for o in others):
        return "above"
    return "level"


def _holds(sides: list[str], want: str) -> str:
    if sides and all(s == want for s in sides):
        return "yes"
    if sides and all(s not in (want, "level") for s in sides):
        return "no"
    return "mixed"


def _num(x: float, key: str) -> str:
    return f"{x:,.0f}".replace(",", " ") if key in ("gaussians", "train_seconds") else f"{x:.3f}"


def reference_verdicts(rows: list[dict], tie: float = 0.02) -> dict[str, str]:
    """The claims of the verdict table that the reference speaks to, each as "yes/no/mixed: figures"."""
    scenes = sorted({r["scene"] for r in rows})
    out = {}

    def claim(labels, keys, others, want, relative=False) -> tuple[str, str]:
        """("yes"/"no"/"mixed", the figures), or ("not measured", "") when no room has the cells."""
        sides, parts = [], []
        for label in labels:
            for key, name in keys:
                figs = []
                for scene in scenes:
                    ours = _value(rows, "strings", scene, label, key)
                    theirs = [_value(rows, m, scene, label, key) for m in others]
                    if ours is None or None in theirs:
                        continue
                    sides.append(_side(ours, theirs, COUNT_TIE if relative else tie, relative))
                    figs.append(f"{scene} {_num(ours, key)} against " + ", ".join(
                        f"{m} {_num(v, key)}" for m, v in zip(others, theirs)))
                if figs:
                    parts.append(f"{label} {name}: " + "; ".join(figs))
        if not sides:
            return "not measured", ""
        return _holds(sides, want), f"(STRinGS; {' | '.join(parts)})"

    def text(verdict_and_figures: tuple[str, str], what: str = "") -> str:
        verdict, figures = verdict_and_figures
        return f"{verdict}{what} {figures}" if figures else verdict

    cers = (("cer_known", "known-text CER"), ("cer", "OCR-CER"))
    out["lower CER than every baseline at 7K"] = text(claim(("7K",), cers, CLAIM_BASELINES, "below"))
    out["lower CER at 30K"] = "not measured (the reference ends at 7K)"
    out["fewer Gaussians"] = text(claim(("7K",), (("gaussians", "Gaussians"),), ("3dgs",), "below", relative=True),
                                  " at 7K")
    _, seconds = claim(("7K",), (("train_seconds", "training s"),), ("3dgs",), "below", relative=True)
    out["less training time"] = f"not decided: one shared core under a varying load {seconds}".rstrip()
    out["text densification helps"] = "not measured (no ablation in the reference)"
    out["the phase-1 position lock helps"] = text(claim(("3K", "7K"), cers, ("strings-pos-lr",), "below"))
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = ap.add_subparsers(dest="what", required=True)
    m = sub.add_parser("motion", help="shrinking's effects, read from run folders")
    m.add_argument("runs", nargs="+")
    m.add_argument("--csv", type=Path)
    a = sub.add_parser("agreement", help="candidate miniatures against the full-schedule reference (blind)")
    a.add_argument("--reference", action="append", required=True, help="a run folder or results.csv (repeatable)")
    a.add_argument("candidates", nargs="+", metavar="NAME=RUN_OR_CSV[+RUN_OR_CSV]")
    a.add_argument("--tie", type=float, default=0.02, help="CER differences under this are ties (default 0.02)")
    a.add_argument("--csv", type=Path)
    a.add_argument("--show", action="store_true", help="also list the CERs (not blind)")
    c = sub.add_parser("choose", help="the frozen-miniature rule of docs/miniature.md (blind)")
    c.add_argument("--reference", action="append", required=True, help="a run folder or results.csv (repeatable)")
    c.add_argument("--baseline", required=True, help="the candidate whose training time is the cost unit (cpu-long)")
    c.add_argument("candidates", nargs="+", metavar="NAME=RUN_OR_CSV[+RUN_OR_CSV]")
    c.add_argument("--tie", type=float, default=0.02)
    c.add_argument("--max-cost", type=float, default=2.0, help="eligible up to this multiple of the baseline's time")
    c.add_argument("--level", type=float, default=0.05, help="scores within this of the best count as level")
    c.add_argument("--csv", type=Path)
    v = sub.add_parser("verdicts", help="the paper's claims held against the reference (prints CERs)")
    v.add_argument("--reference", action="append", required=True, help="a run folder or results.csv (repeatable)")
    v.add_argument("--tie", type=float, default=0.02)
    v.add_argument("--verdict-table", type=Path, help="set this verdict table's column REFERENCE_COLUMN")
    args = ap.parse_args(argv)
    if args.what == "verdicts":
        texts = reference_verdicts([r for src in args.reference for r in _rows(src)], args.tie)
        for claim_name, text in texts.items():
            print(f"{claim_name}: {text}")
        if args.verdict_table:
            set_table_column(args.verdict_table, REFERENCE_COLUMN, texts)
        return 0
    if args.what == "choose":
        reference = [r for src in args.reference for r in _rows(src)]
        cands = {}
        for spec in args.candidates:
            name, _, sources = spec.partition("=")
            cands[name] = [r for src in sources.split("+") for r in _rows(src)]
        rows, chosen, reason = choose(reference, cands, args.baseline, args.tie, args.max_cost, args.level)
        show_and_save(rows, args.csv)
        print(f"choice: {reason}")
        return 0
    if args.what == "motion":
        show_and_save(motion_rows(args.runs), args.csv)
        return 0
    reference = [r for src in args.reference for r in _rows(src)]
    out = []
    for spec in args.candidates:
        name, _, sources = spec.partition("=")
        cand = [r for src in sources.split("+") for r in _rows(src)]
        for row in agreement(reference, cand, args.tie):
            out.append({"candidate": name, **row})
        if args.show:
            for r in cand:
                print(name, r["method"], r["scene"], r["label"], r.get("cer_known"), r.get("cer"))
    show_and_save(out, args.csv)
    return 0


if __name__ == "__main__":
    sys.exit(main())
