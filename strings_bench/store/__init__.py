"""The run folder: what a run (or `strings-bench evaluate`) writes and what the reports read back.

    RUN_DIR/
      run.json                 the run's settings (manifest.py: read_manifest, write_manifest, check_manifest)
      results.csv              one row per cell, rebuilt from the cells (table.py: cell_row, write_results_csv)
      cells/<method>/<dataset>/<scene>/<iteration>/
          result.json          one cell (cells.py: CellRecord, CellConfig, write_cell, read_cell, iter_cells)
          words.csv            its per-word records (words.py)
          renders/<view stem>.png
      gt/<dataset>/<scene>/<view stem>.png
      .run.lock                held by the run writing here (lock.py: run_folder_lock, run_folder_busy)

The schema (file names, columns) and the former field names under which older folders are read as today's are
schema.py. This layer sits below `bench/` (which writes through it) and `reports/` (which only reads it), and
imports neither (docs/architecture.md).
"""

from __future__ import annotations

from pathlib import Path

from strings_bench.core.results import CellKey, is_finished, safe_name
from strings_bench.core.schedules import iteration_label
from strings_bench.store.cells import (CellConfig, CellRecord, check_cell, ensure_words_csv, iter_cells, read_cell,
                                       read_json, render_file_name, write_cell, write_png)
from strings_bench.store.lock import LOCK_FILE, run_folder_busy, run_folder_lock
from strings_bench.store.manifest import check_manifest, read_manifest, write_manifest
from strings_bench.store.schema import (CSV_COLUMNS, ENGINE_COLUMNS, FORMER_NAMES, NA, READABILITY_COLUMNS,
                                        RESULT_FILE, RESULTS_CSV, RUN_FILE, WORDS_COLUMNS, WORDS_FILE, upgrade_names)
from strings_bench.store.table import (budget_column, cell_row, engine_columns, readability_columns, script_columns,
                                       timing_columns, write_results_csv)
from strings_bench.store.words import read_words_csv, word_rows, words_csv_text, words_summary, write_words_csv

__all__ = [
    "CellConfig", "CellKey", "CellRecord", "CSV_COLUMNS", "ENGINE_COLUMNS", "FORMER_NAMES", "LOCK_FILE", "NA", "READABILITY_COLUMNS",
    "RESULT_FILE", "RESULTS_CSV", "RUN_FILE", "WORDS_COLUMNS", "WORDS_FILE", "budget_column", "cell_row",
    "check_cell", "check_manifest", "engine_columns", "ensure_words_csv", "is_finished", "iter_cells",
    "iteration_label", "read_cell", "read_json", "read_manifest", "read_words_csv", "readability_columns", "refresh",
    "render_file_name", "run_folder_busy", "run_folder_lock", "safe_name", "script_columns", "timing_columns", "upgrade_names", "word_rows",
    "words_csv_text", "words_summary", "write_cell", "write_manifest", "write_png", "write_results_csv",
    "write_words_csv",
]


def refresh(run_dir: str | Path) -> None:
    """Bring a run folder's derived files up to date with its cells: results.csv rebuilt from them (they are the
    truth), words.csv written for cells that lack one (written before it existed). `strings-bench report` calls
    it before the report is read."""
    if (Path(run_dir) / "cells").is_dir():
        write_results_csv(run_dir)
        ensure_words_csv(run_dir)
