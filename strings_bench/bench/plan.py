"""Planning a run: its configuration (`RunConfig`), its jobs (one per method x scene) and its manifest.

`plan_run(config)` checks everything that can be checked before any scene is built or method trained:
method names, `--set` keys, `--presets` names, the OCR profile, the device name, then resolves the
scenes and makes one `Job` per (method, scene). The manifest becomes run.json; `check_manifest` refuses
to resume a folder made under other settings.

A method's settings, in the order they apply: the spec's defaults, its presets whose "@apply"
conditions match the scene (e.g. STRinGS' N_max per dataset), the presets chosen with `--presets`, the
schedule's steps scale, then `--set` values (methods/registry.py).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field, fields, replace
from pathlib import Path
from typing import Iterable

from strings_bench.bench.executors import Job
from strings_bench.core.io import jsonable
from strings_bench.core.schedules import DEFAULT_SCHEDULE, schedule
from strings_bench.core.errors import StringsBenchError
from strings_bench.core.results import CellKey

DEFAULT_RUN_DIR = Path("runs") / "default"
# Key of `method_overrides` whose settings apply to every method of a run (`--set KEY=VALUE`, no
# method named); a method's own entry wins over it, key by key.
ALL_METHODS = "*"
LPIPS_AT = ("last", "all")  # LPIPS at each job's last checkpoint (default) or at every checkpoint
# How the checkpoints that only `--checkpoints every:N` adds are evaluated: "words" (default: word-crop readability
# and PSNR/SSIM, no OCR of the renders; cheap) or "full" (OCR-CER and every metric, as the other checkpoints).
DENSE_EVAL = ("words", "full")


@dataclass
class RunConfig:
    """Everything a run is given; `strings-bench run`'s options, one field each (docs/running.md).

    methods: method names (`--methods`).
    datasets: registry ids or scene folders (`--datasets`); None: the schedule's default scenes.
    run_dir: the run folder; the same folder resumes.
    schedule: the run's schedule (core/schedules.py: paper, standard, early, quick, tiny).
    steps_scale, checkpoints: replace the schedule's scale / paper checkpoints.
    dense_every: also evaluate every that many paper iterations (`--checkpoints every:500`); dense_eval: how the
        checkpoints only it adds are evaluated: "words" (the word-crop metrics and PSNR/SSIM; no OCR of the renders,
        no LPIPS) or "full" (as every other checkpoint).
    downscale: image downscale (None: the schedule's).
    method_presets: method -> preset names chosen for it (`--presets strings=release`).
    method_overrides: method (or ALL_METHODS) -> settings (`--set`).
    ocr: OCR engine name(s), comma-separated; the first is the primary.
    ocr_backend: an OCR backend object used in place of the names (tests, benchmarks).
    budget: the equal Gaussian budget (`--budget`): None (none), a number N (every method is capped at N
        Gaussians), or a method name (e.g. "3dgs": that method trains first, uncapped, as the reference, and
        every other method is capped at the Gaussian count it reaches on the same scene at the job's last
        checkpoint; its cells may also be in the run folder already). Reaches each method as its
        `max_gaussians` setting (`parse_budget`).
    budget_from: with a method name as `budget`, another run folder that holds that method's cells (trained there
        uncapped), read in place of this run's own: e.g. a seed-1 run at the count 3DGS reached at seed 0, without
        training 3DGS again. The reference method is then not among this run's methods.
    """

    methods: list[str] = field(default_factory=list)
    datasets: list[str] | None = None
    run_dir: Path = DEFAULT_RUN_DIR
    schedule: str = DEFAULT_SCHEDULE
    steps_scale: float | None = None
    checkpoints: Iterable[int] | None = None
    dense_every: int | None = None
    dense_eval: str = "words"
    downscale: float | None = None
    method_presets: dict = field(default_factory=dict)
    method_overrides: dict = field(default_factory=dict)
    ocr: str = "rapidocr"
    ocr_backend: object = None
    cer_profile: str = "paper"
    device: str = "auto"
    save_every: str = "10"
    keep_models: bool = False
    executor: str = "local"
    executor_options: dict | None = None
    with_lpips: bool = True
    lpips_at: str = "last"
    progress: bool = True
    write_report: bool = True
    budget: int | str | None = None
    budget_from: Path | str | None = None

    @classmethod
    def of(cls, config: "RunConfig | list[str] | None" = None, datasets=None, **given) -> "RunConfig":
        """A RunConfig from a RunConfig, or from methods, datasets and fields as keywords (`preset` is the
        old word for `schedule`). An unknown keyword is an error naming the fields."""
        if "preset" in given:
            given["schedule"] = given.pop("preset")
        names = {f.name for f in fields(cls)}
        unknown = sorted(set(given) - names)
        if unknown:
            raise TypeError(f"unknown run setting(s) {', '.join(unknown)}; RunConfig fields: {', '.join(sorted(names))}")
        if isinstance(config, RunConfig):
            return replace(config, **given)
        base = cls(methods=list(config or []), datasets=datasets)
        return replace(base, **given)


@dataclass
class RunPlan:
    run_dir: Path
    jobs: list[Job]
    manifest: dict

    @property
    def cells(self) -> list[CellKey]:
        return [k for j in self.jobs for k in j.cells()]


BUDGET_SETTING = "max_gaussians"  # the strategy field a budget reaches every method as (engine/strategies/base.py)


def parse_budget(value) -> int | str | None:
    """`--budget`'s value: None/"" (no budget), a positive count (int, or a string of digits, "40k" = 40 000), or a
    method name (the reference method, e.g. "3dgs"). Anything else is a clear error."""
    if value is None or value == "":
        return None
    if isinstance(value, bool):
        raise StringsBenchError(f"--budget {value!r} is neither a number of Gaussians nor a method name")
    if isinstance(value, (int, float)):
        if int(value) != value or value < 1:
            raise StringsBenchError(f"--budget {value!r} is not a positive whole number of Gaussians",
                                    hint="e.g. --budget 40000, --budget 40k, or --budget 3dgs")
        return int(value)
    text = str(value).strip()
    digits, mult = (text[:-1], 1000) if text[-1:] in ("k", "K") else (text, 1)
    if digits.isdigit():
        return parse_budget(int(digits) * mult)
    try:
        float(digits)
        numeric = True
    except ValueError:
        numeric = False
    if numeric or not text or text.startswith("-"):
        raise StringsBenchError(f"--budget {value!r} is neither a number of Gaussians nor a method name",
                                hint="e.g. --budget 40000, --budget 40k, or --budget 3dgs")
    return text


def budget_reference(job: "Job") -> "CellKey":
    """The cell whose Gaussian count is the budget of `job` under `--budget METHOD`: METHOD's cell on the job's
    scene at the job's last checkpoint (in `budget_folder(job)`)."""
    return CellKey(str(job.budget), job.dataset, job.scene, max(job.checkpoints))


def budget_folder(job: "Job") -> Path:
    """The run folder that holds `job`'s budget reference: `--budget-from`'s, else the job's own."""
    return Path(job.budget_from or job.run_dir)


def check_budget_from(folder: Path, reference: str, schedule_now: dict, downscale: float) -> Path:
    """`--budget-from FOLDER` with `--budget METHOD`: FOLDER must be a run folder whose METHOD cells were trained
    uncapped, at this run's schedule and image scale (so a count at an iteration means the same model size).
    Returns the folder resolved."""
    from strings_bench.reports.results import read_manifest

    folder = Path(folder).expanduser().resolve()
    old = read_manifest(folder) if folder.is_dir() else None
    if old is None:
        raise StringsBenchError(f"--budget-from {folder}: not a run folder (no run.json)",
                                hint="give the --out folder of a finished run that trained the reference method")
    if not (folder / "cells" / reference).is_dir():
        raise StringsBenchError(f"--budget-from {folder} holds no {reference} cells",
                                hint=f"the folder must hold {reference}'s cells (--budget {reference})")
    if old.get("budget") not in (None, reference):
        raise StringsBenchError(f"--budget-from {folder}: its {reference} cells were capped (--budget "
                                f"{old.get('budget')}), so their counts are no reference",
                                hint="give a folder where the reference method trained uncapped")
    was = old.get("schedule") or {}
    for key, option in (("steps_scale", "--steps-scale"), ("name", "--schedule")):
        if was.get(key) != schedule_now.get(key):
            raise StringsBenchError(f"--budget-from {folder} was run with {option} {was.get(key)}; this run asks for "
                                    f"{schedule_now.get(key)}", hint="the reference must come from the same schedule")
    if old.get("downscale") is not None and float(old["downscale"]) != float(downscale):
        raise StringsBenchError(f"--budget-from {folder} was run at downscale {old['downscale']}; this run asks for "
                                f"{downscale}", hint="the reference must come from the same image scale")
    return folder


def plan_run(config: RunConfig | list[str] | None = None, datasets=None, **given) -> RunPlan:
    """Plan the jobs of a run: one per (method, scene), with its checkpoints and settings (see the module
    docstring). Takes a RunConfig, or methods, datasets and RunConfig fields as keywords."""
    from strings_bench.datasets.registry import resolve_scenes
    from strings_bench.engine.trainer import SaveEvery, check_device_name
    from strings_bench.eval.cer import get_profile
    from strings_bench.eval.ocr import parse_engines
    from strings_bench.methods.registry import get_method

    c = RunConfig.of(config, datasets, **given)
    methods = list(c.methods)
    if not methods:
        raise StringsBenchError("no methods given", hint="e.g. --methods strings,3dgs; see `strings-bench methods list`")
    p = schedule(c.schedule, c.steps_scale, c.checkpoints, c.dense_every)
    if c.dense_eval not in DENSE_EVAL:
        raise StringsBenchError(f"unknown --dense-eval {c.dense_eval!r}", hint=f"one of: {', '.join(DENSE_EVAL)}")
    datasets = list(c.datasets) if c.datasets else p.default_datasets()
    get_profile(c.cer_profile)  # fails early on an unknown name
    specs = {m: get_method(m) for m in methods}  # fails early on an unknown name
    ocr = c.ocr
    if isinstance(ocr, str):  # canonical names ("rapid,tess" = "rapidocr,tesseract"), so that resume compares like with like
        ocr = ",".join(parse_engines(ocr, strict=False))  # strict where the engines are built from the names (run, _get_ocr)
    check_device_name(c.device)
    SaveEvery.parse(c.save_every)
    ds = float(c.downscale if c.downscale is not None else p.downscale)
    run_dir = Path(c.run_dir)
    overrides = dict(c.method_overrides or {})
    unknown = sorted(k for k in set(overrides) - set(methods) if k != ALL_METHODS)
    if unknown:
        raise StringsBenchError(f"--set names method(s) {', '.join(unknown)} that this run does not train",
                                hint=f"methods of this run: {', '.join(methods)}")
    chosen_presets = {m: list(v) for m, v in (c.method_presets or {}).items()}
    unknown = sorted(set(chosen_presets) - set(methods))
    if unknown:
        raise StringsBenchError(f"--presets names method(s) {', '.join(unknown)} that this run does not train",
                                hint=f"methods of this run: {', '.join(methods)}")
    budget = parse_budget(c.budget)
    budget_from = None
    if c.budget_from is not None:
        if not isinstance(budget, str):
            raise StringsBenchError("--budget-from goes with --budget METHOD (the method whose cells it holds)",
                                    hint="e.g. --budget 3dgs --budget-from runs/seed0")
        if budget in methods:
            raise StringsBenchError(f"--budget {budget} --budget-from: {budget}'s cells come from that folder, so "
                                    f"{budget} is not trained in this run",
                                    hint=f"leave {budget} out of --methods, or drop --budget-from")
        budget_from = check_budget_from(Path(c.budget_from), budget, asdict(p), ds)
    elif isinstance(budget, str) and budget not in methods and not (Path(c.run_dir) / "cells" / budget).is_dir():
        from strings_bench.reports.results import read_manifest

        made_from = (read_manifest(Path(c.run_dir)) or {}).get("budget_from") if Path(c.run_dir).is_dir() else None
        raise StringsBenchError(f"--budget {budget} needs {budget} among the run's methods: it trains first, uncapped, "
                                f"and its Gaussian count on each scene is the others' budget",
                                hint=(f"{c.run_dir} was made with --budget-from {made_from}: give it again to resume"
                                      if made_from else f"add it: --methods {budget},{','.join(methods)}"))
    for_all = dict(overrides.get(ALL_METHODS, {}))
    if BUDGET_SETTING in for_all or any(BUDGET_SETTING in v for v in overrides.values()):
        raise StringsBenchError(f"{BUDGET_SETTING} is set with --budget, not --set",
                                hint="--budget N caps every method of the run at N Gaussians (docs/running.md)")
    if budget is not None:
        for m in methods:
            schema = specs[m].settings()
            if m != budget and schema is not None and BUDGET_SETTING not in {s.name for s in schema}:
                raise StringsBenchError(f"method {m} takes no Gaussian budget (it trains no Gaussians of its own)",
                                        hint="leave it out of a --budget run")
    taken: set[str] = set()
    planned = []
    given_settings: dict[str, dict] = {}  # each method's --set values, the all-methods ones included
    for m in methods:
        spec = specs[m]
        chosen = spec.check_presets(chosen_presets.get(m))
        # An all-methods setting goes to every method that has it (a method without a settings schema takes all).
        schema = spec.settings()
        mine = for_all if schema is None else {k: v for k, v in for_all.items() if k in {s.name for s in schema}}
        taken |= set(mine)
        given_settings[m] = {**mine, **overrides.get(m, {})}
        # The schedule's scale reaches every method that trains (a --set steps_scale for the method wins).
        m_over = spec.with_steps_scale(p.steps_scale, given_settings[m])
        if isinstance(budget, int):
            m_over[BUDGET_SETTING] = budget
        spec.check_keys(spec.resolve(chosen, **m_over))  # a typo in --set is refused before any scene is built
        planned.append((m, chosen, m_over))
    if set(for_all) - taken:
        raise StringsBenchError(f"no method of this run has the setting(s) {', '.join(sorted(set(for_all) - taken))}",
                                hint="see `strings-bench methods show METHOD` for each method's settings")
    refs = resolve_scenes(datasets)  # may generate the synthetic scenes: after every check above
    if not refs:
        raise StringsBenchError(f"no scenes found for {datasets}", hint="see `strings-bench datasets list`")
    jobs = []
    if isinstance(budget, str):  # the reference method's jobs first: the others' budgets are its counts
        planned.sort(key=lambda item: item[0] != budget)
    for m, chosen, m_over in planned:
        for ref in refs:
            # The presets the job gets: those that apply to the scene by themselves, then the chosen ones. Its
            # checkpoints follow from the settings alone: the method is built once, by the job (bench/runner.py).
            presets = tuple(specs[m].presets_for(ref.dataset, ref.scene)) + tuple(chosen)
            settings = specs[m].resolve(presets, **m_over)
            m_scale = float(settings.get("steps_scale", p.steps_scale))
            fixed = specs[m].fixed_checkpoints(settings)  # e.g. the ply adapter: the model's own iteration
            steps = fixed or p.checkpoints(m_scale)
            labels = {it: p.label_of(it, m_scale) for it in steps}
            dense = () if fixed or c.dense_eval == "full" else tuple(p.dense_checkpoints(m_scale))
            jobs.append(Job(str(run_dir), m, ref.dataset, ref.scene, str(ref.path), dict(ref.settings), tuple(steps),
                            labels, p.name, ds, ocr, m_over, c.cer_profile, c.device, str(c.save_every),
                            bool(c.keep_models), presets, dense,
                            budget if isinstance(budget, str) and m != budget else None,
                            None if budget_from is None else str(budget_from)))
    manifest = {
        "schedule": asdict(p), "downscale": ds, "ocr": ocr, "cer_profile": c.cer_profile,
        # --steps-scale / --checkpoints as given (None: the schedule's); `schedule` above holds the one in effect.
        "steps_scale": None if c.steps_scale is None else p.steps_scale,
        "checkpoints": None if c.checkpoints is None else list(p.paper_checkpoints),
        "dense_every": c.dense_every, "dense_eval": c.dense_eval if c.dense_every else None,
        "method_presets": {m: chosen for m, chosen, _ in planned},
        "method_overrides": {m: jsonable(given_settings[m]) for m in methods},
        "methods": {m: {"paper": specs[m].paper, "description": specs[m].description, "title": specs[m].title or m,
                        "group": specs[m].group,
                        **({"ablation_of": specs[m].ablation_of, "ablation_at": specs[m].ablation_at,
                            "ablation_effect": specs[m].ablation_effect} if specs[m].ablation_of else {})}
                    for m in methods},
        "datasets": datasets,
        "device": c.device,  # as asked; execute() adds where it resolved to on this machine
        # The equal Gaussian budget (--budget): a count, or the reference method's name; absent when none, so that
        # folders made without it keep resuming.
        **({"budget": budget} if budget is not None else {}),
        # --budget-from: the folder the reference's counts are read from; absent when they are this folder's own
        **({"budget_from": str(budget_from)} if budget_from is not None else {}),
    }
    return RunPlan(run_dir, jobs, manifest)


def _as_list(x):
    return list(x) if isinstance(x, (list, tuple)) else x


def _fmt_schedule(x) -> str:
    if x is None:
        return "(not recorded)"
    return ",".join(str(c) for c in x) if isinstance(x, (list, tuple)) else f"{x:g}"


def check_manifest(run_dir: Path, manifest: dict) -> dict:
    """Refuse to mix results made under other settings in one folder; merge method/dataset lists."""
    from strings_bench.reports.results import read_manifest

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
