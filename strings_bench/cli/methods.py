"""CLI: `strings-bench methods list` and `methods show NAME`: the methods available to `run`."""

from __future__ import annotations

import argparse

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
