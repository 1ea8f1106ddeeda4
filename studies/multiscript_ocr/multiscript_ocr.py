"""OCR of the multilingual synthetic scenes' GT test views: known-text CER per script.

For each `synthetic-multi` scene (built on first use): its test views (every 8th), each read through its
dilated text mask as the runner reads them, by Tesseract with the scene's language and, where its
dictionary covers the script, by RapidOCR; known-text CER under the `paper` and `graphemes` profiles,
with the 6.5 px legibility filter and without it. Prints a Markdown table (docs/ocr.md, "Other scripts").

    STRINGS_BENCH_CACHE=... python studies/multiscript_ocr/multiscript_ocr.py [--scenes cyrillic,greek] [--views N]
"""

from __future__ import annotations

import argparse
import time

from strings_bench.core.errors import OCRError
from strings_bench.core.scripts import LANGUAGES
from strings_bench.datasets.synthetic import SCENE_NAMES_MULTI, build_scene
from strings_bench.datasets.synthetic.multiscript import WORDS
from strings_bench.eval.cer import known_scene_cer
from strings_bench.eval.ocr import engine_settings, get_backend
from strings_bench.eval.protocol import scene_views, to_uint8
from strings_bench.scene.scene import Scene


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", default=",".join(SCENE_NAMES_MULTI))
    ap.add_argument("--views", type=int, default=0, help="test views per scene (0: all)")
    ap.add_argument("--rapidocr", action="store_true", help="also RapidOCR on the scripts it reads")
    ap.add_argument("--tesseract", default="", metavar="KEY=VALUE:...",
                    help="further Tesseract settings, e.g. upscale=3:mask_fill=128 (lang is the scene's)")
    args = ap.parse_args()
    print("| scene | language | engine | views | legible words | CER paper (>= 6.5 px) | CER graphemes (>= 6.5 px) "
          "| CER paper (all) | CER graphemes (all) | s / view |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for name in args.scenes.split(","):
        lang = WORDS[name].lang
        scene = Scene.load(build_scene(name, progress=False))
        views = scene_views(scene, 1)
        if args.views:
            views = views[: args.views]
        extra = engine_settings("tesseract:" + args.tesseract) if args.tesseract else {}
        engines = [("tesseract", get_backend("tesseract", lang=lang, **extra))]
        if args.rapidocr:
            engines.append(("rapidocr", get_backend("rapidocr")))
        scripts = [LANGUAGES[lang].script]
        for label, engine in engines:
            try:
                engine.require_scripts(scripts, f"synthetic-multi/{name}")
            except OCRError as exc:
                print(f"| {name} | {lang} | {label} | refused: {exc.message.split(';')[0]} |||||||")
                continue
            t0 = time.perf_counter()
            reads = {v.name: engine.read(to_uint8(v.gt), mask=v.mask) for v in views}
            dt = (time.perf_counter() - t0) / len(views)
            pairs = {v.name: ([(k.text, k.polygon) for k in v.known_words], reads[v.name]) for v in views}
            cells = []
            for min_h in (6.5, 0.0):
                for prof in ("paper", "graphemes"):
                    r = known_scene_cer(pairs, min_text_height_px=min_h, profile=prof)
                    cells.append(f"{r.cer:.3f} ({r.errors}/{r.chars})")
            legible = known_scene_cer(pairs, profile="paper")
            n_legible = sum(len(c.components) for c in legible.images.values())
            shown = ":".join(f"{k}={v}" for k, v in engine.settings.items() if k in ("lang", "upscale", "mask_fill"))
            print(f"| {name} | {lang} | {label}{' ' + shown if label == 'tesseract' else ''} "
                  f"| {len(views)} | {n_legible} | " + " | ".join(cells) + f" | {dt:.1f} |", flush=True)


if __name__ == "__main__":
    main()
