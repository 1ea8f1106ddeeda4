"""A run folder's manifest, run.json: the run's settings (schedule, steps scale, checkpoints, downscale, OCR, `--set`
values, presets, budget), read back checked (`read_manifest`), and the rule under which a run resumes a folder
(`check_manifest`: a re-run must ask for the settings the folder's cells were made under)."""

from __future__ import annotations

from pathlib import Path

from strings_bench.core.errors import StringsBenchError
from strings_bench.core.io import atomic_write_json, jsonable
from strings_bench.core.results import RUN_FILE
from strings_bench.store.cells import read_json
from strings_bench.store.schema import upgrade_names

_NUMBER = (int, float)


def read_manifest(run_dir: str | Path) -> dict | None:
    """RUN_DIR/run.json, checked for the fields a resumed run and the report read; None when there is
    none. A malformed file is a StringsBenchError naming it."""
    p = Path(run_dir) / RUN_FILE
    if not p.exists():
        return None
    m = read_json(p, "run settings")

    def need(cond: bool, what: str) -> None:
        if not cond:
            raise StringsBenchError(f"run settings {p} are malformed: {what}",
                                    hint="restore it from a backup, or use another --out folder (the cells are kept)")
    need(isinstance(m, dict), f"a JSON {type(m).__name__}, not an object")
    m = upgrade_names(m)  # an older folder names the schedule "preset"
    need(isinstance(m.get("schedule"), dict) and isinstance(m["schedule"].get("name"), str),
         "'schedule' is missing or not an object with a name")
    need(isinstance(m.get("methods"), dict) and all(isinstance(v, dict) for v in m["methods"].values()),
         "'methods' is missing or not an object of objects")
    need(isinstance(m.get("datasets"), list), "'datasets' is missing or not a list")
    need(m.get("method_overrides") is None or isinstance(m["method_overrides"], dict), "'method_overrides' is not an object")
    need(isinstance(m.get("ocr"), str), "'ocr' is missing or not a string")
    need(isinstance(m.get("downscale"), _NUMBER), "'downscale' is missing or not a number")
    return m


def write_manifest(run_dir: str | Path, manifest: dict) -> Path:
    """Write RUN_DIR/run.json (atomically)."""
    return atomic_write_json(Path(run_dir) / RUN_FILE, jsonable(manifest))


def _as_list(x):
    return list(x) if isinstance(x, (list, tuple)) else x


def _fmt_schedule(x) -> str:
    if x is None:
        return "(not recorded)"
    return ",".join(str(c) for c in x) if isinstance(x, (list, tuple)) else f"{x:g}"


def check_manifest(run_dir: Path, manifest: dict) -> dict:
    """Refuse to mix results made under other settings in one folder; merge method/dataset lists."""
    old = read_manifest(run_dir)
    if old is None:
        return manifest
    for k in ("downscale", "ocr"):
        if old.get(k) != manifest.get(k):
            what = "--ocr engine list" if k == "ocr" else k
            raise StringsBenchError(
                f"{run_dir} holds results made with {what} {old.get(k)!r}; this run asks for {manifest.get(k)!r}",
                hint="use another --out folder, or the same settings to resume"
                     + (" (every cell is scored by every engine of the list, the first being the primary)" if k == "ocr" else ""))
    # Folders made before the profile was recorded were scored with the rules now named "robust".
    old_profile = old.get("cer_profile", "robust")
    if old_profile != manifest.get("cer_profile", "paper"):
        raise StringsBenchError(
            f"{run_dir} holds CER scored with profile {old_profile!r}"
            + ("" if "cer_profile" in old else " (made before --cer-profile existed: the rules now named robust)")
            + f"; this run asks for {manifest.get('cer_profile', 'paper')!r}",
            hint="use another --out folder, or the same --cer-profile to resume")
    if old["schedule"].get("name") != manifest["schedule"]["name"]:
        raise StringsBenchError(
            f"{run_dir} holds results of schedule {old['schedule'].get('name')!r}; this run asks for {manifest['schedule']['name']!r}",
            hint="use another --out folder (e.g. --out runs/paper), or the same --schedule to resume")
    # The miniature: folders made before miniatures existed shrank the schedule ("shrink").
    was, now = old["schedule"].get("miniature", "shrink"), manifest["schedule"].get("miniature", "shrink")
    if was != now:
        raise StringsBenchError(f"{run_dir} holds results made with --miniature {was}; this run asks for {now}",
                                hint="use another --out folder, or the same --miniature to resume")
    # The schedule: compared in effect (so `--steps-scale 0.01` resumes a quick folder) whenever either
    # run gave the option; folders made without it keep resuming as before.
    for k, field_name, option in (("steps_scale", "steps_scale", "--steps-scale"),
                                  ("checkpoints", "paper_checkpoints", "--checkpoints"),
                                  ("dense_every", "dense_every", "--checkpoints every:N")):
        if old.get(k) is None and manifest.get(k) is None:
            continue
        was = old["schedule"].get(field_name)
        now = manifest["schedule"].get(field_name)
        if _as_list(was) != _as_list(now):
            raise StringsBenchError(
                f"{run_dir} holds results made with {option} {_fmt_schedule(was)}; this run asks for {_fmt_schedule(now)}",
                hint=f"use another --out folder, or the same {option} to resume")
    if manifest.get("dense_every") and old.get("dense_eval") not in (None, manifest.get("dense_eval")):
        raise StringsBenchError(f"{run_dir} holds dense checkpoints evaluated with --dense-eval {old.get('dense_eval')}; "
                                f"this run asks for {manifest.get('dense_eval')}",
                                hint="use another --out folder, or the same --dense-eval to resume")
    # Cells are keyed by method, scene and iteration only: a budgeted cell must never be taken for an unbudgeted
    # one (or one of another budget), so a folder holds one budget.
    if (old.get("budget"), old.get("budget_from")) != (manifest.get("budget"), manifest.get("budget_from")):
        def _b(m):
            b = m.get("budget")
            return ("no budget" if b is None else f"--budget {b}") + (
                f" --budget-from {m['budget_from']}" if m.get("budget_from") else "")
        raise StringsBenchError(f"{run_dir} holds results made with {_b(old)}; this run asks for {_b(manifest)}",
                                hint="use another --out folder for each budget (e.g. runs/NAME-budget-3dgs), or the "
                                     "same --budget to resume")
    # A finished cell is skipped on resume, so cells trained with other --set values must not be
    # taken for this run's (folders made before overrides were recorded carry no such entry).
    old_over = old.get("method_overrides")
    if old_over is not None:
        for m, given in manifest.get("method_overrides", {}).items():
            if m in old.get("methods", {}) and old_over.get(m, {}) != given:
                raise StringsBenchError(
                    f"{run_dir} holds {m} results made with settings {old_over.get(m, {})}; this run asks for {given}",
                    hint="use another --out folder, or the same --set values to resume")
    # Likewise the method presets chosen with --presets (folders made before them chose none).
    old_presets = old.get("method_presets") or {}
    for m, chosen in (manifest.get("method_presets") or {}).items():
        if m in old.get("methods", {}) and list(old_presets.get(m, [])) != list(chosen):
            raise StringsBenchError(
                f"{run_dir} holds {m} results made with presets {old_presets.get(m, [])}; this run asks for {chosen}",
                hint="use another --out folder, or the same --presets to resume")
    merged = dict(manifest)
    merged["method_presets"] = {**old_presets, **(manifest.get("method_presets") or {})}
    merged["methods"] = {**old.get("methods", {}), **manifest["methods"]}
    merged["method_overrides"] = {**(old_over or {}), **manifest.get("method_overrides", {})}
    merged["datasets"] = list(dict.fromkeys(list(old.get("datasets", [])) + list(manifest["datasets"])))
    return merged
