"""Run methods x scenes x checkpoints, evaluate every checkpoint, and keep the results resumable.

One *cell* is (method, dataset, scene, checkpoint iteration). A cell is finished when its
`result.json` exists; that file is written last and atomically, so a killed run loses at most the
cell in progress. Re-running the same command skips finished cells. A trained method's training
state is saved at every checkpoint and every `--save-every` (engine.trainer), so a (method, scene)
killed mid-training continues from its last saved state (`resumed_from_step` in result.json);
checkpoints already evaluated are passed over (never rewritten).

Run folder (see docs/running.md):

    RUN_DIR/
      run.json                          the run's settings (preset, steps scale, checkpoints, downscale, OCR,
                                        --set values); a re-run must match
      results.csv                       one row per cell, rebuilt after every cell
      cells/<method>/<dataset>/<scene>/<iteration>/
          result.json                   everything about the cell (config, timings, metrics, OCR words, CER)
          renders/<view stem>.png       the method's test-view renders
          model.ply                     the model at this checkpoint (--keep-models)
      state/<method>/<dataset>/<scene>/training_state.pt
                                        the resumable training state; removed when the (method, scene) is done
      gt/<dataset>/<scene>/<view stem>.png   ground-truth test views at the evaluated size
      report/                           tables, figures, index.html (strings_bench.reports.write_report)

Execution goes through an `Executor` (`submit(job)` / `map(jobs)`); `LocalExecutor` runs jobs one
after another in this process, `RayExecutor` (bench/ray_executor.py, `--executor ray`) runs each job
as a Ray task. A distributed executor only has to run `run_job(job)` somewhere that sees RUN_DIR (jobs
are plain data) — cells are independent files, and results.csv is rebuilt from them on the driver.
"""

from __future__ import annotations

import json
import logging
import math
import numbers
import platform
import time
from concurrent.futures import FIRST_COMPLETED, Future, wait
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any, Callable, Iterable, Iterator, Protocol

import numpy as np
from PIL import Image

from strings_bench import __version__
from strings_bench.core.errors import StringsBenchError
from strings_bench.bench.ray_executor import RayExecutor
from strings_bench.reports.results import iteration_label, write_results_csv
from strings_bench.core.io import atomic_write, atomic_write_json
from strings_bench.core.method import Method
from strings_bench.core.results import RESULT_FILE, RUN_FILE, CellKey, is_finished, safe_name
from strings_bench.core.schedules import SCHEDULE_SCALES
from strings_bench.eval.protocol import Evaluator, to_uint8

log = logging.getLogger(__name__)

LPIPS_AT = ("last", "all")  # LPIPS at each job's last checkpoint (default) or at every checkpoint
DEFAULT_RUN_DIR = Path("runs") / "default"
# Key of `method_overrides` whose settings apply to every method of a run (`--set KEY=VALUE`, no
# method named); a method's own entry wins over it, key by key.
ALL_METHODS = "*"

# Schedules. Checkpoints are named by the paper iteration they stand for; the iteration actually
# trained is round(paper_iteration * steps_scale). DEFAULT_PRESET is the default of `strings-bench run`.
# 3K is the end of STRinGS' phase 1 (the position-LR ablation of the paper is read there).
PAPER_CHECKPOINTS = (3000, 7000, 30000)
DEFAULT_DATASETS = ("synthetic",)
DEFAULT_PRESET = "early"


@dataclass(frozen=True)
class Preset:
    name: str
    steps_scale: float
    paper_checkpoints: tuple[int, ...] = PAPER_CHECKPOINTS
    downscale: float = 1
    description: str = ""
    # the scenes a run of this preset uses when no --datasets is given (None: every synthetic scene)
    datasets: tuple[str, ...] | None = None

    def default_datasets(self) -> list[str]:
        """The --datasets of a run of this preset that names none."""
        return list(self.datasets or DEFAULT_DATASETS)

    def checkpoints(self, steps_scale: float | None = None) -> list[int]:
        s = self.steps_scale if steps_scale is None else steps_scale
        return sorted({max(1, int(round(c * s))) for c in self.paper_checkpoints})

    def label_of(self, iteration: int, steps_scale: float | None = None) -> str:
        s = self.steps_scale if steps_scale is None else steps_scale
        for c in self.paper_checkpoints:
            if max(1, int(round(c * s))) == iteration:
                return iteration_label(c)
        return iteration_label(iteration)


PRESETS: dict[str, Preset] = {
    "paper": Preset("paper", SCHEDULE_SCALES["paper"],
                    description="the paper's schedule: 30K iterations, checkpoints 3K/7K/30K"),
    # standard and quick leave out 3K: OCR of every test view costs ~1 s per view and cell on a CPU.
    "standard": Preset("standard", SCHEDULE_SCALES["standard"], paper_checkpoints=(7000, 30000),
                       description="the paper's schedule scaled by 0.05 (350/1500 iterations for 7K/30K)"),
    # The default run: one scene, the paper's early checkpoints, long enough to read (docs/ocr.md).
    "early": Preset("early", SCHEDULE_SCALES["early"], paper_checkpoints=(3000, 7000),
                    datasets=("synthetic/extinguisher",),
                    description="the default: the paper's schedule scaled by 0.15 (450/1050 iterations for 3K/7K) "
                                "on synthetic/extinguisher, ~10 min on 2 CPU cores; text becomes legible"),
    "quick": Preset("quick", SCHEDULE_SCALES["quick"], paper_checkpoints=(7000, 30000),
                    description="the paper's schedule scaled by 0.01 (70/300 iterations for 7K/30K) on the five "
                                "synthetic scenes, ~10 min on 2 CPU cores; text stays illegible (CER ~1.0)"),
    "tiny": Preset("tiny", SCHEDULE_SCALES["tiny"], description="smoke test: scaled by 0.005 (35/150 iterations for 7K/30K)"),
}


def get_preset(name: str) -> Preset:
    if name not in PRESETS:
        raise StringsBenchError(f"unknown preset {name!r}", hint=f"presets: {', '.join(PRESETS)}")
    return PRESETS[name]


def schedule(preset: str, steps_scale: float | None = None, checkpoints: Iterable[int] | None = None) -> Preset:
    """The run's schedule: preset `preset` with `run --steps-scale` and `--checkpoints` applied.

    steps_scale replaces the preset's scale (every method is then scaled by it); checkpoints are
    paper iterations (e.g. (3000, 7000)), each trained as round(iteration x steps_scale). The name
    stays the preset's: methods still take their own preset of that name, with the scale replaced.
    """
    p = get_preset(preset)
    if steps_scale is not None:
        if not (isinstance(steps_scale, (int, float)) and math.isfinite(steps_scale) and steps_scale > 0):
            raise StringsBenchError(f"steps scale must be a number > 0, got {steps_scale!r}",
                                    hint="e.g. --steps-scale 0.2 (7K = 1400 steps); 1 is the paper's schedule")
        p = replace(p, steps_scale=float(steps_scale), description=f"{p.description} [--steps-scale {steps_scale:g}]")
    if checkpoints is not None:
        given = list(checkpoints)
        if not given or not all(isinstance(c, numbers.Integral) and not isinstance(c, bool) and c >= 1 for c in given):
            raise StringsBenchError(f"checkpoints must be paper iterations (integers >= 1), got {given!r}",
                                    hint="e.g. --checkpoints 3000,7000")
        its = tuple(sorted({int(c) for c in given}))
        p = replace(p, paper_checkpoints=its, description=f"{p.description} [--checkpoints {','.join(map(str, its))}]")
    return p


# ---- jobs and executors ---------------------------------------------------------------------
@dataclass(frozen=True)
class Job:
    """Train one method on one scene and evaluate its checkpoints. Plain data: it can travel."""

    run_dir: str
    method: str
    dataset: str
    scene: str
    scene_path: str
    scene_settings: dict
    checkpoints: tuple[int, ...]
    labels: dict  # iteration -> paper label
    preset: str
    downscale: float
    ocr: str
    method_overrides: dict = field(default_factory=dict)
    cer_profile: str = "paper"  # strings_bench.eval.cer.PROFILES; the authors' rules by default
    device: str = "auto"  # resolved where the job runs (engine.trainer.resolve_device)
    save_every: str = "10"  # minutes, "<N>steps" or "off" (engine.trainer.SaveEvery.parse)
    keep_models: bool = False  # write each cell's model.ply

    def state_path(self) -> Path:
        """The resumable training state of this (method, scene)."""
        return (Path(self.run_dir) / "state" / safe_name(self.method) / safe_name(self.dataset) / safe_name(self.scene)
                / "training_state.pt")

    def cells(self) -> list[CellKey]:
        return [CellKey(self.method, self.dataset, self.scene, it) for it in self.checkpoints]


class Executor(Protocol):
    """Where jobs run. `submit` returns a Future of `run_job(job)`'s return value.

    Optional members `execute` uses when an executor has them: `in_process` (False: jobs run in other
    processes, so the driver follows progress from the run folder and rebuilds results.csv itself),
    `start(run_dir, jobs)` (before the first submit: connect, check that workers see the run folder),
    `cancel()` (on Ctrl-C: stop every job still running) and `close()` (after the run).
    """

    def submit(self, job: Job) -> Future: ...

    def map(self, jobs: Iterable[Job]) -> list[Any]: ...


class LocalExecutor:
    """Runs each job in this process, one after another (the default)."""

    in_process = True

    def __init__(self, runner: Callable[[Job], Any]):
        self.runner = runner

    def submit(self, job: Job) -> Future:
        fut: Future = Future()
        try:
            fut.set_result(self.runner(job))
        except (KeyboardInterrupt, SystemExit):
            raise
        except BaseException as exc:  # noqa: BLE001 - handed to the caller through the future
            fut.set_exception(exc)
        return fut

    def map(self, jobs: Iterable[Job]) -> list[Any]:
        return [self.submit(j).result() for j in jobs]


# name -> factory(runner, **options); the Ray executor imports ray only when it is built.
EXECUTORS: dict[str, Callable[..., Executor]] = {"local": LocalExecutor, "ray": RayExecutor}


def executor_factory(name: str) -> Callable[..., Executor]:
    """The factory registered under `name` in EXECUTORS; a clear error for an unknown name."""
    if name not in EXECUTORS:
        raise StringsBenchError(f"unknown executor {name!r}", hint=f"executors: {', '.join(EXECUTORS)}")
    return EXECUTORS[name]


def get_executor(name: str, runner: Callable[[Job], Any], **options) -> Executor:
    """The executor `name` running jobs with `runner`; `options` go to its factory (e.g. the Ray
    executor's `address`, `max_retries`)."""
    return executor_factory(name)(runner, **options)


# ---- helpers ----------------------------------------------------------------------------------
def _write_png(path: Path, img: np.ndarray) -> None:
    """`img` as the 8-bit PNG the evaluation scores (eval.protocol.to_uint8), written atomically."""
    def write(tmp: Path) -> None:
        Image.fromarray(to_uint8(img)).save(tmp, format="PNG")

    atomic_write(path, write)


def write_gt_pngs(run_dir: Path, dataset: str, scene_name: str, evaluator: Evaluator) -> None:
    """RUN_DIR/gt/<dataset>/<scene>/<view stem>.png: the ground truth as scored, for the report's crops."""
    folder = Path(run_dir) / "gt" / safe_name(dataset) / safe_name(scene_name)
    for name in evaluator.names:
        path = folder / f"{Path(name).stem}.png"
        if not path.exists():
            _write_png(path, evaluator.gt(name))


def _nan_to_none(x):
    if isinstance(x, float) and (math.isnan(x) or math.isinf(x)):
        return None if math.isnan(x) else ("inf" if x > 0 else "-inf")
    return x


def _jsonable(obj):
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return _jsonable(obj.tolist())
    if isinstance(obj, (np.floating,)):
        return _nan_to_none(float(obj))
    if isinstance(obj, (np.integer,)):
        return int(obj)
    if isinstance(obj, float):
        return _nan_to_none(obj)
    return obj


def versions() -> dict:
    import torch

    out = {"strings_bench": __version__, "python": platform.python_version(), "numpy": np.__version__,
           "torch": torch.__version__, "platform": platform.platform()}
    try:
        from importlib.metadata import version

        out["rapidocr"] = version("rapidocr")
    except Exception:  # noqa: BLE001 - optional
        pass
    return out


def device_info(device: str) -> dict:
    """The device a job ran on, as recorded in result.json and run.json: {"device", "gpu"} (the GPU's
    name from torch.cuda.get_device_name on CUDA, else None)."""
    import torch

    gpu = None
    if str(device).startswith("cuda") and torch.cuda.is_available():
        gpu = torch.cuda.get_device_name(torch.device(device))
    return {"device": str(device), "gpu": gpu}


# ---- running ------------------------------------------------------------------------------------
def _build_method(job: Job):
    from strings_bench.methods.registry import get_method

    spec = get_method(job.method)
    preset = job.preset if job.preset in spec.presets else None
    return spec.build(preset=preset, **job.method_overrides)


def _load_scene(job: Job):
    from strings_bench.scene.scene import Scene

    return Scene.load(job.scene_path, name=job.scene, settings=job.scene_settings)


def _get_ocr(name_or_backend) -> list:
    """The OCR engines of a job: from `--ocr` ("rapidocr" or "rapidocr,tesseract"), a backend object
    (tests), or a list of either; the first is the primary."""
    from strings_bench.eval.ocr import get_backend, parse_engines

    if isinstance(name_or_backend, str):
        return [get_backend(n) for n in parse_engines(name_or_backend)]
    if isinstance(name_or_backend, (list, tuple)):
        return [x for item in name_or_backend for x in _get_ocr(item)]
    return [name_or_backend]


class Runner:
    """Runs jobs and writes cells. `ocr` may be a backend name or a backend object (tests).

    `results_csv`: rebuild results.csv after every cell (in-process runs); a worker of a distributed
    executor leaves it to the driver.
    """

    def __init__(self, run_dir: str | Path, ocr="rapidocr", with_lpips: bool = True, progress: bool = True,
                 on_cell: Callable[[CellKey], None] | None = None, lpips_at: str = "last", results_csv: bool = True):
        self.run_dir = Path(run_dir)
        self.results_csv = results_csv
        self.ocr = ocr
        self.with_lpips = with_lpips
        if lpips_at not in LPIPS_AT:
            raise StringsBenchError(f"unknown LPIPS policy {lpips_at!r}", hint=f"one of: {', '.join(LPIPS_AT)}")
        self.lpips_at = lpips_at
        self.progress = progress
        self.on_cell = on_cell

    def __call__(self, job: Job) -> list[CellKey]:
        return self.run_job(job)

    def run_job(self, job: Job) -> list[CellKey]:
        run_dir = Path(job.run_dir)
        todo = [k for k in job.cells() if not is_finished(run_dir, k)]
        if not todo:
            job.state_path().unlink(missing_ok=True)  # left by a run killed after its last cell was written
            return []
        scene = _load_scene(job)
        adapter = _build_method(job)
        adapter.progress = self.progress is not False  # --no-progress reaches the training and mask bars
        ocr = _get_ocr(self.ocr)
        from strings_bench.engine.trainer import resolve_device

        device = resolve_device(job.device)  # checked here, where the job runs
        evaluator = Evaluator.for_scene(scene, ocr, job.downscale, with_lpips=self.with_lpips,
                                        cer_profile=job.cer_profile, device=device)
        write_gt_pngs(run_dir, job.dataset, job.scene, evaluator)
        wanted = set(job.checkpoints)
        written: list[CellKey] = []
        seen: set[int] = set()
        describe = _jsonable(adapter.describe())
        for result in self._checkpoints(job, adapter, scene, describe):
            if result.iteration not in wanted:
                log.debug("%s yielded unrequested checkpoint %d; ignored", job.method, result.iteration)
                continue
            seen.add(result.iteration)
            key = CellKey(job.method, job.dataset, job.scene, result.iteration)
            if is_finished(run_dir, key):
                continue  # evaluated in an earlier run; training had to pass through it again
            self._write_cell(job, key, result, evaluator, describe, scene)
            written.append(key)
            if self.on_cell:
                self.on_cell(key)
            if all(is_finished(run_dir, k) for k in job.cells()):
                break
        missing = sorted(k.iteration for k in job.cells() if not is_finished(run_dir, k))
        if missing:
            raise StringsBenchError(f"method {job.method} stopped without checkpoint(s) {missing} on {job.dataset}/{job.scene}",
                                    hint="the adapter's train() must yield one CheckpointResult per requested iteration")
        if all(is_finished(run_dir, k) for k in job.cells()):
            job.state_path().unlink(missing_ok=True)  # every cell is written: the state is no longer needed
        return written

    def _checkpoints(self, job: Job, adapter, scene, describe: dict) -> Iterator:
        """The method's checkpoints: trained by the framework's loop for a `Method` (resumable), or
        yielded by an adapter for models trained elsewhere."""
        if not isinstance(adapter, Method):
            return adapter.train(scene, list(job.checkpoints), job.downscale)
        from strings_bench.engine.trainer import SaveEvery, Trainer

        def model_path(step: int) -> Path:
            return CellKey(job.method, job.dataset, job.scene, step).path(Path(job.run_dir)) / "model.ply"

        fingerprint = {"settings": json.loads(json.dumps(describe.get("settings", {}), sort_keys=True, default=str)),
                       "scene_path": job.scene_path, "dataset": job.dataset}
        return Trainer(adapter, scene, job.checkpoints, downscale=job.downscale, device=job.device,
                       progress=self.progress is not False, state_path=job.state_path(),
                       save_every=SaveEvery.parse(job.save_every), model_path=model_path if job.keep_models else None,
                       fingerprint=fingerprint).train()

    def _write_cell(self, job: Job, key: CellKey, result, evaluator: Evaluator, describe: dict, scene) -> None:
        t0 = time.perf_counter()
        # LPIPS (a VGG16 pass per view, seconds on a CPU) at the last checkpoint only unless asked:
        # the paper reports it at 30K.
        lpips_here = self.with_lpips and (self.lpips_at == "all" or key.iteration == max(job.checkpoints))
        ev = evaluator.evaluate(job.method, result.renders, with_lpips=lpips_here)
        cell_dir = key.path(Path(job.run_dir))  # the job's folder: absolute when it runs on a Ray worker
        for name, img in result.renders.items():
            if name in evaluator.names:
                _write_png(cell_dir / "renders" / f"{Path(name).stem}.png", img)
        record = {
            "method": job.method,
            "dataset": job.dataset,
            "scene": job.scene,
            "iteration": key.iteration,
            "label": job.labels.get(key.iteration, job.labels.get(str(key.iteration), iteration_label(key.iteration))),
            "config": {
                "method": describe,
                "scene": {"path": job.scene_path, "settings": job.scene_settings, "test_views": evaluator.names},
                "preset": job.preset,
                "downscale": job.downscale,
                "cer_profile": job.cer_profile,
                "checkpoints": list(job.checkpoints),
                "versions": versions(),
                "metrics": _metrics_describe(),
            },
            "resumed_from_step": int(getattr(result, "resumed_from_step", 0)),
            "device": result.extra.get("device", ""),  # as resolved by the training loop ("" for adapters)
            "gpu": device_info(result.extra["device"])["gpu"] if result.extra.get("device") else None,
            "timings": {"train_seconds": result.train_seconds,
                        "preprocess_seconds": _preprocess_seconds(result),
                        "total_seconds": result.train_seconds + _preprocess_seconds(result),
                        "eval_seconds": time.perf_counter() - t0},
            "gaussians": int(result.gaussians),
            "peak_memory_mb": result.peak_memory_mb,
            "extra": result.extra,
            **ev,
        }
        atomic_write_json(cell_dir / RESULT_FILE, _jsonable(record))
        if self.results_csv:
            write_results_csv(job.run_dir)


def _preprocess_seconds(result) -> float:
    value = getattr(result, "preprocess_seconds", 0.0)  # adapters written before the field: none
    return 0.0 if value is None else float(value)


def _metrics_describe() -> dict:
    import strings_bench.eval.metrics as metrics

    return metrics.describe()


# ---- the whole run ---------------------------------------------------------------------------------
@dataclass
class RunPlan:
    run_dir: Path
    jobs: list[Job]
    manifest: dict

    @property
    def cells(self) -> list[CellKey]:
        return [k for j in self.jobs for k in j.cells()]


def plan_run(methods: list[str], datasets: list[str] | None, run_dir: str | Path = DEFAULT_RUN_DIR,
             preset: str = DEFAULT_PRESET,
             ocr: str = "rapidocr", downscale: float | None = None, method_overrides: dict | None = None,
             cer_profile: str = "paper", steps_scale: float | None = None,
             checkpoints: Iterable[int] | None = None, device: str = "auto", save_every: str = "10",
             keep_models: bool = False) -> RunPlan:
    """Plan the jobs of a run: one per (method, scene), with its checkpoints and settings.

    method_overrides maps a method name, or ALL_METHODS for every method, to settings over its
    preset. steps_scale / checkpoints (paper iterations) replace the preset's schedule (see `schedule`).
    Methods and their settings are checked before any scene is built or generated: an unknown
    method or `--set` key fails at once, naming the valid ones. datasets None (or empty): the
    preset's default scenes (Preset.default_datasets).
    """
    from strings_bench.engine.trainer import SaveEvery, check_device_name
    from strings_bench.eval.cer import get_profile
    from strings_bench.datasets.registry import resolve_scenes
    from strings_bench.methods.registry import get_method

    if not methods:
        raise StringsBenchError("no methods given", hint="e.g. --methods strings,3dgs; see `strings-bench methods list`")
    p = schedule(preset, steps_scale, checkpoints)
    if not datasets:
        datasets = p.default_datasets()
    get_profile(cer_profile)  # fails early on an unknown name
    specs = {m: get_method(m) for m in methods}  # fails early on an unknown name
    from strings_bench.eval.ocr import parse_engines

    if isinstance(ocr, str):  # canonical names ("rapid,tess" = "rapidocr,tesseract"), so that resume compares like with like
        ocr = ",".join(parse_engines(ocr, strict=False))  # strict where the engines are built from the names (run, _get_ocr)
    check_device_name(device)
    SaveEvery.parse(save_every)
    ds = float(downscale if downscale is not None else p.downscale)
    run_dir = Path(run_dir)
    overrides = dict(method_overrides or {})
    unknown = sorted(k for k in set(overrides) - set(methods) if k != ALL_METHODS)
    if unknown:
        raise StringsBenchError(f"--set names method(s) {', '.join(unknown)} that this run does not train",
                                hint=f"methods of this run: {', '.join(methods)}")
    for_all = dict(overrides.get(ALL_METHODS, {}))
    taken: set[str] = set()
    planned = []
    given: dict[str, dict] = {}  # each method's --set values, the all-methods ones included
    for m in methods:
        spec = specs[m]
        # An all-methods setting goes to every method that has it (a method without a settings schema takes all).
        schema = spec.settings()
        mine = for_all if schema is None else {k: v for k, v in for_all.items() if k in {s.name for s in schema}}
        taken |= set(mine)
        m_over = {**mine, **overrides.get(m, {})}
        given[m] = dict(m_over)
        if "steps_scale" in spec.defaults and "steps_scale" not in m_over and (
                steps_scale is not None or preset not in spec.presets):
            # --steps-scale replaces the scale of the method's preset; a method without that preset is
            # scaled like the run. A --set steps_scale given for the method wins.
            m_over["steps_scale"] = p.steps_scale
        adapter = spec.build(preset=preset if preset in spec.presets else None, **m_over)
        # A method may carry its own schedule scale (its preset), else the run preset's applies.
        m_scale = float(adapter.settings.get("steps_scale", p.steps_scale))
        steps = p.checkpoints(m_scale)
        fixed = getattr(adapter, "fixed_checkpoints", None)
        if callable(fixed) and fixed():
            steps = sorted(int(c) for c in fixed())  # e.g. the ply adapter: the model's own iteration
        labels = {c: p.label_of(c, m_scale) for c in steps}
        planned.append((m, m_over, steps, labels))
    if set(for_all) - taken:
        raise StringsBenchError(f"no method of this run has the setting(s) {', '.join(sorted(set(for_all) - taken))}",
                                hint="see `strings-bench methods show METHOD` for each method's settings")
    refs = resolve_scenes(datasets)  # may generate the synthetic scenes: after every check above
    if not refs:
        raise StringsBenchError(f"no scenes found for {datasets}", hint="see `strings-bench datasets list`")
    jobs = [Job(str(run_dir), m, ref.dataset, ref.scene, str(ref.path), dict(ref.settings), tuple(steps), labels,
                preset, ds, ocr, m_over, cer_profile, device, str(save_every), bool(keep_models))
            for m, m_over, steps, labels in planned for ref in refs]
    manifest = {
        "preset": asdict(p), "downscale": ds, "ocr": ocr, "cer_profile": cer_profile,
        # --steps-scale / --checkpoints as given (None: the preset's); `preset` above holds the schedule in effect.
        "steps_scale": None if steps_scale is None else p.steps_scale,
        "checkpoints": None if checkpoints is None else list(p.paper_checkpoints),
        "method_overrides": {m: _jsonable(given[m]) for m in methods},
        "methods": {m: {"paper": specs[m].paper, "description": specs[m].description} for m in methods},
        "datasets": datasets,
        "device": device,  # as asked; execute() adds where it resolved to on this machine
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
    if (old.get("preset") or {}).get("name") != manifest["preset"]["name"]:
        raise StringsBenchError(
            f"{run_dir} holds results of preset {(old.get('preset') or {}).get('name')!r}; this run asks for {manifest['preset']['name']!r}",
            hint="use another --out folder (e.g. --out runs/paper), or the same preset to resume")
    # The schedule: compared in effect (so `--steps-scale 0.01` resumes a quick folder) whenever either
    # run gave the option; folders made without it keep resuming as before.
    for k, field_name, option in (("steps_scale", "steps_scale", "--steps-scale"),
                                  ("checkpoints", "paper_checkpoints", "--checkpoints")):
        if old.get(k) is None and manifest.get(k) is None:
            continue
        was = (old.get("preset") or {}).get(field_name)
        now = manifest["preset"].get(field_name)
        if _as_list(was) != _as_list(now):
            raise StringsBenchError(
                f"{run_dir} holds results made with {option} {_fmt_schedule(was)}; this run asks for {_fmt_schedule(now)}",
                hint=f"use another --out folder, or the same {option} to resume")
    # A finished cell is skipped on resume, so cells trained with other --set values must not be
    # taken for this run's (folders made before overrides were recorded carry no such entry).
    old_over = old.get("method_overrides")
    if old_over is not None:
        for m, given in manifest.get("method_overrides", {}).items():
            if m in old.get("methods", {}) and old_over.get(m, {}) != given:
                raise StringsBenchError(
                    f"{run_dir} holds {m} results made with settings {old_over.get(m, {})}; this run asks for {given}",
                    hint="use another --out folder, or the same --set values to resume")
    merged = dict(manifest)
    merged["methods"] = {**old.get("methods", {}), **manifest["methods"]}
    merged["method_overrides"] = {**(old_over or {}), **manifest.get("method_overrides", {})}
    merged["datasets"] = list(dict.fromkeys(list(old.get("datasets", [])) + list(manifest["datasets"])))
    return merged


POLL_SECONDS = 2.0  # how often the driver looks at the run folder while jobs run elsewhere


def execute(plan: RunPlan, ocr=None, executor: str | Executor = "local", with_lpips: bool = True,
            progress: bool = True, write_report: bool = True, lpips_at: str = "last",
            executor_options: dict | None = None) -> Path:
    """Run every unfinished cell of `plan`, then write results.csv and (optionally) the report.

    `executor` is a name in EXECUTORS (built with `executor_options`) or an executor object. A job
    that fails does not stop the others; once all have ended, one StringsBenchError lists every cell
    that was not written and why. Ctrl-C cancels the running jobs, removes their incomplete cells
    and re-raises KeyboardInterrupt.
    """
    run_dir = plan.run_dir
    run_dir.mkdir(parents=True, exist_ok=True)
    from strings_bench.core.io import cache_root, sweep_stale_temps
    from strings_bench.engine.trainer import resolve_device

    if isinstance(executor, str):
        factory = executor_factory(executor)
        in_process = getattr(factory, "in_process", True)
    else:
        factory, in_process = None, getattr(executor, "in_process", True)
    # Temporary files of runs killed mid-write (kill -9, the OOM killer): finished files are never half-written,
    # but their temporaries would stay for ever. Compiled kernels are numba's own.
    sweep_stale_temps(run_dir)
    sweep_stale_temps(cache_root(), skip=("numba",))

    # The device of the latest execution (a resumed run may continue elsewhere); a distributed executor's
    # workers resolve their own and record it in each result.json.
    asked = plan.manifest.get("device", "auto")
    resolved = device_info(resolve_device(asked)) if in_process else {"device": "on each worker (see result.json)",
                                                                       "gpu": None}
    atomic_write_json(run_dir / RUN_FILE, _jsonable({**check_manifest(run_dir, plan.manifest), "versions": versions(),
                                                     "resolved_device": resolved}))
    cells = plan.cells
    done = sum(is_finished(run_dir, k) for k in cells)
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=len(cells), initial=done, desc="cells", unit="cell")

    def on_cell(key: CellKey) -> None:
        if bar is not None:
            bar.update(1)
            bar.set_postfix_str(f"{key.method} {key.dataset}/{key.scene} @{key.iteration}")

    # Jobs run elsewhere get a runner without callbacks into this process; the driver follows them on disk.
    runner = Runner(run_dir, ocr=ocr if ocr is not None else plan.manifest["ocr"], with_lpips=with_lpips,
                    on_cell=on_cell if in_process else None, lpips_at=lpips_at,
                    progress=progress if in_process else False, results_csv=in_process)
    ex = factory(runner, **(executor_options or {})) if factory is not None else executor
    pending = []
    for job in plan.jobs:
        if all(is_finished(run_dir, k) for k in job.cells()):
            # A run killed between writing the last cell and removing the training state left the state.
            job.state_path().unlink(missing_ok=True)
        else:
            pending.append(job)
    errors: list[tuple[Job, BaseException]] = []
    try:
        if pending and hasattr(ex, "start"):
            ex.start(run_dir, pending)
        futures = {ex.submit(job): job for job in pending}
        waiting = set(futures)
        while waiting:
            finished, waiting = wait(waiting, timeout=POLL_SECONDS, return_when=FIRST_COMPLETED)
            if not in_process:
                now = sum(is_finished(run_dir, k) for k in cells)
                if now != done:  # results.csv follows the cells as they arrive
                    done = now
                    write_results_csv(run_dir)
                    if bar is not None:
                        bar.n = now
                        bar.refresh()
            for fut in finished:
                exc = fut.exception()
                if exc is not None:
                    job = futures[fut]
                    errors.append((job, exc))
                    log.error("%s on %s/%s failed: %s", job.method, job.dataset, job.scene, exc)
    except KeyboardInterrupt:
        if hasattr(ex, "cancel"):
            ex.cancel()
        discard_incomplete_cells(run_dir, [j for j in pending if not all(is_finished(run_dir, k) for k in j.cells())])
        raise
    finally:
        if hasattr(ex, "close"):
            ex.close()
        if bar is not None:
            bar.close()
        write_results_csv(run_dir)
    if write_report:
        from strings_bench.reports import write_report as _write_report

        _write_report(run_dir)
    if errors:
        raise failure_summary(run_dir, errors, total_jobs=len(pending))
    return run_dir


def failure_summary(run_dir: Path, errors: list[tuple[Job, BaseException]], total_jobs: int) -> StringsBenchError:
    """One error naming every cell of the failed jobs that was not written, with its job's reason."""
    lines = []
    n_cells = 0
    for job, exc in errors:
        reason = (exc.message if isinstance(exc, StringsBenchError) else f"{type(exc).__name__}: {exc}").strip()
        first, *more = reason.splitlines() or [type(exc).__name__]
        unwritten = []
        for key in job.cells():
            if not is_finished(run_dir, key):
                label = job.labels.get(key.iteration, job.labels.get(str(key.iteration), iteration_label(key.iteration)))
                unwritten.append(f"@{key.iteration} ({label})")
        n_cells += len(unwritten)
        lines.append(f"  {job.method} {job.dataset}/{job.scene} {', '.join(unwritten) or '(all cells written)'}: {first}")
        lines.extend(f"      {line}" for line in more)
    hint = "finished cells are kept; fix the cause and re-run the same command"
    only = errors[0][1]
    if len(errors) == 1 and isinstance(only, StringsBenchError) and only.hint:
        hint = f"{only.hint}; {hint}"
    err = StringsBenchError(f"{len(errors)} of {total_jobs} job(s) failed; {n_cells} cell(s) not written:\n"
                            + "\n".join(lines), hint=hint)
    err.__cause__ = only
    return err


def discard_incomplete_cells(run_dir: Path, jobs: Iterable[Job]) -> list[Path]:
    """Remove what interrupted jobs left half-written: cell folders without result.json and the
    temporary files of unfinished atomic writes in their state and ground-truth folders (the
    training state itself is kept, to resume from). Returns the removed paths."""
    import shutil

    removed: list[Path] = []
    for job in jobs:
        for key in job.cells():
            cell = key.path(run_dir)
            if cell.is_dir() and not is_finished(run_dir, key):
                shutil.rmtree(cell, ignore_errors=True)
                removed.append(cell)
        gt_dir = run_dir / "gt" / safe_name(job.dataset) / safe_name(job.scene)
        for folder in (job.state_path().parent, gt_dir):
            if folder.is_dir():
                for tmp in folder.glob(".*.tmp"):  # core.io.atomic_write's temporary names
                    tmp.unlink(missing_ok=True)
                    removed.append(tmp)
    return removed


def run(methods: list[str], datasets: list[str] | None, run_dir: str | Path = DEFAULT_RUN_DIR,
        preset: str = DEFAULT_PRESET,
        ocr: str = "rapidocr", downscale: float | None = None, executor: str = "local", with_lpips: bool = True,
        progress: bool = True, write_report: bool = True, ocr_backend=None,
        method_overrides: dict[str, dict] | None = None, lpips_at: str = "last", cer_profile: str = "paper",
        steps_scale: float | None = None, checkpoints: Iterable[int] | None = None, device: str = "auto",
        save_every: str = "10", keep_models: bool = False, executor_options: dict | None = None) -> Path:
    """Plan and execute a run; `method_overrides` maps a method name (or ALL_METHODS) to settings
    overriding its preset; steps_scale and checkpoints (paper iterations) replace the preset's schedule.
    `device` (auto, cpu, cuda, cuda:N) trains every method there; `save_every` saves the resumable
    training state every so many minutes ("10", "2.5min"), steps ("20steps") or never ("off");
    `keep_models` writes each cell's model.ply; `ocr` names one OCR engine or a comma-separated list (the
    first is the primary; see `Evaluator`). `executor` names where jobs run (EXECUTORS);
    `executor_options` go to its factory (`--executor ray`: address, max_retries, cpus_per_job)."""
    factory = executor_factory(executor)
    if getattr(factory, "in_process", True):  # jobs run here: a missing GPU is refused before any scene is built
        from strings_bench.engine.trainer import resolve_device

        resolve_device(device)
    check = getattr(factory, "check_options", None)
    if check is not None:  # e.g. Ray not installed, or --device cuda:1: refused before any scene is built
        check(device=device, **(executor_options or {}))
    elif executor_options:
        raise StringsBenchError(f"executor {executor!r} takes no options (given: {', '.join(sorted(executor_options))})",
                                hint="--ray-address, --max-retries and --cpus-per-job apply to --executor ray")
    if ocr_backend is None:  # the engines are built from the names: an unknown one fails before any training
        from strings_bench.eval.ocr import parse_engines

        parse_engines(ocr)
    plan = plan_run(methods, datasets, run_dir, preset, ocr, downscale, method_overrides, cer_profile,
                    steps_scale=steps_scale, checkpoints=checkpoints, device=device, save_every=save_every,
                    keep_models=keep_models)
    return execute(plan, ocr=ocr_backend, executor=executor, with_lpips=with_lpips, progress=progress,
                   write_report=write_report, lpips_at=lpips_at, executor_options=executor_options)
