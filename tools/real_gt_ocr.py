"""What an OCR engine reads on a real scene's GT test views (e.g. saharov32 with Tesseract rus).

For each downscale and engine: the test views read through the evaluation text mask as the runner reads
them (and, for comparison, the whole image): words and characters read per view, and the texts. A scene
whose GT reads few characters cannot rank methods by OCR-CER (docs/guide/datasets.md, "saharov32").

    python tools/real_gt_ocr.py SCENE --ocr tesseract:lang=rus --ocr tesseract:lang=rus:upscale=3:mask_fill=128 \\
        --downscale 1,2,4
"""

from __future__ import annotations

import argparse

from strings_bench.eval.ocr import get_engine
from strings_bench.eval.protocol import scene_views, to_uint8
from strings_bench.scene.scene import Scene


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scene")
    ap.add_argument("--ocr", action="append", default=None)
    ap.add_argument("--downscale", default="1,2,4")
    args = ap.parse_args()
    scene = Scene.load(args.scene)
    print("| downscale | engine | read through | views | words | characters (no spaces) | texts |")
    print("|---|---|---|---|---|---|---|")
    for ds in (float(x) for x in args.downscale.split(",")):
        views = scene_views(scene, ds)
        for spec in args.ocr or ["tesseract:lang=rus"]:
            engine = get_engine(spec)
            for how in ("mask", "whole image"):
                reads = [engine.read(to_uint8(v.gt), mask=v.mask if how == "mask" else None) for v in views]
                words = [w for r in reads for w in r]
                chars = sum(len(w.text.replace(" ", "")) for w in words)
                texts = " / ".join(" ".join(w.text for w in r) or "-" for r in reads)
                print(f"| {ds:g} | {spec} | {how} | {len(views)} | {len(words)} | {chars} | {texts[:200]} |", flush=True)


if __name__ == "__main__":
    main()
