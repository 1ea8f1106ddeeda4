"""`strings-bench methods check NAME`: the conformance check of a method, after nerfbaselines' `test-method`.

Size (~490 lines): one command's checks, each a top-level function over one CheckContext, in the order they run, with the stand-ins they need.

On a tiny embedded scene (the synthetic `books` scene at 96x72 pixels, 8 views: 7 training views and
1 test view, built into the cache in about a second) the check runs, in order:

- `settings`: the method's settings are listable (`settings_schema()`: names, defaults, meanings);
- `builds`: the spec builds the method (at the `tiny` schedule, then `--set` values);
- `trains (cpu)`: the framework's loop (`engine.trainer.Trainer`) trains it `CHECK_STEPS` steps on
  the CPU, or an adapter yields its checkpoint;
- `renders (cpu)`: every test view is rendered, (H, W, 3) at the camera's size, finite, within
  [0, 1] and not constant;
- `save/load`: the training state the loop saved (`torch.save`, as a run does) is loaded into a
  freshly built method through the loop's own resume path; its renders equal the original's within
  `RENDER_TOLERANCE` (1e-5);
- `re-save`: the reloaded method's `state_dict()` is identical to the saved state (every tensor bit
  for bit, every other value equal);
- `trains (cuda)` and `renders (cuda)`: the same on the GPU when torch sees one;
- `runner`: a one-cell run through the real runner (`bench.plan.plan_run` and `bench.runner.execute`: training,
  the real metrics, the real OCR engine, result.json and results.csv).

Adapters (`MethodAdapter`: models trained elsewhere) have no training state: their save/load,
re-save and CUDA checks are skipped with that reason. The built-in adapters need an input: when no
`--set` value gives it, the check makes a stand-in (`ply`: a PLY of a 3DGS model trained on the tiny
scene; `external`: a command that copies the scene's test views as its renders) and says so.

A failed check does not stop the others; a check whose input is missing (a method that does not
build cannot train) is skipped, naming the check it needs.
"""

from __future__ import annotations

from strings_bench.core.schedules import get_schedule

import dataclasses
import json
import logging
import math
import shlex
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import numpy as np

from strings_bench.core.errors import StringsBenchError
from strings_bench.core.method import Method, MethodAdapter

log = logging.getLogger(__name__)

CHECK_SCHEDULE = "tiny"
CHECK_PAPER_ITERATION = 1000  # the runner's checkpoint, a paper iteration: x0.005 (tiny) = 5 steps
CHECK_STEPS = 5  # steps of the check's own training (= the runner's checkpoint at the tiny scale)
RENDER_TOLERANCE = 1e-5  # save -> load -> render must reproduce the renders this closely
CONSTANT_PTP = 1e-4  # a render whose values span less than this is constant

PASS, FAIL, SKIP = "pass", "FAIL", "skip"


@dataclass
class CheckResult:
    """One check: its name, `pass` / `FAIL` / `skip`, why (or what was measured), and its seconds."""

    check: str
    status: str
    detail: str = ""
    seconds: float = 0.0

    @property
    def failed(self) -> bool:
        return self.status == FAIL

    def line(self) -> str:
        """The line `methods check` prints."""
        secs = f"({self.seconds:.1f} s)" if self.status != SKIP else ""
        return f"{self.status:4s}  {self.check:15s} {secs:>9s}  {self.detail}".rstrip()


class CheckFailed(Exception):
    """A check's failure; its message is the reason printed on the check's line."""


def tiny_scene() -> Path:
    """The check's scene folder: the synthetic books room at 96x72, 8 views (`datasets.synthetic.tiny_scene`)."""
    from strings_bench.datasets.synthetic import tiny_scene as build_tiny_scene

    return build_tiny_scene()


def resolve_spec(name: str):
    """A registered method's spec, or, for `module:Class`, a spec of that class (not registered)."""
    from strings_bench.methods.registry import MethodSpec, get_method

    if ":" in name:
        module, _, attr = name.partition(":")
        if not module or not attr:
            raise StringsBenchError(f"{name!r} is neither a method name nor module:Class",
                                    hint="e.g. `strings-bench methods check 3dgs` or `... check mypkg.mymethod:MyMethod`")
        spec = MethodSpec(name=attr.lower(), implementation=name, description=f"{name} (checked by its implementation path)")
        spec.load()  # a clear error now when it does not import
        return spec
    return get_method(name)


# ---- comparisons ----------------------------------------------------------------------------------
def first_difference(a: Any, b: Any, path: str = "state") -> str | None:
    """Where two states differ (a path such as state['model']['means'] and how), or None when identical:
    tensors and arrays bit for bit (same dtype and shape, NaN equal to NaN), everything else by ==."""
    import torch

    if isinstance(a, torch.Tensor) or isinstance(b, torch.Tensor):
        if not (isinstance(a, torch.Tensor) and isinstance(b, torch.Tensor)):
            return f"{path}: a {type(a).__name__} against a {type(b).__name__}"
        a, b = a.detach().cpu(), b.detach().cpu()
        if a.dtype != b.dtype or a.shape != b.shape:
            return f"{path}: {a.dtype} {tuple(a.shape)} against {b.dtype} {tuple(b.shape)}"
        if not torch.equal(a, b):
            if a.is_floating_point() and torch.equal(torch.nan_to_num(a, nan=0.0), torch.nan_to_num(b, nan=0.0)) \
                    and torch.equal(a.isnan(), b.isnan()):
                return None
            n = int((a != b).sum())
            return f"{path}: {n} of {a.numel()} values differ"
        return None
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        if not (isinstance(a, np.ndarray) and isinstance(b, np.ndarray)):
            return f"{path}: a {type(a).__name__} against a {type(b).__name__}"
        if a.dtype != b.dtype or a.shape != b.shape or not np.array_equal(a, b, equal_nan=a.dtype.kind in "fc"):
            return f"{path}: arrays differ ({a.dtype} {a.shape} against {b.dtype} {b.shape})"
        return None
    if isinstance(a, dict) and isinstance(b, dict):
        if set(a) != set(b):
            missing, extra = sorted(map(str, set(a) - set(b))), sorted(map(str, set(b) - set(a)))
            return (f"{path}: keys differ" + (f"; missing {', '.join(missing)}" if missing else "")
                    + (f"; extra {', '.join(extra)}" if extra else ""))
        for k in a:
            d = first_difference(a[k], b[k], f"{path}[{k!r}]")
            if d:
                return d
        return None
    if isinstance(a, (list, tuple)) and isinstance(b, (list, tuple)):
        if len(a) != len(b):
            return f"{path}: length {len(a)} against {len(b)}"
        for i, (x, y) in enumerate(zip(a, b)):
            d = first_difference(x, y, f"{path}[{i}]")
            if d:
                return d
        return None
    if isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b):
        return None
    if dataclasses.is_dataclass(a) and not isinstance(a, type) and type(a) is type(b):
        # field by field: a dataclass's own == compares array fields ambiguously
        for f in dataclasses.fields(a):
            d = first_difference(getattr(a, f.name), getattr(b, f.name), f"{path}.{f.name}")
            if d:
                return d
        return None
    try:
        same = bool(a == b)
    except Exception:  # noqa: BLE001 - objects whose == is not a plain truth value
        same = False
    return None if same else f"{path}: {a!r:.80} against {b!r:.80}"


def check_renders(renders: dict, scene, downscale: float = 1.0) -> str:
    """Raise CheckFailed unless every test view is rendered as the evaluation accepts it (the protocol's
    own check: `eval.protocol.render_problems`) and, stricter for a conformance check, as floats within
    [0, 1] and not constant; return a summary."""
    from strings_bench.eval.protocol import render_problems

    names = [scene.names[i] for i in scene.test_idx]
    shapes = {scene.names[i]: (scene.camera(i, downscale).height, scene.camera(i, downscale).width, 3) for i in scene.test_idx}
    problems = render_problems(renders, shapes, strict=True, constant_ptp=CONSTANT_PTP)
    if problems:
        raise CheckFailed(problems[0])
    lo = min(float(np.asarray(renders[n]).min()) for n in names)
    hi = max(float(np.asarray(renders[n]).max()) for n in names)
    cam = scene.camera(scene.test_idx[0], downscale)
    return f"{len(names)} test view(s) at {cam.width}x{cam.height}, values in [{lo:.3f}, {hi:.3f}]"


# ---- stand-in inputs of the built-in adapters -------------------------------------------------------
_COPY_VIEWS = ("import sys, pathlib, shutil; scene, out, views = sys.argv[1:4]; "
               "[shutil.copy(pathlib.Path(scene) / 'images' / v, pathlib.Path(out) / (pathlib.Path(v).stem + '.png')) "
               "for v in views.split(',')]")


def _stand_in_settings(spec, overrides: dict, scene_path: Path, work: Path) -> tuple[dict, str]:
    """Settings a built-in adapter needs and the user did not give, and a note saying what was used."""
    from strings_bench.methods.external import ExternalCommandAdapter
    from strings_bench.methods.ply_adapter import PlyAdapter

    impl = spec.load()
    if isinstance(impl, type) and issubclass(impl, ExternalCommandAdapter) and not overrides.get("command"):
        # The scene's test views are PNG files, so copying them is a valid (perfect) set of renders.
        command = shlex.join([sys.executable, "-c", _COPY_VIEWS]) + " {scene} {out} {test_views}"
        return {"command": command}, "stand-in command: copies the test views (give --set command=... to check yours)"
    if isinstance(impl, type) and issubclass(impl, PlyAdapter) and not overrides.get("ply_path"):
        from strings_bench.engine.trainer import Trainer
        from strings_bench.methods.registry import get_method
        from strings_bench.scene.scene import Scene

        ply = work / "stand_in" / "point_cloud.ply"
        trainer = Trainer(get_method("3dgs").build(steps_scale=get_schedule(CHECK_SCHEDULE).steps_scale), Scene.load(scene_path), [CHECK_STEPS],
                          device="cpu", progress=False, render_test=False, model_path=lambda step: ply)
        for _ in trainer.train():
            pass
        return ({"ply_path": str(ply), "iteration": CHECK_STEPS},
                f"stand-in model: 3DGS after {CHECK_STEPS} steps (give --set ply_path=... to check yours)")
    return {}, ""


# ---- the checks ------------------------------------------------------------------------------------
@dataclass
class CheckContext:
    """What the checks of one method share: its spec, the tiny scene, a work folder, and what earlier
    checks produced (the settings used, the trained methods, their renders and saved states)."""

    spec: Any
    overrides: dict
    scene: Any
    scene_path: Path
    work: Path
    settings: dict = dataclasses.field(default_factory=dict)
    note: str = ""
    is_adapter: bool = False
    renders: dict = dataclasses.field(default_factory=dict)  # device -> renders
    trained: dict = dataclasses.field(default_factory=dict)  # device -> trained method
    states: dict = dataclasses.field(default_factory=dict)  # device -> saved training state
    reloaded: Any = None

    def build(self) -> Any:
        from strings_bench.bench.plan import with_steps_scale

        obj = self.spec.build(**with_steps_scale(self.spec, get_schedule(CHECK_SCHEDULE).steps_scale, self.settings))
        if not isinstance(obj, (Method, MethodAdapter)):
            raise CheckFailed(f"the spec built a {type(obj).__name__}, neither a Method nor a MethodAdapter "
                              "(strings_bench.core.method)")
        obj.progress = False
        return obj


def check_settings(ctx: CheckContext) -> str:
    """The settings are listable: names, defaults and meanings, none twice, every key valid."""
    from strings_bench.core.settings import format_settings

    schema = ctx.spec.settings()
    if schema is None:
        raise CheckFailed("the implementation has no settings_schema(): `methods show` cannot list its settings")
    if not schema:
        return "no settings"
    names = [s.name for s in schema]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise CheckFailed(f"setting(s) listed twice: {', '.join(dup)}")
    no_help = [s.name for s in schema if not str(s.help or "").strip()]
    if no_help:
        raise CheckFailed(f"setting(s) without a meaning: {', '.join(no_help[:8])}" + (" ..." if len(no_help) > 8 else ""))
    format_settings(schema)
    ctx.spec.check_keys(ctx.spec.resolve())
    return f"{len(schema)} settings, each with a default and a meaning"


def check_builds(ctx: CheckContext) -> str:
    """The spec builds a Method or a MethodAdapter, with stand-in inputs where a built-in adapter needs one."""
    extra, ctx.note = _stand_in_settings(ctx.spec, ctx.overrides, ctx.scene_path, ctx.work)
    ctx.settings = {**extra, **ctx.overrides}
    obj = ctx.build()
    json.dumps(obj.describe(), default=str)
    ctx.is_adapter = isinstance(obj, MethodAdapter)
    kind = "Method (trained by the framework's loop)" if isinstance(obj, Method) else "MethodAdapter"
    return f"{type(obj).__name__}: a {kind}" + (f"; {ctx.note}" if ctx.note else "")


def check_trains(ctx: CheckContext, device: str) -> str:
    """The framework's loop trains it CHECK_STEPS steps on `device` (an adapter yields its checkpoints)."""
    obj = ctx.build()
    if isinstance(obj, MethodAdapter):
        its = [int(i) for i in (obj.fixed_checkpoints(obj.settings) or [CHECK_STEPS])]
        out = list(obj.train(ctx.scene, its, 1.0))
        got = [r.iteration for r in out]
        if got != sorted(its):
            raise CheckFailed(f"train() yielded checkpoint(s) {got}, expected {sorted(its)}")
        ctx.renders[device] = out[-1].renders
        return f"adapter yielded checkpoint {got[-1]}"
    from strings_bench.engine.trainer import SaveEvery, Trainer

    state_path = ctx.work / f"state-{device}.pt"
    state_path.unlink(missing_ok=True)
    trainer = Trainer(obj, ctx.scene, [CHECK_STEPS], device=device, progress=False, state_path=state_path,
                      save_every=SaveEvery.parse("off"))
    out = list(trainer.train())
    if len(out) != 1 or out[0].iteration != CHECK_STEPS:
        raise CheckFailed(f"the loop yielded {[r.iteration for r in out]}, expected [{CHECK_STEPS}]")
    ctx.renders[device], ctx.trained[device], ctx.states[device] = out[0].renders, obj, state_path
    loss = getattr(obj, "last_loss", None)  # a Method may keep no loss
    return (f"{CHECK_STEPS} steps on {device}, {obj.num_gaussians()} Gaussians"
            + (f", last loss {loss:.4f}" if isinstance(loss, float) else ""))


def check_save_load(ctx: CheckContext) -> str:
    """The saved training state, loaded into a fresh method through the loop's resume path, renders the same."""
    from strings_bench.engine.trainer import SaveEvery, Trainer

    scene = ctx.scene
    first = ctx.trained["cpu"]
    before = {scene.names[i]: np.asarray(first.render(i)) for i in scene.test_idx}
    second = ctx.build()
    trainer = Trainer(second, scene, [CHECK_STEPS], device="cpu", progress=False, state_path=ctx.states["cpu"],
                      save_every=SaveEvery.parse("off"))
    trainer_log = logging.getLogger("strings_bench.engine.trainer")
    level = trainer_log.level
    trainer_log.setLevel(logging.WARNING)  # its "resuming from the training state" is this check's point
    try:
        list(trainer.train())  # the resume path: set up, load the saved state, nothing left to train
    finally:
        trainer_log.setLevel(level)
    if trainer.resumed_from_step != CHECK_STEPS:
        raise CheckFailed(f"the loop resumed from step {trainer.resumed_from_step}, expected {CHECK_STEPS}")
    ctx.reloaded = second
    worst, where = 0.0, ""
    for i in scene.test_idx:
        n = scene.names[i]
        after = np.asarray(second.render(i))
        if after.shape != before[n].shape:
            raise CheckFailed(f"render of {n} after loading is {after.shape}, before {before[n].shape}")
        same_nan = np.isnan(after) & np.isnan(before[n])  # NaN reproduced is reproduced (the renders check judges it)
        delta = np.abs(after.astype(np.float64) - before[n].astype(np.float64))
        diff = float(np.max(np.where(same_nan, 0.0, delta)))
        if not diff <= worst:
            worst, where = diff, n
    if not worst <= RENDER_TOLERANCE:
        raise CheckFailed(f"render of {where} after save -> load differs by up to {worst:.3g} "
                          f"(> {RENDER_TOLERANCE:g}): state_dict/load_state_dict lose something")
    return f"renders reproduced, max difference {worst:.2g} (<= {RENDER_TOLERANCE:g})"


def check_resave(ctx: CheckContext) -> str:
    """The reloaded method's state_dict() is identical to the saved one."""
    import torch

    saved = torch.load(ctx.states["cpu"], map_location="cpu", weights_only=False)["method"]
    diff = first_difference(saved, ctx.reloaded.state_dict())
    if diff:
        raise CheckFailed(f"the reloaded method's state_dict() differs from the saved one at {diff}")
    return "state_dict() after loading is identical to the saved state"


def check_runner(ctx: CheckContext, ocr: str, with_lpips: bool) -> str:
    """A one-cell run through the real runner: training, metrics, OCR, result.json, results.csv."""
    from strings_bench.bench.plan import plan_run
    from strings_bench.bench.runner import execute
    from strings_bench.methods.registry import registered
    from strings_bench.store import RESULTS_CSV, iter_cells

    spec, run_dir = ctx.spec, ctx.work / "run"
    with registered(spec):
        plan = plan_run([spec.name], [str(ctx.scene_path)], run_dir=run_dir, schedule=CHECK_SCHEDULE, ocr=ocr,
                        method_overrides={spec.name: ctx.settings} if ctx.settings else None,
                        checkpoints=[CHECK_PAPER_ITERATION], device="cpu", save_every="off", with_lpips=with_lpips)
        execute(plan, progress=False, write_report=False)
    cells = [c for c in iter_cells(run_dir) if c.get("method") == spec.name]
    if len(cells) != len(plan.cells):
        raise CheckFailed(f"the run wrote {len(cells)} cell(s), planned {len(plan.cells)}")
    if not (run_dir / RESULTS_CSV).is_file():
        raise CheckFailed(f"the run wrote no {RESULTS_CSV}")
    cell = cells[-1]
    psnr = (cell.get("metrics") or {}).get("psnr")
    try:
        psnr = float(psnr)  # result.json writes an exact render's infinite PSNR as "inf"
    except (TypeError, ValueError):
        psnr = math.nan
    if math.isnan(psnr):
        raise CheckFailed(f"the cell's PSNR is {(cell.get('metrics') or {}).get('psnr')!r}")
    cer = (cell.get("cer") or {}).get("cer")
    engine = ((cell.get("ocr") or {}).get("backend") or {}).get("name", ocr)
    return (f"{len(cells)} cell(s): PSNR {psnr:.2f} dB, OCR-CER {'n/a' if cer is None else f'{cer:.3f}'} "
            f"({engine}), evaluation {cell['timings']['eval_seconds']:.1f} s")


class _Results:
    """The results so far: runs a check when the checks it needs passed, names a failure, never raises."""

    def __init__(self, on_result: Callable[[CheckResult], None] | None):
        self.results: list[CheckResult] = []
        self.passed: set[str] = set()
        self.on_result = on_result

    def record(self, res: CheckResult) -> CheckResult:
        self.results.append(res)
        if res.status == PASS:
            self.passed.add(res.check)
        if self.on_result is not None:
            self.on_result(res)
        return res

    def run(self, name: str, needs: tuple[str, ...], fn: Callable[[], str]) -> None:
        missing = [n for n in needs if n not in self.passed]
        if missing:
            self.record(CheckResult(name, SKIP, f"needs {', '.join(missing)} to pass"))
            return
        t0 = time.perf_counter()
        try:
            self.record(CheckResult(name, PASS, fn() or "", time.perf_counter() - t0))
        except CheckFailed as exc:
            self.record(CheckResult(name, FAIL, str(exc), time.perf_counter() - t0))
        except StringsBenchError as exc:
            self.record(CheckResult(name, FAIL, exc.message + (f" (hint: {exc.hint})" if exc.hint else ""),
                                    time.perf_counter() - t0))
        except Exception as exc:  # noqa: BLE001 - a method's own bug is a failed check, named, not a traceback
            log.debug("check %s failed", name, exc_info=True)
            self.record(CheckResult(name, FAIL, f"{type(exc).__name__}: {exc}", time.perf_counter() - t0))


def check_method(method: str | Any, overrides: dict | None = None, *, devices: list[str] | None = None,
                 runner: bool = True, ocr: str = "rapidocr", with_lpips: bool = True, work_dir: str | Path | None = None,
                 on_result: Callable[[CheckResult], None] | None = None) -> list[CheckResult]:
    """Run every check on `method` (a registered name, `module:Class`, or a `MethodSpec`).

    Args:
        overrides: settings over the spec's defaults at the tiny schedule (`--set`).
        devices: where to train (default: "cpu", plus "cuda" when torch sees a GPU).
        runner: include the one-cell run through the real runner (the slowest check).
        ocr: the OCR engine(s) of that run (`run --ocr`).
        with_lpips: compute LPIPS in that run.
        work_dir: where the training state, the stand-ins and the run go (default a temporary folder,
            removed afterwards).
        on_result: called with each result as soon as it is known (the CLI prints it).
    Returns:
        the results in order; the method conforms when none has status FAIL.
    """
    import torch

    from strings_bench.methods.registry import MethodSpec
    from strings_bench.scene.scene import Scene

    if devices is None:
        devices = ["cpu"] + (["cuda"] if torch.cuda.is_available() else [])
    out = _Results(on_result)
    try:
        spec = method if isinstance(method, MethodSpec) else resolve_spec(str(method))
    except StringsBenchError as exc:
        out.record(CheckResult("builds", FAIL, str(exc)))
        return out.results
    tmp = tempfile.TemporaryDirectory(prefix="strings-bench-check-") if work_dir is None else None
    work = Path(tmp.name if tmp is not None else work_dir)
    work.mkdir(parents=True, exist_ok=True)
    try:
        scene_path = tiny_scene()
        ctx = CheckContext(spec, dict(overrides or {}), Scene.load(scene_path), scene_path, work)
        out.run("settings", (), lambda: check_settings(ctx))
        out.run("builds", (), lambda: check_builds(ctx))
        for device in devices:
            if device != "cpu" and ctx.is_adapter:
                out.record(CheckResult(f"trains ({device})", SKIP, "an adapter: it picks its own device"))
                continue
            out.run(f"trains ({device})", ("builds",), lambda d=device: check_trains(ctx, d))
            out.run(f"renders ({device})", (f"trains ({device})",), lambda d=device: check_renders(ctx.renders[d], ctx.scene))
            if device != "cpu":
                continue
            if ctx.is_adapter:
                for name in ("save/load", "re-save"):
                    out.record(CheckResult(name, SKIP, "an adapter: the suite keeps no training state of it"))
            else:
                out.run("save/load", ("trains (cpu)",), lambda: check_save_load(ctx))
                out.run("re-save", ("save/load",), lambda: check_resave(ctx))
        if "cuda" not in devices:
            out.record(CheckResult("trains (cuda)", SKIP, "torch sees no CUDA GPU"))
        if runner:
            out.run("runner", ("builds",), lambda: check_runner(ctx, ocr, with_lpips))
        else:
            out.record(CheckResult("runner", SKIP, "left out (--no-runner)"))
    finally:
        if tmp is not None:
            tmp.cleanup()
    return out.results
