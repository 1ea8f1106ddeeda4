"""The run folder's schema: its file names, the columns of results.csv and words.csv, and the former names of its
fields, under which folders written by older versions of the suite are read as today's (`upgrade_names`)."""

from __future__ import annotations

from strings_bench.core.results import RESULT_FILE, RESULTS_CSV, RUN_FILE  # noqa: F401 - the run folder's file names

# Word-crop readability (eval.readability) of the render, its GT-view ceiling (_gt), and the text-region image
# metrics (eval.metrics.text_region_metrics); read_words / read_oov_chars count the reference words and the
# reference characters outside the recogniser's dictionary.
READABILITY_COLUMNS = ["word_cer", "word_acc", "text_nll", "text_psnr", "text_ssim", "text_lpips", "word_cer_gt",
                       "text_nll_gt", "read_words", "read_oov_chars"]
CSV_COLUMNS = [
    "method", "dataset", "scene", "iteration", "label", "cer", "cer_known", "psnr", "ssim", "lpips",
    *READABILITY_COLUMNS,
    "train_seconds", "preprocess_seconds", "total_seconds", "train_cpu_seconds", "gaussians", "budget", "peak_gaussians", "budget_reached_at",
    "peak_memory_mb", "peak_memory_scope", "cer_errors", "cer_chars", "cer_views", "ocr_failed",
    "gt_empty_ignored", "known_views", "eval_seconds", "schedule", "downscale", "ocr_backend",
]
# Former names of the run folder's fields: "preset" named the run's schedule before "schedule" did (run.json,
# result.json's config, results.csv's column); the readers of the store take such folders as today's.
FORMER_NAMES = {"preset": "schedule"}


def upgrade_names(d: dict) -> dict:
    """`d` (run.json, a cell's config, a results.csv row) with its former field names as today's (FORMER_NAMES);
    a field present under both names keeps today's."""
    out = dict(d)
    for old, new in FORMER_NAMES.items():
        if old in out:
            value = out.pop(old)
            out.setdefault(new, value)
    return out



# Per further OCR engine E of `run --ocr PRIMARY,E` (its name replaces {engine}): its CER and known-text CER
# (the primary's keep the names cer / cer_known), the views it failed on, and its agreement with the
# primary engine (cer.word_agreement): text regions and those read identically, on the render views
# and on the GT views.
ENGINE_COLUMNS = ["cer_{engine}", "cer_known_{engine}", "ocr_failed_{engine}", "agree_words_{engine}",
                  "agree_identical_{engine}", "agree_gt_words_{engine}", "agree_gt_identical_{engine}"]

# One row per reference word and view of the word-crop readability (eval.readability): the word, where it came
# from, its box's size at the evaluated resolution, the viewing angle and distance where the scene knows them
# (synthetic scenes; "n/a" elsewhere), and what the recogniser read on the GT crop and on the render crop. The
# cell's word-crop figures (results.csv: word_cer, word_acc, text_nll and their _gt ceilings) are sums over these
# rows (`words_summary`); floats are written with repr, so they read back exactly.
WORDS_FILE = "words.csv"
WORDS_COLUMNS = ["view", "word", "source", "headline", "height_px", "width_px", "angle_deg", "distance", "turn",
                 "chars", "oov_chars", "gt_read", "gt_errors", "gt_nll", "gt_nll_chars", "render_read",
                 "render_errors", "render_nll", "render_nll_chars"]
NA = "n/a"
