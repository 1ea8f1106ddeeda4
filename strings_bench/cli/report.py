"""CLI: `strings-bench report RUN_DIR`: (re)write the tables and figures of a run folder."""

from __future__ import annotations

import argparse

from strings_bench.cli import command_help


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = subparsers.add_parser("report", help=command_help("report"))
    p.add_argument("run_dir", help="a folder made by `strings-bench run`")
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    """Write RUN_DIR/report/ from the run folder's cells and print where."""
    from strings_bench.bench.reports import write_report

    path = write_report(args.run_dir)
    print(f"report: {path}")
    return 0
