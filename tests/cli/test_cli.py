"""The command table: one module per command, imported only when its command runs."""

from __future__ import annotations

import importlib
import json
import subprocess
import sys
from pathlib import Path

import pytest

import strings_bench.cli as cli

ROOT = Path(__file__).resolve().parents[2]

PROBE = """
import json, sys
from strings_bench.cli import main
try:
    main(sys.argv[1:])
except SystemExit:
    pass
print(json.dumps(sorted(m for m in sys.modules if m.startswith(("strings_bench", "torch", "numpy", "PIL")))))
"""


def _modules_after(argv: list[str]) -> tuple[list[str], str]:
    out = subprocess.run([sys.executable, "-c", PROBE, *argv], cwd=ROOT, capture_output=True, text=True, check=True)
    *text, last = out.stdout.strip().splitlines()
    return json.loads(last), "\n".join(text)


def test_top_level_help_imports_no_command_module():
    mods, text = _modules_after(["--help"])
    assert not [m for m in mods if m.startswith("strings_bench.cli.")], mods
    assert not {"torch", "numpy", "PIL"} & set(mods), mods
    for name, cmd in cli.COMMANDS.items():  # the help lists every command from the table
        assert name in text and cmd.help.split()[0] in text


def test_a_command_imports_its_own_module_only():
    mods, text = _modules_after(["cer", "--help"])
    assert [m for m in mods if m.startswith("strings_bench.cli.")] == ["strings_bench.cli.cer"]
    assert "--cer-profile" in text


def test_every_command_module_has_the_interface():
    parser = cli.build_parser()  # every command's full parser
    sub = next(a for a in parser._actions if a.dest == "command")
    helps = {c.dest: c.help for c in sub._choices_actions}
    assert list(sub.choices) == list(cli.COMMANDS)
    for name, cmd in cli.COMMANDS.items():
        assert cmd.module == f"strings_bench.cli.{name}"  # named after its command
        mod = importlib.import_module(cmd.module)
        assert callable(mod.add_parser) and callable(mod.run)
        assert helps[name] == cmd.help  # the module takes its help from the table
        assert sub.choices[name].get_default("func") is mod.run


def test_groups_without_subcommand(capsys):
    assert cli.main(["datasets"]) == 2
    assert "add" in capsys.readouterr().out  # its help, listing the moved subcommands
    assert cli.main(["ocr"]) == 2
    assert cli.main(["methods"]) == 0 and "strings" in capsys.readouterr().out  # lists, as `methods list`


def test_datasets_group_holds_add_check_download():
    parser = cli.build_parser(["datasets"])
    for sub in ("list", "prepare", "add", "check", "download"):
        args = parser.parse_args(["datasets", sub, *(["x", "/tmp"] if sub == "add" else ["x"] if sub == "download" else [])])
        assert args.func.__module__ == "strings_bench.cli.datasets"
    args = parser.parse_args(["--verbose", "datasets", "list"])
    assert args.verbose and args.func.__name__ == "cmd_list"


def test_command_detection():
    assert cli._command_of(["-v", "run", "--methods", "x"]) == "run"
    assert cli._command_of(["--help"]) is None
    assert cli._command_of(["nosuch"]) is None
    with pytest.raises(SystemExit):
        cli.main(["nosuch"])
