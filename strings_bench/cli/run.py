"""CLI: `strings-bench run`, `strings-bench report RUN_DIR`, `strings-bench methods list`."""

from __future__ import annotations

import argparse

DEFAULT_METHODS = "strings,3dgs"
DEFAULT_DATASETS = "synthetic"


def _split(s: str) -> list[str]:
    return [x.strip() for x in s.split(",") if x.strip()]


def add_cli(sub: argparse._SubParsersAction) -> None:
    from strings_bench.bench.runner import DEFAULT_RUN_DIR, EXECUTORS, PRESETS

    p = sub.add_parser("run", help="train and evaluate methods on scenes, write results.csv and a report",
                       description="Runs every method x scene x checkpoint not already finished in the run folder "
                                   "(re-running the same command resumes), then writes the report.")
    p.add_argument("--methods", default=DEFAULT_METHODS, help=f"comma-separated method names (default {DEFAULT_METHODS}); "
                                                              "see `strings-bench methods list`")
    p.add_argument("--datasets", default=DEFAULT_DATASETS,
                   help="comma-separated dataset ids (synthetic, synthetic/books, strings360/globe) or scene folders "
                        f"(default {DEFAULT_DATASETS})")
    p.add_argument("--preset", default="quick", choices=sorted(PRESETS),
                   help="schedule: paper = 30K iterations (3K/7K/30K); standard = x0.05 (350/1500 steps); "
                        "quick (default) = x0.01 (70/300 steps, ~10 min for the default run on 2 cores); tiny = smoke test")
    p.add_argument("--out", default=str(DEFAULT_RUN_DIR),
                   help=f"run folder (default {DEFAULT_RUN_DIR}; the same folder resumes)")
    p.add_argument("--ocr", default="rapidocr", help="OCR backend for OCR-CER (rapidocr, tesseract, gcv)")
    p.add_argument("--cer-profile", default="paper",
                   help="OCR-CER profile (default paper: the authors' rules exactly; robust: repairs invalid polygons, "
                        "NFC, all whitespace removed); recorded in run.json and every result.json; see docs/ocr.md")
    p.add_argument("--executor", default="local", choices=sorted(EXECUTORS), help="where jobs run (default local)")
    p.add_argument("--downscale", type=float, default=None, help="image downscale factor (default: the preset's, 1)")
    p.add_argument("--set", dest="settings", action="append", default=[], metavar="METHOD.KEY=VALUE",
                   help="override a method setting (VALUE parsed as JSON when it can be), e.g. "
                        "--set ply.ply_path=/models/{scene}/point_cloud.ply; repeatable")
    p.add_argument("--no-lpips", action="store_true", help="skip LPIPS (reported as n/a)")
    p.add_argument("--lpips-at", default="last", choices=["last", "all"],
                   help="LPIPS at each method x scene's last checkpoint (default; the paper reports it at 30K) or at all")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--device", default="auto",
                   help="where methods train: auto (CUDA when torch sees a GPU, else cpu; default), cpu, cuda, cuda:N")
    p.add_argument("--save-every", default="10", metavar="MINUTES|Nsteps",
                   help="save the resumable training state every MINUTES of training (default 10), every N steps "
                        "('500steps'), or 'off'; it is also saved at every checkpoint. A killed run continues from it")
    p.add_argument("--keep-models", action="store_true",
                   help="write each cell's model (model.ply, 3DGS layout) next to its result.json")
    p.set_defaults(func=_run)

    r = sub.add_parser("report", help="(re)write the tables and figures of a run folder")
    r.add_argument("run_dir", help="a folder made by `strings-bench run`")
    r.set_defaults(func=_report)

    m = sub.add_parser("methods", help="methods available to `run`")
    msub = m.add_subparsers(dest="methods_command", metavar="SUBCOMMAND")
    ml = msub.add_parser("list", help="names, papers, presets and descriptions")
    ml.set_defaults(func=_methods_list)
    m.set_defaults(func=_methods_list)


def _run(args) -> int:
    from strings_bench.bench.runner import run

    out = run(_split(args.methods), _split(args.datasets), run_dir=args.out, preset=args.preset, ocr=args.ocr,
              downscale=args.downscale, executor=args.executor, with_lpips=not args.no_lpips,
              progress=not args.no_progress, method_overrides=parse_settings(args.settings), lpips_at=args.lpips_at,
              cer_profile=args.cer_profile, device=args.device, save_every=args.save_every,
              keep_models=args.keep_models)
    print(f"results: {out / 'results.csv'}")
    print(f"report:  {out / 'report' / 'report.md'}")
    return 0


def parse_settings(items: list[str]) -> dict[str, dict]:
    """['ply.ply_path=/x', 'strings.n_max=25'] -> {'ply': {'ply_path': '/x'}, 'strings': {'n_max': 25}}."""
    import json

    from strings_bench.core.errors import StringsBenchError

    out: dict[str, dict] = {}
    for item in items:
        key, eq, value = item.partition("=")
        method, dot, name = key.partition(".")
        if not eq or not dot or not method or not name:
            raise StringsBenchError(f"--set {item!r} is not METHOD.KEY=VALUE", hint="e.g. --set strings.n_max=25")
        try:
            parsed = json.loads(value)
        except ValueError:
            parsed = value
        out.setdefault(method, {})[name] = parsed
    return out


def _report(args) -> int:
    from strings_bench.bench.reports import write_report

    path = write_report(args.run_dir)
    print(f"report: {path}")
    return 0


def _methods_list(args) -> int:
    from strings_bench.methods.registry import list_methods

    specs = sorted(list_methods(), key=lambda s: s.name)
    if not specs:
        print("no methods registered")
        return 1
    for s in specs:
        presets = ", ".join(s.presets) or "-"
        print(f"{s.name:20s} presets: {presets}")
        if s.description:
            print(f"{'':20s} {s.description}")
        if s.paper:
            print(f"{'':20s} paper: {s.paper}")
    return 0
