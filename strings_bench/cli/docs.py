"""CLI: `strings-bench docs refresh [--check]`: rewrite the documentation's generated parts from their sources;
`strings-bench docs build [--site-dir DIR]`: build the documentation site (MkDocs, strict: a warning fails it).

Two kinds of generated text, both in a source checkout:

- every table block of README.md and docs/**/*.md (`<!-- table (strings-bench docs refresh): DATA ... -->` ...
  `<!-- end table -->`), from the CSV it names (strings_bench.reports.doc_tables);
- the command-line reference, docs/guide/cli.md, from the argument parsers themselves (`cli_reference`).

`--check` writes nothing and exits with status 1, naming the files, when one differs from its sources, or when the
results break the rule that every results table is derived: a page outside docs/history/ has a table read from a
transcribed CSV (one under a `data/tables/` folder, or anything under docs/history/: tables first typed by hand, not
derived from banked records or a command's output on them; `transcribed_reads`), or a page outside docs/history/
says it is a history page (`misplaced_history_pages`), or a page under docs/history/ (its README.md aside) does not
(`unmarked_history_pages`). A history page says so in its first lines with HISTORY_MARK; its tables are what was
measured then, transcribed, and their CSVs lie in docs/history/data/tables/.

`build` runs MkDocs on mkdocs.yml in strict mode, so that a broken link, a page missing from the navigation's
targets or an API object that does not exist stops the build (the `docs` extra installs MkDocs:
`pip install -e ".[docs]"`; docs/site.md says why MkDocs).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from strings_bench.cli import COMMANDS, build_parser, command_help

CLI_REFERENCE = Path("docs/guide/cli.md")
HISTORY = Path("docs/history")  # the history pages and their transcribed CSVs (data/tables/)
TRANSCRIBED_FOLDER = "tables"  # a data/tables/ folder holds CSVs transcribed from hand-typed Markdown tables
HISTORY_MARK = "<!-- history page (strings-bench docs refresh):"


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = subparsers.add_parser("docs", help=command_help("docs"))
    sub = p.add_subparsers(dest="docs_command", metavar="SUBCOMMAND")
    r = sub.add_parser("refresh", help="rewrite the generated tables and the command-line reference",
                       description="Rewrites every generated table of README.md and docs/ from the CSV it names, and "
                                   "docs/guide/cli.md from the command-line parsers. With --check, writes nothing and "
                                   "exits with status 1 when a file differs from its sources, when a page outside "
                                   "docs/history/ has a table read from a transcribed CSV (data/tables/, docs/history/), "
                                   "or when a history page is not under docs/history/ or lacks its mark.")
    r.add_argument("--check", action="store_true", help="only compare; exit status 1 when something is out of date")
    r.add_argument("--root", default=".", help="the source checkout (default: the current folder)")
    r.set_defaults(func=cmd_refresh)
    b = sub.add_parser("build", help="build the documentation site (MkDocs, strict) into build/site",
                       description="Builds the documentation site from docs/ and mkdocs.yml with MkDocs in strict mode: "
                                   "a broken link, a missing page or a missing API object fails the build. Open "
                                   "SITE_DIR/index.html in a browser. Needs the docs extra (pip install -e \".[docs]\").")
    b.add_argument("--site-dir", default=None, help="where to write the site (default: build/site under the checkout)")
    b.add_argument("--root", default=".", help="the source checkout (default: the current folder)")
    b.set_defaults(func=cmd_build)
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    """`strings-bench docs` without a subcommand: its help."""
    print("usage: strings-bench docs refresh [--check] [--root DIR]\n"
          "       strings-bench docs build [--site-dir DIR] [--root DIR]")
    return 2


# ---- the command-line reference ------------------------------------------------------------------------
def _help_text(action: argparse.Action) -> str:
    text = action.help or ""
    if "%(" in text:
        params = {k: v for k, v in vars(action).items() if v is not argparse.SUPPRESS}
        if isinstance(params.get("choices"), (list, tuple, dict)):
            params["choices"] = ", ".join(map(str, params["choices"]))
        try:
            text = text % params
        except (KeyError, TypeError, ValueError):
            pass
    return " ".join(text.split())


def _option_line(action: argparse.Action) -> str:
    if action.option_strings:
        names = ", ".join(f"`{o}`" for o in action.option_strings)
        if action.nargs != 0:
            metavar = action.metavar or (f"{{{','.join(map(str, action.choices))}}}" if action.choices
                                         else action.dest.upper())
            names += f" `{metavar}`" if not isinstance(metavar, tuple) else " " + " ".join(f"`{m}`" for m in metavar)
    else:
        names = f"`{action.metavar or action.dest}`"
    help_text = _help_text(action)
    return f"- {names}" + (f": {help_text}" if help_text else "")


def _subparsers(parser: argparse.ArgumentParser):
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            helps = {a.dest: a.help for a in action._choices_actions}
            for name, sub in action.choices.items():
                yield name, sub, helps.get(name, "")


def _describe(parser: argparse.ArgumentParser, title: str, summary: str, level: int) -> list[str]:
    out = [f"{'#' * level} `{title}`", ""]
    text = " ".join((parser.description or summary or "").split())
    if text:
        out += [text, ""]
    args = [a for a in parser._actions
            if not isinstance(a, (argparse._HelpAction, argparse._SubParsersAction, argparse._VersionAction))]
    positionals = [a for a in args if not a.option_strings]
    options = [a for a in args if a.option_strings]
    if positionals:
        out += ["Arguments:", ""] + [_option_line(a) for a in positionals] + [""]
    if options:
        out += ["Options:", ""] + [_option_line(a) for a in options] + [""]
    subs = list(_subparsers(parser))
    if subs:
        out += ["Subcommands: " + ", ".join(f"`{n}`" for n, _, _ in subs) + ".", ""]
        for name, sub, help_text in subs:
            out += _describe(sub, f"{title} {name}", help_text or "", level + 1)
    return out


def cli_reference() -> str:
    """docs/guide/cli.md: every command, subcommand and option, from the parsers."""
    parser = build_parser()
    lines = [
        "# Command-line reference",
        "",
        "<!-- Generated by `strings-bench docs refresh` from the argument parsers; do not edit by hand. -->",
        "",
        "Every command of `strings-bench`, with its options. `strings-bench COMMAND --help` prints the same.",
        "Top-level options: `--version`, `-v`/`--verbose` (debug logging).",
        "",
        "| command | what it does |",
        "|---|---|",
    ]
    lines += [f"| [`{name}`](#strings-bench-{name}) | {cmd.help} |" for name, cmd in COMMANDS.items()]
    lines.append("")
    for name, sub, _ in _subparsers(parser):
        lines += _describe(sub, f"strings-bench {name}", COMMANDS[name].help, 2)
    return "\n".join(lines).rstrip() + "\n"


# ---- refresh -----------------------------------------------------------------------------------------
def pages(root: Path) -> list[Path]:
    """The Markdown files whose tables are generated: README.md and everything under docs/."""
    out = [root / "README.md"] if (root / "README.md").is_file() else []
    return out + sorted((root / "docs").rglob("*.md"))


def is_history_page(text: str) -> bool:
    """Whether a page declares itself a history page (HISTORY_MARK among its first 5 lines)."""
    return any(line.startswith(HISTORY_MARK) for line in text.splitlines()[:5])


def _is_transcribed(data: Path, history: Path) -> bool:
    """Whether a table's data (resolved) is a transcribed CSV: anything under docs/history/, or in a data/tables/
    folder."""
    parts = data.parts
    in_tables = any(a == "data" and b == TRANSCRIBED_FOLDER for a, b in zip(parts, parts[1:]))
    return in_tables or data.is_relative_to(history)


def transcribed_reads(root: Path) -> list[tuple[Path, str]]:
    """(page, data) for every table of a page outside docs/history/ that reads a transcribed CSV."""
    from strings_bench.reports.doc_tables import blocks, parse_spec

    history = (root / HISTORY).resolve()
    out = []
    for page in pages(root):
        if page.resolve().is_relative_to(history):
            continue
        for b in blocks(page.read_text(encoding="utf-8")):
            data, _ = parse_spec(b.spec)
            if _is_transcribed((page.parent / data).resolve(), history):
                out.append((page, data))
    return out


def misplaced_history_pages(root: Path) -> list[Path]:
    """The pages outside docs/history/ that mark themselves history pages (a results page holds derived tables)."""
    history = (root / HISTORY).resolve()
    return [p for p in pages(root) if not p.resolve().is_relative_to(history)
            and is_history_page(p.read_text(encoding="utf-8"))]


def unmarked_history_pages(root: Path) -> list[Path]:
    """The pages under docs/history/ (its README.md aside) that do not say at their top that they are history."""
    history = root / HISTORY
    return [p for p in sorted(history.rglob("*.md")) if p != history / "README.md"
            and not is_history_page(p.read_text(encoding="utf-8"))] if history.is_dir() else []


def refresh(root: Path, check: bool = False) -> list[Path]:
    """Rewrite (or, with `check`, compare) every generated part under `root`; the files that differ(ed)."""
    from strings_bench.core.errors import StringsBenchError
    from strings_bench.reports.doc_tables import refresh_page

    if not (root / "docs").is_dir():
        raise StringsBenchError(f"{root} has no docs/ folder", hint="run it in a source checkout, or pass --root DIR")
    changed = [page for page in pages(root) if refresh_page(page, check=check)]
    ref = root / CLI_REFERENCE
    text = cli_reference()
    if not ref.is_file() or ref.read_text(encoding="utf-8") != text:
        changed.append(ref)
        if not check:
            ref.parent.mkdir(parents=True, exist_ok=True)
            ref.write_text(text, encoding="utf-8")
    return changed


def cmd_refresh(args: argparse.Namespace) -> int:
    root = Path(args.root)
    changed = refresh(root, check=args.check)
    rel = [str(p.relative_to(root)) if p.is_relative_to(root) else str(p) for p in changed]
    if args.check:
        def name(page: Path) -> Path:
            return page.relative_to(root) if page.is_relative_to(root) else page

        reads = transcribed_reads(root)
        for page, data in reads:
            print(f"{name(page)}: a table reads {data}, a transcribed CSV (make it from banked records or a "
                  f"command's output on them, or move the section to a history page under {HISTORY}/)")
        misplaced = misplaced_history_pages(root)
        for page in misplaced:
            print(f"{name(page)}: a history page outside {HISTORY}/ (move it there; the results pages hold "
                  f"derived tables only)")
        unmarked = unmarked_history_pages(root)
        for page in unmarked:
            print(f"{name(page)}: a page under {HISTORY}/ without the history mark at its top ({HISTORY_MARK} ... -->)")
        if changed:
            print("out of date (run `strings-bench docs refresh`): " + ", ".join(rel))
        if changed or reads or misplaced or unmarked:
            return 1
        print("the generated tables and the command-line reference match their sources")
        return 0
    print("rewrote: " + ", ".join(rel) if rel else "nothing to rewrite")
    return 0


# ---- build -------------------------------------------------------------------------------------------
SITE_CONFIG = Path("mkdocs.yml")


def build_site(root: Path, site_dir: Path | None = None) -> Path:
    """Build the documentation site of the checkout `root` with MkDocs in strict mode; the site folder.

    Raises StringsBenchError when MkDocs is not installed, when `root` has no mkdocs.yml, or when the build
    fails (MkDocs' own messages, warnings included, are printed above it)."""
    import subprocess
    import sys

    from strings_bench.core.errors import StringsBenchError

    root = Path(root).resolve()
    config = root / SITE_CONFIG
    if not config.is_file():
        raise StringsBenchError(f"{root} has no {SITE_CONFIG}", hint="run it in a source checkout, or pass --root DIR")
    try:
        import mkdocs  # noqa: F401
        import mkdocstrings  # noqa: F401
        import material  # noqa: F401
    except ImportError as exc:
        raise StringsBenchError(f"the documentation tools are not installed ({exc.name} is missing)",
                                hint='pip install -e ".[docs]"  (bash scripts/bootstrap.sh --test installs them)') from None
    site = Path(site_dir).resolve() if site_dir else root / "build" / "site"
    cmd = [sys.executable, "-m", "mkdocs", "build", "--strict", "--clean", "-f", str(config), "-d", str(site)]
    done = subprocess.run(cmd, cwd=root)
    if done.returncode != 0:
        raise StringsBenchError(f"the documentation site did not build (mkdocs exited with status {done.returncode})",
                                hint="fix the warnings MkDocs printed above: strict mode counts each as an error")
    return site


def cmd_build(args: argparse.Namespace) -> int:
    site = build_site(Path(args.root), Path(args.site_dir) if args.site_dir else None)
    print(f"built the documentation site: {site / 'index.html'}")
    return 0
