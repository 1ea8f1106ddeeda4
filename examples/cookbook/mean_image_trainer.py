"""A stand-in for a trainer of your own, outside strings-bench (docs/cookbook/external.md): a program with its own
command line that reads a scene folder and writes one PNG per test view, here the blend of the training images
nearest in name, sharper with more iterations. It imports nothing from strings-bench.

    python examples/cookbook/mean_image_trainer.py --scene SCENE --iterations N --test-views a.png,b.png --out DIR
"""

import argparse
import json
import zlib
from pathlib import Path

import numpy as np
from PIL import Image


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--scene", required=True, type=Path)
    p.add_argument("--iterations", required=True, type=int)
    p.add_argument("--test-views", required=True)
    p.add_argument("--out", required=True, type=Path)
    a = p.parse_args()
    test = a.test_views.split(",")
    images = sorted(f for f in (a.scene / "images").iterdir() if f.name not in test)
    for name in test:
        order = sorted(images, key=lambda f: zlib.crc32(f"{name}/{f.name}".encode()))  # any fixed order will do
        k = max(1, len(order) // max(1, a.iterations // 100))  # fewer images blended as training goes on
        blend = np.mean([np.asarray(Image.open(f).convert("RGB"), np.float32) for f in order[:k]], axis=0)
        Image.fromarray(blend.round().astype(np.uint8)).save(a.out / f"{Path(name).stem}.png")
    (a.out / "stats.json").write_text(json.dumps({"gaussians": 0, "train_seconds": a.iterations * 1e-3}))


if __name__ == "__main__":
    main()
