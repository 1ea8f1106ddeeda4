"""Test doubles for the runner: a tiny scene on disk, a deterministic OCR, and fake method adapters."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from PIL import Image

from strings_bench.scene.camera import Camera
from strings_bench.scene.colmap import ColmapModel, write_model
from strings_bench.core.method import CheckpointResult, MethodAdapter
from strings_bench.methods.registry import MethodSpec, register_method
from strings_bench.eval.ocr.base import Word

W, H = 64, 48
TEXT_BOX = (8, 12, 56, 30)  # x0, y0, x1, y1: where the "text" is in every view
N_VIEWS = 9  # views 0 and 8 are test views (every 8th)


def _draw_glyphs(img: np.ndarray) -> np.ndarray:
    """The word "hello" in light letters on the dark text block (Pillow's bundled font), thin enough that
    the block stays dark for FakeOCR (mean < 60) while the recogniser can read the word."""
    from PIL import ImageDraw, ImageFont

    im = Image.fromarray(img)
    draw = ImageDraw.Draw(im)
    font = ImageFont.load_default(size=14)
    x0, y0, x1, y1 = TEXT_BOX
    left, top, right, bottom = draw.textbbox((0, 0), "hello", font=font)
    draw.text(((x0 + x1 - (right - left)) / 2 - left, (y0 + y1 - (bottom - top)) / 2 - top), "hello", font=font,
              fill=(235, 235, 235))
    return np.asarray(im).copy()


def make_scene(root: Path, name: str = "toy", with_masks: bool = True, glyphs: bool = False) -> Path:
    """A 9-view scene folder (64x48 images, a dark text block; with `glyphs`, "hello" written in it)."""
    scene = root / name
    (scene / "images").mkdir(parents=True)
    rng = np.random.default_rng(0)
    cams = []
    for v in range(N_VIEWS):
        img = np.full((H, W, 3), 200, np.uint8)
        img += rng.integers(0, 20, (H, W, 3), dtype=np.uint8)
        x0, y0, x1, y1 = TEXT_BOX
        img[y0:y1, x0:x1] = 30  # dark "text" block read by FakeOCR
        if glyphs:
            img = _draw_glyphs(img)
        fname = f"view_{v:02d}.png"
        Image.fromarray(img).save(scene / "images" / fname)
        t = np.array([0.1 * v, 0.0, 4.0])
        cams.append(Camera(60.0, 60.0, W / 2, H / 2, W, H, np.eye(3), t, fname))
        if with_masks:
            (scene / "masks").mkdir(exist_ok=True)
            m = np.zeros((H, W), np.uint8)
            m[y0:y1, x0:x1] = 255
            Image.fromarray(m).save(scene / "masks" / fname)
    xyz = rng.normal(0, 0.3, (20, 3))
    track_view = np.array([0, 1] * 20, np.int32)
    model = ColmapModel(cams, xyz, np.full((20, 3), 128, np.uint8), np.arange(0, 41, 2, dtype=np.int64), track_view,
                        np.tile([[32.0, 24.0]], (40, 1)), np.arange(1, 21, dtype=np.int64))
    write_model(model, scene / "sparse" / "0")
    x0, y0, x1, y1 = TEXT_BOX
    poly = [[x0, y0], [x1, y0], [x1, y1], [x0, y1]]
    (scene / "text_annotations.json").write_text(json.dumps(
        {"views": {c.name: [{"text": "hello", "polygon": poly}] for c in cams}}))
    return scene


class FakeOCR:
    """Reads 'hello' when the text box is dark, 'hallo' when it is half-dark, nothing otherwise."""

    name = "fake"

    def __init__(self):
        self.calls = 0

    def describe(self):
        return {"name": "fake", "version": "1", "settings": {}}

    def read(self, image, mask=None):
        self.calls += 1
        img = np.asarray(image, dtype=np.float32)
        if mask is not None:
            img = img * np.asarray(mask)[..., None]
        x0, y0, x1, y1 = TEXT_BOX
        v = img[y0:y1, x0:x1].mean()
        poly = [[x0, y0], [x1, y0], [x1, y1], [x0, y1]]
        if v < 60:
            return [Word("hello", poly)]
        if v < 120:
            return [Word("hallo", poly)]
        return []


CALLS = {"train": [], "yield": []}


class FakeAdapter(MethodAdapter):
    """Renders = ground truth faded towards grey; sharper with more iterations and a lower `blur`."""

    name = "fake"

    def train(self, scene, checkpoints, downscale=1):
        CALLS["train"].append((self.settings.get("tag", self.name), scene.name, tuple(checkpoints)))
        blur = float(self.settings.get("blur", 0.5))
        stop_after = self.settings.get("interrupt_after")
        for k, it in enumerate(checkpoints):
            if stop_after is not None and k >= stop_after:
                raise KeyboardInterrupt
            a = 1.0 - blur * (1.0 - it / checkpoints[-1]) - self.settings.get("floor", 0.0)
            renders = {}
            for i in scene.test_idx:
                gt = scene.load_image(i, downscale)
                renders[scene.names[i]] = (gt * a + 0.5 * (1 - a)).astype(np.float32)
            CALLS["yield"].append((self.settings.get("tag", self.name), scene.name, it))
            yield CheckpointResult(iteration=it, renders=renders, train_seconds=10.0 * (k + 1) * (1 + blur),
                                   gaussians=1000 * (k + 1))


def register_fakes():
    register_method(MethodSpec(name="fake-a", implementation=lambda **s: FakeAdapter(tag="fake-a", blur=0.2, **s),
                               description="fake method A", paper="Test'25",
                               presets={"tiny": {}}))
    register_method(MethodSpec(name="fake-b", implementation=lambda **s: FakeAdapter(tag="fake-b", blur=0.9, **s),
                               description="fake method B", paper="Test'24"))
    register_method(MethodSpec(name="fake-c", implementation=lambda **s: FakeAdapter(tag="fake-c", blur=0.6, floor=0.3, **s),
                               description="fake method C"))
