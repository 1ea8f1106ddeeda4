"""Readability analysis (issue 30): CER by text size, time to legibility, the speed/accuracy front; each checked
against values worked out by hand, and the report's Markdown and LaTeX carrying them."""

from __future__ import annotations

import math

import pandas as pd
import pytest

from strings_bench.reports import readability_analysis as ra
from strings_bench.reports.table_model import GT_CEILING, to_latex, to_markdown


def test_time_to_threshold_interpolates_between_the_straddling_checkpoints():
    c = ra.time_to_threshold([100, 200, 300], [10.0, 20.0, 40.0], [0.9, 0.6, 0.3], 0.5)
    # 0.6 -> 0.3 crosses 0.5 a third of the way: step 200 + 100/3, seconds 20 + 20/3
    assert c.step == pytest.approx(233.3333333) and c.seconds == pytest.approx(26.6666667) and not c.at_first
    # given out of order: sorted by step first
    assert ra.time_to_threshold([300, 100, 200], [40.0, 10.0, 20.0], [0.3, 0.9, 0.6], 0.5) == c
    # not reached; equal to the threshold is not below it
    assert ra.time_to_threshold([100, 200], [1, 2], [0.9, 0.5], 0.5) is None
    # below at the first checkpoint: that checkpoint, flagged as an upper bound
    first = ra.time_to_threshold([100, 200], [5, 9], [0.4, 0.1], 0.5)
    assert (first.step, first.seconds, first.at_first) == (100, 5, True)
    # the FIRST fall below counts even when the curve comes back up
    again = ra.time_to_threshold([1, 2, 3, 4], [1, 2, 3, 4], [0.9, 0.4, 0.7, 0.1], 0.5)
    assert again.step == pytest.approx(1 + 0.4 / 0.5)
    # NaN checkpoints are skipped: the crossing is interpolated between 100 (0.8) and 300 (0.2)
    nan = ra.time_to_threshold([100, 200, 300], [1, 2, 3], [0.8, math.nan, 0.2], 0.5)
    assert nan.step == pytest.approx(200.0) and nan.seconds == pytest.approx(2.0)
    assert ra.time_to_threshold([], [], [], 0.5) is None


def test_pareto_front_hand_cases():
    pts = {"a": (1.0, 0.9), "b": (2.0, 0.5), "c": (3.0, 0.6), "d": (2.0, 0.5), "e": (math.nan, 0.1), "f": (5.0, 0.4)}
    # c is beaten by b on both; b and d tie (neither beats the other); e has no time; f is slowest but best
    assert ra.pareto_front(pts) == ["a", "b", "d", "f"]
    assert ra.pareto_front({"x": (1.0, 1.0), "y": (1.0, 0.5)}) == ["y"]  # equal time, better value dominates
    assert ra.pareto_front({"x": (1.0, 0.5), "y": (2.0, 0.5)}) == ["x"]
    assert ra.pareto_front({}) == []


def test_size_bins_are_half_open():
    assert [ra.size_bin(h) for h in (0.5, 5.999, 6.0, 8.99, 9.0, 13.0, 19.9, 20.0, 300.0)] == \
        ["<6", "<6", "6-9", "6-9", "9-13", "13-20", "13-20", ">=20", ">=20"]
    assert ra.size_bin(math.nan) is None and ra.size_bin(None) is None


def _words():
    """Two methods on two scenes at label 7K: hand-made words.csv rows."""
    rows = []

    def add(method, scene, height, chars, render_errors, gt_errors, source="known", headline=1, label="7K"):
        rows.append({"method": method, "dataset": "synthetic", "scene": scene, "iteration": 70, "label": label,
                     "height_px": height, "chars": chars, "render_errors": render_errors, "gt_errors": gt_errors,
                     "source": source, "headline": headline})

    for m, errs in (("3dgs", (4, 1, 0)), ("strings", (2, 3, 1))):
        add(m, "s1", 5.0, 4, errs[0], 1)            # <6
        add(m, "s1", 7.0, 5, errs[1], 0, "gt_ocr")  # 6-9
        add(m, "s2", 8.0, 6, errs[2], 2)            # 6-9
        add(m, "s2", 8.0, 3, 3, 3, "gt_ocr", headline=0)  # not a headline word: left out
        add(m, "s2", 8.0, 9, 9, 9, label="3K")      # another checkpoint: left out
    w = pd.DataFrame(rows)
    w["bin"] = [ra.size_bin(h) for h in w["height_px"]]
    return w


def test_cer_by_size_pools_the_scenes_and_adds_the_gt_ceiling(monkeypatch):
    monkeypatch.setattr(ra, "MIN_BIN_WORDS", 2)
    t = ra.cer_by_size(_words(), "7K").set_index(["method", "bin"])
    assert t.loc[("3dgs", "<6"), "cer"] == 4 / 4 and t.loc[("strings", "<6"), "cer"] == 2 / 4
    assert t.loc[("3dgs", "6-9"), "cer"] == (1 + 0) / (5 + 6) and t.loc[("strings", "6-9"), "cer"] == (3 + 1) / 11
    assert t.loc[(GT_CEILING, "6-9"), "cer"] == (0 + 2) / 11 and t.loc[(GT_CEILING, "<6"), "cer"] == 1 / 4
    assert t.loc[("3dgs", "6-9"), "words"] == 2 and t.loc[("3dgs", "<6"), "words"] == 1
    assert bool(t.loc[("3dgs", "<6"), "greyed"]) and not bool(t.loc[("3dgs", "6-9"), "greyed"])
    assert t.loc[("3dgs", ">=20"), "words"] == 0 and math.isnan(t.loc[("3dgs", ">=20"), "cer"])
    k = ra.cer_by_size(_words(), "7K", known=True).set_index(["method", "bin"])
    assert k.loc[("strings", "6-9"), "cer"] == 1 / 6 and k.loc[("strings", "6-9"), "words"] == 1
    spread = ra.size_spread(ra.cer_by_size(_words(), "7K"))
    assert list(spread["bin"]) == ["6-9"] and spread["spread"].iloc[0] == pytest.approx(4 / 11 - 1 / 11)


def test_greyed_bins_are_never_ranked_and_shown_greyed(monkeypatch):
    monkeypatch.setattr(ra, "MIN_BIN_WORDS", 2)
    t = ra.size_table(ra.cer_by_size(_words(), "7K"), "7K", known=False)
    md = to_markdown(t)
    lines = md.splitlines()
    assert "<6 px (n=1)" in lines[0] and "6-9 px (n=2)" in lines[0] and ">=20" not in lines[0]  # empty bins left out
    row = {ln.split("|")[1].strip(): [c.strip() for c in ln.split("|")[2:-1]] for ln in lines[2:]}
    assert row["STRinGS"][0] == "_0.500_"  # the better value of a greyed bin: greyed, not ranked
    assert row["3DGS"][1] == "0.091 **(1)**" and row["STRinGS"][1] == "0.364 (2)"
    tex = to_latex(t)
    assert r"\textcolor{gray}{0.500}" in tex and r"\cellcolor{first}0.091" in tex
    assert r"\cellcolor{first}\textcolor{gray}" not in tex


def test_time_to_legibility_table(monkeypatch):
    df = pd.DataFrame({
        "method": ["3dgs"] * 3 + ["strings"] * 3, "dataset": "synthetic", "scene": "s1",
        "iteration": [100, 200, 300] * 2, "label": ["1K", "2K", "3K"] * 2,
        "total_seconds": [60.0, 120.0, 180.0, 90.0, 150.0, 210.0],
        "word_cer": [0.9, 0.6, 0.4, 0.7, 0.45, 0.3], "cer": [1.0, 1.0, 0.95, 1.0, 0.9, 0.85]})
    leg = ra.legibility(df, thresholds=(0.5,)).set_index(["method", "metric"])
    assert leg.loc[("3dgs", "word_cer"), "step"] == pytest.approx(250.0)
    assert leg.loc[("3dgs", "word_cer"), "minutes"] == pytest.approx(2.5)
    assert leg.loc[("strings", "word_cer"), "step"] == pytest.approx(100 + 100 * 0.2 / 0.25)
    assert not leg.loc[("strings", "cer"), "reached"]
    md = to_markdown(ra.legibility_table(ra.legibility(df, thresholds=(0.5,))))
    assert "not reached" in md and "2.50 (250)" in md



def test_size_label_is_the_latest_checkpoint_the_most_methods_reached():
    df = pd.DataFrame({"method": ["a", "a", "a", "b", "b"], "label": ["3K", "7K", "30K", "3K", "7K"],
                       "dataset": "d", "scene": "s"})
    assert ra.size_label(df) == "7K"
    df["evaluation"] = ["full", "full", "full", "full", "words"]  # b's 7K is a dense (word-crop only) checkpoint
    assert ra.size_label(df) == "3K"
    assert ra.size_label(df.iloc[:0]) is None
