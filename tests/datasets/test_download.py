"""Downloader and safe extraction against a local HTTP server (127.0.0.1, Range support)."""

from __future__ import annotations

import hashlib
import os
import tarfile
import threading
import zipfile
from functools import partial
from http.server import SimpleHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

import pytest
from _archives import tar_of, zip_of

from strings_bench.datasets.download import (
    DownloadError,
    UnsafeArchiveError,
    download_file,
    safe_extract,
)


class RangeHandler(SimpleHTTPRequestHandler):
    """Serves files from a folder; honours `Range: bytes=N-` with 206, like real servers.

    Class switches for the tests: `ignore_range` answers 200 with the whole file; `cut_after`
    sends only that many bytes of the body then closes (a truncated transfer).
    """

    ignore_range = False
    cut_after: int | None = None
    requests: list[dict] = []

    def log_message(self, *args):  # keep test output clean
        pass

    def do_GET(self):
        path = Path(self.translate_path(self.path))
        if not path.is_file():
            self.send_error(404)
            return
        data = path.read_bytes()
        rng = self.headers.get("Range")
        type(self).requests.append({"path": self.path, "range": rng})
        start = 0
        if rng and not self.ignore_range:
            start = int(rng.split("=")[1].split("-")[0])
            if start >= len(data):
                self.send_response(416)
                self.send_header("Content-Range", f"bytes */{len(data)}")
                self.end_headers()
                return
            self.send_response(206)
            self.send_header("Content-Range", f"bytes {start}-{len(data) - 1}/{len(data)}")
        else:
            self.send_response(200)
        body = data[start:]
        self.send_header("Content-Length", str(len(body)))
        self.send_header("Content-Type", "application/octet-stream")
        self.end_headers()
        if self.cut_after is not None:
            self.wfile.write(body[: self.cut_after])
            self.wfile.flush()
            self.close_connection = True
            return
        self.wfile.write(body)


@pytest.fixture
def server(tmp_path):
    root = tmp_path / "served"
    root.mkdir()
    handler = type("H", (RangeHandler,), {"ignore_range": False, "cut_after": None, "requests": []})
    httpd = ThreadingHTTPServer(("127.0.0.1", 0), partial(handler, directory=str(root)))
    thread = threading.Thread(target=httpd.serve_forever, kwargs={"poll_interval": 0.05}, daemon=True)
    thread.start()
    try:
        yield root, f"http://127.0.0.1:{httpd.server_address[1]}", handler
    finally:
        httpd.shutdown()
        httpd.server_close()


def _payload(n=300_000, seed=1):
    import numpy as np

    return np.random.default_rng(seed).integers(0, 256, n, dtype=np.uint8).tobytes()


def test_download_verifies_sha256(server, tmp_path):
    root, url, _ = server
    data = _payload()
    (root / "a.bin").write_bytes(data)
    res = download_file(f"{url}/a.bin", tmp_path / "out" / "a.bin", sha256=hashlib.sha256(data).hexdigest(),
                        progress=False, echo=lambda s: None)
    assert res.verified and res.path.read_bytes() == data and res.resumed_from == 0
    assert not (tmp_path / "out" / "a.bin.part").exists()


def test_download_without_hash_prints_computed_hash(server, tmp_path):
    root, url, _ = server
    data = _payload(5000)
    (root / "b.bin").write_bytes(data)
    said = []
    res = download_file(f"{url}/b.bin", tmp_path / "b.bin", sha256=None, progress=False, echo=said.append)
    assert not res.verified
    assert any(hashlib.sha256(data).hexdigest() in s and "could not be verified" in s for s in said)


def test_sha256_mismatch_is_an_error_and_leaves_no_target(server, tmp_path):
    root, url, _ = server
    (root / "c.bin").write_bytes(_payload(1000))
    with pytest.raises(DownloadError, match="sha256 mismatch"):
        download_file(f"{url}/c.bin", tmp_path / "c.bin", sha256="0" * 64, progress=False, echo=lambda s: None)
    assert not (tmp_path / "c.bin").exists()


def test_resume_after_truncated_transfer(server, tmp_path):
    root, url, handler = server
    data = _payload()
    (root / "d.bin").write_bytes(data)
    digest = hashlib.sha256(data).hexdigest()
    handler.cut_after = 100_000
    with pytest.raises(DownloadError, match="resume"):
        download_file(f"{url}/d.bin", tmp_path / "d.bin", sha256=digest, progress=False, echo=lambda s: None)
    part = tmp_path / "d.bin.part"
    assert part.stat().st_size == 100_000 and not (tmp_path / "d.bin").exists()
    handler.cut_after = None
    res = download_file(f"{url}/d.bin", tmp_path / "d.bin", sha256=digest, progress=False, echo=lambda s: None)
    assert res.resumed_from == 100_000 and res.verified
    assert (tmp_path / "d.bin").read_bytes() == data
    assert handler.requests[-1]["range"] == "bytes=100000-"


def test_server_ignoring_range_restarts_cleanly(server, tmp_path):
    root, url, handler = server
    data = _payload()
    (root / "e.bin").write_bytes(data)
    (tmp_path / "e.bin.part").write_bytes(data[:1234])
    handler.ignore_range = True
    res = download_file(f"{url}/e.bin", tmp_path / "e.bin", sha256=hashlib.sha256(data).hexdigest(),
                        progress=False, echo=lambda s: None)
    assert res.resumed_from == 0 and (tmp_path / "e.bin").read_bytes() == data


def test_complete_part_file_and_416(server, tmp_path):
    root, url, _ = server
    data = _payload(2000)
    (root / "f.bin").write_bytes(data)
    (tmp_path / "f.bin.part").write_bytes(data)
    res = download_file(f"{url}/f.bin", tmp_path / "f.bin", sha256=hashlib.sha256(data).hexdigest(),
                        progress=False, echo=lambda s: None)
    assert res.path.read_bytes() == data


def test_http_404_is_a_clear_error(server, tmp_path):
    _, url, _ = server
    with pytest.raises(DownloadError, match="HTTP 404"):
        download_file(f"{url}/missing.zip", tmp_path / "m.zip", progress=False, echo=lambda s: None)


# ---- archives -------------------------------------------------------------------------------
def test_download_and_extract_good_archives(server, tmp_path):
    root, url, _ = server
    zip_of(root / "good.zip", {"tandt/truck/images/a.jpg": b"x", "tandt/truck/sparse/0/cameras.bin": b"y"})
    tar_of(root / "good.tar.gz", [("scene/images/a.jpg", b"x"), ("scene/sparse/0/points3D.bin", b"z")])
    for name, probe in (("good.zip", "tandt/truck/images/a.jpg"), ("good.tar.gz", "scene/sparse/0/points3D.bin")):
        res = download_file(f"{url}/{name}", tmp_path / "dl" / name, progress=False, echo=lambda s: None)
        out = safe_extract(res.path, tmp_path / f"x_{name}", progress=False)
        assert (out / probe).is_file()
        assert not any(p.name.endswith("extract-tmp") for p in tmp_path.iterdir())


@pytest.mark.parametrize("kind", ["zip_slip", "zip_absolute", "zip_symlink", "tar_slip", "tar_absolute",
                                  "tar_symlink", "tar_hardlink", "tar_device"])
def test_malicious_archives_are_refused(server, tmp_path, kind):
    root, url, _ = server
    outside = tmp_path / "evil"
    if kind == "zip_slip":
        arc = zip_of(root / "a.zip", {"ok.txt": b"fine", "../evil": b"pwned"})
    elif kind == "zip_absolute":
        arc = zip_of(root / "a.zip", {"ok.txt": b"fine", str(outside): b"pwned"})
    elif kind == "zip_symlink":
        arc = zip_of(root / "a.zip", {"scene/link": b"/etc/passwd"}, modes={"scene/link": 0o120777})  # S_IFLNK
    else:
        members: list = [("ok.txt", b"fine")]
        if kind == "tar_slip":
            members.append(("../evil", b"pwned"))
        elif kind == "tar_absolute":
            members.append((str(outside), b"pwned"))
        else:
            info = tarfile.TarInfo("link")
            if kind == "tar_symlink":
                info.type, info.linkname = tarfile.SYMTYPE, "/etc/passwd"
            elif kind == "tar_hardlink":
                info.type, info.linkname = tarfile.LNKTYPE, "ok.txt"
            else:
                info.type = tarfile.CHRTYPE
            members.append(info)
        arc = tar_of(root / "a.tar.gz", members)
    got = download_file(f"{url}/{arc.name}", tmp_path / "dl" / arc.name, progress=False, echo=lambda s: None)
    target = tmp_path / "work" / "target"
    with pytest.raises(UnsafeArchiveError):
        safe_extract(got.path, target, progress=False)
    # Nothing was written: not the target, not the temp folder, not the escape destination.
    assert not target.exists()
    assert not outside.exists() and not (tmp_path / "work" / "evil").exists()
    assert not (tmp_path / "work").exists() or not os.listdir(tmp_path / "work")


def test_extract_refuses_existing_target(tmp_path):
    arc = zip_of(tmp_path / "a.zip", {"x": b"1"})
    (tmp_path / "t").mkdir()
    with pytest.raises(Exception, match="already exists"):
        safe_extract(arc, tmp_path / "t", progress=False)


# ---- datasets: direct URL end to end, manual steps otherwise -----------------------------------
def _tiny_scene_zip(path: Path, prefix: str) -> Path:
    """A valid 3-view PINHOLE scene (written by pycolmap) inside a zip, under `prefix`/."""
    import numpy as np
    import pycolmap
    from PIL import Image

    stage = path.parent / "stage"
    scene = stage / prefix
    (scene / "images").mkdir(parents=True)
    (scene / "sparse" / "0").mkdir(parents=True)
    rec = pycolmap.Reconstruction()
    rec.add_camera_with_trivial_rig(pycolmap.Camera(camera_id=1, model="PINHOLE", width=32, height=24,
                                                    params=[30.0, 30.0, 16.0, 12.0]))
    for i in range(3):
        Image.fromarray(np.full((24, 32, 3), 60 * i, np.uint8)).save(scene / "images" / f"{i:05d}.jpg")
        im = pycolmap.Image(name=f"{i:05d}.jpg", keypoints=np.zeros((0, 2)), camera_id=1, image_id=i + 1)
        rec.add_image_with_trivial_frame(im, pycolmap.Rigid3d(np.hstack([np.eye(3), [[0.1 * i], [0], [0]]])))
    rec.write_binary(str(scene / "sparse" / "0"))
    with zipfile.ZipFile(path, "w") as zf:
        for p in sorted(stage.rglob("*")):
            if p.is_file():
                zf.write(p, p.relative_to(stage).as_posix())
    return path


def test_download_dataset_end_to_end(server, tmp_path, monkeypatch):
    from strings_bench.datasets.download import download_dataset
    from strings_bench.datasets.registry import (DatasetCard, SceneCard, _REGISTRY, read_index,
                                                 register_dataset, resolve_scenes)

    monkeypatch.setenv("STRINGS_BENCH_CACHE", str(tmp_path / "cache"))
    root, url, _ = server
    arc = _tiny_scene_zip(root / "tandt_test.zip", "tandt/truck")
    digest = hashlib.sha256(arc.read_bytes()).hexdigest()
    card = register_dataset(DatasetCard(
        id="tandt_test", title="test card", scenes=[SceneCard("truck", {"n_max": 20})],
        download={"url": f"{url}/tandt_test.zip", "sha256": digest, "archive_subdir": "tandt",
                  "filename": "tandt_test.zip"}))
    try:
        said = []
        got = download_dataset("tandt_test", progress=False, echo=said.append)
        assert got == tmp_path / "cache" / "datasets" / "tandt_test" / "tandt"
        assert read_index()["tandt_test"] == str(got.resolve())
        assert any("1 OK" in s for s in said)
        (ref,) = resolve_scenes(["tandt_test/truck"])
        assert ref.settings == {"n_max": 20} and (ref.path / "sparse" / "0" / "images.bin").exists()
        # Running it again reuses the verified archive and the unpacked folder.
        assert download_dataset("tandt_test", progress=False, echo=said.append) == got
    finally:
        _REGISTRY.pop(card.id, None)


@pytest.mark.parametrize("dataset", ["strings360", "dl3dv"])
def test_manual_datasets_print_steps(dataset, tmp_path, monkeypatch):
    from strings_bench.datasets.download import download_dataset

    monkeypatch.setenv("STRINGS_BENCH_CACHE", str(tmp_path / "cache"))
    said = []
    assert download_dataset(dataset, echo=said.append) is None
    text = "\n".join(said)
    assert "Steps:" in text and f"datasets add {dataset} ROOT" in text
    if dataset == "dl3dv":
        assert "huggingface.co/datasets/DL3DV/DL3DV-Benchmark" in text and "scenes.json" in text
    else:
        assert "strings-official.github.io" in text
    assert not (tmp_path / "cache" / "downloads").exists()


def test_real_cards_and_strings_presets_carry_the_paper_settings():
    """N_max per scene of the release's full_eval.py: on STRinGS' spec (@apply presets), not on the cards."""
    from strings_bench.datasets.registry import get_dataset
    from strings_bench.methods.registry import get_method

    spec = get_method("strings")
    n_max = {c.id: {s.name: spec.resolve(spec.presets_for(c.id, s.name)).get("n_max") for s in c.scenes}
             for c in map(get_dataset, ["strings360", "tandt", "dl3dv"])}
    assert n_max["strings360"] == dict.fromkeys(["extinguisher", "books", "chemicals", "globe", "shelf"], 25)
    assert n_max["tandt"] == {"truck": 20, "train": 15}
    assert n_max["dl3dv"] == {"3": 20, "21": 20, "80": 15, "92": 20, "107": 20, "132": 15, "136": 15}
    assert not any("n_max" in s.settings for c in map(get_dataset, ["strings360", "tandt", "dl3dv"]) for s in c.scenes)
    tandt = get_dataset("tandt")
    assert tandt.download["url"].startswith("https://repo-sam.inria.fr/") and tandt.download["sha256"] is None
