"""LPIPS-VGG network: properties, weight provenance, and a float64 brute-force forward pass."""

import numpy as np
import pytest
from scipy.ndimage import gaussian_filter

import strings_bench.eval.lpips_net as lpips_net

pytestmark = pytest.mark.skipif(not lpips_net.available(), reason="LPIPS weights not installed: " + lpips_net.INSTALL_HINT)


@pytest.fixture(scope="module")
def net():
    return lpips_net.get_lpips()


def _img(seed, h=64, w=80):
    x = gaussian_filter(np.random.default_rng(seed).random((h, w, 3)), (2, 2, 0))
    return ((x - x.min()) / (x.max() - x.min())).astype(np.float32)


def test_identity_symmetry_range(net):
    x, y = _img(0), _img(1)
    assert net(x, x) == 0.0
    d_xy, d_yx = net(x, y), net(y, x)
    assert d_xy == pytest.approx(d_yx, rel=1e-6)
    assert 0.0 < d_xy < 1.2


def test_monotone_in_noise(net):
    x = _img(2)
    rng = np.random.default_rng(3)
    noise = rng.normal(0, 1, x.shape).astype(np.float32)
    values = [net(x, np.clip(x + s * noise, 0, 1)) for s in (0.0, 0.01, 0.03, 0.1, 0.3)]
    assert values[0] == 0.0
    assert all(b > a for a, b in zip(values, values[1:])), values
    assert values[-1] < 1.2


def test_batch_equals_single(net):
    x, y = _img(4), _img(5)
    batch = net(np.stack([x, y]), np.stack([y, x]))
    assert batch.shape == (2,)
    np.testing.assert_allclose(batch, [net(x, y), net(y, x)], rtol=1e-5)


def test_linear_layers_agree_between_packages():
    vgg, lin = lpips_net.default_weight_paths()
    if lin is None:
        pytest.skip("lpips package not installed")
    _, lins_official, _ = lpips_net.load_weights(vgg, lin)
    ckpt = lpips_net.load_jax_checkpoint(vgg)
    for i, w in enumerate(lins_official):
        np.testing.assert_array_equal(w.numpy(), ckpt[f"NetLinLayer_{i}"]["Conv_0"]["kernel"].reshape(-1))
        assert (w.numpy() >= 0).all()  # LPIPS clamps its linear weights non-negative


def test_unpickler_refuses_code(tmp_path):
    import pickle

    bad = tmp_path / "bad.ckpt"
    bad.write_bytes(pickle.dumps({"x": print}))
    with pytest.raises(lpips_net.LPIPSUnavailable, match="refusing"):
        lpips_net.load_jax_checkpoint(bad)


def _brute_force_lpips(x, y, convs, lins):
    """Independent float64 forward pass with scipy (cross-correlation, zero padding, 2x2 max-pool)."""
    from scipy.signal import correlate

    def feats(img):
        a = (img.astype(np.float64) * 2 - 1).transpose(2, 0, 1)
        a = (a - np.array(lpips_net.SHIFT)[:, None, None]) / np.array(lpips_net.SCALE)[:, None, None]
        taps, ci = [], 0
        for v in lpips_net.VGG16_CFG:
            if v == "M":
                c, h, w = a.shape
                a = a[:, : h // 2 * 2, : w // 2 * 2].reshape(c, h // 2, 2, w // 2, 2).max(axis=(2, 4))
                continue
            wgt, b = (t.numpy().astype(np.float64) for t in convs[ci])
            p = np.pad(a, ((0, 0), (1, 1), (1, 1)))
            out = np.stack([sum(correlate(p[i], wgt[o, i], mode="valid") for i in range(a.shape[0])) + b[o]
                            for o in range(wgt.shape[0])])
            a = np.maximum(out, 0)
            if ci in lpips_net.TAP_AFTER_CONV:
                taps.append(a)
            ci += 1
        return taps

    total = 0.0
    for fa, fb, lin in zip(feats(x), feats(y), lins):
        fa = fa / (np.sqrt((fa**2).sum(0, keepdims=True)) + 1e-10)
        fb = fb / (np.sqrt((fb**2).sum(0, keepdims=True)) + 1e-10)
        total += (((fa - fb) ** 2) * lin.numpy().astype(np.float64)[:, None, None]).sum(0).mean()
    return total


@pytest.mark.slow
def test_matches_float64_brute_force(net):
    x, y = _img(6, 16, 16), _img(7, 16, 16)
    convs, lins, _ = lpips_net.load_weights()
    assert net(x, y) == pytest.approx(_brute_force_lpips(x, y, convs, lins), rel=1e-4)


def test_too_small_is_clear(net):
    from strings_bench.core.errors import StringsBenchError

    with pytest.raises(StringsBenchError, match="16x16"):
        net(np.zeros((8, 8, 3)), np.zeros((8, 8, 3)))


def test_reference_path_equals_pairwise(net):
    x, y = _img(8), _img(9)
    ref = net.reference(y)
    assert net.distance_to(x, ref) == pytest.approx(net(x, y), rel=1e-5, abs=1e-7)
    assert net.distance_to(y, ref) == 0.0
