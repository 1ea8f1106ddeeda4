"""The `strings-bench` command line.

Each command group lives in its own module that exposes `add_cli(subparsers)`; the parser calls
`args.func(args)`. Modules are imported lazily-ish (only argparse setup at import), so
`strings-bench --help` stays fast.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import sys

from strings_bench import __version__
from strings_bench.core.errors import StringsBenchError

# One entry per command module; each defines add_cli(subparsers).
COMMAND_MODULES = [
    "strings_bench.cli.render",
    "strings_bench.cli.datasets",
    "strings_bench.cli.cer",
    "strings_bench.cli.run",
    "strings_bench.cli.prepare",
]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="strings-bench",
        description="Text readability benchmark for 3D Gaussian Splatting (STRinGS, WACV 2026).",
    )
    parser.add_argument("--version", action="version", version=f"strings-bench {__version__}")
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in COMMAND_MODULES:
        importlib.import_module(name).add_cli(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
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
