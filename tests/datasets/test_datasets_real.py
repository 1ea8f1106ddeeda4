"""Real-dataset handling on a real COLMAP capture (the mouse photos, downscaled in the test):
registration of a STRinGS-360-style copy, `datasets check` problem reports, the foundation's
bad-input errors, and the train/test split rules. Every check is shown to leave files unchanged."""

from __future__ import annotations

import hashlib
import json
import os
import shutil
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from strings_bench.scene.colmap import read_model, write_model
from strings_bench.datasets.check import check_path, check_scene, check_target, format_reports
from strings_bench.core.errors import DatasetError
from strings_bench.scene.scene import Scene, default_split

# The capture sits in ../shared/data beside the repository (as for tests/integration/test_realdata_slow.py);
# STRINGS_BENCH_MOUSE_COLMAP=DIR points elsewhere.
MOUSE = Path(os.environ.get("STRINGS_BENCH_MOUSE_COLMAP",
                            Path(__file__).resolve().parents[3] / "shared" / "data" / "mouse_colmap"))
DOWN = 8  # 1440x1920 -> 180x240
pytestmark = [pytest.mark.skipif(not (MOUSE / "sparse" / "0").is_dir(),
                                 reason=f"shared mouse_colmap data not present at {MOUSE}"),
              pytest.mark.usefixtures("private_cache")]  # tests/conftest.py


def _mask_rect(w, h):
    m = np.zeros((h, w), np.uint8)
    m[h // 4: h // 2, w // 4: 3 * w // 4] = 255
    return m


@pytest.fixture(scope="module")
def mouse_scene(tmp_path_factory) -> Path:
    """A STRinGS-360-style scene folder: images/ (downscaled), sparse/0 (rescaled), masks/."""
    root = tmp_path_factory.mktemp("mouse") / "scene"
    model = read_model(MOUSE)
    cams = [c.scaled(DOWN) for c in model.cameras]
    for c0, c in zip(model.cameras, cams):
        assert (c.width, c.height) == (round(c0.width / DOWN), round(c0.height / DOWN))
    model.cameras = cams
    model.track_xy = model.track_xy / DOWN
    write_model(model, root / "sparse" / "0")
    (root / "images").mkdir()
    (root / "masks").mkdir()
    for c in cams:
        with Image.open(MOUSE / "images" / c.name) as im:
            im.draft("RGB", (c.width, c.height))  # JPEG DCT scaling: fast decode at low resolution
            im.convert("RGB").resize((c.width, c.height), Image.Resampling.LANCZOS).save(root / "images" / c.name, quality=90)
        Image.fromarray(_mask_rect(c.width, c.height)).save(root / "masks" / f"{Path(c.name).stem}.png")
    return root


def tree_hash(root: Path) -> str:
    h = hashlib.sha256()
    for p in sorted(root.rglob("*")):
        h.update(str(p.relative_to(root)).encode())
        if p.is_file():
            h.update(p.read_bytes())
    return h.hexdigest()


@pytest.fixture
def scene_copy(mouse_scene, tmp_path) -> Path:
    dst = tmp_path / "copy" / "extinguisher"
    shutil.copytree(mouse_scene, dst)
    return dst


def _messages(reports, level=None):
    return [p.message for r in reports for p in r.problems if level is None or p.level == level]


# ---- a good copy registers and loads with no code changes --------------------------------------
def test_strings360_style_copy_registers_and_loads(scene_copy):
    from strings_bench.cli.datasets import add_local_copy
    from strings_bench.datasets.registry import read_index, resolve_scenes

    root = scene_copy.parent
    shutil.copytree(scene_copy, root / "Books")  # capitalised folder names are found too
    before = tree_hash(root)
    said = []
    reports = add_local_copy("strings360", root, echo=said.append)
    assert [r.name for r in reports] == ["strings360/extinguisher", "strings360/books"]
    assert all(r.ok for r in reports), format_reports(reports)
    assert any("3 scene(s) of strings360 are not in" in s for s in said)
    assert read_index()["strings360"] == str(root.resolve())
    assert tree_hash(root) == before

    refs = resolve_scenes(["strings360/extinguisher", "strings360/books"])
    assert refs[0].settings == {"masks_dilated": True} and refs[0].path == (root / "extinguisher").resolve()
    assert refs[1].path.name == "Books"
    scene = Scene.load(refs[0].path, settings=refs[0].settings)
    assert scene.num_views == 56 and scene.settings["masks_dilated"] is True
    mask = scene.load_mask(0)
    cam = scene.camera(0)
    assert mask.shape == (cam.height, cam.width) and mask.dtype == bool
    assert mask[cam.height * 3 // 8, cam.width // 2] and not mask[0, 0]
    assert scene.load_image(0).shape == (cam.height, cam.width, 3)

    # A path works as well as a name.
    by_path = resolve_scenes([str(scene_copy)])
    assert len(by_path) == 1 and Scene.load(by_path[0].path).num_views == 56
    # A missing scene of a registered card says where it looked.
    with pytest.raises(DatasetError, match="globe"):
        resolve_scenes(["strings360/globe"])


def test_own_scene_under_a_new_name(scene_copy):
    from strings_bench.datasets.check import SceneReport  # noqa: F401
    from strings_bench.cli.datasets import add_local_copy
    from strings_bench.datasets.registry import resolve_scenes

    add_local_copy("my_mouse", scene_copy, echo=lambda s: None)
    refs = resolve_scenes(["my_mouse"])
    assert len(refs) == 1 and refs[0].path == scene_copy.resolve()
    assert [r.name for r in check_target("my_mouse")] == ["my_mouse/extinguisher"]
    with pytest.raises(DatasetError, match="may only hold"):
        add_local_copy("bad/name", scene_copy, echo=lambda s: None)


def test_add_refuses_a_broken_copy_unless_forced(scene_copy):
    from strings_bench.cli.datasets import add_local_copy
    from strings_bench.datasets.registry import read_index

    shutil.rmtree(scene_copy / "sparse")
    with pytest.raises(DatasetError, match="not registered"):
        add_local_copy("broken", scene_copy, echo=lambda s: None)
    assert "broken" not in read_index()
    add_local_copy("broken", scene_copy, force=True, echo=lambda s: None)
    assert "broken" in read_index()


def test_good_copy_check_is_clean(scene_copy):
    (rep,) = check_path(scene_copy)
    assert rep.ok and [p for p in rep.problems if p.level != "info"] == []
    assert rep.stats["registered images"] == 56 and rep.stats["masks"] == 56
    assert rep.stats["camera models"] == "PINHOLE"


# ---- check reports: one per kind of problem, files untouched -----------------------------------
def _check(scene_dir):
    before = tree_hash(scene_dir.parent)
    reports = check_path(scene_dir)
    assert tree_hash(scene_dir.parent) == before, "the check modified the user's files"
    return reports


def test_check_missing_folders(scene_copy):
    shutil.rmtree(scene_copy / "images")
    shutil.rmtree(scene_copy / "sparse")
    errors = _messages(_check(scene_copy), "error")
    assert any("missing folder images/" in m for m in errors)
    assert any("missing folder sparse/0/" in m for m in errors)


def test_check_image_without_pose(scene_copy):
    first = sorted((scene_copy / "images").iterdir())[0]
    shutil.copy(first, scene_copy / "images" / "extra_photo.jpg")
    (rep,) = _check(scene_copy)
    assert rep.ok
    assert any("have no pose" in p.message and "extra_photo.jpg" in p.message for p in rep.problems if p.level == "warning")


def test_check_pose_without_image(scene_copy):
    victim = sorted((scene_copy / "images").iterdir())[3]
    victim.unlink()
    (rep,) = _check(scene_copy)
    assert not rep.ok
    assert any("have a pose in the model but no file" in m and victim.name in m for m in _messages([rep], "error"))


def test_check_distorted_camera_model(tmp_path):
    import pycolmap

    scene = tmp_path / "distorted"
    (scene / "images").mkdir(parents=True)
    (scene / "sparse" / "0").mkdir(parents=True)
    rec = pycolmap.Reconstruction()
    rec.add_camera_with_trivial_rig(pycolmap.Camera(camera_id=1, model="SIMPLE_RADIAL", width=64, height=48,
                                                    params=[60.0, 32.0, 24.0, 0.05]))
    for i in range(3):
        name = f"v{i}.png"
        Image.fromarray(np.full((48, 64, 3), 40 * i, np.uint8)).save(scene / "images" / name)
        im = pycolmap.Image(name=name, keypoints=np.zeros((0, 2)), camera_id=1, image_id=i + 1)
        rec.add_image_with_trivial_frame(im, pycolmap.Rigid3d(np.hstack([np.eye(3), [[i * 0.1], [0], [0]]])))
    rec.write_binary(str(scene / "sparse" / "0"))
    (rep,) = _check(scene)
    errors = _messages([rep], "error")
    assert any("need undistortion" in m and "SIMPLE_RADIAL" in m for m in errors), errors
    assert any("undistort" in p.hint for p in rep.problems if p.level == "error")
    with pytest.raises(DatasetError, match="SIMPLE_RADIAL"):
        Scene.load(scene)


def test_check_mask_sizes(scene_copy):
    masks = sorted((scene_copy / "masks").iterdir())
    Image.fromarray(np.zeros((100, 100), np.uint8)).save(masks[0])  # wrong aspect
    w, h = Image.open(masks[1]).size
    Image.fromarray(_mask_rect(w * 2, h * 2)).save(masks[2])  # same aspect, another resolution
    masks[3].unlink()  # an image without mask
    Image.fromarray(_mask_rect(w, h)).save(scene_copy / "masks" / "not_an_image.png")
    (rep,) = _check(scene_copy)
    assert not rep.ok
    assert any("wrong size" in m and masks[0].name in m for m in _messages([rep], "error"))
    assert any("another resolution" in m and masks[2].name in m for m in _messages([rep], "info"))
    warnings = _messages([rep], "warning")
    assert any("no mask" in m and masks[3].stem in m for m in warnings)
    assert any("match no image" in m and "not_an_image.png" in m for m in warnings)


def test_check_absent_masks_is_reported_not_an_error(scene_copy):
    shutil.rmtree(scene_copy / "masks")
    (rep,) = _check(scene_copy)
    assert rep.ok and rep.stats["masks"] == "absent"
    assert any("no masks/ folder" in m for m in _messages([rep], "info"))


@pytest.mark.parametrize("victim", ["cameras.bin", "images.bin", "points3D.bin"])
def test_check_truncated_bin_names_the_file(scene_copy, victim):
    p = scene_copy / "sparse" / "0" / victim
    data = p.read_bytes()
    p.write_bytes(data[: len(data) * 2 // 3])
    (rep,) = _check(scene_copy)
    errors = _messages([rep], "error")
    assert any(victim in m and "truncated" in m for m in errors), errors


def test_check_empty_images_folder(scene_copy):
    for p in (scene_copy / "images").iterdir():
        p.unlink()
    errors = _messages(_check(scene_copy), "error")
    assert any("is empty" in m for m in errors)


def test_check_cli_exit_codes(scene_copy, capsys):
    import argparse

    from strings_bench.cli.datasets import add_dataset_subcommands

    parser = argparse.ArgumentParser()
    add_dataset_subcommands(parser.add_subparsers())
    args = parser.parse_args(["check", str(scene_copy)])
    assert args.func(args) == 0
    (scene_copy / "images" / sorted(p.name for p in (scene_copy / "images").iterdir())[0]).unlink()
    assert args.func(args) == 1
    assert "have a pose in the model but no file" in capsys.readouterr().out


# ---- the foundation's bad-input cases through Scene.load: clear error, nothing lost ------------
def _load_fails(scene_dir, match):
    before = tree_hash(scene_dir)
    with pytest.raises(DatasetError, match=match) as exc:
        Scene.load(scene_dir)
    assert tree_hash(scene_dir) == before
    assert exc.value.hint
    return exc.value


def test_scene_load_missing_sparse(scene_copy):
    shutil.rmtree(scene_copy / "sparse")
    _load_fails(scene_copy, "no sparse/ folder")


def test_scene_load_truncated_bin(scene_copy):
    p = scene_copy / "sparse" / "0" / "points3D.bin"
    p.write_bytes(p.read_bytes()[:1000])
    err = _load_fails(scene_copy, "corrupt COLMAP model")
    assert str(p) in err.message and "truncated" in err.message


def test_scene_load_image_missing_on_disk(scene_copy):
    victim = sorted((scene_copy / "images").iterdir())[5]
    victim.unlink()
    _load_fails(scene_copy, victim.name)


def test_scene_load_mask_wrong_size(scene_copy):
    scene = Scene.load(scene_copy)
    mask_file = scene.mask_path(0)
    Image.fromarray(np.zeros((10, 50), np.uint8)).save(mask_file)
    before = tree_hash(scene_copy)
    with pytest.raises(DatasetError, match=mask_file.name):
        Scene.load(scene_copy).load_mask(0)
    assert tree_hash(scene_copy) == before


def test_scene_load_empty_images(scene_copy):
    for p in (scene_copy / "images").iterdir():
        p.unlink()
    _load_fails(scene_copy, "is empty")


# ---- splits -------------------------------------------------------------------------------------
def test_default_split_every_eighth_of_sorted_names():
    names = [f"img_{i:03d}.jpg" for i in range(20)]
    shuffled = [names[i] for i in np.random.default_rng(0).permutation(20)]
    train, test = default_split(shuffled)
    assert sorted(shuffled[i] for i in test) == ["img_000.jpg", "img_008.jpg", "img_016.jpg"]
    assert sorted(train + test) == list(range(20)) and not set(train) & set(test)


def test_scene_split_default_and_override(scene_copy):
    scene = Scene.load(scene_copy)
    names = scene.names
    assert names == sorted(names)
    assert scene.test_idx == list(range(0, len(names), 8))
    (scene_copy / "split.json").write_text(json.dumps({"test": [names[1], names[2]]}))
    scene = Scene.load(scene_copy)
    assert scene.test_idx == [1, 2] and len(scene.train_idx) == len(names) - 2 and 1 not in scene.train_idx
    (scene_copy / "split.json").write_text(json.dumps({"test": ["nope.jpg"]}))
    with pytest.raises(DatasetError, match="nope.jpg"):
        Scene.load(scene_copy)
    (rep,) = check_path(scene_copy)  # the checker reports what Scene.load refuses
    assert any("nope.jpg" in m for m in _messages([rep], "error"))


# ---- prepare (SfM) on a few real photos ---------------------------------------------------------
@pytest.fixture(scope="module")
def few_photos(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("photos")
    names = sorted(p.name for p in (MOUSE / "images").iterdir())[:12]
    for n in names:
        shutil.copy(MOUSE / "images" / n, d / n)
    return d


def test_prepare_small_real_capture(few_photos, tmp_path, monkeypatch):
    import strings_bench.datasets.sfm as sfm
    from strings_bench.datasets.registry import read_index, resolve_scenes
    from strings_bench.eval.ocr import Word

    class FakeOCR:  # stands in for the detector: one word box per image
        def read(self, img, mask=None):
            h, w = img.shape[:2]
            return [Word.from_box("MOUSE", w * 0.25, h * 0.25, w * 0.5, h * 0.4)]

    monkeypatch.setattr("strings_bench.eval.ocr.get_backend", lambda name="rapidocr", **kw: FakeOCR())
    before = tree_hash(few_photos)
    out = tmp_path / "scenes" / "mouse12"
    said = []
    # one thread: with a fixed seed COLMAP is then deterministic (multi-threaded RANSAC is not)
    r = sfm.prepare_scene(few_photos, "mouse12", out=out, max_size=480, masks=True, progress=False,
                          echo=said.append, num_threads=1)
    assert tree_hash(few_photos) == before  # the photos are only read
    assert r.num_photos == 12 and 3 <= r.num_registered <= 12 and r.num_points > 50, r.summary()
    assert set(r.stage_seconds) == {"resize", "features", "matching", "mapping", "undistort", "downscale", "masks"}
    assert "registered" in r.summary() and any(s.startswith("[1/7]") for s in said)
    assert not any(p.name.endswith("prepare-tmp") for p in out.parent.iterdir())
    assert read_index()["mouse12"] == str(out)
    (rep,) = check_path(out)
    assert rep.ok, rep.format()
    assert rep.stats["camera models"] in ("PINHOLE", "SIMPLE_PINHOLE") and rep.stats["masks"] == r.num_registered
    scene = Scene.load(resolve_scenes(["mouse12"])[0].path)
    cam = scene.camera(0)
    assert max(cam.width, cam.height) <= 480
    m = scene.load_mask(0)
    assert m[int(cam.height * 0.3), int(cam.width * 0.37)] and not m[int(cam.height * 0.8), int(cam.width * 0.8)]
    with Image.open(scene.image_path(0, 2)) as im2:  # images_2/ holds round(w / 2) x round(h / 2)
        assert scene.image_path(0, 2).parent.name == "images_2"
        assert im2.size == (int(round(cam.width / 2)), int(round(cam.height / 2)))
    with pytest.raises(DatasetError, match="already exists"):
        sfm.prepare_scene(few_photos, "mouse12", out=out, progress=False, echo=said.append)


def test_prepare_refuses_too_few_photos(tmp_path):
    from strings_bench.datasets.sfm import prepare_scene

    (tmp_path / "p").mkdir()
    shutil.copy(next((MOUSE / "images").iterdir()), tmp_path / "p" / "one.jpg")
    with pytest.raises(DatasetError, match="needs at least 3"):
        prepare_scene(tmp_path / "p", "x", out=tmp_path / "out", progress=False, echo=lambda s: None)
    with pytest.raises(DatasetError, match="does not exist"):
        prepare_scene(tmp_path / "nope", "x", out=tmp_path / "out", progress=False, echo=lambda s: None)
    assert not (tmp_path / "out").exists()


def test_downscaled_camera_matches_downscaled_image(tmp_path):
    import pycolmap

    scene_dir = tmp_path / "odd"
    (scene_dir / "images").mkdir(parents=True)
    (scene_dir / "sparse" / "0").mkdir(parents=True)
    rec = pycolmap.Reconstruction()
    rec.add_camera_with_trivial_rig(pycolmap.Camera(camera_id=1, model="PINHOLE", width=301, height=400,
                                                    params=[300.0, 300.0, 150.5, 200.0]))
    Image.fromarray(np.zeros((400, 301, 3), np.uint8)).save(scene_dir / "images" / "a.png")
    rec.add_image_with_trivial_frame(pycolmap.Image(name="a.png", keypoints=np.zeros((0, 2)), camera_id=1, image_id=1),
                                     pycolmap.Rigid3d())
    rec.write_binary(str(scene_dir / "sparse" / "0"))
    scene = Scene.load(scene_dir)
    cam = scene.camera(0, 2)
    assert scene.load_image(0, 2).shape[:2] == (cam.height, cam.width)
