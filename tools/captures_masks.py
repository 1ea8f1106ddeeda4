"""A montage of the OCR text masks of the `captures` scenes, to check them by eye.

    python tools/captures_masks.py [--out docs/figures/captures_masks.png] [--views 3] [--height 240]

One row per capture (built on first use, as any run builds it): its first `--views` held-out views, each with its
text mask (masks/, the OCR detector's word polygons, tight) drawn in red over the photo, the view's name and the
share of its pixels the mask covers.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw

from strings_bench.core.io import atomic_write
from strings_bench.datasets.captures import CAPTURES, build_capture
from strings_bench.scene.scene import Scene


def tile(scene: Scene, i: int, height: int) -> Image.Image:
    img = np.asarray(Image.open(scene.image_path(i)).convert("RGB"), np.float32)
    mask = scene.load_mask(i)
    cover = 0.0
    if mask is not None:
        m = np.asarray(mask, np.float32)
        m = m / max(float(m.max()), 1.0)
        if m.shape != img.shape[:2]:
            m = np.asarray(Image.fromarray((m * 255).astype(np.uint8)).resize(img.shape[1::-1]), np.float32) / 255
        cover = float(m.mean())
        img = img * (1 - 0.55 * m[..., None]) + np.array([255.0, 0, 0]) * 0.55 * m[..., None]
    im = Image.fromarray(img.clip(0, 255).astype(np.uint8))
    im = im.resize((max(1, round(im.width * height / im.height)), height), Image.Resampling.LANCZOS)
    ImageDraw.Draw(im).text((4, 4), f"{scene.names[i]}  mask {100 * cover:.1f} %", fill=(255, 255, 0))
    return im


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, default=Path("docs/figures/captures_masks.png"))
    ap.add_argument("--views", type=int, default=3)
    ap.add_argument("--height", type=int, default=240)
    args = ap.parse_args(argv)
    rows = []
    for name in CAPTURES:
        scene = Scene.load(build_capture(name), name=name)
        tiles = [tile(scene, i, args.height) for i in scene.test_idx[:args.views]]
        row = Image.new("RGB", (sum(t.width for t in tiles) + 4 * len(tiles), args.height + 18), (255, 255, 255))
        ImageDraw.Draw(row).text((4, 2), name, fill=(0, 0, 0))
        x = 0
        for t in tiles:
            row.paste(t, (x, 18))
            x += t.width + 4
        rows.append(row)
    sheet = Image.new("RGB", (max(r.width for r in rows), sum(r.height for r in rows)), (255, 255, 255))
    y = 0
    for r in rows:
        sheet.paste(r, (0, y))
        y += r.height
    sheet = sheet.quantize(colors=256, method=Image.Quantize.MEDIANCUT)  # a palette PNG: a third of the bytes
    atomic_write(args.out, lambda p: sheet.save(p, format="PNG", optimize=True))
    print(f"wrote {args.out} ({sheet.width}x{sheet.height})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
