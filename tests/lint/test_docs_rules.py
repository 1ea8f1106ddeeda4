"""The user guide and the README hold the user's task only: no dates, commit hashes, load averages or the project's
own run folders (history goes to CHANGELOG.md, measurements to docs/results/, the GPU campaign to
docs/maintainers/); README's links resolve, anchors included; and a figure stated in several places has one source
(the default run's time: `core.schedules.DEFAULT_RUN_TIME`, held to its measurement)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
DOCS = ROOT / "docs"
# cli.md is generated from the parsers (its text is --help's, checked by test_docs.py)
GUIDE = sorted(p for p in (DOCS / "guide").glob("*.md") if p.name != "cli.md")
USER_TEXT = [ROOT / "README.md", *GUIDE]

DATE = r"\b20\d\d-[01]\d-[0-3]\d\b"
COMMIT = r"\b(?=[0-9a-f]*\d)(?=[0-9a-f]*[a-f])[0-9a-f]{7,40}\b"  # hex with a digit and a letter
LOAD = r"\bload averages?\b|\buptime\b|\bload of \d|\(load \d"
HISTORY = re.compile("|".join([DATE, COMMIT, LOAD]), re.I)


def project_run_folders() -> set[str]:
    """The run folders the project's own studies name (docs/results/): never examples in the user's guide."""
    names = set()
    for page in (DOCS / "results").rglob("*.md"):
        names |= set(re.findall(r"\bruns/([\w.@+-]+)", page.read_text(encoding="utf-8")))
    generic = {"default", "evaluate", "gpu_check", "first", "smoke"}  # the defaults and the guide's own examples
    return {f"runs/{n.rstrip('.')}" for n in names} - {f"runs/{g}" for g in generic}


def history_in(text: str, run_folders: set[str]) -> list[str]:
    found = [m.group(0) for m in HISTORY.finditer(text)]
    found += [r for r in run_folders if re.search(rf"{re.escape(r)}(?![\w.@+-])", text)]
    return found


def test_the_matcher_finds_planted_history():
    planted = ("Measured on 2026-11-28 with commit 142d0ce (load average 5 to 11); "
               "see strings-bench compare runs/s360long-7k")
    found = history_in(planted, {"runs/s360long-7k"})
    assert len(found) == 4, found
    assert history_in("a 320x240 scene, 3K/7K/30K, sha256 of the pixels, cafe, runs/default", {"runs/s360long-7k"}) == []


def test_project_run_folders_are_known():
    assert "runs/s360long-7k" in project_run_folders()  # the study folders the results pages name


@pytest.mark.parametrize("page", USER_TEXT, ids=lambda p: str(p.relative_to(ROOT)))
def test_no_history_in_the_guide(page):
    found = history_in(page.read_text(encoding="utf-8"), project_run_folders())
    assert not found, f"{page.relative_to(ROOT)}: {found} (history: CHANGELOG.md; measurements: docs/results/)"


def test_a_planted_date_or_hash_in_the_guide_fails(tmp_path):
    page = (DOCS / "guide" / "running.md").read_text(encoding="utf-8")
    for planted in ("Measured on 2026-11-30.", "Since commit 0368c75 the loop is faster.", "(load average 9)"):
        assert history_in(page + "\n" + planted + "\n", project_run_folders()), planted


# ---- README's links ----------------------------------------------------------------------------------------------
def slug(heading: str) -> str:
    """The anchor MkDocs (Python-Markdown's toc) and GitHub give a heading, for the headings these pages use."""
    text = re.sub(r"[`*_]", "", heading).strip().lower()
    text = re.sub(r"[^\w\s-]", "", text)
    return re.sub(r"[\s]+", "-", text)


def anchors(page: Path) -> set[str]:
    text = re.sub(r"```.*?```", "", page.read_text(encoding="utf-8"), flags=re.S)
    return {slug(h) for h in re.findall(r"^#{1,6} (.+?)\s*$", text, re.M)}


def test_slug_matches_the_site():
    assert slug("Checking a method: `methods check`") == "checking-a-method-methods-check"
    assert slug("Your own photos: `prepare`") == "your-own-photos-prepare"


def test_readme_links_resolve_with_their_anchors():
    broken = []
    for target in re.findall(r"\]\(([^)\s]+)\)", (ROOT / "README.md").read_text(encoding="utf-8")):
        if re.match(r"^[a-z]+:", target):
            continue
        path, _, anchor = target.partition("#")
        file = ROOT / path if path else ROOT / "README.md"
        if not file.exists():
            broken.append(target)
        elif anchor and file.suffix == ".md" and anchor not in anchors(file):
            broken.append(target)
    assert not broken, broken


# ---- one source per figure ---------------------------------------------------------------------------------------
def test_default_run_time_is_its_measurement():
    import pandas as pd

    from strings_bench.core.schedules import DEFAULT_RUN_MINUTES

    data = pd.read_csv(DOCS / "results" / "data" / "engine-stages" / "demo-fresh-clone-4.csv")
    run = data[data.iloc[:, 0].str.startswith("the run")].iloc[0, 1]
    assert round(float(run) / 60) == DEFAULT_RUN_MINUTES, (run, DEFAULT_RUN_MINUTES)


def test_default_run_time_is_stated_from_its_one_source():
    """`run --help` (hence cli.md and the report) and the README give DEFAULT_RUN_TIME; no page gives another."""
    from strings_bench.cli import build_parser
    from strings_bench.core.schedules import DEFAULT_RUN_TIME, SCHEDULES

    assert DEFAULT_RUN_TIME in SCHEDULES["cpu"].description
    sub = next(a for a in build_parser(["run"])._actions if a.choices and "run" in a.choices)
    assert DEFAULT_RUN_TIME in " ".join(sub.choices["run"].format_help().split())
    assert DEFAULT_RUN_TIME in (DOCS / "guide" / "cli.md").read_text(encoding="utf-8")
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    assert DEFAULT_RUN_TIME in " ".join(readme.split())
    stray = re.compile(r"(default run|demo\.sh)[^.\n]{0,80}?\b\d+(?:-\d+)? ?(?:min|minutes)\b"
                       r"|\b(?:ten|five) minutes\b", re.I)
    found = {str(p.relative_to(ROOT)): [m.group(0) for m in stray.finditer(
        " ".join(p.read_text(encoding="utf-8").split()).replace(DEFAULT_RUN_TIME, ""))] for p in USER_TEXT}
    assert not {k: v for k, v in found.items() if v}, found


NUMBERS = {"two": 2, "three": 3, "four": 4, "five": 5, "six": 6, "seven": 7, "eight": 8, "nine": 9, "ten": 10}


def _stated(pattern: str, text: str) -> list[int]:
    return [NUMBERS[m.lower()] if m.lower() in NUMBERS else int(m) for m in re.findall(pattern, text, re.I)]


def test_counts_of_methods_and_scenes_are_the_registries():
    """"six other Gaussian Splatting methods" (README) is the registry's count of published baselines besides 3DGS;
    "the five synthetic scenes" (the guide, and `run --help` through cli.md) is the synthetic card's."""
    from strings_bench.datasets.registry import get_dataset
    from strings_bench.methods.registry import builtin_specs  # not list_methods: other tests register methods

    others = [s for s in builtin_specs() if s.group == "baseline" and s.name != "3dgs"
              and not s.description.startswith("this suite's variant")]
    readme = " ".join((ROOT / "README.md").read_text(encoding="utf-8").split())
    assert _stated(r"\b(\w+) other Gaussian Splatting methods", readme) == [len(others)], [s.name for s in others]
    n_synthetic = len(get_dataset("synthetic").scenes)
    texts = [readme, *(" ".join(p.read_text(encoding="utf-8").split()) for p in [*GUIDE, DOCS / "guide" / "cli.md"])]
    number = "|".join(NUMBERS) + r"|\d+"
    stated = [n for t in texts for n in _stated(rf"\b({number}) synthetic scenes\b", t)]
    assert stated and set(stated) == {n_synthetic}, (stated, n_synthetic)
