"""CLI: `strings-bench run`: train and evaluate methods on scenes, write results.csv and a report."""

from __future__ import annotations

import argparse

from strings_bench.cli import command_help
from strings_bench.core.errors import StringsBenchError

DEFAULT_METHODS = "strings,3dgs"
ALL_METHODS = "*"  # = strings_bench.bench.plan.ALL_METHODS


def _split(s: str) -> list[str]:
    return [x.strip() for x in s.split(",") if x.strip()]


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    from strings_bench.bench.executors import EXECUTORS
    from strings_bench.bench.plan import DEFAULT_RUN_DIR, DENSE_EVAL, LPIPS_AT
    from strings_bench.core.schedules import DEFAULT_SCHEDULE, MINIATURES, SCHEDULES

    p = subparsers.add_parser("run", help=command_help("run"),
                              description="Runs every method x scene x checkpoint not already finished in the run folder "
                                          "(re-running the same command resumes), then writes the report.")
    p.add_argument("--methods", default=DEFAULT_METHODS, help=f"comma-separated method names (default {DEFAULT_METHODS}); "
                                                              "see `strings-bench methods list`")
    p.add_argument("--datasets", default=None,
                   help="comma-separated dataset ids (synthetic, synthetic/books, strings360/globe) or scene folders "
                        "(default: the schedule's scenes: " + "; ".join(
                            f"{n}: {','.join(pr.default_datasets())}" for n, pr in SCHEDULES.items()) + ")")
    p.add_argument("--schedule", dest="schedule", default=DEFAULT_SCHEDULE, choices=sorted(SCHEDULES),
                   help=f"how long every method trains and which checkpoints are evaluated (default {DEFAULT_SCHEDULE}): "
                        + "; ".join(f"{n} = {pr.description}" for n, pr in SCHEDULES.items()))
    # refused by name: argparse would otherwise take it for an abbreviated --presets
    p.add_argument("--preset", dest="former_preset", default=None, metavar="NAME",
                   help="refused: the former name of --schedule (the error names the --schedule to give)")
    p.add_argument("--presets", dest="method_presets", action="append", default=[], metavar="METHOD=PRESET[+PRESET]",
                   help="a named variant of one method's settings, e.g. --presets strings=release (the authors' release "
                        "where it differs from the paper); repeatable; `strings-bench methods show METHOD` lists them. "
                        "Presets that apply to a dataset by themselves (STRinGS' N_max) need no option")
    p.add_argument("--steps-scale", type=float, default=None, metavar="S",
                   help="replace the schedule's scale for every method (e.g. 0.2: 7K = 1400 steps; 1 = the paper's); "
                        "recorded in run.json, a run folder holds one scale")
    p.add_argument("--miniature", default=None, choices=sorted(MINIATURES),
                   help="how a shrunk schedule stands in for the paper's (default shrink): " + "; ".join(
                       f"{m.name} = {m.description}" for m in MINIATURES.values()) + "; recorded in run.json")
    p.add_argument("--checkpoints", type=parse_checkpoints, default=None, metavar="ITERS",
                   help="paper iterations to evaluate, e.g. 3000,7000 or 3K,7K (each trained as round(it x scale)); "
                        "default: the schedule's; every:N adds a checkpoint every N paper iterations up to the last "
                        "(e.g. every:500, or 3K,7K,every:500), for time to legibility (docs/readability.md); the "
                        "checkpoints only every:N adds get the word-crop metrics only (see --dense-eval); recorded "
                        "in run.json")
    p.add_argument("--dense-eval", choices=DENSE_EVAL, default=DENSE_EVAL[0],
                   help="how the checkpoints that only --checkpoints every:N adds are evaluated: words (default: "
                        "word-crop readability and PSNR/SSIM; no OCR of the renders, no LPIPS; GT reads are made once "
                        "per scene) or full (OCR-CER and every metric, as the other checkpoints)")
    p.add_argument("--out", default=str(DEFAULT_RUN_DIR),
                   help=f"run folder (default {DEFAULT_RUN_DIR}; the same folder resumes; one run at a time)")
    p.add_argument("--ocr", default="rapidocr",
                   help="OCR engine for OCR-CER (rapidocr, tesseract, gcv), or a comma-separated list, e.g. "
                        "rapidocr,tesseract: the first is the primary (cer, cer_known), each further engine adds "
                        "cer_<engine> and its agreement with the primary (docs/ocr.md); recorded in run.json. A scene that "
                        "names its own GT engine (the captures' saharov32: Tesseract, Russian) is read by it first")
    p.add_argument("--cer-profile", default="paper",
                   help="OCR-CER profile (default paper: the authors' rules exactly; robust: repairs invalid polygons, "
                        "NFC, all whitespace removed); recorded in run.json and every result.json; see docs/ocr.md")
    p.add_argument("--executor", default="local", choices=sorted(EXECUTORS),
                   help="where jobs run: local (default; one after another in this process), ray (each method x scene "
                        "a Ray task, concurrently; needs the ray extra) or slurm (each method x scene a task of a Slurm "
                        "job array; needs the slurm extra); ray and slurm need a run folder every node sees "
                        "(docs/guide/cluster.md)")
    p.add_argument("--ray-address", default=None, metavar="ADDRESS",
                   help="with --executor ray: the Ray cluster to join (e.g. auto, HEAD_IP:6379, ray://HEAD_IP:10001); "
                        "default: RAY_ADDRESS, else a local Ray is started")
    p.add_argument("--max-retries", type=int, default=None, metavar="N",
                   help="with --executor ray: run a job again up to N times when its worker dies (default 3); it continues "
                        "from its saved training state. A job that fails by itself is not retried")
    p.add_argument("--cpus-per-job", type=float, default=None, metavar="N",
                   help="with --executor ray or slurm: CPUs each job asks for (default 1; with ray a GPU job also asks "
                        "for 1 GPU; with slurm an integer, its --cpus-per-task)")
    p.add_argument("--slurm-partition", default=None, metavar="P",
                   help="with --executor slurm: the partition the jobs are submitted to (default: the cluster's default)")
    p.add_argument("--slurm-gpus-per-task", type=int, default=None, metavar="N",
                   help="with --executor slurm: GPUs each job asks for (default 1 with --device cuda, else 0: the jobs "
                        "train on the CPU)")
    p.add_argument("--slurm-mem", default=None, metavar="MEM",
                   help="with --executor slurm: memory each job asks for, as sbatch --mem (e.g. 16G; default: the "
                        "partition's)")
    p.add_argument("--slurm-time", type=int, default=None, metavar="MINUTES",
                   help="with --executor slurm: each job's time limit in minutes (default 1440); a job at its limit is "
                        "requeued and continues from its saved training state")
    p.add_argument("--slurm-array-parallelism", type=int, default=None, metavar="N",
                   help="with --executor slurm: at most N jobs of an array run at once (sbatch --array=...%%N)")
    p.add_argument("--slurm-resources", action="append", default=[], metavar="METHOD=KEY:VALUE[,KEY:VALUE]",
                   help="with --executor slurm: one method's resources where they differ from the above, KEY one of "
                        "gpus, cpus, mem, time, e.g. --slurm-resources strings=gpus:1,mem:32G; repeatable. Jobs that "
                        "ask for the same resources go to Slurm as one job array")
    p.add_argument("--slurm-option", action="append", default=[], metavar="KEY=VALUE",
                   help="with --executor slurm: any other sbatch option, without its --, e.g. --slurm-option "
                        "account=proj42 --slurm-option qos=high; repeatable")
    p.add_argument("--detach", action="store_true",
                   help="with --executor slurm: submit the jobs and return; the same command again follows them (it "
                        "submits only what is missing) and writes the report")
    p.add_argument("--downscale", type=float, default=None, help="image downscale factor (default: the schedule's, 1)")
    p.add_argument("--set", dest="settings", action="append", default=[], metavar="[METHOD.]KEY=VALUE",
                   help="override a method setting (VALUE parsed as JSON when it can be): KEY=VALUE for every method of "
                        "the run, METHOD.KEY=VALUE for one (it wins over the former), e.g. --set lr_means=1e-3 "
                        "--set ply.ply_path=/models/{scene}/point_cloud.ply; repeatable")
    p.add_argument("--budget", default=None, metavar="N|METHOD",
                   help="equal Gaussian budget: hold every method to N Gaussians (40000 or 40k), or to the count "
                        "METHOD reaches on the same scene at the last checkpoint (--budget 3dgs: 3dgs trains first, "
                        "without a budget, as the reference; it must be in --methods or its cells in the run folder). "
                        "Each method keeps "
                        "to it by its own rules (docs/baselines.md); recorded in run.json and every result.json, and a "
                        "run folder holds one budget (docs/guide/running.md)")
    p.add_argument("--budget-from", default=None, metavar="FOLDER",
                   help="with --budget METHOD: read METHOD's counts from the cells of another run folder (trained "
                        "there without a budget, same schedule and image scale) instead of training METHOD in this "
                        "run, e.g. other seeds at the count 3DGS reached at seed 0")
    p.add_argument("--no-lpips", action="store_true", help="skip LPIPS (reported as n/a)")
    p.add_argument("--lpips-at", default=LPIPS_AT[0], choices=LPIPS_AT,
                   help="LPIPS at each method x scene's last checkpoint (default; the paper reports it at 30K) or at all")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--device", default="auto",
                   help="where methods train: auto (CUDA when torch sees a GPU, else cpu; default), cpu, cuda, cuda:N")
    p.add_argument("--save-every", default="10", metavar="MINUTES|Nsteps",
                   help="save the resumable training state every MINUTES of wall time (default 10), every N steps "
                        "('500steps'), or 'off'; it is also saved at every checkpoint. A killed run continues from it")
    p.add_argument("--keep-models", action="store_true",
                   help="write each cell's model (model.ply, 3DGS layout) next to its result.json")
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    """`strings-bench run`: plan and execute the run, print where its results and report are."""
    from strings_bench.bench import run as run_bench

    out = run_bench(run_config(args))
    if getattr(args, "detach", False):  # the runner has said how many cells are still to come
        print(f"jobs:    {out / 'slurm' / 'jobs.json'}")
        print(f"results: {out / 'results.csv'} (so far; the same command again follows the jobs and writes the report)")
        return 0
    print(f"results: {out / 'results.csv'}")
    print(f"report:  {out / 'report' / 'report.md'}")
    print(f"html:    {(out / 'report' / 'index.html').resolve().as_uri()}")
    return 0


RAY_OPTIONS = {"address": "--ray-address", "max_retries": "--max-retries"}
SLURM_OPTIONS = {"partition": "--slurm-partition", "gpus_per_task": "--slurm-gpus-per-task", "mem": "--slurm-mem",
                 "time_min": "--slurm-time", "array_parallelism": "--slurm-array-parallelism",
                 "method_resources": "--slurm-resources", "sbatch_options": "--slurm-option", "detach": "--detach"}
SHARED_OPTIONS = {"cpus_per_job": "--cpus-per-job"}  # ray and slurm


def executor_options(args: argparse.Namespace) -> dict | None:
    """The options of --executor ray or slurm given on the command line (None for the local executor); an option
    of another executor is refused."""
    values = {"address": args.ray_address, "max_retries": args.max_retries, "cpus_per_job": args.cpus_per_job,
              "partition": getattr(args, "slurm_partition", None),
              "gpus_per_task": getattr(args, "slurm_gpus_per_task", None), "mem": getattr(args, "slurm_mem", None),
              "time_min": getattr(args, "slurm_time", None),
              "array_parallelism": getattr(args, "slurm_array_parallelism", None),
              "method_resources": getattr(args, "slurm_resources", None) or None,
              "sbatch_options": getattr(args, "slurm_option", None) or None,
              "detach": getattr(args, "detach", False) or None}
    given = {k: v for k, v in values.items() if v is not None}
    own = {"ray": {**RAY_OPTIONS, **SHARED_OPTIONS}, "slurm": {**SLURM_OPTIONS, **SHARED_OPTIONS}}.get(args.executor, {})
    names = {**RAY_OPTIONS, **SLURM_OPTIONS, **SHARED_OPTIONS}
    foreign = [k for k in given if k not in own]
    if foreign:
        takers = [ex for ex, opts in (("ray", RAY_OPTIONS), ("slurm", SLURM_OPTIONS)) if foreign[0] in {**opts, **SHARED_OPTIONS}]
        flags = ", ".join(names[k] for k in foreign)
        raise StringsBenchError(f"{flags} appl{'ies' if len(foreign) == 1 else 'y'} to --executor {' or '.join(takers)} only",
                                hint=f"add --executor {takers[0]}, or leave the option out")
    if args.executor == "ray":
        return {**given, "log_to_driver": bool(getattr(args, "verbose", False))}
    if args.executor == "slurm":
        return given
    return None


def run_config(args: argparse.Namespace):
    """The run the command line asks for, as one RunConfig (bench/plan.py)."""
    from strings_bench.bench.plan import RunConfig

    if getattr(args, "former_preset", None) is not None:
        raise StringsBenchError(f"--preset {args.former_preset} is no option: the schedule is --schedule",
                                hint=f"--schedule {args.former_preset}; --presets METHOD=PRESET chooses a method's "
                                     "named settings")
    checkpoints, dense_every = split_checkpoints(args.checkpoints)
    return RunConfig(methods=_split(args.methods), datasets=_split(args.datasets) if args.datasets else None,
                     run_dir=args.out, schedule=args.schedule, ocr=args.ocr, downscale=args.downscale,
                     executor=args.executor, executor_options=executor_options(args), with_lpips=not args.no_lpips,
                     progress=not args.no_progress, method_presets=parse_presets(args.method_presets),
                     method_overrides=parse_settings(args.settings), lpips_at=args.lpips_at,
                     cer_profile=args.cer_profile, steps_scale=args.steps_scale,
                     checkpoints=checkpoints, dense_every=dense_every, miniature=args.miniature,
                     dense_eval=args.dense_eval,
                     device=args.device, save_every=args.save_every, keep_models=args.keep_models,
                     budget=args.budget, budget_from=args.budget_from)


def parse_presets(items: list[str]) -> dict[str, list[str]]:
    """`--presets` values -> {method: [preset, ...]}: 'strings=release' or 'strings=release+other', repeatable;
    several methods in one value as 'a=x,b=y'."""
    out: dict[str, list[str]] = {}
    for item in items:
        for part in _split(item):
            method, eq, names = part.partition("=")
            presets = [n.strip() for n in names.split("+") if n.strip()]
            if not eq or not method.strip() or not presets:
                raise StringsBenchError(f"--presets {part!r} is not METHOD=PRESET",
                                        hint="e.g. --presets strings=release; `strings-bench methods show strings` lists them")
            out.setdefault(method.strip(), []).extend(presets)
    return out


def split_checkpoints(given: list | None) -> tuple[list[int] | None, int | None]:
    """`parse_checkpoints`' result -> (the paper iterations in the order given, or None; every:N's N, or None)."""
    given = given or []
    return [c for c in given if isinstance(c, int)] or None, next((c[1] for c in given if isinstance(c, tuple)), None)


def parse_checkpoints(text: str) -> list:
    """'3000,7000' or '3K,7k' -> [3000, 7000] (paper iterations; argparse type of --checkpoints); an 'every:N'
    item (N paper iterations, e.g. every:500 or every:1K) becomes ("every", N)."""
    its: list = []
    for item in _split(text):
        if item.lower().startswith("every:"):
            if any(isinstance(x, tuple) for x in its):
                raise argparse.ArgumentTypeError("every:N given twice")
            n = parse_checkpoints(item[6:]) if item[6:] else []
            if len(n) != 1 or not isinstance(n[0], int):
                raise argparse.ArgumentTypeError(f"{item!r} is not every:N with N paper iterations (e.g. every:500)")
            its.append(("every", n[0]))
            continue
        digits, mult = (item[:-1], 1000) if item[-1:] in ("k", "K") else (item, 1)
        try:
            value = int(digits) * mult
        except ValueError:
            value = 0
        if value < 1:
            raise argparse.ArgumentTypeError(f"{item!r} is not a paper iteration (an integer >= 1, e.g. 7000 or 7K)")
        its.append(value)
    if not its:
        raise argparse.ArgumentTypeError("no checkpoints given (e.g. 3000,7000 or every:500)")
    return its


def parse_settings(items: list[str]) -> dict[str, dict]:
    """Parse `--set` values into runner method overrides.

    `METHOD.KEY=VALUE` sets KEY for METHOD only; `KEY=VALUE` (no '.' before the '=') sets it for every
    method of the run, under the key ALL_METHODS ('*'). VALUE is parsed as JSON when it can be, else
    kept as a string. Example:
    ['lr_means=1e-3', 'strings.n_max=25', 'ply.ply_path=/x.ply']
        -> {'*': {'lr_means': 0.001}, 'strings': {'n_max': 25}, 'ply': {'ply_path': '/x.ply'}}
    """
    import json

    out: dict[str, dict] = {}
    for item in items:
        key, eq, value = item.partition("=")
        method, dot, name = key.strip().partition(".")
        if not dot:
            method, name = ALL_METHODS, method
        if not eq or not method or not name:
            raise StringsBenchError(f"--set {item!r} is not KEY=VALUE or METHOD.KEY=VALUE",
                                    hint="e.g. --set lr_means=1e-3 (every method) or --set strings.n_max=25 (one)")
        try:
            parsed = json.loads(value)
        except ValueError:
            parsed = value
        out.setdefault(method, {})[name] = parsed
    return out
