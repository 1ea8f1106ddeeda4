"""CLI: `strings-bench compare RUN_DIR...`: the paper's tables over run folders of several seeds."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from strings_bench.cli import command_help


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    from strings_bench.reports.compare import PAPER_DATASET, VALUES

    p = subparsers.add_parser(
        "compare", help=command_help("compare"),
        description="The paper's tables (CER at 7K/30K, training time, PSNR/SSIM/LPIPS/Gaussians, ablations) over run "
                    "folders of one seed each: mean over scenes, then over seeds with the seeds' range, the paper's "
                    "figures beside, and whether the seeds decide each method against STRinGS (or --against METHOD; "
                    "reports/compare/). "
                    "Scene draws (ROOM@N, docs/guide/datasets.md) count like seeds: the mean over draws with the range over "
                    "seeds and draws, and per room and over all rooms the mean over draws with the draws' range.")
    p.add_argument("run_dirs", nargs="+", type=Path, help="run folders, one seed each")
    p.add_argument("--dataset", default=None, help="only this dataset's cells (e.g. synthetic360-cpu)")
    p.add_argument("--methods", default=None, type=_names,
                   help="only these methods (comma-separated spec names, e.g. 3dgs,strings): the scenes every "
                        "method shares are found among these")
    p.add_argument("--scenes", default=None, type=_names,
                   help="only these scenes (comma-separated, e.g. storeroom,pantry,office for draw 0 of the "
                        "three rooms; a draw is ROOM@N)")
    p.add_argument("--out", type=Path, default=None,
                   help="write comparison.md, comparison.tex, comparison.csv and index.html there (default: "
                        "<first run folder>/comparison)")
    p.add_argument("--paper-dataset", default=PAPER_DATASET,
                   help=f"the paper's dataset whose figures stand beside (default {PAPER_DATASET})")
    p.add_argument("--per-scene", metavar="VALUE", default=None, choices=VALUES,
                   help="also list VALUE (cer, cer_known, word_cer, ...) per method, checkpoint and scene, every seed")
    p.add_argument("--against", metavar="METHOD", default=None,
                   help="hold every method against METHOD in 'Decided or not' (a spec name, e.g. edc-absgs; "
                        "default: STRinGS)")
    p.add_argument("--json", action="store_true", help="print the numbers as JSON instead of Markdown")
    p.set_defaults(func=run)
    return p


def _names(text: str) -> list[str]:
    names = [n.strip() for n in text.split(",") if n.strip()]
    if not names:
        raise argparse.ArgumentTypeError("give one name or more, comma-separated")
    return names


def run(args: argparse.Namespace) -> int:
    from strings_bench.reports.compare import compare, comparison_markdown, write_comparison

    c = compare(args.run_dirs, args.dataset, args.paper_dataset, args.methods, args.scenes, args.against)
    out = args.out or args.run_dirs[0] / "comparison"
    written = write_comparison(c, out, args.per_scene)
    print(json.dumps(c.numbers, indent=1) if args.json else comparison_markdown(c, args.per_scene))
    print(f"written: {', '.join(str(p) for p in written.values())}")
    return 0
