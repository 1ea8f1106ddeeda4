"""Where two machines' runs part: a hash of every stage of the default run's first steps, to compare across machines.

    python tools/fingerprint.py [--steps 150] [--every 10] [--json FILE] [--compare FILE]
    python tools/fingerprint.py --files A.json B.json

`--compare FILE` prints the first entry, in data-path order, where this machine's fingerprint differs from FILE (the
machine's own entries aside), e.g. one committed under docs/results/data/engine-reproducible/; `--files` compares two
fingerprint files without running anything. Both exit 1 when an entry differs.

A CPU training should give the same bits on every x86-64 CPU with AVX2 (docs/reproducibility.md). When two machines'
figures differ, this finds the first stage that differs: run it on both and compare the JSON files line by line
(`diff`). The training is 3DGS on the default run's room (`synthetic360-cpu/storeroom`) at the `cpu` schedule's
scale, seed 0, its steps driven directly (not through the trainer, so its trajectory is not the run's; the same
kernels run). It prints, in data-path order:

- the machine: CPU model, the libraries' versions, the instruction-set record of the CPU kernels;
- library probes on fixed inputs: torch's float32 sqrt (MKL's vsSqrt, rounded by MKL's code branch), a batch of 3x3 float32
  matrix products (torch.bmm, densification's split samples), torch.randn, numpy's float64 exp and sin;
- the scene as the run reads it: its content hash (images, masks, cameras, points, text: scene/content_hash.py), its
  training images, text masks and SfM points (decoded arrays, not file bytes);
- the initial model, then the first step apart (step 1): every gradient, the parameters after Adam;
- the parameters and the Gaussian count every --every steps up to --steps (one call of train_step and refine each,
  as the trainer runs them).

Each entry is a short SHA-256 of the arrays' bytes. Not a timing: it takes about a minute for 150 steps.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import platform
import sys
from pathlib import Path

SCENE = "synthetic360-cpu/storeroom"


def digest(*arrays) -> str:
    """A short SHA-256 of the arrays' dtypes, shapes and bytes (torch tensors or numpy arrays)."""
    import numpy as np

    h = hashlib.sha256()
    for a in arrays:
        if hasattr(a, "detach"):
            a = a.detach().contiguous().cpu().numpy()
        a = np.ascontiguousarray(a)
        h.update(str(a.dtype).encode() + str(a.shape).encode())
        h.update(a.tobytes())
    return h.hexdigest()[:16]


def params_digest(model) -> str:
    return digest(*(v for _, v in sorted(model.params.items())))


def machine() -> dict:
    import importlib.metadata as md

    from strings_bench.core.cpus import isa_record

    versions = {}
    for name in ("numpy", "numba", "llvmlite", "torch", "scipy", "pillow", "opencv-python-headless", "rapidocr"):
        try:
            versions[name] = md.version(name)
        except md.PackageNotFoundError:
            versions[name] = None
    return {"python": platform.python_version(), "glibc": "-".join(platform.libc_ver()), **versions,
            "cpu_kernels": isa_record()}


def probes() -> dict:
    import numpy as np
    import torch

    g = torch.Generator().manual_seed(0)
    x = torch.rand(1 << 16, generator=g) * 10
    a = torch.rand(4096, 3, 3, generator=g) - 0.5
    b = torch.rand(4096, 3, 3, generator=g) - 0.5
    v = np.linspace(-20.0, 20.0, 1 << 16)
    return {"torch.sqrt f32": digest(torch.sqrt(x)), "torch.bmm 3x3 f32": digest(torch.bmm(a, b)),
            "torch.randn": digest(torch.randn(1 << 16, generator=torch.Generator().manual_seed(1))),
            "numpy exp f64": digest(np.exp(v)), "numpy sin f64": digest(np.sin(v))}


def entries(fingerprint: dict, prefix: str = "") -> list[tuple[str, object]]:
    """The fingerprint's entries as (path, value) in data-path order (the order they were written)."""
    out = []
    for key, value in fingerprint.items():
        path = f"{prefix}{key}"
        out += entries(value, path + " / ") if isinstance(value, dict) else [(path, value)]
    return out


def first_difference(mine: dict, theirs: dict) -> dict:
    """Where two fingerprints part: {"probes": the library probes that differ (informative: a probe is not a
    stage of the run), "compared": run entries both files hold that agree before the first difference,
    "first": (path, mine, theirs) of the first run entry that differs or None, "differ": every run entry both hold
    that differs, "one_side": run entries only one
    file holds (e.g. a shorter --steps)}. The machine's own entries and the scene's folder name are not compared."""
    def split(f):  # the scene's folder is a name (the cache key, which names the generator version), not content
        items = [(k, v) for k, v in entries(f) if not k.startswith("machine / ") and k != "scene / folder"]
        return ({k: v for k, v in items if k.startswith("probes / ")},
                [(k, v) for k, v in items if not k.startswith("probes / ")])

    (pa, ra), (pb, rb) = split(mine), split(theirs)
    probes = [k for k in pa if k in pb and pa[k] != pb[k]]
    b = dict(rb)
    common = [(k, v) for k, v in ra if k in b]
    one_side = len(ra) + len(rb) - 2 * len(common)
    differ = [k for k, v in common if v != b[k]]
    found = {"probes": probes, "compared": len(common), "differ": differ, "first": None, "one_side": one_side}
    for n, (key, value) in enumerate(common):
        if value != b[key]:
            return {**found, "compared": n, "first": (key, value, b[key])}
    return found


def report_difference(mine: dict, theirs: dict, mine_name: str, theirs_name: str) -> int:
    def cpu(f):
        return (f.get("machine", {}).get("cpu_kernels") or {}).get("cpu_model", "?")

    d = first_difference(mine, theirs)
    print(f"{mine_name}: {cpu(mine)}\n{theirs_name}: {cpu(theirs)}")
    if d["probes"]:
        print(f"library probes that differ (not stages of the run): {', '.join(k.split(' / ', 1)[1] for k in d['probes'])}")
    if d["one_side"]:
        print(f"{d['one_side']} entries are in one file only (e.g. another --steps) and are not compared")
    if d["first"] is None:
        print(f"the run is the same: all {d['compared']} entries both hold agree")
        return 0
    key, a, b = d["first"]
    print(f"{d['compared']} entries agree, then the first that differs: {key}\n  {mine_name}: {a}\n  {theirs_name}: {b}")
    print(f"{len(d['differ'])} of the entries both hold differ in all: {', '.join(d['differ'][:6])}"
          + (" ..." if len(d["differ"]) > 6 else ""))
    return 1


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--steps", type=int, default=150, help="steps to follow (default 150)")
    ap.add_argument("--every", type=int, default=10, help="a parameter hash every this many steps")
    ap.add_argument("--json", type=Path, default=None, help="also write the fingerprint here")
    ap.add_argument("--compare", type=Path, default=None, metavar="FILE",
                    help="print the first entry where this machine differs from the fingerprint in FILE")
    ap.add_argument("--files", type=Path, nargs=2, default=None, metavar=("A", "B"),
                    help="compare two fingerprint files (nothing is run)")
    args = ap.parse_args(argv)
    if args.files:
        a, b = (json.loads(p.read_text()) for p in args.files)
        return report_difference(a, b, str(args.files[0]), str(args.files[1]))
    theirs = json.loads(args.compare.read_text()) if args.compare else None  # a bad file fails before the run

    import strings_bench  # noqa: F401 - pins the CPU kernels before torch runs any
    try:
        from tools.engine_profile import build_method, load_scene
    except ImportError:  # run as a file (python tools/fingerprint.py): its own folder is on the path
        from engine_profile import build_method, load_scene
    from strings_bench.engine.trainer import cpu_threads, seed_everything

    out: dict = {"machine": machine(), "probes": probes()}
    scene = load_scene(SCENE)
    method = build_method("cpu")
    seed_everything(method.config.seed)
    method.setup(scene, device="cpu")  # decodes the training images (the targets) and builds the initial model
    from strings_bench.scene.content_hash import scene_content_hash

    content = scene_content_hash(scene.root)
    out["scene"] = {"folder": Path(scene.root).name, "content hash": content["hash"],
                    **{f"content hash: {k}": v for k, v in content["parts"].items()},
                    "training views": len(scene.train_idx),
                    "training images": digest(*(method.target(i) for i in scene.train_idx)),
                    "SfM points": digest(scene.model.xyz, scene.model.rgb)}
    out["initial model"] = params_digest(method.model)
    steps = {}
    with cpu_threads():
        for step in range(1, args.steps + 1):  # the trainer's step numbers
            method.train_step(step)
            if step == 1:
                grads = {k: digest(p.grad) for k, p in sorted(method.model.params.items()) if p.grad is not None}
                out["step 1 gradients"] = grads
                out["step 1 parameters after Adam"] = params_digest(method.model)
            method.refine(step)
            if step % args.every == 0 or step == args.steps:
                steps[step] = {"gaussians": method.num_gaussians(), "parameters": params_digest(method.model)}
    out["after step"] = steps
    text = json.dumps(out, indent=1)
    print(text)
    if args.json:
        from strings_bench.core.io import atomic_write_text

        atomic_write_text(args.json, text + "\n")
    if theirs is not None:
        return report_difference(out, theirs, "this machine", str(args.compare))
    return 0


if __name__ == "__main__":
    sys.exit(main())
