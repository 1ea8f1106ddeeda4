"""A scene's record, as `strings-bench datasets show NAME[/SCENE]` prints it: where the scene is, its views and
held-out views, what preparing it left out (photos SfM did not register), what OCR reads on its held-out GT
(captures), rho (scene/difficulty.py) and the content hash of its images, masks, cameras, points and text
(scene/content_hash.py). A scene that is not built is reported as such unless `build` is
given; nothing is built behind the user's back.
"""

from __future__ import annotations

import json
from pathlib import Path

from strings_bench.datasets.card import DatasetCard, SceneCard, locate_scene

SYNTHETIC_IDS = ("synthetic", "synthetic360", "synthetic360-cpu")


def _not_built(card: DatasetCard, scene: SceneCard) -> str | None:
    """Why the scene is not built yet (None: it is, or it is a folder the user keeps)."""
    if card.id == "captures":
        from strings_bench.datasets import captures

        if not captures.is_built(scene.name):
            return f"not built yet (its scene folder will be {captures.scene_dir(scene.name)})"
    elif card.id in SYNTHETIC_IDS:
        from strings_bench.core.draws import split_draw
        from strings_bench.datasets.synthetic import default_settings, is_built

        if not is_built(split_draw(scene.name)[0], default_settings(scene.name, card.id)):
            return "not built yet"
    return None


def _locate(card: DatasetCard, scene: SceneCard) -> Path:
    if card.id in SYNTHETIC_IDS:
        from strings_bench.core.draws import split_draw
        from strings_bench.datasets.synthetic import build_scene, default_settings

        return build_scene(split_draw(scene.name)[0], default_settings(scene.name, card.id), progress=True)
    return locate_scene(card, scene.name)


def scene_record(card: DatasetCard, scene: SceneCard, build: bool = False) -> dict:
    """The record of one scene of `card` (built first when `build`)."""
    from strings_bench.scene.content_hash import scene_content_hash
    from strings_bench.scene.difficulty import recorded_difficulty
    from strings_bench.scene.scene import Scene

    rec: dict = {"id": f"{card.id}/{scene.name}", "settings": dict(scene.settings)}
    why = _not_built(card, scene)
    if why and not build:
        rec["not_built"] = why + f"; `strings-bench datasets show {card.id}/{scene.name} --build` builds it"
        return rec
    path = _locate(card, scene)
    sc = Scene.load(path, name=scene.name, settings=dict(scene.settings))
    rec.update(path=str(path), views=sc.num_views, points=int(sc.model.num_points),
               test_views=[sc.names[i] for i in sc.test_idx], train_views=len(sc.train_idx),
               masks=sc.masks_dir is not None, known_text=sc.known_text is not None)
    for name in ("prepare.json", "capture.json"):
        try:
            rec[name.split(".")[0]] = json.loads((path / name).read_text())
        except (OSError, ValueError):
            pass
    rec["difficulty"] = recorded_difficulty(sc).as_dict()
    rec["content_hash"] = scene_content_hash(path)
    return rec


def format_record(rec: dict) -> str:
    """The record as lines of text."""
    from strings_bench.scene.difficulty import Difficulty

    lines = [rec["id"]]
    if "not_built" in rec:
        return "\n".join([*lines, f"  {rec['not_built']}"])
    lines.append(f"  path {rec['path']}")
    lines.append(f"  views {rec['views']} ({rec['train_views']} train, {len(rec['test_views'])} test: "
                 f"{', '.join(rec['test_views'][:8])}{' ...' if len(rec['test_views']) > 8 else ''}), "
                 f"{rec['points']} SfM points, text masks {'yes' if rec['masks'] else 'no'}, "
                 f"known text {'yes' if rec['known_text'] else 'no (known-text CER absent)'}")
    prep = rec.get("prepare")
    if prep:
        left = prep.get("unregistered") or []
        lines.append(f"  photos {prep['num_photos']}, registered {prep['num_registered']}"
                     + (f"; not registered (left out): {', '.join(left)}" if left else ""))
        intr = prep.get("intrinsics")
        if intr:
            lines.append(f"  known intrinsics fx {intr['fx']} fy {intr['fy']} cx {intr['cx']} cy {intr['cy']} "
                         "(kept fixed by SfM)")
        elif prep.get("bundler_file"):
            lines.append(f"  cameras given by {prep['bundler_file']} (no SfM)")
        split = prep.get("split")
        if split and split.get("every", 8) != 8:
            lines.append(f"  split: one view in {split['every']} held out (sorted by name; one in 8 would hold out "
                         "fewer than 3)")
    cap = rec.get("capture")
    if cap:
        floor = cap["min_gt_chars"]
        for ds, g in sorted(cap["gt_characters"].items()):
            lines.append(f"  GT characters read ({cap['gt_ocr']}, downscale {ds}): {g['chars']} "
                         f"({'scored' if g['chars'] >= floor else f'below the floor of {floor}: OCR-CER not scored'})")
    content = rec.get("content_hash")
    if content:
        lines.append(f"  content hash {content['hash']} (" + ", ".join(f"{k} {v}" for k, v in content["parts"].items())
                     + "): equal on two machines when the scene is")
    d = rec["difficulty"]
    if d["rho"] is None:
        lines.append(f"  rho n/a (no text strokes measured), extent {d['extent']:.3g}")
    else:
        lines.append(f"  rho {d['rho']:.3f} (extent {d['extent']:.3g}, median stroke {d['stroke_world']:.3g} world "
                     f"units = {d['stroke_px']:.2f} px, {d['words']} text regions"
                     f"{Difficulty(**d).how_measured()})")
    return "\n".join(lines)
