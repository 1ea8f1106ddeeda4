"""CLI: `strings-bench report RUN_DIR`: (re)write the tables, figures and HTML page of a run folder."""

from __future__ import annotations

import argparse

from strings_bench.cli import command_help


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = subparsers.add_parser("report", help=command_help("report"))
    p.add_argument("run_dir", help="a folder made by `strings-bench run`")
    p.add_argument("--metric", action="append", default=None, metavar="NAME",
                   help="a results.csv metric to plot against training time and over iterations (repeatable; "
                        "e.g. text_nll, word_cer, text_psnr, cer); default: cer, word_cer and text_nll")
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    """Write RUN_DIR/report/ from the run folder's cells and print where (report.md and index.html)."""
    from strings_bench.reports import write_report
    from strings_bench.store import refresh

    refresh(args.run_dir)  # results.csv from the cells (they are the truth); words.csv where an older cell lacks it
    path = write_report(args.run_dir, metrics=args.metric)
    print(f"report: {path}")
    print(f"html:   {(path.parent / 'index.html').resolve().as_uri()}")
    return 0
