"""The paper's tables over run folders of several seeds (`strings-bench compare RUN_DIR...`).

Along its jobs: collect.py reads the cells of the folders (`collect`, `common_scenes`), statistics.py turns them
into the numbers (`summarise`, `decided`, `Comparison`, `compare`, `decided_rows`), tables.py builds the tables
(`comparison_tables`, `draws_tables`) and writers.py writes them as Markdown, LaTeX, CSV and HTML
(`write_comparison`).

Each run folder holds one seed (`strings-bench calibrate --seed N`, or `run --set seed=N`); a cell's seed is read
from its own settings (0 when none was given). For each method, in the registry's (the paper's) order:

- CER at 7K and 30K (the paper's Table "OCR-CER"): OCR-CER, the known-text CER the CPU regime is judged by
  (OCR-CER saturates at 320x240) and the word CER, each the mean over the scenes of one seed, then the mean over
  the seeds with the seeds' range; the paper's own OCR-CER beside, from the method's spec (`PaperFigures`);
- training time in minutes at 7K and 30K (the paper's Table "Training Time"), with the paper's minutes beside
  (folders measured under different load are not comparable: say so beside the table);
- PSNR, SSIM, LPIPS and Gaussians at 30K (the paper's appendix table);
- the ablations (its Table "Ablations"): every method whose spec names `ablation_of`, beside that method, at the
  checkpoint the spec names (`ablation_at`), or the last both have where the folders lack it (the caption says so);
- "decided / not decided": each method against STRinGS (the spec of group "ours") where both have several seeds:
  decided when the seeds' ranges do not overlap. Beside it, the (seed, draw) replicates in which the method is below STRinGS
  (`paired_lower`), which never changes the verdict.

Scene draws (core/draws.py) count like seeds: a cell of scene `pantry@1` is room pantry at draw 1, and
a (seed, draw) pair is one *replicate*. Each replicate's figure is the mean over the rooms every replicate has; a
method's mean is the mean over the draws of the mean over the seeds of each draw (= the mean over seeds when there
is one draw, today's figure), and its range, the one "decided" reads, is over every replicate (seeds and draws).
With several draws the comparison adds, per CER value, the mean over draws with the draws' range per room and
over all rooms (`draws_tables`); the per-scene rows stay (`per_scene_table`).

`methods` and `scenes` (`--methods`, `--scenes`) choose the cells before anything else.
Only fully evaluated checkpoints count (not the word-crop-only ones of `--checkpoints every:N`). Every method is
held to the scenes all methods have at that checkpoint (`common_scenes`: a folder still filling, or a draw trained
for some methods only, would otherwise rank methods on different rooms). Within a method, a ragged coverage keeps
the replicates that have every room or every replicate over the rooms they all have, whichever keeps more cells.
What is held back is listed, not averaged. The same cell in two folders counts once when its figures agree and is an error when they differ.
Written as Markdown, LaTeX, CSV and an HTML page in the run report's style (`write_comparison`).
"""

from __future__ import annotations

from strings_bench.reports.compare.collect import VALUES, cell_seed, collect, common_scenes
from strings_bench.reports.compare.statistics import (CER_VALUES, PAPER_DATASET, Comparison, compare, decided,
                                                      decided_rows, mean_of, paired_lower, room_draw, summarise)
from strings_bench.reports.compare.tables import DRAWS_NOTE, SEEDS_NOTE, comparison_tables, draws_tables, has_draws
from strings_bench.reports.compare.writers import (DECIDED_CAPTION, comparison_csv, comparison_from_csv, comparison_html,
                                                   comparison_markdown,
                                                   per_scene_table, write_comparison)

__all__ = ["CER_VALUES", "Comparison", "DECIDED_CAPTION", "DRAWS_NOTE", "PAPER_DATASET", "SEEDS_NOTE", "VALUES",
           "cell_seed", "collect", "common_scenes", "compare", "comparison_csv", "comparison_from_csv", "comparison_html", "comparison_markdown",
           "comparison_tables", "decided", "decided_rows", "draws_tables", "has_draws", "mean_of", "paired_lower",
           "per_scene_table", "room_draw", "summarise", "write_comparison"]
