"""STRinGS' phase-1 position lock against rho: where the lock starts to help.

    python studies/lock_rho/lock_rho.py RUN_DIR [RUN_DIR ...] [--lock strings] [--no-lock strings-pos-lr]
                                  [--variant METHOD ...] [--tie 0.02] [--csv FILE] [--crossover-csv FILE]
                                  [--lock-any-gain 3K] [--cer both|known|ocr]

rho (docs/difficulty.md) is how much of a text stroke one early 3DGS position step moves a Gaussian. Each run
folder holds cells of STRinGS with the lock (`--lock`, default `strings`) and without it (`--no-lock`, default
`strings-pos-lr`, the paper's ablation) on scenes of known rho, any seeds (`--set seed=N`, one folder per seed or
per setting). A scene's rho is the one its record holds now (the scene folder named in each cell's config; the
value the cell recorded when the folder is gone, as cells written before a change of the measurement hold another
value for the same scene, docs/difficulty.md). A position-LR gain set
on top of the run's miniature (`--set position_lr_gain=G`, G the miniature's own gain times the stand-in factor)
stands in for a scene with that factor times the rho (every position step, text and not, is G times larger): the
table's `rho (effective)` is the scene's rho times that factor.

Per effective rho, scene and checkpoint the table gives each side's CER per seed (known-text CER; OCR-CER beside
it), the lock's effect (mean CER with the lock minus without: negative = the lock helps) and a verdict: `helps`
when every seed with the lock reads better than every seed without by more than --tie, `hurts` the other way,
`not decided` otherwise (one seed is never decided). `--variant METHOD` adds a method's mean CER and its
difference from each side (e.g. STRinGS with the phase-1 step capped in text strokes, `--set
phase1_step_strokes=X`).

At the end of phase 1 (3K) the locked side has not used the position LR at all, so its cells at factor 1 are its
cells at every factor (the grid at x0.1 gives the same figures to the last digit at factors 1-20): `--lock-any-gain
3K` lets them stand in where a run trained only the unlocked side at a factor (the full schedule, where a cell
costs an hour).

The crossover, per checkpoint and CER: the effective rho where the mean effect turns from positive (the lock
hurts) to negative (it helps) between two neighbouring rho values of the table, interpolated linearly in log rho;
`none in range` when the sign never turns that way.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

from strings_bench.reports.doc_tables import show_and_save

CERS = (("cer_known", "known-text CER"), ("cer", "OCR-CER"))
# Settings that make a method a variant of itself: a cell that sets one is named METHOD[KEY=VALUE] (a run folder of
# `--methods strings --set strings.phase1_step_strokes=0.4` gives `strings[phase1_step_strokes=0.4]`, for --variant)
VARIANT_KEYS = ("phase1_step_strokes",)


def cell_method(method: str, settings: dict) -> str:
    """The method's name, with the variant settings it sets: `strings[phase1_step_strokes=0.4]`."""
    tags = [f"{k}={settings[k]:g}" if isinstance(settings[k], (int, float)) else f"{k}={settings[k]}"
            for k in VARIANT_KEYS if settings.get(k) is not None]
    return f"{method}[{','.join(tags)}]" if tags else method


def _cer(value) -> float | None:
    value = value.get("cer") if isinstance(value, dict) else value
    return None if value is None else float(value)


def _miniature_gain(run_dir: Path) -> float:
    """The position-LR gain the run's miniature gives by itself (1 for `shrink`)."""
    from strings_bench.core.schedules import MINIATURES

    manifest = json.loads((run_dir / "run.json").read_text())
    sched = manifest.get("schedule") or {}
    name = sched.get("miniature") or "shrink"
    return float(MINIATURES[name].settings(float(sched.get("steps_scale", 1.0))).get("position_lr_gain", 1.0))


def _current_rho(path: str | None, cache: dict) -> float | None:
    """rho of the scene folder `path` as its record holds it now (a synthetic room of the cache measured as its
    build keeps it), or None when the folder is gone or holds no measurable text."""
    if not path or not Path(path).is_dir():
        return None
    if path not in cache:
        from strings_bench.datasets.synthetic.generate import ensure_rho_record
        from strings_bench.scene.difficulty import recorded_difficulty
        from strings_bench.scene.scene import Scene

        ensure_rho_record(Path(path))
        cache[path] = recorded_difficulty(Scene.load(Path(path))).rho
    return cache[path]


def read_cells(run_dirs: list[str]) -> list[dict]:
    """One dict per finished cell of the run folders: method, scene, label, seed, rho, gain (the stand-in factor
    over the miniature's gain), rho_eff and both CERs."""
    cells, rhos = [], {}
    for run_dir in map(Path, run_dirs):
        if not (run_dir / "run.json").is_file():
            print(f"{run_dir}: no run.json (not started yet), left out", file=sys.stderr)
            continue
        mini_gain = _miniature_gain(run_dir)
        for result in sorted(run_dir.glob("cells/*/*/*/*/result.json")):
            rec = json.loads(result.read_text())
            config = rec.get("config") or {}
            settings = (config.get("method") or {}).get("settings") or {}
            scene_cfg = config.get("scene") or {}
            rho = _current_rho(scene_cfg.get("path"), rhos)
            rho = scene_cfg.get("rho") if rho is None else rho
            if rho is None:
                print(f"{result}: the scene records no rho, left out", file=sys.stderr)
                continue
            gain = float(settings.get("position_lr_gain", mini_gain)) / mini_gain
            cells.append({"method": cell_method(rec["method"], settings), "scene": rec["scene"], "label": rec["label"],
                          "iteration": int(rec["iteration"]), "seed": int(settings.get("seed", 0)),
                          "rho": float(rho), "gain": gain, "rho_eff": float(rho) * gain,
                          "cer_known": _cer(rec.get("cer_known")), "cer": _cer(rec.get("cer"))})
    return cells


def verdict(lock: list[float], free: list[float], tie: float) -> str:
    """`helps` / `hurts` when the seeds' ranges are apart by more than `tie`, else `not decided` (also with fewer
    than two seeds a side)."""
    if len(lock) < 2 or len(free) < 2:
        return "not decided"
    if max(lock) < min(free) - tie:
        return "helps"
    if min(lock) > max(free) + tie:
        return "hurts"
    return "not decided"


def _mean(xs: list[float]) -> float:
    return sum(xs) / len(xs)


def lock_table(cells: list[dict], lock: str, no_lock: str, variants: list[str], tie: float,
               lock_any_gain: tuple[str, ...] = ()) -> list[dict]:
    """Rows per effective rho, scene, stand-in factor and checkpoint. `lock_any_gain`: checkpoints at or before the end
    of phase 1, where the locked side never uses the position LR (its positions do not move), so its cells at
    factor 1 stand for every factor of the same scene where the run has none of its own."""
    groups: dict = {}
    for c in cells:
        key = (round(c["rho_eff"], 6), c["scene"], round(c["gain"], 6), c["label"])
        groups.setdefault(key, []).append(c)
    for (rho_eff, scene, gain, label), group in groups.items():
        if label in lock_any_gain and not any(c["method"] == lock for c in group):
            group += [c for c in cells if c["method"] == lock and c["scene"] == scene and c["label"] == label
                      and round(c["gain"], 6) == 1.0]
    rows = []
    for (rho_eff, scene, gain, label), group in sorted(groups.items(), key=lambda kv: (kv[0][3], kv[0][0], kv[0][1])):
        row = {"ckpt": label, "scene": scene, "rho": f"{group[0]['rho']:.3f}", "LR factor": f"{gain:g}",
               "rho (effective)": f"{rho_eff:.3f}"}
        for col, name in CERS:
            by = {m: sorted((c["seed"], c[col]) for c in group if c["method"] == m and c[col] is not None)
                  for m in (lock, no_lock, *variants)}
            lk, fr = [v for _, v in by[lock]], [v for _, v in by[no_lock]]
            row[f"seeds ({name})"] = f"{len(lk)}/{len(fr)}"
            row[f"lock ({name})"] = " ".join(f"{v:.3f}" for v in lk)
            row[f"no lock ({name})"] = " ".join(f"{v:.3f}" for v in fr)
            if lk and fr:
                row[f"effect ({name})"] = f"{_mean(lk) - _mean(fr):+.3f}"
                row[f"verdict ({name})"] = verdict(lk, fr, tie)
            else:
                row[f"effect ({name})"] = ""
                row[f"verdict ({name})"] = "not measured"
            for v in variants:
                vv = [x for _, x in by[v]]
                row[f"{v} ({name})"] = "" if not vv else f"{_mean(vv):.3f}"
                row[f"{v} - lock ({name})"] = "" if not (vv and lk) else f"{_mean(vv) - _mean(lk):+.3f}"
                row[f"{v} - no lock ({name})"] = "" if not (vv and fr) else f"{_mean(vv) - _mean(fr):+.3f}"
        row["_rho_eff"] = rho_eff
        rows.append(row)
    return rows


def crossover(rows: list[dict]) -> list[dict]:
    """Per checkpoint and CER: the effective rho where the lock's mean effect (averaged over the scenes measured
    at that rho) turns from > 0 to < 0, interpolated in log rho between the neighbouring rho values."""
    out = []
    for label in sorted({r["ckpt"] for r in rows}, key=lambda s: (len(s), s)):
        for _, name in CERS:
            at: dict = {}
            for r in rows:
                if r["ckpt"] == label and r[f"effect ({name})"] != "":
                    at.setdefault(r["_rho_eff"], []).append(float(r[f"effect ({name})"]))
            points = sorted((rho, _mean(e)) for rho, e in at.items())
            found = ""
            for (r1, e1), (r2, e2) in zip(points, points[1:]):
                if e1 > 0 > e2:
                    t = e1 / (e1 - e2)
                    found = f"{math.exp(math.log(r1) + t * (math.log(r2) - math.log(r1))):.3f}"
                    break
            out.append({"ckpt": label, "CER": name, "rho values": len(points),
                        "rho range": "" if not points else f"{points[0][0]:.3f}-{points[-1][0]:.3f}",
                        "crossover rho": found or ("none in range" if len(points) >= 2 else "")})
    return out


def _write(rows: list[dict], path: Path | None) -> None:
    show_and_save([{k: v for k, v in r.items() if not k.startswith("_")} for r in rows], path)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("runs", nargs="+")
    ap.add_argument("--lock", default="strings")
    ap.add_argument("--no-lock", default="strings-pos-lr")
    ap.add_argument("--variant", action="append", default=[])
    ap.add_argument("--lock-any-gain", action="append", default=[], metavar="LABEL",
                    help="a checkpoint at or before the end of phase 1 (e.g. 3K): the lock's cells at factor 1 stand "
                         "for every factor there (locked positions never use the LR in phase 1)")
    ap.add_argument("--tie", type=float, default=0.02, help="CER differences under this do not decide (default 0.02)")
    ap.add_argument("--cer", choices=("both", "known", "ocr"), default="both",
                    help="the CER(s) whose columns are written (default both; one keeps a table narrow enough to read)")
    ap.add_argument("--csv", type=Path)
    ap.add_argument("--crossover-csv", type=Path)
    args = ap.parse_args(argv)
    rows = lock_table(read_cells(args.runs), args.lock, args.no_lock, args.variant, args.tie,
                      tuple(args.lock_any_gain))
    cross = crossover(rows)
    if args.cer != "both":
        drop = dict(CERS)["cer" if args.cer == "known" else "cer_known"]
        rows = [{k: v for k, v in r.items() if not k.endswith(f"({drop})")} for r in rows]
        cross = [c for c in cross if c["CER"] != drop]
    _write(rows, args.csv)
    print()
    _write(cross, args.crossover_csv)
    return 0


if __name__ == "__main__":
    sys.exit(main())
