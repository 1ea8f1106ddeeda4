"""The `strings-bench` command line.

One table, COMMANDS, names every command, its module and its one-line help. A command's module is
`strings_bench.cli.<command>` and is imported only when that command runs, so `strings-bench
--help` imports nothing heavy: the top-level help is built from the table alone.

Every command module exposes the same interface:

    add_parser(subparsers) -> argparse.ArgumentParser
        adds the command (its help: `command_help(NAME)`), its options and its subcommands, and sets
        `func` on the parser (subcommands set their own `func`);
    run(args) -> int
        the command itself (for a command group: what it does without a subcommand).

`main` calls `args.func(args)`; a StringsBenchError becomes `error: ...` and exit status 1.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import sys
from dataclasses import dataclass
from typing import Iterable

from strings_bench import __version__
from strings_bench.core.errors import StringsBenchError


@dataclass(frozen=True)
class Command:
    module: str  # imported only when the command runs
    help: str


# The one table of commands, in the order `strings-bench --help` lists them.
COMMANDS: dict[str, Command] = {
    "run": Command("strings_bench.cli.run", "train and evaluate methods on scenes, write results.csv and a report"),
    "report": Command("strings_bench.cli.report", "(re)write the tables, figures and HTML page of a run folder"),
    "compare": Command("strings_bench.cli.compare",
                       "the paper's tables over run folders of several seeds, with the seeds' range and the paper's figures"),
    "calibrate": Command("strings_bench.cli.calibrate",
                         "calibrate synthetic360 against the paper (3DGS' CER over a grid of settings), or run the frozen "
                         "configuration's comparison"),
    "evaluate": Command("strings_bench.cli.evaluate",
                        "score renders made anywhere (a folder, Inria 3DGS output, nerfbaselines predictions)"),
    "methods": Command("strings_bench.cli.methods", "methods available to `run`"),
    "datasets": Command("strings_bench.cli.datasets",
                        "list datasets, prepare scenes (build synthetic ones), add/check/download real data"),
    "prepare": Command("strings_bench.cli.prepare",
                       "make a scene from your photos: SfM (pycolmap), undistortion, downscaled copies, OCR text masks"),
    "render": Command("strings_bench.cli.render", "render a 3DGS PLY at a scene's cameras (one PNG per view)"),
    "ocr": Command("strings_bench.cli.ocr", "OCR backends: check them, read images"),
    "cer": Command("strings_bench.cli.cer", "OCR-CER of predicted OCR results against GT OCR results"),
    "verdicts": Command("strings_bench.cli.verdicts",
                        "the paper's claims judged from the banked data by one rule, at every scale measured"),
    "docs": Command("strings_bench.cli.docs",
                    "rewrite the documentation's generated tables and command reference, or build the site (in a source checkout)"),
}


def command_help(name: str) -> str:
    """The one-line help of command `name`, from the table."""
    return COMMANDS[name].help


def command_module(name: str):
    """Import and return the module of command `name`."""
    return importlib.import_module(COMMANDS[name].module)


def build_parser(commands: Iterable[str] | None = None) -> argparse.ArgumentParser:
    """The `strings-bench` parser. Commands in `commands` (default: all) get their full parser, which
    imports their module; the others appear in the help and the choices only."""
    parser = argparse.ArgumentParser(
        prog="strings-bench",
        description="Text readability benchmark for 3D Gaussian Splatting (STRinGS, WACV 2026).",
    )
    parser.add_argument("--version", action="version", version=f"strings-bench {__version__}")
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    full = set(COMMANDS if commands is None else commands)
    for name, cmd in COMMANDS.items():
        if name in full:
            command_module(name).add_parser(sub)
        else:
            sub.add_parser(name, help=cmd.help)  # placeholder; never parsed (see main)
    return parser


def _command_of(argv: list[str]) -> str | None:
    """The command named on the line: the first word that is not an option (the top-level options take no value)."""
    for word in argv:
        if word == "--":
            return None
        if not word.startswith("-"):
            return word if word in COMMANDS else None
    return None


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    command = _command_of(argv)
    parser = build_parser([command] if command else [])
    args = parser.parse_args(argv)
    logging.basicConfig(
        level=logging.DEBUG if args.verbose else logging.INFO,
        format="%(levelname)s %(name)s: %(message)s",
    )
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        rc = args.func(args)
    except StringsBenchError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("interrupted; finished results are kept, re-run the same command to resume", file=sys.stderr)
        return 130
    return int(rc or 0)


if __name__ == "__main__":
    sys.exit(main())
