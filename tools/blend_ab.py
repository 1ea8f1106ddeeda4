"""The float32 blend kernels of an older commit against this checkout's, alternating in one process on one captured render.

    python tools/blend_ab.py --old COMMIT [--at 1050] [--view 0] [--reps 30] [--new-first] [--compile-new-here]
                             [--capture FILE] [--json FILE]

A whole training step (tools/engine_ab.py) moves by 10 % from run to run on a shared 2-core machine, more than a
change to one kernel gains, so this times the two blends alone. It restores tools/engine_profile.py's trained 3DGS
state after step --at (cached; 1 050: about 335 000 Gaussians), renders view --view once and keeps the blend's inputs
(the rasterizer hands them to an installed recorder), then calls the forward and the backward blend of both versions
on those inputs in turn, --reps times, the order of the two arms swapped every repetition. The older commit's
`strings_bench/raster/cpu_kernels_f32.py` is read from a `git worktree` of it and imported as a module of its own
(its imports resolve to this checkout, so the commit must share this checkout's `cpu_kernels` helpers). The backward
gets fixed random output gradients (seed 0). Each arm's kernels are loaded from numba's cache where they are there
(the first run compiles them); `--compile-new-here` copies this checkout's kernel file to a new temporary folder, so
that its kernels are compiled in this process instead: with --old HEAD, that compares a kernel compiled in the process
that calls it with the same kernel loaded from the cache (how each arm got its code is printed).

Printed per blend: each arm's median milliseconds and the median over repetitions of new / old (with its quartiles);
and whether both arms gave the same bits (a SHA-256 of every output: colour, transmittance, last contributor and
the per-intersection gradients). Exits 1 when they differ. Run it more than once with the arms' import order
swapped (--new-first): on a 2-core virtual machine the same code imported twice has timed 1.36x apart in one run.
"""

from __future__ import annotations

import argparse
import hashlib
import importlib.util
import json
import pickle
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
KERNELS = "strings_bench/raster/cpu_kernels_f32.py"


def load_kernels(path: Path, name: str):
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module  # numba's cache locates a module's functions by its name
    spec.loader.exec_module(module)
    return module


def how_compiled(module) -> str:
    """'loaded from the cache' or 'compiled in this process', from numba's counters of the two blends."""
    hits = sum(sum(getattr(module, f).stats.cache_hits.values()) for f in ("forward", "backward"))
    misses = sum(sum(getattr(module, f).stats.cache_misses.values()) for f in ("forward", "backward"))
    return "compiled in this process" if misses else "loaded from the cache" if hits else "unknown"


def capture(at: int, view: int, path: Path) -> dict:
    """The blend's inputs of one render of `view` by the profile's 3DGS state after step `at` (cached in `path`)."""
    if path.is_file():
        return pickle.loads(path.read_bytes())
    import torch

    try:
        from tools import engine_profile as ep
    except ImportError:  # run as a file (python tools/blend_ab.py): its own folder is on the path
        import engine_profile as ep

    from strings_bench.core.instrument import StageTimes, recording
    from strings_bench.core.io import cache_root

    scene = ep.load_scene(ep.DEFAULT_SCENE)
    state = ep.trained_states(scene, ep.DEFAULT_SCHEDULE, [at], cache_root() / "engine_profile")[at]
    method = ep.restore(scene, ep.DEFAULT_SCHEDULE, state)
    times = StageTimes()
    with recording(times), torch.no_grad():
        method.render_raster(view, sh_degree=method.sh_degree_for_step(method.step))
    note = times.notes["blend.forward"]
    inputs = {k: note[k] for k in ("tile_start", "lst", "P", "BB", "W", "H", "tiles_x")}
    inputs["gaussians"] = method.num_gaussians()
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp")
    tmp.write_bytes(pickle.dumps(inputs))
    tmp.replace(path)
    return inputs


class Arm:
    """One version's kernels with output buffers of its own."""

    def __init__(self, kernels, b: dict, grad_f: np.ndarray, grad_alpha: np.ndarray):
        self.k, self.b, self.gF, self.gA = kernels, b, grad_f, grad_alpha
        H, W = b["H"], b["W"]
        self.f = np.empty((H, W, 4), np.float32)
        self.T = np.empty((H, W), np.float32)
        self.last = np.empty((H, W), np.int32)
        self.buf = np.empty((b["lst"].shape[0], 12), np.float32)

    def forward(self) -> float:
        b = self.b
        t = time.perf_counter()
        self.k.forward(b["tile_start"], b["lst"], b["P"], b["BB"], b["W"], b["H"], b["tiles_x"], self.f, self.T,
                       self.last)
        return time.perf_counter() - t

    def backward(self) -> float:
        b = self.b
        t = time.perf_counter()
        self.k.backward(b["tile_start"], b["lst"], b["P"], b["BB"], b["W"], b["H"], b["tiles_x"], self.T, self.last,
                        self.gF, self.gA, self.buf)
        return time.perf_counter() - t

    def digest(self) -> str:
        return hashlib.sha256(b"".join(a.tobytes() for a in (self.f, self.T, self.last, self.buf))).hexdigest()[:16]


def compare(old: Arm, new: Arm, reps: int) -> dict:
    """Both blends of both arms, the arms' order swapped every repetition; seconds per call."""
    import numba

    from strings_bench.raster.cpu import CHUNK

    times = {(blend, arm): [] for blend in ("forward", "backward") for arm in ("old", "new")}
    arms = {"old": old, "new": new}
    with numba.parallel_chunksize(CHUNK):  # as the rasterizer calls them
        for arm in arms.values():  # compile or load, and a first call
            arm.forward()
            arm.backward()
        for r in range(reps):
            order = ("old", "new") if r % 2 == 0 else ("new", "old")
            for blend in ("forward", "backward"):
                for name in order:
                    times[blend, name].append(getattr(arms[name], blend)())
    return times


def summary(times: dict) -> dict:
    out = {}
    for blend in ("forward", "backward"):
        old, new = np.array(times[blend, "old"]), np.array(times[blend, "new"])
        ratio = new / old
        out[blend] = {"old_ms": float(np.median(old) * 1e3), "new_ms": float(np.median(new) * 1e3),
                      "new_over_old": float(np.median(ratio)), "q25": float(np.quantile(ratio, 0.25)),
                      "q75": float(np.quantile(ratio, 0.75))}
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--old", required=True, help="the commit whose blend kernels are the reference")
    ap.add_argument("--at", type=int, default=1050, help="the profile's trained state after this step")
    ap.add_argument("--view", type=int, default=0)
    ap.add_argument("--reps", type=int, default=30)
    ap.add_argument("--new-first", action="store_true", help="import this checkout's kernels first")
    ap.add_argument("--compile-new-here", action="store_true",
                    help="compile this checkout's kernels in this process (a copy of the file in a new folder)")
    ap.add_argument("--capture", default=None, help="the captured blend inputs (default: under the system's "
                    "temporary folder, per --at and --view)")
    ap.add_argument("--json", default=None, help="write the figures here")
    args = ap.parse_args(argv)
    if args.reps < 1:
        ap.error("--reps must be at least 1")
    cap = Path(args.capture) if args.capture else Path(tempfile.gettempdir()) / f"blend-ab-{args.at}-{args.view}.pkl"
    b = capture(args.at, args.view, cap)
    try:
        from tools.checkouts import ref_checkout
    except ImportError:  # run as a file (python tools/blend_ab.py): its own folder is on the path
        from checkouts import ref_checkout

    old_file = ref_checkout(args.old) / KERNELS
    if not old_file.is_file():
        print(f"blend_ab: {args.old} has no {KERNELS}", file=sys.stderr)
        return 2
    new_file = REPO / KERNELS
    if args.compile_new_here:  # a file numba has never cached
        new_file = Path(tempfile.mkdtemp(prefix="blend-ab-")) / "cpu_kernels_f32_here.py"
        new_file.write_bytes((REPO / KERNELS).read_bytes())
    loads = [("old", old_file), ("new", new_file)]
    modules = dict((name, load_kernels(path, f"blend_ab_{name}_kernels"))
                   for name, path in (reversed(loads) if args.new_first else loads))
    rng = np.random.default_rng(0)
    grad_f = (rng.standard_normal((b["H"], b["W"], 4)) * 1e-3).astype(np.float32)
    grad_alpha = (rng.standard_normal((b["H"], b["W"])) * 1e-3).astype(np.float32)
    old, new = (Arm(modules[n], b, grad_f, grad_alpha) for n in ("old", "new"))
    figures = summary(compare(old, new, args.reps))
    same = old.digest() == new.digest()
    print(f"blends of one {b['W']}x{b['H']} render: {b.get('gaussians', '?')} Gaussians, {b['lst'].shape[0]} tile "
          f"intersections; {args.reps} repetitions, {'this checkout' if args.new_first else args.old} imported first")
    print("| blend | old ms | new ms | new / old (median of repetitions) | quartiles |")
    print("|---|---|---|---|---|")
    for blend, f in figures.items():
        print(f"| {blend} | {f['old_ms']:.1f} | {f['new_ms']:.1f} | {f['new_over_old']:.3f} | "
              f"{f['q25']:.3f}-{f['q75']:.3f} |")
    print(f"same bits: {same} (old {old.digest()}, new {new.digest()})")
    compiled = {name: how_compiled(modules[name]) for name in ("old", "new")}
    print(f"old arm: {compiled['old']}; new arm: {compiled['new']}")
    if args.json:
        Path(args.json).write_text(json.dumps({"old": args.old, "at": args.at, "view": args.view, "reps": args.reps,
                                               "new_first": args.new_first, "compiled": compiled,
                                               "blends": figures, "same_bits": same,
                                               "intersections": int(b["lst"].shape[0])}, indent=1))
    return 0 if same else 1


if __name__ == "__main__":
    sys.exit(main())
