"""A fuzz set of malformed inputs through the public entry points (issue 19, item 1).

Every case starts from a valid small file (a COLMAP model in .bin and .txt, images, masks, a 3DGS
PLY, text_annotations.json / split.json / run.json / result.json, OCR results, archives), breaks it
one way (generated with a seeded generator: truncations at random offsets, flipped bytes, inflated
counts, NaN/Inf, wrong types, missing keys, unsafe archive members, a zip bomb), and runs one public
command in-process through `strings_bench.cli.main` (`datasets check`, `prepare`, `run`,
`render --ply`, `cer`, `report`, `datasets download`).

A case survives when the command ends without a traceback, and either
- refuses the input with exit status 1 and a message that names the broken file, or
- (only where the mutation may leave a valid input: a flipped byte, a grayscale photo, an all-black
  mask) accepts it;
and in both cases the case's input folder is unchanged and nothing is written outside the case's
target and cache folders. Each case runs in its own folder (also the working directory).

The outcomes are written to `fuzz_summary.json` in the test's temporary folder (and to the file named
by STRINGS_BENCH_FUZZ_SUMMARY when set: docs/reliability.md counts them).
"""

from __future__ import annotations

import strings_bench.bench as bench

import contextlib
import hashlib
import io
import json
import logging
import os
import random
import shutil
import struct
import tarfile
import traceback
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np
import pytest
import torch
from PIL import Image

import runner_fakes as rf  # noqa: E402
from strings_bench.eval.ocr.base import OCRBackend, BackendStatus, Word  # noqa: E402

SEED = 19
MIN_CASES = 200


# ---- a deterministic OCR backend reachable by name from `run --ocr` ------------------------------
class FuzzOCR(OCRBackend):
    """runner_fakes.FakeOCR as a registered backend (`--ocr fuzzfake`), with the on-disk cache."""

    name = "fuzzfake"

    def __init__(self, cache=None, **settings):
        super().__init__(settings, cache)
        self._fake = rf.FakeOCR()

    @property
    def version(self) -> str:
        return "1"

    @classmethod
    def status(cls) -> BackendStatus:
        return BackendStatus(cls.name, True, "1")

    def _recognize(self, rgb):
        return self._fake.read(rgb)


# ---- running one case ------------------------------------------------------------------------------
@dataclass
class Outcome:
    kind: str
    case: str
    entry: str
    status: str  # "refused" | "accepted" | "traceback" | "silent" (refused without naming the file) | "leak"
    rc: int | None
    detail: str = ""


@dataclass
class Collector:
    outcomes: list[Outcome] = field(default_factory=list)

    def summary(self) -> dict:
        by_kind: dict[str, dict[str, int]] = {}
        for o in self.outcomes:
            k = by_kind.setdefault(o.kind, {"tried": 0, "refused": 0, "accepted": 0, "failed": 0})
            k["tried"] += 1
            if o.status in ("refused", "accepted"):
                k[o.status] += 1
            else:
                k["failed"] += 1
        entries: dict[str, int] = {}
        for o in self.outcomes:
            entries[o.entry] = entries.get(o.entry, 0) + 1
        return {"tried": len(self.outcomes), "survived": sum(o.status in ("refused", "accepted") for o in self.outcomes),
                "by_kind": by_kind, "by_entry_point": entries, "cases": [o.__dict__ for o in self.outcomes]}


COLLECTOR = Collector()


def _snapshot(folder: Path) -> dict[str, str]:
    out = {}
    for p in sorted(folder.rglob("*")):
        if p.is_symlink():
            out[str(p.relative_to(folder))] = "link:" + os.readlink(p)
        elif p.is_file():
            out[str(p.relative_to(folder))] = hashlib.sha256(p.read_bytes()).hexdigest()
        elif p.is_dir():
            out[str(p.relative_to(folder))] = "dir"
    return out


def run_case(case_dir: Path, kind: str, case: str, argv: list[str], names: list[str], may_accept: bool,
             monkeypatch) -> Outcome:
    """Run `strings-bench ARGV` in-process in `case_dir` (holding input/, where the broken files are),
    and judge it. `names`: strings of which one must appear in a refusal (the broken file's name)."""
    from strings_bench.cli import main

    for sub in ("out", "cache"):
        (case_dir / sub).mkdir(exist_ok=True)
    before = _snapshot(case_dir)
    monkeypatch.chdir(case_dir)
    monkeypatch.setenv("STRINGS_BENCH_CACHE", str(case_dir / "cache"))
    out, err = io.StringIO(), io.StringIO()
    handler = logging.StreamHandler(err)
    logging.getLogger().addHandler(handler)
    rc: int | None = None
    tb = ""
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            try:
                rc = main(argv)
            except SystemExit as exc:  # argparse
                rc = exc.code if isinstance(exc.code, int) else 2
            except BaseException:  # noqa: BLE001 - a traceback is what this test looks for
                tb = traceback.format_exc()
    finally:
        logging.getLogger().removeHandler(handler)
    text = out.getvalue() + err.getvalue()
    entry = argv[0] if argv[0] != "datasets" else f"datasets {argv[1]}"
    after = _snapshot(case_dir)
    changed = sorted(k for k in set(before) | set(after)
                     if before.get(k) != after.get(k) and not k.startswith(("out", "cache")))
    if tb or "Traceback (most recent call last)" in text:
        return Outcome(kind, case, entry, "traceback", rc, (tb or text)[-3000:])
    if changed:
        return Outcome(kind, case, entry, "leak", rc, f"written or changed outside out/ and cache/: {changed[:5]}")
    if rc == 0:
        return Outcome(kind, case, entry, "accepted" if may_accept else "silent", rc,
                       "" if may_accept else "accepted a broken input: " + text[-500:])
    if rc == 1 and any(n in text for n in names):
        return Outcome(kind, case, entry, "refused", rc, text.strip().splitlines()[0][:300] if text.strip() else "")
    return Outcome(kind, case, entry, "silent", rc, f"exit {rc}; does not name any of {names}: {text[-800:]}")


def record(outcomes: list[Outcome]) -> None:
    COLLECTOR.outcomes.extend(outcomes)
    bad = [o for o in outcomes if o.status not in ("refused", "accepted")]
    assert not bad, "\n\n".join(f"[{o.kind}/{o.case} via {o.entry}] {o.status}: {o.detail}" for o in bad)


# ---- valid base files ----------------------------------------------------------------------------
@pytest.fixture(scope="module")
def base(tmp_path_factory):
    """Valid inputs every case starts from: a scene (binary and text model, masks, annotations,
    split), a PLY, a finished run folder, OCR results files, a good archive."""
    from strings_bench.bench import runner
    from strings_bench.engine.gaussians import GaussianModel
    from strings_bench.engine.ply import write_ply
    from strings_bench.scene.colmap import read_model, write_model

    root = tmp_path_factory.mktemp("fuzz-base")
    os.environ.setdefault("STRINGS_BENCH_CACHE", str(root / "cache"))
    rf.register_fakes()
    scene = rf.make_scene(root, "scene")
    (scene / "split.json").write_text(json.dumps({"test": ["view_00.png", "view_08.png"]}))
    txt_scene = root / "scene_txt"
    shutil.copytree(scene, txt_scene)
    shutil.rmtree(txt_scene / "sparse" / "0")
    write_model(read_model(scene), txt_scene / "sparse" / "0", binary=False)
    rng = np.random.default_rng(0)
    model = GaussianModel.from_points(rng.normal(0, 0.3, (30, 3)), rng.integers(0, 255, (30, 3)).astype(np.uint8),
                                      sh_degree=1)
    ply = write_ply(root / "model.ply", model)
    run_dir = root / "run"
    bench.run(["fake-a"], [str(scene)], run_dir=run_dir, schedule="tiny", ocr="fuzzfake", ocr_backend=rf.FakeOCR(),
               with_lpips=False,
               progress=False, write_report=False)
    poly = [[8, 12], [56, 12], [56, 30], [8, 30]]
    gt = {"format": "strings-bench-ocr/1", "images": {"a.png": [{"text": "hello", "polygon": poly}],
                                                      "b.png": [{"text": "exit", "polygon": poly}]}}
    (root / "gt.json").write_text(json.dumps(gt))
    (root / "pred.json").write_text(json.dumps(gt))
    return {"root": root, "scene": scene, "txt_scene": txt_scene, "ply": ply, "run": run_dir,
            "gt": root / "gt.json", "pred": root / "pred.json"}


@pytest.fixture(autouse=True)
def _fake_backend(monkeypatch):
    import strings_bench.eval.ocr as ocr

    monkeypatch.setitem(ocr.BACKENDS, "fuzzfake", f"{__name__}:FuzzOCR")


@pytest.fixture(scope="module", autouse=True)
def _write_summary(tmp_path_factory):
    yield
    if not COLLECTOR.outcomes:
        return
    summary = COLLECTOR.summary()
    text = json.dumps(summary, indent=1)
    (tmp_path_factory.getbasetemp() / "fuzz_summary.json").write_text(text)
    if os.environ.get("STRINGS_BENCH_FUZZ_SUMMARY"):
        Path(os.environ["STRINGS_BENCH_FUZZ_SUMMARY"]).write_text(text)


def new_case(tmp_path: Path, label: str) -> Path:
    d = tmp_path / label
    (d / "input").mkdir(parents=True)
    return d


def scene_copy(base, case_dir: Path, which: str = "scene") -> Path:
    dst = case_dir / "input" / "scene"
    shutil.copytree(base[which], dst)
    return dst


def run_argv(scene: Path) -> list[str]:
    return ["run", "--methods", "fake-a", "--datasets", str(scene), "--schedule", "tiny", "--checkpoints", "30000",
            "--ocr", "fuzzfake", "--no-lpips", "--no-progress", "--out", "out/run"]


# ---- mutations of bytes ----------------------------------------------------------------------------
def truncate_at(path: Path, frac: float) -> int:
    data = path.read_bytes()
    cut = max(1, min(len(data) - 1, int(len(data) * frac)))
    path.write_bytes(data[:cut])
    return cut


def flip_byte(path: Path, frac: float, rng: random.Random) -> int:
    data = bytearray(path.read_bytes())
    pos = min(len(data) - 1, int(len(data) * frac))
    data[pos] ^= rng.randrange(1, 256)
    path.write_bytes(bytes(data))
    return pos


# ---- COLMAP binary ---------------------------------------------------------------------------------
def _bin_cases() -> list[tuple[str, str, Callable[[Path], None], bool]]:
    """(case id, file stem, mutate(model_dir), may_accept)."""
    rng = random.Random(SEED)
    cases = []
    for stem in ("cameras", "images", "points3D"):
        for k in range(4):
            frac = rng.uniform(0.02, 0.98)
            cases.append((f"{stem}.bin truncated at {frac:.3f}", stem,
                          lambda d, s=stem, f=frac: truncate_at(d / f"{s}.bin", f), False))
        for k in range(4):
            frac = rng.random()
            seed = rng.randrange(1 << 30)
            cases.append((f"{stem}.bin byte flipped at {frac:.3f}", stem,
                          lambda d, s=stem, f=frac, sd=seed: flip_byte(d / f"{s}.bin", f, random.Random(sd)), True))

        def inflate(d, s=stem):
            p = d / f"{s}.bin"
            data = bytearray(p.read_bytes())
            (n,) = struct.unpack_from("<Q", data, 0)
            struct.pack_into("<Q", data, 0, n + 1000)
            p.write_bytes(bytes(data))
        cases.append((f"{stem}.bin record count inflated", stem, inflate, False))

        def empty(d, s=stem):
            (d / f"{s}.bin").write_bytes(b"")
        cases.append((f"{stem}.bin empty", stem, empty, False))

        def missing(d, s=stem):
            (d / f"{s}.bin").unlink()
        cases.append((f"{stem}.bin missing", stem, missing, False))

    for stem in ("frames", "rigs"):
        for k in range(2):
            frac = rng.uniform(0.05, 0.95)
            cases.append((f"{stem}.bin truncated at {frac:.3f}", stem,
                          lambda d, s=stem, f=frac: truncate_at(d / f"{s}.bin", f), False))

    def unknown_model(d):
        p = d / "cameras.bin"
        data = bytearray(p.read_bytes())
        struct.pack_into("<i", data, 8 + 4, 77)  # model id of the first camera record
        p.write_bytes(bytes(data))
    cases.append(("cameras.bin unknown camera model id", "cameras", unknown_model, False))

    def point_value(value, which):
        def mutate(d):
            p = d / "points3D.bin"
            data = bytearray(p.read_bytes())
            struct.pack_into("<d", data, 8 + 8 + 8 * which, value)  # first point: id, then x y z
            p.write_bytes(bytes(data))
        return mutate
    for value, label in ((float("nan"), "NaN"), (float("inf"), "Inf"), (float("-inf"), "-Inf")):
        cases.append((f"points3D.bin {label} coordinate", "points3D", point_value(value, rng.randrange(3)), False))

    def pose_value(value, offset):
        def mutate(d):
            # pycolmap >= 3.12 writes the poses to frames.bin as well and reads them from there; a model
            # in the older layout (COLMAP 3.11 and before) has them in images.bin only.
            (d / "frames.bin").unlink(missing_ok=True)
            (d / "rigs.bin").unlink(missing_ok=True)
            p = d / "images.bin"
            data = bytearray(p.read_bytes())
            struct.pack_into("<d", data, 8 + 4 + 8 * offset, value)  # first image: id, then qvec, tvec
            p.write_bytes(bytes(data))
        return mutate
    cases.append(("images.bin NaN rotation", "images", pose_value(float("nan"), 0), False))
    cases.append(("images.bin Inf translation", "images", pose_value(float("inf"), 5), False))

    def camera_param(value, label):
        def mutate(d):
            p = d / "cameras.bin"
            data = bytearray(p.read_bytes())
            struct.pack_into("<d", data, 8 + 4 + 4 + 8 + 8, value)  # first camera: fx
            p.write_bytes(bytes(data))
        return mutate
    cases.append(("cameras.bin NaN focal length", "cameras", camera_param(float("nan"), "nan"), False))
    cases.append(("cameras.bin zero focal length", "cameras", camera_param(0.0, "zero"), False))
    cases.append(("cameras.bin negative focal length", "cameras", camera_param(-60.0, "neg"), False))
    return cases


BIN_CASES = _bin_cases()


def test_colmap_binary_models(base, tmp_path, monkeypatch):
    outcomes = []
    for k, (label, stem, mutate, may_accept) in enumerate(BIN_CASES):
        entries = [["datasets", "check", "input/scene"]]
        # `run` on an input it accepts trains and evaluates (seconds): only refusals go through it here.
        if k % 3 == 0 and not may_accept:
            entries.append(run_argv(Path("input/scene")))
        if k % 3 == 1:
            entries.append(["render", "--ply", str(base["ply"]), "--scene", "input/scene", "--out", "out/renders",
                            "--device", "cpu"])
        for j, argv in enumerate(entries):
            case_dir = new_case(tmp_path, f"bin{k}-{j}")
            scene = scene_copy(base, case_dir)
            mutate(scene / "sparse" / "0")
            outcomes.append(run_case(case_dir, "COLMAP .bin", label, argv, [f"{stem}.bin", "sparse/0"], may_accept,
                                     monkeypatch))
    record(outcomes)


# ---- COLMAP text -----------------------------------------------------------------------------------
def _data_lines(text: str) -> list[int]:
    return [i for i, ln in enumerate(text.splitlines()) if ln.strip() and not ln.startswith("#")]


def _txt_cases():
    rng = random.Random(SEED + 1)
    cases = []
    for stem in ("cameras", "images", "points3D"):
        for k in range(3):
            frac = rng.uniform(0.3, 0.97)
            cases.append((f"{stem}.txt truncated at {frac:.3f}", stem,
                          lambda d, s=stem, f=frac: truncate_at(d / f"{s}.txt", f), True))

        def garbage(d, s=stem, seed=rng.randrange(1 << 30)):
            p = d / f"{s}.txt"
            lines = p.read_text().splitlines()
            r = random.Random(seed)
            i = r.choice(_data_lines("\n".join(lines)))
            toks = lines[i].split()
            toks[r.randrange(len(toks))] = r.choice(["abc", "1e999x", "--", "0x1F"])
            lines[i] = " ".join(toks)
            p.write_text("\n".join(lines) + "\n")
        cases.append((f"{stem}.txt non-numeric token", stem, garbage, False))

        def dropped_tokens(d, s=stem):
            p = d / f"{s}.txt"
            lines = p.read_text().splitlines()
            i = _data_lines("\n".join(lines))[0]
            lines[i] = " ".join(lines[i].split()[:3])
            p.write_text("\n".join(lines) + "\n")
        cases.append((f"{stem}.txt too few values on a line", stem, dropped_tokens, False))

    def unknown_model(d):
        p = d / "cameras.txt"
        lines = p.read_text().splitlines()
        i = _data_lines("\n".join(lines))[0]
        toks = lines[i].split()
        toks[1] = "FISHEYE_DELUXE"
        lines[i] = " ".join(toks)
        p.write_text("\n".join(lines) + "\n")
    cases.append(("cameras.txt unknown camera model", "cameras", unknown_model, False))

    def distorted(d):
        p = d / "cameras.txt"
        lines = p.read_text().splitlines()
        i = _data_lines("\n".join(lines))[0]
        toks = lines[i].split()
        toks[1] = "OPENCV"
        toks = toks[:4] + toks[4:8] + ["0.1", "0.01", "0", "0"]
        lines[i] = " ".join(toks)
        p.write_text("\n".join(lines) + "\n")
    cases.append(("cameras.txt distorted OPENCV camera", "cameras", distorted, False))

    def nan_point(d):
        p = d / "points3D.txt"
        lines = p.read_text().splitlines()
        i = _data_lines("\n".join(lines))[0]
        toks = lines[i].split()
        toks[2] = "nan"
        lines[i] = " ".join(toks)
        p.write_text("\n".join(lines) + "\n")
    cases.append(("points3D.txt NaN coordinate", "points3D", nan_point, False))

    def missing_image(d):
        p = d / "images.txt"
        text = p.read_text().replace("view_03.png", "view_99.png")
        p.write_text(text)
    cases.append(("images.txt names a missing image file", "images", missing_image, False))
    return cases


TXT_CASES = _txt_cases()


def test_colmap_text_models(base, tmp_path, monkeypatch):
    outcomes = []
    for k, (label, stem, mutate, may_accept) in enumerate(TXT_CASES):
        entries = [["datasets", "check", "input/scene"]]
        if k % 2 == 0 and not may_accept:
            entries.append(run_argv(Path("input/scene")))
        for j, argv in enumerate(entries):
            case_dir = new_case(tmp_path, f"txt{k}-{j}")
            scene = scene_copy(base, case_dir, "txt_scene")
            mutate(scene / "sparse" / "0")
            names = [f"{stem}.txt", "sparse/0", "view_99.png"]
            outcomes.append(run_case(case_dir, "COLMAP .txt", label, argv, names, may_accept, monkeypatch))
    record(outcomes)


# ---- images and masks ------------------------------------------------------------------------------
def _png_bytes(arr: np.ndarray, **kw) -> bytes:
    buf = io.BytesIO()
    Image.fromarray(arr, **kw).save(buf, format="PNG")
    return buf.getvalue()


def _image_cases():
    rng = random.Random(SEED + 2)
    W, H = rf.W, rf.H
    cases = []

    def view(d: Path) -> Path:
        return d / "images" / "view_00.png"  # a test view: run reads it for training and evaluation

    for k in range(3):
        frac = rng.uniform(0.1, 0.9)
        cases.append((f"PNG truncated at {frac:.2f}", lambda d, f=frac: truncate_at(view(d), f), False))
    for k in range(2):
        frac = rng.uniform(0.2, 0.9)

        def jpeg_truncated(d, f=frac):
            p = view(d)
            im = Image.open(p).convert("RGB")
            im.save(p, format="JPEG", quality=90)  # a JPEG behind a .png name: PIL reads by content
            truncate_at(p, f)
        cases.append((f"JPEG truncated at {frac:.2f}", jpeg_truncated, False))

    def resized(size, label, may):
        def mutate(d):
            Image.open(view(d)).convert("RGB").resize(size).save(view(d))
        return (label, mutate, may)
    cases.append(resized((W + 13, H), f"wrong aspect {W + 13}x{H}", False))
    cases.append(resized((W // 2, H // 2), "half size, same aspect", True))

    def mode(fn, label):
        def mutate(d):
            arr = np.asarray(Image.open(view(d)).convert("RGB"))
            view(d).write_bytes(fn(arr))
        return (label, mutate, True)
    cases.append(mode(lambda a: _png_bytes(a.mean(2).astype(np.uint8)), "grayscale"))
    cases.append(mode(lambda a: _png_bytes((a.mean(2) * 257).astype(np.uint16)), "16-bit grayscale"))
    cases.append(mode(lambda a: _png_bytes(np.dstack([a, np.full(a.shape[:2], 200, np.uint8)])), "RGBA"))
    cases.append(mode(lambda a: _png_bytes(a.mean(2).astype(np.uint8) > 100), "1-bit"))

    def not_an_image(d):
        view(d).write_text("this is not a picture\n")
    cases.append(("text file named .png", not_an_image, False))

    def empty(d):
        view(d).write_bytes(b"")
    cases.append(("empty file", empty, False))
    return cases


IMAGE_CASES = _image_cases()


def test_images(base, tmp_path, monkeypatch):
    outcomes = []
    for k, (label, mutate, may_accept) in enumerate(IMAGE_CASES):
        entries = [["datasets", "check", "input/scene"]] + ([] if may_accept else [run_argv(Path("input/scene"))])
        for j, argv in enumerate(entries):
            case_dir = new_case(tmp_path, f"img{k}-{j}")
            scene = scene_copy(base, case_dir)
            mutate(scene)
            outcomes.append(run_case(case_dir, "images", label, argv, ["view_00.png"], may_accept, monkeypatch))
    record(outcomes)


def _mask_cases():
    W, H = rf.W, rf.H
    rng = random.Random(SEED + 3)

    def mask(d: Path) -> Path:
        return d / "masks" / "view_00.png"

    def put(arr_fn, label, may):
        def mutate(d):
            mask(d).write_bytes(_png_bytes(arr_fn()))
        return (label, mutate, may)
    return [
        put(lambda: np.zeros((H, W + 7), np.uint8), "wrong aspect", False),
        put(lambda: np.zeros((H * 2, W * 2), np.uint8), "twice the size (same aspect)", True),
        put(lambda: np.zeros((H, W), np.uint8), "all zero", True),
        put(lambda: np.full((H, W), 255, np.uint8), "all one", True),
        put(lambda: np.random.default_rng(3).integers(0, 256, (H, W)).astype(np.uint8), "non-binary", True),
        put(lambda: (np.random.default_rng(4).integers(0, 65535, (H, W))).astype(np.uint16), "16-bit", True),
        put(lambda: np.zeros((H, W, 3), np.uint8) + 255, "RGB", True),
        ("truncated", lambda d: truncate_at(mask(d), rng.uniform(0.2, 0.8)), False),
        ("not an image", lambda d: mask(d).write_text("mask"), False),
    ]


MASK_CASES = _mask_cases()


def test_masks(base, tmp_path, monkeypatch):
    outcomes = []
    for k, (label, mutate, may_accept) in enumerate(MASK_CASES):
        entries = [["datasets", "check", "input/scene"]] + ([] if may_accept else [run_argv(Path("input/scene"))])
        for j, argv in enumerate(entries):
            case_dir = new_case(tmp_path, f"mask{k}-{j}")
            scene = scene_copy(base, case_dir)
            mutate(scene)
            outcomes.append(run_case(case_dir, "masks", label, argv, ["view_00.png"], may_accept, monkeypatch))
    record(outcomes)


def test_16bit_and_grayscale_images_load_as_their_8bit_picture(base, tmp_path):
    """Regression: PIL's convert("RGB") clips 16-bit values at 255, which made a 16-bit photo all white."""
    from strings_bench.scene.scene import Scene

    scene_dir = tmp_path / "scene"
    shutil.copytree(base["scene"], scene_dir)
    rgb = np.asarray(Image.open(scene_dir / "images" / "view_00.png").convert("RGB"))
    gray8 = rgb.mean(2).round().astype(np.uint8)
    (scene_dir / "images" / "view_00.png").write_bytes(_png_bytes(gray8.astype(np.uint16) * 257))
    (scene_dir / "images" / "view_01.png").write_bytes(_png_bytes(gray8))
    (scene_dir / "masks" / "view_00.png").write_bytes(_png_bytes(
        (np.asarray(Image.open(base["scene"] / "masks" / "view_00.png")) > 0).astype(np.uint16) * 65535))
    scene = Scene.load(scene_dir)
    want = np.repeat(gray8[:, :, None], 3, axis=2) / 255.0
    np.testing.assert_allclose(scene.load_image(0), want, atol=1 / 255 + 1e-6)
    np.testing.assert_allclose(scene.load_image(1), want, atol=1e-6)
    np.testing.assert_array_equal(scene.load_mask(0), np.asarray(Image.open(base["scene"] / "masks" / "view_00.png")) > 127)


# ---- PLY -------------------------------------------------------------------------------------------
def _split_ply(data: bytes) -> tuple[list[str], bytes]:
    end = data.index(b"end_header\n") + len(b"end_header\n")
    return data[:end].decode("ascii").splitlines(), data[end:]


def _join_ply(header: list[str], body: bytes) -> bytes:
    return ("\n".join(header) + "\n").encode("ascii") + body


def _ply_cases():
    rng = random.Random(SEED + 4)
    cases = []

    def truncated(frac):
        return lambda p: truncate_at(p, frac)
    for k in range(4):
        frac = rng.uniform(0.05, 0.98)
        cases.append((f"truncated at {frac:.3f}", truncated(frac), False))

    def drop_property(name):
        def mutate(p: Path):
            header, body = _split_ply(p.read_bytes())
            props = [ln.split()[-1] for ln in header if ln.startswith("property")]
            n = int(next(ln for ln in header if ln.startswith("element")).split()[2])
            arr = np.frombuffer(body, dtype="<f4").reshape(n, len(props))
            keep = [i for i, q in enumerate(props) if q != name]
            header = [ln for ln in header if not (ln.startswith("property") and ln.split()[-1] == name)]
            p.write_bytes(_join_ply(header, np.ascontiguousarray(arr[:, keep]).tobytes()))
        return mutate
    for name in ("opacity", "scale_1", "rot_0", "x"):
        cases.append((f"missing property {name}", drop_property(name), False))
    cases.append(("wrong SH count (one f_rest removed)", drop_property("f_rest_4"), False))

    def set_value(name, value, row=0):
        def mutate(p: Path):
            header, body = _split_ply(p.read_bytes())
            props = [ln.split()[-1] for ln in header if ln.startswith("property")]
            n = int(next(ln for ln in header if ln.startswith("element")).split()[2])
            arr = np.frombuffer(body, dtype="<f4").reshape(n, len(props)).copy()
            arr[row, props.index(name)] = value
            p.write_bytes(_join_ply(header, arr.tobytes()))
        return mutate
    for name, value in (("x", np.nan), ("scale_0", np.inf), ("opacity", np.nan), ("rot_2", -np.inf),
                        ("f_dc_1", np.nan)):
        cases.append((f"{value} in {name}", set_value(name, value, rng.randrange(30)), False))

    def header_count(delta):
        def mutate(p: Path):
            header, body = _split_ply(p.read_bytes())
            header = [f"element vertex {int(ln.split()[2]) + delta}" if ln.startswith("element") else ln for ln in header]
            p.write_bytes(_join_ply(header, body))
        return mutate
    cases.append(("header claims 5 more vertices", header_count(5), False))
    cases.append(("header claims 1000000000 more vertices", header_count(10 ** 9), False))
    cases.append(("header claims 3 fewer vertices", header_count(-3), True))
    cases.append(("header claims -5 vertices", header_count(-35), False))

    def edit_header(fn, label, may=False):
        def mutate(p: Path):
            header, body = _split_ply(p.read_bytes())
            p.write_bytes(_join_ply(fn(header), body))
        return (label, mutate, may)
    cases.append(edit_header(lambda h: [ln.replace("binary_little_endian", "ascii") for ln in h], "ascii format"))
    cases.append(edit_header(lambda h: [ln.replace("binary_little_endian", "binary_big_endian") for ln in h],
                             "big-endian format"))
    cases.append(edit_header(lambda h: [("element vertex many" if ln.startswith("element") else ln) for ln in h],
                             "non-numeric vertex count"))
    cases.append(edit_header(lambda h: [("property float" if ln.endswith(" y") else ln) for ln in h],
                             "property without a name"))
    cases.append(edit_header(lambda h: [("property quadruple y" if ln.endswith(" y") else ln) for ln in h],
                             "unknown property type"))
    cases.append(edit_header(lambda h: [ln for ln in h if not ln.startswith("format")], "no format line"))
    cases.append(edit_header(lambda h: h[:2] + ["element face 1", "property list uchar int vertex_indices"] + h[2:],
                             "face element before the vertices"))
    cases.append(("not a PLY", lambda p: p.write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(200)), False))
    cases.append(("empty", lambda p: p.write_bytes(b""), False))
    cases.append(("header only, cut before end_header", lambda p: p.write_bytes(p.read_bytes()[:40]), False))
    return cases


PLY_CASES = _ply_cases()


def test_ply(base, tmp_path, monkeypatch):
    outcomes = []
    for k, (label, mutate, may_accept) in enumerate(PLY_CASES):
        case_dir = new_case(tmp_path, f"ply{k}")
        ply = case_dir / "input" / "model.ply"
        shutil.copy(base["ply"], ply)
        mutate(ply)
        argv = ["render", "--ply", "input/model.ply", "--scene", str(base["scene"]), "--out", "out/renders",
                "--device", "cpu"]
        outcomes.append(run_case(case_dir, "PLY", label, argv, ["model.ply"], may_accept, monkeypatch))
    record(outcomes)


# ---- JSON files --------------------------------------------------------------------------------------
BROKEN_JSON = [
    ("truncated JSON", lambda text: text[: max(1, len(text) // 2)]),
    ("not JSON", lambda text: "views: all of them\n"),
    ("empty file", lambda text: ""),
    ("a JSON list", lambda text: "[]"),
    ("a JSON string", lambda text: '"hello"'),
    ("null", lambda text: "null"),
    ("binary garbage", lambda text: "\udcff"),
]


def _annotation_cases():
    good = {"views": {"view_00.png": [{"text": "hello", "polygon": [[8, 12], [56, 12], [56, 30], [8, 30]]}]}}
    cases = [(label, fn, False) for label, fn in BROKEN_JSON]
    typed = [
        ("views is a list", {"views": []}),
        ("views is a string", {"views": "view_00.png"}),
        ("view entry is a dict", {"views": {"view_00.png": {"text": "hello"}}}),
        ("word is a string", {"views": {"view_00.png": ["hello"]}}),
        ("text is missing", {"views": {"view_00.png": [{"polygon": [[0, 0], [1, 0], [1, 1]]}]}}),
        ("polygon is missing", {"views": {"view_00.png": [{"text": "hello"}]}}),
        ("polygon has odd numbers", {"views": {"view_00.png": [{"text": "a", "polygon": [1, 2, 3]}]}}),
        ("polygon holds strings", {"views": {"view_00.png": [{"text": "a", "polygon": [["x", "y"], [1, 2], [3, 4]]}]}}),
        ("polygon holds NaN", {"views": {"view_00.png": [{"text": "a", "polygon": [[float("nan"), 1], [2, 2], [3, 4]]}]}}),
        ("no views key", {"words": good["views"]}),
    ]
    cases += [(label, (lambda text, o=obj: json.dumps(o)), False) for label, obj in typed]
    return cases


def _split_cases():
    cases = [(label, fn, False) for label, fn in BROKEN_JSON]
    typed = [
        ("test is a number", {"test": 5}),
        ("test is a string", {"test": "view_00.png"}),
        ("test holds lists", {"test": [["view_00.png"]]}),
        ("train is a number", {"test": ["view_00.png"], "train": 5}),
        ("train holds numbers", {"test": ["view_00.png"], "train": [1, 2]}),
        ("no test key", {"train": ["view_01.png"]}),
        ("names an unknown image", {"test": ["view_77.png"]}),
        ("every view is a test view", {"test": [f"view_{i:02d}.png" for i in range(rf.N_VIEWS)]}),
        ("a view both train and test", {"test": ["view_00.png"], "train": ["view_00.png", "view_01.png"]}),
        ("no test view", {"test": []}),
    ]
    cases += [(label, (lambda text, o=obj: json.dumps(o)), False) for label, obj in typed]
    return cases


ANNOTATION_CASES = _annotation_cases()
SPLIT_CASES = _split_cases()


def _write_text(path: Path, text: str) -> None:
    path.write_bytes(text.encode("utf-8", "surrogateescape"))


@pytest.mark.parametrize("file_name,cases", [("text_annotations.json", ANNOTATION_CASES), ("split.json", SPLIT_CASES)],
                         ids=["text_annotations", "split"])
def test_scene_json(base, tmp_path, monkeypatch, file_name, cases):
    outcomes = []
    for k, (label, fn, may_accept) in enumerate(cases):
        for j, argv in enumerate([["datasets", "check", "input/scene"], run_argv(Path("input/scene"))]):
            case_dir = new_case(tmp_path, f"{file_name}{k}-{j}")
            scene = scene_copy(base, case_dir)
            _write_text(scene / file_name, fn((scene / file_name).read_text()))
            outcomes.append(run_case(case_dir, file_name, label, argv, [file_name], may_accept, monkeypatch))
    record(outcomes)


def _run_json_cases():
    cases = [(label, fn) for label, fn in BROKEN_JSON]

    def edit(fn):
        def apply(text):
            obj = json.loads(text)
            fn(obj)
            return json.dumps(obj)
        return apply
    cases += [
        ("schedule is a string", edit(lambda o: o.__setitem__("schedule", "tiny"))),
        ("methods is a list", edit(lambda o: o.__setitem__("methods", ["fake-a"]))),
        ("datasets is a number", edit(lambda o: o.__setitem__("datasets", 3))),
        ("method_overrides is a string", edit(lambda o: o.__setitem__("method_overrides", "x"))),
        ("no schedule", edit(lambda o: o.pop("schedule"))),
    ]
    return cases


RUN_JSON_CASES = _run_json_cases()


def test_run_json(base, tmp_path, monkeypatch):
    outcomes = []
    for k, (label, fn) in enumerate(RUN_JSON_CASES):
        for j in range(2):
            case_dir = new_case(tmp_path, f"runjson{k}-{j}")
            run_dir = case_dir / "out" / "run"
            shutil.copytree(base["run"], run_dir)
            _write_text(run_dir / "run.json", fn((run_dir / "run.json").read_text()))
            argv = ["report", "out/run"] if j == 0 else run_argv(base["scene"])
            outcomes.append(run_case(case_dir, "run.json", label, argv, ["run.json"], False, monkeypatch))
    record(outcomes)


def _result_json_cases():
    cases = [(label, fn) for label, fn in BROKEN_JSON]

    def edit(fn):
        def apply(text):
            obj = json.loads(text)
            fn(obj)
            return json.dumps(obj)
        return apply
    for key in ("method", "iteration", "metrics", "timings", "config", "dataset"):
        cases.append((f"no {key}", edit(lambda o, k=key: o.pop(k))))
    cases += [
        ("iteration is a string", edit(lambda o: o.__setitem__("iteration", "many"))),
        ("metrics is a list", edit(lambda o: o.__setitem__("metrics", [1, 2]))),
        ("cer is a string", edit(lambda o: o.__setitem__("cer", "0.5"))),
        ("psnr is a string", edit(lambda o: o["metrics"].__setitem__("psnr", "high"))),
        ("gaussians is a string", edit(lambda o: o.__setitem__("gaussians", "lots"))),
        ("timings is null", edit(lambda o: o.__setitem__("timings", None))),
        ("ocr views is a list", edit(lambda o: o["ocr"].__setitem__("views", []))),
        ("method is a number", edit(lambda o: o.__setitem__("method", 7))),
    ]
    return cases


RESULT_JSON_CASES = _result_json_cases()


def test_result_json(base, tmp_path, monkeypatch):
    outcomes = []
    for k, (label, fn) in enumerate(RESULT_JSON_CASES):
        case_dir = new_case(tmp_path, f"resjson{k}")
        run_dir = case_dir / "out" / "run"
        shutil.copytree(base["run"], run_dir)
        cell = sorted(run_dir.glob("cells/**/result.json"))[-1]
        _write_text(cell, fn(cell.read_text()))
        outcomes.append(run_case(case_dir, "result.json", label, ["report", "out/run"], ["result.json"], False,
                                 monkeypatch))
    record(outcomes)


def _ocr_results_cases():
    cases = [(label, fn) for label, fn in BROKEN_JSON]

    def obj(o):
        return lambda text: json.dumps(o)
    poly = [[8, 12], [56, 12], [56, 30], [8, 30]]
    cases += [
        ("images is a list", obj({"images": []})),
        ("word without text", obj({"images": {"a.png": [{"polygon": poly}]}})),
        ("word without polygon", obj({"images": {"a.png": [{"text": "x"}]}})),
        ("polygon of strings", obj({"images": {"a.png": [{"text": "x", "polygon": [["a", "b"], [1, 2], [3, 4]]}]}})),
        ("polygon flat", obj({"images": {"a.png": [{"text": "x", "polygon": [1, 2, 3, 4]}]}})),
        ("confidence is a string", obj({"images": {"a.png": [{"text": "x", "polygon": poly, "confidence": "high"}]}})),
        ("image entry is a number", obj({"images": {"a.png": 5}})),
        ("two Cloud Vision responses", obj({"images": {"a.png": {"responses": [{}, {}]}}})),
        ("Cloud Vision vertex of strings", obj({"images": {"a.png": {"responses": [{"textAnnotations": [
            {"description": "x"}, {"description": "x", "boundingPoly": {"vertices": [{"x": "a"}]}}]}]}}})),
        ("format unknown", obj({"format": "other/9", "images": {"a.png": []}})),
    ]
    return cases


OCR_RESULTS_CASES = _ocr_results_cases()
# Valid by the format (eval/ocr/results.py): a single-image file holding a word list, or null (a failed OCR).
ACCEPTED_OCR_RESULTS = ("format unknown", "a JSON list", "null")


def test_ocr_results_for_cer(base, tmp_path, monkeypatch):
    outcomes = []
    for k, (label, fn) in enumerate(OCR_RESULTS_CASES):
        for j, side in enumerate(("gt", "pred")):
            case_dir = new_case(tmp_path, f"ocr{k}-{j}")
            for s in ("gt", "pred"):
                shutil.copy(base[s], case_dir / "input" / f"{s}.json")
            bad = case_dir / "input" / f"{side}.json"
            _write_text(bad, fn(bad.read_text()))
            argv = ["cer", "input/gt.json", "input/pred.json", "--out", "out/cer.json"]
            outcomes.append(run_case(case_dir, "OCR results (cer)", label, argv, [f"{side}.json"],
                                     label in ACCEPTED_OCR_RESULTS, monkeypatch))
    record(outcomes)


# ---- photos for `prepare` --------------------------------------------------------------------------
def test_prepare_photos(base, tmp_path, monkeypatch):
    """Broken photos: refused naming the photo before SfM runs (SfM on tiny noise images then fails
    with its own message, which names the folder)."""
    rng = random.Random(SEED + 5)
    outcomes = []
    variants = [
        ("truncated PNG", lambda p: truncate_at(p, rng.uniform(0.1, 0.8)), False),
        ("truncated JPEG", lambda p: (Image.open(p).convert("RGB").save(p.with_suffix(".jpg"), quality=90),
                                      p.unlink(), truncate_at(p.with_suffix(".jpg"), rng.uniform(0.2, 0.8))), False),
        ("text file named .png", lambda p: p.write_text("not a photo"), False),
        ("empty file", lambda p: p.write_bytes(b""), False),
    ]
    for k, (label, mutate, may_accept) in enumerate(variants):
        case_dir = new_case(tmp_path, f"prep{k}")
        photos = case_dir / "input" / "photos"
        shutil.copytree(base["scene"] / "images", photos)
        mutate(photos / "view_03.png")
        argv = ["prepare", "input/photos", "--name", "fuzz", "--out", "out/scene", "--no-masks", "--threads", "1"]
        outcomes.append(run_case(case_dir, "photos (prepare)", label, argv, ["view_03"], may_accept, monkeypatch))
    record(outcomes)


# ---- archives for `datasets download` -------------------------------------------------------------
def _zip(path: Path, members: list[tuple[str, bytes, int | None]]) -> None:
    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        for name, data, mode in members:
            info = zipfile.ZipInfo(name)
            info.compress_type = zipfile.ZIP_DEFLATED
            if mode is not None:
                info.external_attr = mode << 16
            zf.writestr(info, data)


def _tar(path: Path, members: list[tarfile.TarInfo], datas: list[bytes | None]) -> None:
    with tarfile.open(path, "w:gz") as tf:
        for info, data in zip(members, datas):
            tf.addfile(info, io.BytesIO(data) if data is not None else None)


def _tinfo(name, type_=tarfile.REGTYPE, size=0, linkname=""):
    info = tarfile.TarInfo(name)
    info.type = type_
    info.size = size
    info.linkname = linkname
    return info


def _archive_cases():
    ok = b"scene data\n"
    cases = []
    for fmt in ("zip", "tar.gz"):
        def build(members, fmt=fmt):
            def make(path: Path):
                if fmt == "zip":
                    _zip(path, [(n, d, m) for n, d, m, _ in members])
                else:
                    infos, datas = [], []
                    for n, d, m, kind in members:
                        if kind == "sym":
                            infos.append(_tinfo(n, tarfile.SYMTYPE, linkname=d.decode()))
                            datas.append(None)
                        elif kind == "hard":
                            infos.append(_tinfo(n, tarfile.LNKTYPE, linkname=d.decode()))
                            datas.append(None)
                        elif kind == "fifo":
                            infos.append(_tinfo(n, tarfile.FIFOTYPE))
                            datas.append(None)
                        else:
                            infos.append(_tinfo(n, size=len(d)))
                            datas.append(d)
                    _tar(path, infos, datas)
            return make
        cases += [
            (fmt, "member with ..", build([("data/ok.txt", ok, None, "file"), ("data/../../evil.txt", ok, None, "file")])),
            (fmt, "member with an absolute path", build([("/tmp/strings-bench-fuzz-evil.txt", ok, None, "file")])),
            (fmt, "member with a drive letter", build([("C:/evil.txt", ok, None, "file")])),
            (fmt, "symlink out of the target", build([("data/link", b"../../../../etc/passwd", 0o120777, "sym")])),
        ]
        if fmt == "tar.gz":
            cases += [(fmt, "hard link out of the target", build([("data/hard", b"/etc/passwd", None, "hard")])),
                      (fmt, "fifo", build([("data/pipe", b"", None, "fifo")]))]
        else:
            cases += [(fmt, "device file mode", build([("data/dev", b"", 0o020644, "file")]))]
    # A zip bomb: 64 MiB of zeros per member compresses to ~64 KiB; the card's limit is 8 MiB.
    def bomb(path: Path):
        zeros = bytes(64 << 20)
        with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_DEFLATED, compresslevel=9) as zf:
            for i in range(4):
                zf.writestr(f"data/zeros{i}.bin", zeros)
    cases.append(("zip", "zip bomb (256 MiB of zeros)", bomb))

    def lying_bomb(path: Path):
        # The central directory claims 10 bytes; the member inflates to 64 MiB: the count while writing stops it.
        zeros = bytes(64 << 20)
        with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_DEFLATED, compresslevel=9) as zf:
            zf.writestr("data/zeros.bin", zeros)
        data = bytearray(path.read_bytes())
        cd = data.rfind(b"PK\x01\x02")
        struct.pack_into("<I", data, cd + 24, 10)  # uncompressed size in the central directory
        lh = data.find(b"PK\x03\x04")
        struct.pack_into("<I", data, lh + 22, 10)  # and in the local header
        path.write_bytes(bytes(data))
    cases.append(("zip", "zip bomb whose headers lie about the size", lying_bomb))

    def tar_bomb(path: Path):
        with tarfile.open(path, "w:gz", compresslevel=9) as tf:
            info = _tinfo("data/zeros.bin", size=64 << 20)
            tf.addfile(info, io.BytesIO(bytes(64 << 20)))
    cases.append(("tar.gz", "tar bomb (64 MiB of zeros)", tar_bomb))

    def corrupt_zip(path: Path):
        _zip(path, [("data/a.txt", os.urandom(4000), None)])
        data = bytearray(path.read_bytes())
        data[60] ^= 0xFF  # inside the compressed data: a CRC / inflate error on reading
        path.write_bytes(bytes(data))
    cases.append(("zip", "corrupt member data", corrupt_zip))

    def truncated_tar(path: Path):
        _tar(path, [_tinfo("data/a.bin", size=20000)], [os.urandom(20000)])
        truncate_at(path, 0.5)
    cases.append(("tar.gz", "truncated", truncated_tar))

    def truncated_zip(path: Path):
        _zip(path, [("data/a.bin", os.urandom(20000), None)])
        truncate_at(path, 0.7)
    cases.append(("zip", "truncated", truncated_zip))
    cases.append(("zip", "not an archive", lambda path: path.write_bytes(b"<html>login page</html>")))
    return cases


ARCHIVE_CASES = _archive_cases()


def test_archives_for_download(base, tmp_path, monkeypatch):
    from strings_bench.datasets.card import DatasetCard
    from strings_bench.datasets.registry import _REGISTRY, register_dataset

    outcomes = []
    for k, (fmt, label, make) in enumerate(ARCHIVE_CASES):
        case_dir = new_case(tmp_path, f"arch{k}")
        archive = case_dir / "input" / f"data.{fmt}"
        make(archive)
        card_id = f"fuzzdata{k}"
        register_dataset(DatasetCard(
            id=card_id, title="fuzz archive", scenes=[], source="test", licence="test",
            download={"url": archive.resolve().as_uri(), "filename": f"data-{k}.{fmt}", "max_bytes": 8 << 20}))
        try:
            argv = ["datasets", "download", card_id, "--dest", "out/data"]
            o = run_case(case_dir, "archives (download)", f"{fmt}: {label}", argv, [f"data-{k}.{fmt}"], False,
                         monkeypatch)
        finally:
            _REGISTRY.pop(card_id, None)
        left = list((case_dir / "out").rglob("*"))
        if o.status == "refused" and left:  # neither the target nor the temporary extraction folder stays
            o = Outcome(o.kind, o.case, o.entry, "leak", o.rc, f"a refused archive left {left[:5]}")
        assert not Path("/tmp/strings-bench-fuzz-evil.txt").exists()
        assert not (tmp_path / "evil.txt").exists() and not (case_dir / "evil.txt").exists()
        outcomes.append(o)
    record(outcomes)


# ---- the count -------------------------------------------------------------------------------------
ALL_KINDS = {"COLMAP .bin", "COLMAP .txt", "images", "masks", "PLY", "text_annotations.json", "split.json", "run.json",
             "result.json", "OCR results (cer)", "photos (prepare)", "archives (download)"}


def test_zz_at_least_200_cases_recorded(tmp_path_factory):
    """Runs last in this file: when every kind above ran, at least 200 cases were recorded (and all survived)."""
    kinds = {o.kind for o in COLLECTOR.outcomes}
    if kinds != ALL_KINDS:
        pytest.skip(f"only part of the fuzz set ran ({len(kinds)} of {len(ALL_KINDS)} kinds)")
    summary = COLLECTOR.summary()
    assert summary["tried"] >= MIN_CASES, summary["by_kind"]
    assert summary["survived"] == summary["tried"]
    assert set(summary["by_entry_point"]) >= {"datasets check", "prepare", "run", "render", "cer", "report",
                                              "datasets download"}
