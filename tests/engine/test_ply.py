"""PLY in the 3DGS layout: bitwise round trip, property order and channel-major f_rest, a model
written by the trainer, malformed files, and the `render` CLI."""

from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image

from _engine_helpers import make_tiny_scene  # noqa: E402

from strings_bench.core.errors import StringsBenchError  # noqa: E402
from strings_bench.engine.gaussians import GaussianModel  # noqa: E402
from strings_bench.engine.ply import read_ply, write_ply  # noqa: E402


def _model(n=25, degree=3, seed=0):
    g = torch.Generator().manual_seed(seed)
    k = (degree + 1) ** 2 - 1
    params = {"means": torch.randn(n, 3, generator=g), "quats": torch.randn(n, 4, generator=g),
              "log_scales": torch.randn(n, 3, generator=g), "opacity_logits": torch.randn(n, generator=g),
              "sh0": torch.randn(n, 1, 3, generator=g), "shN": torch.randn(n, k, 3, generator=g)}
    return GaussianModel(params, extras={"is_text": torch.arange(n) % 3 == 0})


@pytest.mark.parametrize("degree", [0, 1, 3])
def test_round_trip_is_bitwise(tmp_path, degree):
    m = _model(degree=degree)
    write_ply(tmp_path / "m.ply", m)
    r = read_ply(tmp_path / "m.ply")
    assert r.sh_degree == degree and len(r) == len(m)
    for k, v in m.params.items():
        assert torch.equal(r.params[k].detach(), v.detach()), k
    assert r.extras == {}  # standard layout: extras are not written unless asked


def test_layout_order_and_channel_major_rest(tmp_path):
    m = _model(n=3)
    with torch.no_grad():
        k = torch.arange(15.0)[None, :, None]
        c = torch.arange(3.0)[None, None, :]
        m.params["shN"].copy_((100 * c + k).expand(3, 15, 3))
    path = write_ply(tmp_path / "m.ply", m)
    raw = path.read_bytes()
    header = raw[:raw.index(b"end_header")].decode().splitlines()
    props = [line.split()[2] for line in header if line.startswith("property")]
    assert header[1] == "format binary_little_endian 1.0" and header[2] == "element vertex 3"
    assert all(line.startswith("property float ") for line in header if line.startswith("property"))
    assert props[:9] == ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
    assert props[9:54] == [f"f_rest_{i}" for i in range(45)]
    assert props[54:] == ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
    data = np.frombuffer(raw[raw.index(b"end_header") + 11:], dtype="<f4").reshape(3, 62)
    rest = data[:, 9:54]
    for ch in range(3):
        for kk in range(15):
            assert rest[0, ch * 15 + kk] == 100 * ch + kk  # f_rest index = c * 15 + k
    np.testing.assert_array_equal(data[:, 54], m.params["opacity_logits"].detach().numpy())
    np.testing.assert_array_equal(data[:, 58:62], m.params["quats"].detach().numpy())


def test_extras_and_foreign_properties(tmp_path):
    m = _model(n=6)
    write_ply(tmp_path / "e.ply", m, extras=True)
    r = read_ply(tmp_path / "e.ply")
    assert r.extras["is_text"].tolist() == m.extras["is_text"].float().tolist()
    # a file with properties in another order, a double and an unknown property still reads
    n = 2
    names = ["rot_0", "rot_1", "rot_2", "rot_3", "x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "opacity",
             "scale_0", "scale_1", "scale_2", "filter_3D"]
    dtype = np.dtype([(nm, "<f8" if nm == "x" else "<f4") for nm in names])
    arr = np.zeros(n, dtype)
    arr["x"] = [1.5, -2.25]
    arr["rot_0"] = 1
    hdr = "ply\nformat binary_little_endian 1.0\ncomment made elsewhere\nelement vertex 2\n" + "".join(
        f"property {'double' if nm == 'x' else 'float'} {nm}\n" for nm in names) + "end_header\n"
    (tmp_path / "f.ply").write_bytes(hdr.encode() + arr.tobytes())
    r = read_ply(tmp_path / "f.ply")
    assert r.sh_degree == 0 and r.params["means"][:, 0].tolist() == [1.5, -2.25]


def test_malformed_files_give_clear_errors(tmp_path):
    (tmp_path / "a.ply").write_bytes(b"not a ply")
    with pytest.raises(StringsBenchError, match="not a PLY"):
        read_ply(tmp_path / "a.ply")
    (tmp_path / "b.ply").write_bytes(b"ply\nformat ascii 1.0\nelement vertex 0\nend_header\n")
    with pytest.raises(StringsBenchError, match="binary_little_endian"):
        read_ply(tmp_path / "b.ply")
    (tmp_path / "c.ply").write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 1\n"
                                     b"property float x\nproperty float y\nproperty float z\nend_header\n" + bytes(12))
    with pytest.raises(StringsBenchError, match="point cloud"):
        read_ply(tmp_path / "c.ply")
    good = write_ply(tmp_path / "d.ply", _model(n=4)).read_bytes()
    (tmp_path / "d.ply").write_bytes(good[:-10])
    with pytest.raises(StringsBenchError, match="truncated"):
        read_ply(tmp_path / "d.ply")
    with pytest.raises(StringsBenchError, match="cannot read"):
        read_ply(tmp_path / "missing.ply")


@pytest.fixture(scope="module")
def tiny_scene(tmp_path_factory):
    return make_tiny_scene(tmp_path_factory.mktemp("tiny_ply"))


def test_trainer_ply_reads_back_and_renders_via_cli(tiny_scene, tmp_path):
    from strings_bench.cli import main
    from _engine_helpers import train
    from strings_bench.engine.splatting import GaussianSplatting, TrainConfig

    n_threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        tr = GaussianSplatting(TrainConfig(steps_scale=0.05, sh_degree=1))
        (result,) = train(tr, tiny_scene, (30,), model_path=lambda step: tmp_path / f"iteration_{step}.ply")
        back = read_ply(result.extra["ply"])
        for k, v in tr.model.params.items():
            assert torch.equal(back.params[k].detach(), v.detach()), k
        rc = main(["render", "--ply", result.extra["ply"], "--scene", str(tiny_scene.root), "--out",
                   str(tmp_path / "renders"), "--split", "test"])
    finally:
        torch.set_num_threads(n_threads)
    assert rc == 0
    for i in tiny_scene.test_idx:
        name = Path(tiny_scene.names[i]).stem + ".png"
        png = np.asarray(Image.open(tmp_path / "renders" / name), dtype=np.float32) / 255
        ref = result.renders[tiny_scene.names[i]]
        assert png.shape == ref.shape and np.abs(png - ref).max() <= 1 / 255 + 1e-6
    assert main(["render", "--ply", str(tmp_path / "none.ply"), "--scene", str(tiny_scene.root),
                 "--out", str(tmp_path / "x")]) == 1
