"""Cookbook: an existing trainer wrapped by the built-in method `external` (docs/cookbook/external.md). The method
runs a command per checkpoint and reads the renders it wrote; here the command is mean_image_trainer.py.

Run it:  python examples/cookbook/wrap_external.py
"""

from __future__ import annotations

import sys
from pathlib import Path

TRAINER = Path(__file__).with_name("mean_image_trainer.py")
# The placeholders are filled per checkpoint: {scene} the scene folder, {iteration}, {test_views} the test images'
# names, {out} an empty folder for the renders (and stats.json).
COMMAND = (f"{sys.executable} {TRAINER} --scene {{scene}} --iterations {{iteration}} "
           "--test-views {test_views} --out {out}")


def main() -> None:
    from strings_bench.bench.check import tiny_scene
    from strings_bench.methods import get_method
    from strings_bench.scene.scene import Scene

    scene = Scene.load(tiny_scene())
    external = get_method("external").build(command=COMMAND, timeout=60)
    for result in external.train(scene, checkpoints=[100, 300]):
        shapes = {f"{im.shape[1]}x{im.shape[0]}" for im in result.renders.values()}
        print(f"iteration {result.iteration}: {len(result.renders)} render(s) of {', '.join(sorted(shapes))}, "
              f"train_seconds {result.train_seconds:.1f} (from stats.json)")


if __name__ == "__main__":
    main()
