"""words.csv (issue 30): one row per reference word and view of a cell; the word-crop figures of results.csv are
its aggregates."""

from __future__ import annotations

import strings_bench.bench as bench
from strings_bench.core.results import CellKey

import csv
import math
from pathlib import Path

import pytest

import runner_fakes as rf
import strings_bench.bench.runner as runner
from strings_bench.store import (WORDS_COLUMNS, WORDS_FILE, ensure_words_csv, read_words_csv, word_rows,
                                           words_summary, write_words_csv)


def _reading(read, nll, errors, nll_chars):
    return {"read": read, "nll": nll, "errors": errors, "nll_chars": nll_chars}


def _record():
    """A hand-made cell: 3 words in 2 views, one infeasible render NLL (stored "inf" as result.json does), one word
    with no scorable character (NLL null), one GT-OCR word that is not a headline word."""
    box = [[0, 0], [40, 0], [40, 10], [0, 10]]
    return {"readability": {"views": {
        "a.png": [
            {"text": "Hello", "source": "known", "headline": True, "polygon": box, "height_px": 10.0, "width_px": 40.0,
             "angle_deg": 12.5, "distance": 3.25, "turn": 0, "chars": 5, "oov_chars": 0,
             "gt": _reading("hello", 2.0, 0, 5), "render": _reading("hallo", 7.5, 1, 5)},
            {"text": "hello", "source": "gt_ocr", "headline": False, "polygon": box, "height_px": 10.0,
             "width_px": 40.0, "angle_deg": None, "distance": None, "turn": 0, "chars": 5, "oov_chars": 0,
             "gt": _reading("hello", 1.0, 0, 5), "render": _reading("", 30.0, 5, 5)}],
        "b.png": [
            {"text": "AB C", "source": "gt_ocr", "headline": True, "polygon": [[0, 0], [30, 0], [30, 6], [0, 6]],
             "turn": 90, "chars": 3, "oov_chars": 1,  # no height_px / width_px: an older cell
             "gt": _reading("abc", 3.0, 0, 2), "render": _reading("a", "inf", 2, 2)},
            {"text": "€", "source": "known", "headline": True, "polygon": box, "height_px": 10.0, "width_px": 40.0,
             "turn": 0, "chars": 1, "oov_chars": 1,
             "gt": _reading("", None, 1, 0), "render": _reading("", None, 1, 0)}]}}}


def test_word_rows_and_summary_against_hand_computed_values(tmp_path):
    rec = _record()
    p = write_words_csv(tmp_path, rec)
    with open(p, newline="") as f:
        raw = list(csv.DictReader(f))
    assert list(raw[0]) == WORDS_COLUMNS and len(raw) == 4
    assert raw[0]["angle_deg"] == "12.5" and raw[0]["distance"] == "3.25" and raw[1]["angle_deg"] == "n/a"
    # the older cell's size comes from its box: 30 x 6
    assert float(raw[2]["width_px"]) == pytest.approx(30.0) and float(raw[2]["height_px"]) == pytest.approx(6.0)
    assert raw[2]["render_nll"] == "inf" and raw[3]["render_nll"] == "nan"
    rows = read_words_csv(p)
    # Headline words: Hello, "AB C", "€" (the GT-OCR "hello" over the known word is not one).
    s = words_summary(rows, "render")
    assert s["word_cer"] == (1 + 2 + 1) / (5 + 3 + 1)
    assert s["word_acc"] == 0.0
    assert s["text_nll"] == 7.5 / 5  # the infeasible word and the unscorable one are left out
    assert (s["words"], s["chars"], s["nll_chars"], s["oov_chars"], s["infeasible_words"]) == (3, 9, 5, 2, 1)
    g = words_summary(rows, "gt")
    assert g["word_cer"] == 1 / 9 and g["word_acc"] == 2 / 3 and g["text_nll"] == (2.0 + 3.0) / (5 + 2)
    k = words_summary(rows, "render", source="gt_ocr")
    assert k["word_cer"] == (5 + 2) / (5 + 3) and k["words"] == 2
    assert math.isnan(words_summary([], "render")["word_cer"])
    # no readability -> no file
    assert write_words_csv(tmp_path / "none", {"readability": None}) is None


def test_runner_cells_write_words_csv_whose_aggregates_equal_results_csv(tmp_path, scene_dir):
    rf.register_fakes()
    out = tmp_path / "run"
    bench.run(["fake-a", "fake-b"], [str(scene_dir)], run_dir=out, schedule="tiny", ocr="fake",
               ocr_backend=rf.FakeOCR(), with_lpips=False, progress=False)
    with open(out / "results.csv", newline="") as f:
        results = list(csv.DictReader(f))
    assert len(results) == 6
    pairs = {"word_cer": ("render", "word_cer"), "word_acc": ("render", "word_acc"), "text_nll": ("render", "text_nll"),
             "word_cer_gt": ("gt", "word_cer"), "text_nll_gt": ("gt", "text_nll"), "read_words": ("render", "words"),
             "read_oov_chars": ("render", "oov_chars")}
    distinct = set()
    for r in results:
        cell = CellKey(r["method"], r["dataset"], r["scene"], int(r["iteration"])).path(out)
        rows = read_words_csv(cell / WORDS_FILE)
        assert rows and {w["source"] for w in rows} == {"known", "gt_ocr"}
        assert all(w["height_px"] > 0 and w["width_px"] > 0 for w in rows)
        assert all(w["angle_deg"] is None and w["distance"] is None for w in rows)  # the toy scene does not know them
        for col, (side, key) in pairs.items():
            got = words_summary(rows, side)[key]
            want = float(r[col])
            assert got == want or (math.isnan(got) and math.isnan(want)), (r["method"], r["iteration"], col)
        distinct.add(r["text_nll"])
    assert len(distinct) > 1  # the cells differ, so the equality above is not one number checked six times


def test_ensure_words_csv_backfills_older_cells(tmp_path, scene_dir):
    rf.register_fakes()
    out = tmp_path / "run"
    bench.run(["fake-a"], [str(scene_dir)], run_dir=out, schedule="tiny", ocr="fake", ocr_backend=rf.FakeOCR(),
               with_lpips=False, progress=False, write_report=False)
    files = sorted(Path(out, "cells").glob(f"*/*/*/*/{WORDS_FILE}"))
    assert len(files) == 3
    before = {p: p.read_text() for p in files}
    for p in files:
        p.unlink()
    assert ensure_words_csv(out) == 3
    assert {p: p.read_text() for p in files} == before
    assert ensure_words_csv(out) == 0
    import json

    rec = json.loads((files[0].parent / "result.json").read_text())
    assert len(word_rows(rec)) == sum(len(v) for v in rec["readability"]["views"].values())
