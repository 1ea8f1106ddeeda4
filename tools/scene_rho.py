"""rho (one 3DGS position step in text strokes) of named scenes, as a CSV.

    python tools/scene_rho.py [[LABEL=]SCENE ...] [--csv FILE]

SCENE is a dataset id with a scene (default: the three synthetic360-cpu rooms, draw 0), built or located as
`strings-bench datasets prepare` does, or a scene folder (e.g. a room built with other difficulty settings,
named by LABEL in the table). Prints one row per scene (extent, median stroke in world units and
pixels, words measured, rho, where the strokes were measured and whether they were thick enough there to read
true; strings_bench/scene/difficulty.py) and, with `--csv`, writes them (the table of docs/results/difficulty.md).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from strings_bench.reports.doc_tables import write_csv
from strings_bench.scene.difficulty import recorded_difficulty
from strings_bench.datasets.registry import resolve_scenes
from strings_bench.scene.scene import Scene

DEFAULT = ["synthetic360-cpu/storeroom", "synthetic360-cpu/pantry", "synthetic360-cpu/office"]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("scenes", nargs="*", default=DEFAULT)
    ap.add_argument("--csv", type=Path, default=None)
    args = ap.parse_args(argv)
    rows = [["scene", "extent", "median stroke (world)", "median stroke (px)", "words", "rho", "strokes measured on",
             "reliable"]]
    for arg in args.scenes:
        label, _, spec = arg.rpartition("=")
        spec = spec or arg
        ref = resolve_scenes([spec])[0]
        d = recorded_difficulty(Scene.load(ref.path, settings=ref.settings))
        if d.rho is None:
            rows.append([label or spec, f"{d.extent:.3g}", "", "", "0", "", d.measured_on, ""])
        else:
            rows.append([label or spec, f"{d.extent:.3g}", f"{d.stroke_world:.4f}", f"{d.stroke_px:.2f}", str(d.words),
                         f"{d.rho:.3f}", d.measured_on, "yes" if d.reliable else "no"])
        print(",".join(rows[-1]))
    if args.csv is not None:  # quoted where a label has a comma in it (--text-px 10,16)
        write_csv(args.csv, rows)
    return 0


if __name__ == "__main__":
    sys.exit(main())
