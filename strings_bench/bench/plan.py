"""Planning a run: its configuration (`RunConfig`), its methods (`MethodPlan`), its jobs (one per method x scene)
and its record (`RunPlan.manifest`, written to run.json).

`plan_run(config)` parses, checks and resolves every value of a run once, before any scene is built or method
trained: method names, `--set` keys, `--presets` names, the OCR engines and profile, the device (resolved here
when jobs run in this process; a distributed executor's workers resolve their own), `--save-every`, the executor's
options, the equal Gaussian budget and the LPIPS checkpoints; then it resolves the scenes and makes
one frozen `Job` per (method, scene) holding the method's final settings. The runner and the trainer take a job
as it is. run.json is the plan's record, never read back as configuration: a resumed run compares it with its
new plan and refuses a mismatch (store/manifest.py, `check_manifest`).

A method's settings, in the order they apply: the spec's defaults, its presets whose "@apply" conditions match
the scene (e.g. STRinGS' N_max per dataset), the presets chosen with `--presets`, the schedule's steps scale
(`with_steps_scale`, where the method takes one), then `--set` values. The steps scale is a typed value of the
plan (`MethodPlan.steps_scale`, `Job.steps_scale`): the checkpoints are scaled by it, and the method is built with it.
"""

from __future__ import annotations

import logging
from dataclasses import asdict, dataclass, field, fields, replace
from pathlib import Path
from typing import Iterable

from strings_bench.core.progress import progress_bars
from strings_bench.bench.budget import Budget, refuse_set
from strings_bench.bench.executors import Job
from strings_bench.core.errors import StringsBenchError
from strings_bench.core.io import jsonable
from strings_bench.core.results import CellKey
from strings_bench.core.schedules import DEFAULT_SCHEDULE, Schedule, schedule

log = logging.getLogger(__name__)

DEFAULT_RUN_DIR = Path("runs") / "default"
# Key of `method_overrides` whose settings apply to every method of a run (`--set KEY=VALUE`, no
# method named); a method's own entry wins over it, key by key.
ALL_METHODS = "*"
LPIPS_AT = ("last", "all")  # LPIPS at each job's last checkpoint (default) or at every checkpoint
# How the checkpoints that only `--checkpoints every:N` adds are evaluated: "words" (default: word-crop readability
# and PSNR/SSIM, no OCR of the renders; cheap) or "full" (OCR-CER and every metric, as the other checkpoints).
DENSE_EVAL = ("words", "full")


@dataclass(frozen=True)
class RunConfig:
    """Everything a run is given; `strings-bench run`'s options, one field each (docs/guide/running.md).

    Attributes:
        methods: method names (`--methods`).
        datasets: registry ids or scene folders (`--datasets`); None: the schedule's default scenes.
        run_dir: the run folder; the same folder resumes.
        schedule: the run's schedule (`strings-bench run --help` lists them; core/schedules.py).
        steps_scale: replaces the schedule's scale (1.0 = the paper's 30K iterations).
        checkpoints: replace the schedule's paper checkpoints (paper iterations, e.g. (3000, 7000)).
        dense_every: also evaluate every that many paper iterations (`--checkpoints every:500`).
        miniature: how the shrunk schedule stands in for the paper's (core/schedules.py MINIATURES; None: the
            schedule's).
        dense_eval: how the checkpoints only `dense_every` adds are evaluated: "words" (the word-crop metrics and
            PSNR/SSIM; no OCR of the renders, no LPIPS) or "full" (as every other checkpoint).
        downscale: image downscale (None: the schedule's).
        method_presets: method -> preset names chosen for it (`--presets strings=release`).
        method_overrides: method (or ALL_METHODS, "*") -> settings (`--set`).
        ocr: OCR engine name(s), comma-separated; the first is the primary.
        ocr_backend: an `OCRBackend` object used in place of the names (an engine of your own).
        cer_profile: how text is normalised before CER (`--cer-profile`; "paper": the authors' protocol).
        device: "auto", "cpu", "cuda" or "cuda:N" (`--device`).
        save_every: how often the training state is saved (`--save-every`: minutes, or "Nsteps").
        keep_models: keep each checkpoint's model (PLY) in its cell (`--keep-models`).
        executor: "local" or "ray" (`--executor`), with `executor_options`.
        executor_options: the executor's options (with `--executor ray`: `--ray-address`, `--max-retries`,
            `--cpus-per-job`).
        with_lpips: compute LPIPS (`--no-lpips` turns it off).
        lpips_at: "last" (each job's last checkpoint) or "all".
        progress: show progress bars.
        write_report: write report/ at the end.
        budget: `--budget N|METHOD`, the equal Gaussian count of every method (bench/budget.py).
        budget_from: `--budget-from FOLDER`: the reference's counts from an earlier run folder.
    """

    methods: list[str] = field(default_factory=list)
    datasets: list[str] | None = None
    run_dir: Path = DEFAULT_RUN_DIR
    schedule: str = DEFAULT_SCHEDULE
    steps_scale: float | None = None
    checkpoints: Iterable[int] | None = None
    dense_every: int | None = None
    miniature: str | None = None
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


@dataclass(frozen=True, kw_only=True)
class MethodPlan:
    """One method of a run, as planned: its chosen presets, its `--set` values (with the miniature's settings it
    takes) and the steps scale it trains at."""

    name: str
    presets: tuple[str, ...]  # chosen with --presets (the scene's own presets are added per job)
    settings: dict  # its --set values, the all-methods ones it has included
    steps_scale: float  # the schedule's, or its --set steps_scale


@dataclass(frozen=True, kw_only=True)
class RunPlan:
    """A planned run: its folder, its jobs (the reference method's first), where they run and its record
    (run.json).

    device: the device its jobs train on, resolved on this machine when they run in this process (`in_process`);
        else the checked name each worker resolves ("auto", "cpu", "cuda").
    manifest: what run.json records (write-only: a resumed run compares it with the folder's).
    """

    run_dir: Path
    jobs: list[Job]
    manifest: dict
    device: str = "cpu"
    in_process: bool = True

    @property
    def cells(self) -> list[CellKey]:
        return [k for j in self.jobs for k in j.cells()]


def plan_run(config: RunConfig | list[str] | None = None, datasets=None, **given) -> RunPlan:
    """Plan the jobs of a run: one per (method, scene), with its checkpoints and settings (see the module
    docstring). Takes a RunConfig, or methods, datasets and RunConfig fields as keywords."""
    from strings_bench.datasets.registry import resolve_scenes
    from strings_bench.methods.registry import get_method

    c = RunConfig.of(config, datasets, **given)
    device, in_process = _resolve_device(c)
    if not c.methods:
        raise StringsBenchError("no methods given", hint="e.g. --methods strings,3dgs; see `strings-bench methods list`")
    p = schedule(c.schedule, c.steps_scale, c.checkpoints, c.dense_every, c.miniature)
    datasets = list(c.datasets) if c.datasets else p.default_datasets()
    ocr, save_every = _check_options(c)
    specs = {m: get_method(m) for m in c.methods}  # fails early on an unknown name
    _check_names(c)
    ds = float(c.downscale if c.downscale is not None else p.downscale)
    rule = Budget.parse(c.budget, c.budget_from)
    refuse_set(c.method_overrides or {})
    if rule is not None:
        rule = rule.check(list(c.methods), specs, Path(c.run_dir), asdict(p), ds)
    given_settings = _given_settings(c, specs)
    planned = [_method_plan(specs[m], c, p, given_settings[m]) for m in c.methods]
    if in_process and device == "cpu":  # the CPU kernels compile in a second process while the scenes are built
        from strings_bench.bench.warmup import start as start_kernel_warmup

        start_kernel_warmup(c.methods)
    with progress_bars(c.progress):  # a scene built on first use shows its bars only if the run shows its own
        refs = resolve_scenes(datasets)  # may generate the synthetic scenes: after every check above
    if not refs:
        raise StringsBenchError(f"no scenes found for {datasets}", hint="see `strings-bench datasets list`")
    if rule is not None:  # the reference method's jobs first: the others' counts are its
        planned.sort(key=lambda mp: not rule.is_reference(mp.name))
    jobs = [_job(c, p, mp, specs[mp.name], ref, ocr=_scene_ocr(ocr, ref), downscale=ds, rule=rule, device=device,
                 save_every=save_every) for mp in planned for ref in refs]
    manifest = {
        "schedule": asdict(p), "downscale": ds, "ocr": ocr, "cer_profile": c.cer_profile,
        # --steps-scale / --checkpoints as given (None: the schedule's); `schedule` above holds the one in effect.
        "steps_scale": None if c.steps_scale is None else p.steps_scale,
        "checkpoints": None if c.checkpoints is None else list(p.paper_checkpoints),
        "dense_every": c.dense_every, "dense_eval": c.dense_eval if c.dense_every else None,
        "method_presets": {mp.name: list(mp.presets) for mp in planned},
        "method_overrides": {m: jsonable(given_settings[m]) for m in c.methods},
        "methods": {m: _method_entry(specs[m]) for m in c.methods},
        "datasets": datasets,
        "device": c.device,  # as asked; execute() adds where it resolved to on this machine
        # absent without one, so that folders made before it existed keep resuming
        **(rule.manifest() if rule is not None else {}),
    }
    return RunPlan(run_dir=Path(c.run_dir), jobs=jobs, manifest=manifest, device=device, in_process=in_process)


def _resolve_device(c: RunConfig) -> tuple[str, bool]:
    """(the device jobs train on, whether they run in this process). In-process jobs' device is resolved here
    ('auto' -> 'cuda' or 'cpu'; a GPU torch cannot see is refused before any scene is built); a distributed
    executor's jobs get the checked name, which each worker resolves. The executor's options are checked too
    (Ray not installed, --device cuda:1 on Ray, an option it does not take)."""
    from strings_bench.bench.executors import executor_factory
    from strings_bench.engine.trainer import check_device_name, resolve_device

    factory = executor_factory(c.executor)
    if factory.in_process:
        device = resolve_device(c.device)
    else:
        check_device_name(c.device)
        device = "auto" if c.device in (None, "") else str(c.device)
    factory.check_options(device=c.device, **(c.executor_options or {}))
    return device, factory.in_process


def _check_names(c: RunConfig) -> None:
    """`--set` and `--presets` name only the run's methods."""
    methods = list(c.methods)
    unknown = sorted(k for k in set(c.method_overrides or {}) - set(methods) if k != ALL_METHODS)
    for option, names in (("--set", unknown), ("--presets", sorted(set(c.method_presets or {}) - set(methods)))):
        if names:
            raise StringsBenchError(f"{option} names method(s) {', '.join(names)} that this run does not train",
                                    hint=f"methods of this run: {', '.join(methods)}")


def _check_options(c: RunConfig) -> tuple[str, "SaveEvery"]:
    """Check the CER profile, `--dense-eval` and `--lpips-at`; returns the OCR engine list in canonical names
    ("rapid,tess" = "rapidocr,tesseract"), so that a resumed run compares like with like, and `--save-every` parsed."""
    from strings_bench.engine.trainer import SaveEvery
    from strings_bench.eval.cer import get_profile
    from strings_bench.eval.ocr import parse_engines

    get_profile(c.cer_profile)  # fails early on an unknown name
    if c.dense_eval not in DENSE_EVAL:
        raise StringsBenchError(f"unknown --dense-eval {c.dense_eval!r}", hint=f"one of: {', '.join(DENSE_EVAL)}")
    if c.lpips_at not in LPIPS_AT:
        raise StringsBenchError(f"unknown LPIPS policy {c.lpips_at!r}", hint=f"one of: {', '.join(LPIPS_AT)}")
    save_every = SaveEvery.parse(c.save_every)
    if not isinstance(c.ocr, str):
        return c.ocr, save_every
    # strict where the engines are built from the names; a backend object given in code may carry any name
    return ",".join(parse_engines(c.ocr, strict=c.ocr_backend is None)), save_every


def _given_settings(c: RunConfig, specs: dict) -> dict[str, dict]:
    """Each method's --set values: the all-methods ones it has (a method without a settings schema takes all),
    then its own. An all-methods setting that no method has is an error."""
    overrides = dict(c.method_overrides or {})
    for_all = dict(overrides.get(ALL_METHODS, {}))
    out, taken = {}, set()
    for m, spec in specs.items():
        schema = spec.settings()
        mine = for_all if schema is None else {k: v for k, v in for_all.items() if k in {s.name for s in schema}}
        taken |= set(mine)
        out[m] = {**mine, **overrides.get(m, {})}
    if set(for_all) - taken:
        raise StringsBenchError(f"no method of this run has the setting(s) {', '.join(sorted(set(for_all) - taken))}",
                                hint="see `strings-bench methods show METHOD` for each method's settings")
    return out


def _method_plan(spec, c: RunConfig, p: Schedule, given: dict) -> MethodPlan:
    """A method's plan, its --presets and --set keys checked (a typo is refused before any scene is built)."""
    chosen = tuple(spec.check_presets((c.method_presets or {}).get(spec.name)))
    scale = float(given.get("steps_scale", p.steps_scale))  # a --set steps_scale for the method wins
    if takes_steps_scale(spec):  # the miniature's settings it takes, at the method's scale; its --set values win
        schema = spec.settings()
        mini = replace(p, steps_scale=scale).miniature_settings()
        given = {**{k: v for k, v in mini.items() if schema is None or k in {s.name for s in schema}}, **given}
    spec.check_keys(spec.resolve(chosen, **with_steps_scale(spec, scale, given)))
    return MethodPlan(name=spec.name, presets=chosen, settings=given, steps_scale=scale)


def takes_steps_scale(spec) -> bool:
    """Whether the run's schedule scale reaches `spec`'s method as its `steps_scale` setting: every method whose
    implementation describes that setting (every Gaussian method: engine TrainConfig); an implementation that
    describes no settings takes it when the spec names it (defaults or a preset). Adapters (ply, external)
    train nothing and have no steps to scale."""
    schema = spec.settings()
    if schema is not None:
        return any(s.name == "steps_scale" for s in schema)
    return "steps_scale" in spec.defaults or any("steps_scale" in p for p in spec.presets.values())


def with_steps_scale(spec, steps_scale: float, overrides: dict | None = None) -> dict:
    """`overrides` (`--set` values) with the run's `steps_scale` added where `spec`'s method takes one
    (`takes_steps_scale`); a `steps_scale` in `overrides` wins. The one way a schedule reaches a method."""
    overrides = dict(overrides or {})
    if takes_steps_scale(spec):
        overrides.setdefault("steps_scale", float(steps_scale))
    return overrides


def method_settings(spec, presets, steps_scale: float, given: dict) -> dict:
    """A method's final settings: its spec's defaults, `presets` in order, the steps scale, then `given`."""
    return spec.resolve(presets, **with_steps_scale(spec, steps_scale, given))


_told_ocr: set = set()


def _scene_ocr(ocr, ref) -> tuple[str, ...]:
    """The OCR engines of one scene's jobs: the run's, led by the scene's own GT engine where it names one
    (eval.ocr.scene_engines); said once per scene. A backend object (tests) is used as given."""
    if not isinstance(ocr, str):
        return (ocr,)
    from strings_bench.eval.ocr import scene_engines

    engines, note = scene_engines(ocr, ref.settings)
    if note and (ref.dataset, ref.scene, ocr) not in _told_ocr:
        _told_ocr.add((ref.dataset, ref.scene, ocr))
        log.warning("%s/%s: %s", ref.dataset, ref.scene, note)
    return tuple(engines.split(","))


def _job(c: RunConfig, p: Schedule, mp: MethodPlan, spec, ref, *, ocr, downscale: float, rule,
         device: str, save_every) -> Job:
    """The job of one method on one scene. Its presets: those that apply to the scene by themselves, then the
    chosen ones; its settings final (with a Gaussian count given as a number); its checkpoints follow from its steps
    scale, or from the method (e.g. the ply adapter: the model's own iteration). The method is built once, by the job
    (bench/runner.py)."""
    presets = tuple(spec.presets_for(ref.dataset, ref.scene)) + mp.presets
    settings = method_settings(spec, presets, mp.steps_scale, mp.settings)
    fixed = spec.fixed_checkpoints(settings)
    steps = tuple(fixed or p.checkpoints(mp.steps_scale))
    dense = () if fixed or c.dense_eval == "full" else tuple(p.dense_checkpoints(mp.steps_scale))
    settings, count = (settings, None) if rule is None else rule.for_job(mp.name, settings)
    lpips = () if not c.with_lpips else steps if c.lpips_at == "all" else (max(steps),)
    return Job(run_dir=str(c.run_dir), method=mp.name, dataset=ref.dataset, scene=ref.scene, scene_path=str(ref.path),
               scene_settings=dict(ref.settings), checkpoints=steps,
               labels={it: p.label_of(it, mp.steps_scale) for it in steps}, schedule=p.name, downscale=downscale,
               ocr=ocr, steps_scale=mp.steps_scale, method_settings=dict(mp.settings), settings=settings,
               method_presets=presets,
               cer_profile=c.cer_profile, device=device, save_every=save_every, keep_models=bool(c.keep_models),
               dense_checkpoints=dense, lpips_checkpoints=tuple(lpips), budget=rule, budget_count=count)


def _method_entry(spec) -> dict:
    """run.json's record of a method: its citation, title, group and, for an ablation, what it ablates."""
    return {"paper": spec.paper, "description": spec.description, "title": spec.title or spec.name,
            "group": spec.group,
            **({"ablation_of": spec.ablation_of, "ablation_at": spec.ablation_at,
                "ablation_effect": spec.ablation_effect} if spec.ablation_of else {})}
