"""CLI: `strings-bench methods list`, `methods show NAME` and `methods check NAME`: the methods available
to `run`, and the conformance check of one (strings_bench.bench.check)."""

from __future__ import annotations

import argparse
import json

from strings_bench.cli import command_help


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = subparsers.add_parser("methods", help=command_help("methods"))
    sub = p.add_subparsers(dest="methods_command", metavar="SUBCOMMAND")
    ls = sub.add_parser("list", help="names, papers, presets and descriptions")
    ls.set_defaults(func=cmd_list)
    show = sub.add_parser("show", help="every setting of a method with its default and meaning, its presets, "
                                       "and the paper's published figures")
    show.add_argument("name", help="a method name (see `methods list`)")
    show.set_defaults(func=cmd_show)
    check = sub.add_parser(
        "check", help="conformance check on a tiny scene: builds, trains, renders, save/load, re-save, runner, settings",
        description="Checks a method on a tiny embedded scene (synthetic books, 96x72, 8 views): it builds, trains a "
                    "few steps on the CPU (and CUDA when present), renders the right size with finite, non-constant "
                    "values, save -> load -> render reproduces the renders within 1e-5, re-saving gives an identical "
                    "state, a one-cell run through the runner evaluates it, and its settings are listable. Prints one "
                    "line per check and exits with status 1 when any fails.")
    check.add_argument("name", help="a method name (see `methods list`, plug-ins included) or module:Class of an "
                                    "implementation that is not registered yet")
    check.add_argument("--set", dest="settings", action="append", default=[], metavar="KEY=VALUE",
                       help="a setting over the method's defaults and its tiny preset (VALUE parsed as JSON when it can "
                            "be), e.g. --set command='python train.py -s {scene} --out {out}' for external; repeatable")
    check.add_argument("--ocr", default="rapidocr", help="OCR engine(s) of the runner check (default rapidocr)")
    check.add_argument("--no-runner", action="store_true", help="leave out the one-cell run through the runner")
    check.add_argument("--no-lpips", action="store_true", help="no LPIPS in the runner check")
    check.add_argument("--device", action="append", default=None, metavar="DEVICE",
                       help="train on DEVICE (repeatable; default: cpu, plus cuda when torch sees a GPU)")
    check.set_defaults(func=cmd_check)
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    """`strings-bench methods` without a subcommand lists the methods."""
    return cmd_list(args)


def cmd_list(args: argparse.Namespace | None) -> int:
    """Print every registered method: name, presets, description and paper."""
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


def cmd_show(args: argparse.Namespace) -> int:
    """Print one method's spec: description, paper, presets, published figures and every setting."""
    from strings_bench.methods.registry import show_method

    print(show_method(args.name))
    return 0


def cmd_check(args: argparse.Namespace) -> int:
    """Run the conformance check of one method and print a pass/FAIL/skip line per check; 1 on any failure."""
    from strings_bench.bench.check import check_method
    from strings_bench.core.errors import StringsBenchError

    overrides = {}
    for item in args.settings:
        key, eq, value = item.partition("=")
        key = key.strip()
        if key.startswith(f"{args.name}."):
            key = key[len(args.name) + 1:]
        if not eq or not key:
            raise StringsBenchError(f"--set {item!r} is not KEY=VALUE", hint="e.g. --set lr_means=1e-3")
        try:
            overrides[key] = json.loads(value)
        except ValueError:
            overrides[key] = value
    print(f"checking method {args.name} on a tiny scene (synthetic books, 96x72, 8 views)", flush=True)
    results = check_method(args.name, overrides, devices=args.device, runner=not args.no_runner, ocr=args.ocr,
                           with_lpips=not args.no_lpips, on_result=lambda r: print(r.line(), flush=True))
    failed = [r.check for r in results if r.failed]
    n_pass = sum(r.status == "pass" for r in results)
    if failed:
        print(f"{args.name}: FAILED {len(failed)} check(s): {', '.join(failed)} ({n_pass} passed)")
        return 1
    print(f"{args.name}: all {n_pass} checks passed ({len(results) - n_pass} skipped)")
    return 0
