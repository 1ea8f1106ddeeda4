"""Text-mask providers: polygon filling, dilation kernel, cache, missing-mask errors."""

from __future__ import annotations

import json

import numpy as np
import pytest
from PIL import Image
from scipy.ndimage import binary_dilation as _nd_dilation
from skimage.morphology import disk


def binary_dilation(mask, footprint):
    return _nd_dilation(mask, structure=footprint)

import strings_bench.eval.text_masks as M
from strings_bench.scene.camera import Camera
from strings_bench.scene.colmap import ColmapModel, write_model
from strings_bench.scene.scene import Scene


def look_at(center, target=(0.0, 0.0, 0.0)):
    """World-to-camera (R, t) of a camera at `center` looking at `target` (y down)."""
    center = np.asarray(center, float)
    f = np.asarray(target, float) - center
    f /= np.linalg.norm(f)
    up = np.array([0.0, -1.0, 0.0])
    r = np.cross(up, f)
    if np.linalg.norm(r) < 1e-6:
        r = np.cross(np.array([0.0, 0.0, 1.0]), f)
    r /= np.linalg.norm(r)
    d = np.cross(f, r)
    R = np.stack([r, d, f])
    return R, -R @ center


def make_scene(tmp_path, n_views=4, width=64, height=48, n_points=60, with_masks=True, with_annotations=True,
               text_box=(20, 14, 44, 30), seed=0):
    """A tiny COLMAP scene with images, tracks, masks/ and text_annotations.json."""
    rng = np.random.default_rng(seed)
    root = tmp_path / "scene"
    (root / "images").mkdir(parents=True)
    cams = []
    for v in range(n_views):
        ang = -0.3 + 0.6 * v / max(1, n_views - 1)
        R, t = look_at([3 * np.sin(ang), 0.0, -3 * np.cos(ang)])
        cams.append(Camera(60.0, 60.0, width / 2, height / 2, width, height, R, t, name=f"img_{v:03d}.png"))
        img = (rng.random((height, width, 3)) * 255).astype(np.uint8)
        Image.fromarray(img).save(root / "images" / cams[-1].name)
    xyz = rng.uniform(-0.5, 0.5, (n_points, 3))
    views, xys, ptr = [], [], [0]
    for p in xyz:
        for v, cam in enumerate(cams):
            uv, z = cam.project(p[None])
            views.append(v)
            xys.append(uv[0])
        ptr.append(len(views))
    model = ColmapModel(cams, xyz, (rng.random((n_points, 3)) * 255).astype(np.uint8), np.array(ptr),
                        np.array(views, np.int32), np.array(xys), np.arange(1, n_points + 1))
    write_model(model, root / "sparse" / "0")
    x0, y0, x1, y1 = text_box
    if with_masks:
        (root / "masks").mkdir()
        for cam in cams:
            m = np.zeros((height, width), np.uint8)
            m[y0:y1, x0:x1] = 255
            Image.fromarray(m).save(root / "masks" / cam.name)
    if with_annotations:
        poly = [[x0, y0], [x1, y0], [x1, y1], [x0, y1]]
        (root / "text_annotations.json").write_text(json.dumps(
            {"views": {c.name: [{"text": "HELLO", "polygon": poly}] for c in cams}}))
    return Scene.load(root)


@pytest.fixture(autouse=True)
def _private_cache(tmp_path, monkeypatch):
    monkeypatch.setenv("STRINGS_BENCH_CACHE", str(tmp_path / "cache"))
    M._read_png.cache_clear()


def test_fill_polygons_uses_pixel_centres():
    # Square from x 2..5, y 1..3 (continuous frame): covers pixel centres 2.5, 3.5, 4.5 / 1.5, 2.5.
    mask = M.fill_polygons([np.array([[2, 1], [5, 1], [5, 3], [2, 3]], float)], (6, 8))
    expect = np.zeros((6, 8), bool)
    expect[1:3, 2:5] = True
    assert np.array_equal(mask, expect)


@pytest.mark.parametrize("radius", [1, 2, 3, 7])
def test_dilation_matches_skimage_disk(radius):
    rng = np.random.default_rng(radius)
    mask = rng.random((40, 50)) > 0.985
    ours = M.dilate_mask(mask, 2 * radius)
    ref = binary_dilation(mask, disk(radius))
    assert np.array_equal(ours, ref)


@pytest.mark.parametrize("diameter", [5.0, 8.0, 12.6, 31.0])
def test_single_pixel_dilates_to_kernel_of_given_diameter(diameter):
    mask = np.zeros((81, 81), bool)
    mask[40, 40] = True
    out = M.dilate_mask(mask, diameter)
    cols = np.flatnonzero(out.any(0))
    # Extent in pixels: 2 * floor(d / 2) + 1 (the pixel centres within d / 2 of the seed).
    assert cols.max() - cols.min() + 1 == 2 * int(np.floor(diameter / 2)) + 1
    fp = M.kernel_footprint(diameter)
    k = fp.shape[0] // 2
    assert np.array_equal(out[40 - k:40 + k + 1, 40 - k:40 + k + 1], fp)
    assert out.sum() == fp.sum()


def test_kernel_diameter_settings():
    assert M.MaskSettings().kernel_diameter(1000, 1000) == pytest.approx(50.0)  # paper 5 %
    assert M.MaskSettings(dilation_fraction=0.2).kernel_diameter(500, 1000) == pytest.approx(100.0)
    # Release script: 225 px at full resolution, scaled with the image.
    assert M.MaskSettings(dilation_px=225).kernel_diameter(500, 1000) == pytest.approx(112.5)
    with pytest.raises(M.StringsBenchError):
        M.MaskSettings(source="hisam")
    with pytest.raises(M.StringsBenchError):
        M.MaskSettings.coerce({"dilation": 3})


def test_dataset_mask_dilated_with_fraction_of_width(tmp_path):
    scene = make_scene(tmp_path)
    s = M.MaskSettings(source="dataset", dilation_fraction=0.125)  # 8 px on a 64 px wide image
    m = M.dilated_text_mask(scene, 0, 1, s)
    tight = M.tight_text_mask(scene, 0, 1, s)
    assert tight.sum() == (44 - 20) * (30 - 14)
    assert np.array_equal(m, binary_dilation(tight, disk(4)))
    # Half resolution: image 32 px wide -> 4 px kernel on the half-size tight mask.
    m2 = M.dilated_text_mask(scene, 0, 2, s)
    assert m2.shape == (24, 32)
    assert np.array_equal(m2, binary_dilation(M.tight_text_mask(scene, 0, 2, s), disk(2)))


def test_mask_cache_written_and_reused(tmp_path):
    scene = make_scene(tmp_path)
    s = M.MaskSettings(dilation_fraction=0.05)
    m = M.dilated_text_mask(scene, 1, 1, s)
    files = list(M.mask_cache_dir(scene, s).rglob("*.png"))
    assert len(files) == 1
    assert np.array_equal(m, np.asarray(Image.open(files[0])) > 127)
    # Other settings -> other folder.
    assert M.mask_cache_dir(scene, s) != M.mask_cache_dir(scene, M.MaskSettings(dilation_fraction=0.2))
    # An edited mask file is not served stale.
    new = np.zeros((48, 64), np.uint8)
    new[0:4, 0:4] = 255
    p = scene.mask_path(1)
    Image.fromarray(new).save(p)
    import os
    st = os.stat(p)
    os.utime(p, ns=(st.st_atime_ns, st.st_mtime_ns + 10_000_000))
    from strings_bench.scene.scene import _load_mask
    _load_mask.cache_clear()
    m_new = M.dilated_text_mask(scene, 1, 1, s)
    assert not np.array_equal(m, m_new) and m_new[0, 0]


def test_gt_mask_from_annotations(tmp_path):
    scene = make_scene(tmp_path, with_masks=False)
    m = M.tight_text_mask(scene, 0, 1, M.MaskSettings(source="gt", dilation_fraction=0))
    expect = np.zeros((48, 64), bool)
    expect[14:30, 20:44] = True
    assert np.array_equal(m, expect)


def test_missing_masks_error_names_views_and_provider(tmp_path):
    scene = make_scene(tmp_path, with_masks=False, with_annotations=False)
    with pytest.raises(M.MissingMasksError) as e:
        M.text_masks(scene, [0, 1], 1, M.MaskSettings(source="dataset"))
    text = str(e.value)
    assert "masks/" in text and "img_000.png" in text and "ocr" in text and "Hi-SAM" in text
    with pytest.raises(M.MissingMasksError) as e:
        M.dilated_text_mask(scene, 2, 1, {"source": "gt"})
    assert "img_002.png" in str(e.value) and "synthetic" in str(e.value)


def test_missing_single_mask_file(tmp_path):
    scene = make_scene(tmp_path)
    scene.mask_path(3).unlink()
    with pytest.raises(M.MissingMasksError, match="img_003.png"):
        M.text_masks(scene, range(4), 1)


def test_ocr_masks_read_each_view_once_on_several_cores(tmp_path, monkeypatch):
    """mask_source="ocr": the detector runs on all views at once (eval.ocr.read_many), each view once,
    and every mask is the filled word box dilated, as the one-at-a-time path makes it."""
    from strings_bench.eval.ocr import OCRCache, Word
    from strings_bench.eval.ocr.base import OCR_WORKERS_ENV
    from strings_bench.scene.polygons import fill_polygons
    from tests.eval.test_ocr_parallel import SlowBackend

    class BoxDetector(SlowBackend):  # one word, the scene's text box, in every view; slow as a detector
        name = "boxes"

        def words(self, rgb):
            return [Word.from_box("HELLO", 20, 14, 44, 30)]

    scene = make_scene(tmp_path, n_views=6, with_masks=False)
    det = BoxDetector(cache=OCRCache(tmp_path / "ocr"))
    monkeypatch.setitem(M._backends, "boxes", det)
    monkeypatch.setenv(OCR_WORKERS_ENV, "3")
    s = M.MaskSettings(source="ocr", ocr_backend="boxes", dilation_fraction=0.1)
    masks = M.text_masks(scene, range(6), 1, s, progress=False)
    assert det.calls == 6 and det.most_at_once >= 2
    tight = fill_polygons([Word.from_box("HELLO", 20, 14, 44, 30).polygon], (48, 64))
    expect = M.dilate_mask(tight, s.kernel_diameter(64, 64))
    assert all(np.array_equal(m, expect) for m in masks.values())
    M.text_masks(scene, range(6), 1, s, progress=False)  # cached masks: no detector run
    assert det.calls == 6
