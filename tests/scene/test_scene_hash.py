"""A scene's content hash (scene/content_hash.py), the canonical order of SfM points (scene/colmap.py) and the
written-order arithmetic the scene build uses instead of BLAS (core/vec3.py); the rule that keeps BLAS out of the
scene build is tests/lint/test_rules.py's."""

from __future__ import annotations

import shutil
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from _engine_helpers import make_tiny_scene  # noqa: E402
from strings_bench.core import vec3  # noqa: E402
from strings_bench.scene.colmap import ColmapModel, in_canonical_order, read_model, write_model  # noqa: E402
from strings_bench.scene.content_hash import scene_content_hash  # noqa: E402


@pytest.fixture()
def scene_dir(tmp_path) -> Path:
    root = tmp_path / "scene"
    scene = make_tiny_scene(root, n_views=5, width=32, height=24, n_points=60)
    (root / "masks").mkdir()
    for c in scene.model.cameras:
        m = np.zeros((c.height, c.width), np.uint8)
        m[4:12, 6:20] = 255
        Image.fromarray(m).save(root / "masks" / f"{Path(c.name).stem}.png")
    return root


def test_the_hash_names_the_part_that_changed(scene_dir, tmp_path):
    first = scene_content_hash(scene_dir)
    assert len(first["hash"]) == 16 and set(first["parts"]) == {"images", "masks", "cameras", "points", "text"}
    copy = tmp_path / "copy"
    shutil.copytree(scene_dir, copy)
    assert scene_content_hash(copy) == first  # the folder's place and the files' times are not content

    image = sorted((copy / "images").iterdir())[2]
    pixels = np.asarray(Image.open(image)).copy()
    pixels[3, 5, 1] ^= 1  # one bit of one pixel
    Image.fromarray(pixels).save(image)
    changed = scene_content_hash(copy)
    assert changed["hash"] != first["hash"]
    assert [k for k in first["parts"] if first["parts"][k] != changed["parts"][k]] == ["images"]

    model = read_model(copy)
    write_model(model, copy / "sparse" / "0")  # written again as it was read (the poses go through quaternions)
    rewritten = scene_content_hash(copy)
    model.xyz[7, 2] = np.nextafter(model.xyz[7, 2], np.inf)  # one ulp of one point
    write_model(model, copy / "sparse" / "0")
    moved = scene_content_hash(copy)
    assert [k for k in first["parts"] if rewritten["parts"][k] != moved["parts"][k]] == ["points"]

    (copy / "split.json").write_text('{"test": ["view_000.png"]}')
    assert scene_content_hash(copy)["parts"]["text"] != moved["parts"]["text"]


def test_the_same_pixels_written_by_another_encoder_hash_the_same(scene_dir, tmp_path):
    copy = tmp_path / "copy"
    shutil.copytree(scene_dir, copy)
    for p in (copy / "images").iterdir():
        Image.open(p).save(p, compress_level=1)  # other bytes, the same pixels
    assert any(a.read_bytes() != b.read_bytes() for a, b in zip(sorted((copy / "images").iterdir()),
                                                              sorted((scene_dir / "images").iterdir())))
    assert scene_content_hash(copy) == scene_content_hash(scene_dir)


def _shuffled(model: ColmapModel, rng) -> ColmapModel:
    """The same points and tracks in another order, as another run of SfM's threads would store them."""
    n = model.num_points
    order = rng.permutation(n)
    views, xys, lengths = [], [], []
    for i in order:
        a, b = model.track_ptr[i], model.track_ptr[i + 1]
        within = rng.permutation(b - a) + a
        views += model.track_view[within].tolist()
        xys += model.track_xy[within].tolist()
        lengths.append(b - a)
    return ColmapModel(cameras=model.cameras, xyz=model.xyz[order], rgb=model.rgb[order],
                       track_ptr=np.concatenate([[0], np.cumsum(lengths)]).astype(np.int64),
                       track_view=np.asarray(views, np.int32), track_xy=np.asarray(xys, np.float64).reshape(-1, 2),
                       point_ids=model.point_ids[order])


def test_canonical_order_does_not_depend_on_the_order_sfm_stored(scene_dir):
    model = read_model(scene_dir)
    rng = np.random.default_rng(3)
    canonical = in_canonical_order(model)
    for _ in range(3):
        other = in_canonical_order(_shuffled(model, rng))
        for field in ("xyz", "rgb", "track_ptr", "track_view", "track_xy", "point_ids"):
            np.testing.assert_array_equal(getattr(other, field), getattr(canonical, field))

    def content(m):  # each point with its set of observations: what the order must not change
        return sorted((tuple(m.xyz[i]), tuple(m.rgb[i]), tuple(sorted(
            (int(m.track_view[k]), *m.track_xy[k]) for k in range(m.track_ptr[i], m.track_ptr[i + 1]))))
            for i in range(m.num_points))

    assert content(canonical) == content(model)
    assert canonical.point_ids.tolist() == list(range(1, model.num_points + 1))
    first = [(int(canonical.track_view[canonical.track_ptr[i]]), *canonical.track_xy[canonical.track_ptr[i]])
             for i in range(canonical.num_points)]
    assert first == sorted(first)  # points in the order of their first observation


def test_written_order_arithmetic_agrees_with_numpy_to_rounding():
    """core/vec3 against numpy's BLAS-backed products, on random data: equal to within a few ulps (the order of
    the additions differs, nothing else); the products of exact small integers are exact in both."""
    rng = np.random.default_rng(0)
    a, b = rng.normal(size=(1000, 3)), rng.normal(size=(1000, 3))
    m, m2 = rng.normal(size=(3, 3)), rng.normal(size=(3, 3))
    np.testing.assert_allclose(vec3.dot(a, b), np.einsum("ij,ij->i", a, b), rtol=0, atol=1e-14)
    np.testing.assert_allclose(vec3.norm(a), np.linalg.norm(a, axis=1), rtol=1e-15)
    np.testing.assert_allclose(vec3.matvec(m, a), a @ m.T, rtol=0, atol=1e-14)
    np.testing.assert_allclose(vec3.vecmat(a, m), a @ m, rtol=0, atol=1e-14)
    np.testing.assert_allclose(vec3.matmul(m, m2), m @ m2, rtol=0, atol=1e-14)
    np.testing.assert_allclose(vec3.norm_2d(a[:, :2]), np.hypot(a[:, 0], a[:, 1]), rtol=1e-15)
    ints = rng.integers(-50, 50, size=(3, 3)).astype(np.float64)
    assert (vec3.matmul(ints, ints) == ints @ ints).all() and (vec3.matvec(ints, ints[0]) == ints @ ints[0]).all()
    x = np.array([1.0, 2.0, 3.0], np.float32)
    assert vec3.dot(x, x).dtype == np.float32  # keeps the operands' dtype


def test_datasets_show_prints_the_content_hash(scene_dir, capsys):
    from strings_bench.cli import main

    assert main(["datasets", "add", "hashed-room", str(scene_dir)]) == 0
    capsys.readouterr()
    assert main(["datasets", "show", "hashed-room"]) == 0
    out = capsys.readouterr().out
    content = scene_content_hash(scene_dir)
    assert f"content hash {content['hash']} (images {content['parts']['images']}, masks" in out
