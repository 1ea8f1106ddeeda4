"""Training speed on the CPU: this suite's engine against OpenSplat, at 3 000, 40 000 and 300 000
Gaussians, on the same scene, cameras, images and step count.

    python tools/opensplat_compare.py --opensplat /path/to/opensplat [--sizes 3000,40000,300000]
                                           [--steps 60,30,12] [--short 3] [--reps 2] [--json]

OpenSplat is not part of this project: build it yourself (docs/results/engine-speed.md, "Against OpenSplat", gives
the commands) and pass the binary. Without `--opensplat` the script says so and stops.

For each size a COLMAP project is written under `--work-dir` (default
`cache_root()/opensplat_compare/<size>`): the training images of synthetic/extinguisher (320x240)
with their cameras, and as the point cloud
- 3 000: the scene's own SfM points (the exact count is printed);
- 40 000 and 300 000: the centres (and degree-0 colours) of the default run's 3DGS model at its 3K
  and 7K checkpoints (tools/engine_profile.py's cached states), subsampled to exactly that many.
Both programs initialise one Gaussian per point (3DGS initialisation) and train with densification
off for these short runs (OpenSplat densifies only after 500 steps; ours is given
refine_start_iter and reset_every out of reach), at SH degree 0 (both raise it after 1 000 steps),
loss 0.8 L1 + 0.2 (1 - SSIM), full resolution (`--num-downscales 0`), on the CPU (`--cpu`), each
with its own default threads on this machine.

Arms, interleaved in every repetition: each program with `--short` steps and with the size's long
step count, every run a fresh process. Per-step time = (long wall - short wall) / (long - short
steps), so start-up (imports, image loading, kNN scales, compiled-kernel loading) cancels;
whole-process times of the long runs are printed beside it, and our Trainer's own train_seconds per
step as a cross-check (under heavy load a short run can outlast a long one, which makes the
difference meaningless: such a repetition is left out of the per-step columns and the output
says so; use more steps then). Medians over repetitions; the ratio is OpenSplat's per-step time
over ours.
"""

from __future__ import annotations

import argparse
import json
import shutil
import statistics
import struct
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

HUGE = 10 ** 9
SH_C0 = 0.28209479177387814


def write_colmap(out: Path, cameras, image_paths, xyz: np.ndarray, rgb: np.ndarray) -> None:
    """A COLMAP binary model (cameras.bin, images.bin, points3D.bin, PINHOLE, no tracks) and
    images/ (copies) at `out`."""
    from scipy.spatial.transform import Rotation

    sparse = out / "sparse" / "0"
    images = out / "images"
    sparse.mkdir(parents=True, exist_ok=True)
    images.mkdir(parents=True, exist_ok=True)
    with open(sparse / "cameras.bin", "wb") as f:
        f.write(struct.pack("<Q", len(cameras)))
        for i, c in enumerate(cameras):
            f.write(struct.pack("<IiQQ", i + 1, 1, int(c.width), int(c.height)))
            f.write(struct.pack("<4d", float(c.fx), float(c.fy), float(c.cx), float(c.cy)))
    with open(sparse / "images.bin", "wb") as f:
        f.write(struct.pack("<Q", len(cameras)))
        for i, (c, src) in enumerate(zip(cameras, image_paths)):
            x, y, z, w = Rotation.from_matrix(np.asarray(c.R, np.float64)).as_quat()
            f.write(struct.pack("<I4d3dI", i + 1, w, x, y, z, *np.asarray(c.t, np.float64), i + 1))
            f.write(Path(src).name.encode() + b"\0")
            f.write(struct.pack("<Q", 0))
            shutil.copyfile(src, images / Path(src).name)
    with open(sparse / "points3D.bin", "wb") as f:
        f.write(struct.pack("<Q", len(xyz)))
        for i in range(len(xyz)):
            f.write(struct.pack("<Q3d3BdQ", i + 1, *map(float, xyz[i]), *map(int, rgb[i]), 0.0, 0))


def point_clouds(sizes: list[int], work: Path) -> dict[int, Path]:
    """One COLMAP project per size (cached)."""
    try:
        from tools import engine_profile as E
    except ImportError:  # run as a file (python tools/opensplat_compare.py): its own folder is on the path
        import engine_profile as E
    import torch

    from strings_bench.core.io import cache_root

    dirs = {n: work / str(n) for n in sizes}
    if all((d / "sparse" / "0" / "points3D.bin").is_file() for d in dirs.values()):
        return dirs
    scene = E.load_scene("synthetic/extinguisher")
    cams = [scene.camera(i) for i in scene.train_idx]
    paths = [scene.image_path(i) for i in scene.train_idx]
    def trained_means(n: int):
        """The smallest of the 3K/7K states with at least n Gaussians (trained only if needed)."""
        for step in (450, 1050):
            path = E.trained_states(scene, "early", [step], cache_root() / "engine_profile")[step]
            params = torch.load(path, weights_only=False)["model"]["params"]
            if params["means"].shape[0] >= n:
                return params
        raise SystemExit(f"no trained state has {n} Gaussians")
    rng = np.random.default_rng(0)
    for n, d in dirs.items():
        if (d / "sparse" / "0" / "points3D.bin").is_file():
            continue
        if n <= scene.model.num_points + 500:
            xyz, rgb = scene.model.xyz, scene.model.rgb
        else:
            params = trained_means(n)
            pick = np.sort(rng.choice(params["means"].shape[0], n, replace=False))
            xyz = params["means"].numpy()[pick].astype(np.float64)
            rgb = np.clip((SH_C0 * params["sh0"].numpy()[pick, 0] + 0.5) * 255, 0, 255).round().astype(np.uint8)
        tmp = d.with_name(d.name + ".tmp")
        shutil.rmtree(tmp, ignore_errors=True)
        write_colmap(tmp, cams, paths, xyz, rgb)
        shutil.rmtree(d, ignore_errors=True)
        tmp.rename(d)
    return dirs


def ours_worker(scene_dir: str, steps: int) -> int:
    """Train this suite's 3DGS (densification off) for `steps` on the project; print JSON."""
    from strings_bench.engine.train_config import TrainConfig
    from strings_bench.engine.strategies.default import DefaultStrategy
    from strings_bench.engine.trainer import Trainer
    from strings_bench.methods.gs3d import GS3D
    from strings_bench.scene.scene import Scene

    scene = Scene.load(scene_dir)
    scene.train_idx = list(range(scene.num_views))  # every view trains, as OpenSplat without --val
    method = GS3D(TrainConfig(steps_scale=1.0), DefaultStrategy(refine_start_iter=HUGE, reset_every=HUGE))
    r = list(Trainer(method, scene, [steps], progress=False, render_test=False, device="cpu").train())[-1]
    print(json.dumps({"train_seconds": r.train_seconds, "gaussians": r.gaussians}))
    return 0


def run_ours(scene_dir: Path, steps: int) -> tuple[float, dict]:
    t0 = time.perf_counter()
    out = subprocess.run([sys.executable, __file__, "--ours-worker", str(scene_dir), str(steps)],
                         capture_output=True, text=True, check=True)
    return time.perf_counter() - t0, json.loads(out.stdout.strip().splitlines()[-1])


def run_opensplat(binary: str, scene_dir: Path, steps: int, out_dir: Path) -> tuple[float, str]:
    t0 = time.perf_counter()
    out = subprocess.run([binary, str(scene_dir), "-n", str(steps), "--num-downscales", "0", "--cpu",
                          "-o", str(out_dir / "splat.ply")], capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if out.returncode != 0:
        raise SystemExit(f"opensplat failed ({out.returncode}):\n{out.stdout[-2000:]}\n{out.stderr[-2000:]}")
    return wall, out.stdout


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--opensplat", help="path of the OpenSplat binary (built separately, see docs/engine.md)")
    ap.add_argument("--sizes", default="3000,40000,300000")
    ap.add_argument("--steps", default="60,30,12", help="long-run steps per size")
    ap.add_argument("--short", type=int, default=3, help="steps of the short runs (start-up reference)")
    ap.add_argument("--reps", type=int, default=2)
    ap.add_argument("--work-dir", default=None)
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--ours-worker", nargs=2, metavar=("SCENE_DIR", "STEPS"), help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.ours_worker:
        return ours_worker(args.ours_worker[0], int(args.ours_worker[1]))
    if not args.opensplat:
        print("opensplat_compare: give the OpenSplat binary with --opensplat PATH; OpenSplat is not part of this "
              "project (docs/engine.md, 'Against OpenSplat', shows how to build it on the CPU)", file=sys.stderr)
        return 2
    if not Path(args.opensplat).is_file():
        print(f"opensplat_compare: {args.opensplat} is not a file", file=sys.stderr)
        return 2
    from strings_bench.core.io import cache_root

    sizes = [int(x) for x in args.sizes.split(",")]
    long_steps = [int(x) for x in args.steps.split(",")]
    if len(long_steps) != len(sizes):
        raise SystemExit("--steps needs one step count per size")
    work = Path(args.work_dir) if args.work_dir else cache_root() / "opensplat_compare"
    dirs = point_clouds(sizes, work)
    out_dir = work / "out"
    out_dir.mkdir(parents=True, exist_ok=True)
    rows = []
    for n, steps in zip(sizes, long_steps):
        reps = []
        for r in range(args.reps):
            got = {}
            order = [("ours", args.short), ("ours", steps), ("opensplat", args.short), ("opensplat", steps)]
            if r % 2:
                order = order[2:] + order[:2]
            for arm, s in order:
                if arm == "ours":
                    wall, info = run_ours(dirs[n], s)
                    got[(arm, s)] = wall
                    if s == steps:
                        got["ours_train_ms"] = info["train_seconds"] / s * 1e3
                        got["gaussians"] = info["gaussians"]
                else:
                    got[(arm, s)] = run_opensplat(args.opensplat, dirs[n], s, out_dir)[0]
            rep = {"ours_ms": (got[("ours", steps)] - got[("ours", args.short)]) / (steps - args.short) * 1e3,
                   "opensplat_ms": (got[("opensplat", steps)] - got[("opensplat", args.short)]) / (steps - args.short) * 1e3,
                   "ours_wall_s": got[("ours", steps)], "opensplat_wall_s": got[("opensplat", steps)],
                   "ours_train_ms": got["ours_train_ms"], "gaussians": got["gaussians"]}
            rep["ratio"] = rep["opensplat_ms"] / rep["ours_ms"]
            reps.append(rep)
            print(f"size {n}, rep {r}: ours {rep['ours_ms']:.0f} ms/step (train_seconds {rep['ours_train_ms']:.0f}), "
                  f"OpenSplat {rep['opensplat_ms']:.0f} ms/step, ratio {rep['ratio']:.2f}; whole process "
                  f"{rep['ours_wall_s']:.1f} s vs {rep['opensplat_wall_s']:.1f} s", file=sys.stderr, flush=True)
        # A repetition whose short run outlasted its long one (either program) measured the load, not a
        # step: it is left out of the per-step medians, and the row says how many were kept.
        valid = [x for x in reps if x["ours_ms"] > 0 and x["opensplat_ms"] > 0]
        row = {"size": n, "gaussians": reps[0]["gaussians"], "steps": steps, "short": args.short, "reps": args.reps,
               "valid_reps": len(valid)}
        for key in ("ours_ms", "opensplat_ms", "ratio", "ours_wall_s", "opensplat_wall_s", "ours_train_ms"):
            pool = valid if key in ("ours_ms", "opensplat_ms", "ratio") else reps
            row[key] = statistics.median(x[key] for x in pool) if pool else float("nan")
            row[key + "_range"] = [min(x[key] for x in pool), max(x[key] for x in pool)] if pool else [float("nan")] * 2
        rows.append(row)
    if args.json:
        print(json.dumps(rows, indent=1))
        return 0
    print("| Gaussians | steps | ours ms/step | (ours, train_seconds) | OpenSplat ms/step | OpenSplat / ours | "
          "whole process, ours | whole process, OpenSplat |")
    print("|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['gaussians']} | {r['steps']} | {r['ours_ms']:.0f} | {r['ours_train_ms']:.0f} | {r['opensplat_ms']:.0f} | "
              f"{r['ratio']:.2f} ({r['ratio_range'][0]:.2f}-{r['ratio_range'][1]:.2f}) | {r['ours_wall_s']:.1f} s | "
              f"{r['opensplat_wall_s']:.1f} s |")
    for r in rows:
        if r["valid_reps"] < r["reps"]:
            print(f"({r['gaussians']} Gaussians: {r['reps'] - r['valid_reps']} of {r['reps']} repetitions left out of the "
                  "per-step columns, a short run having outlasted its long one; use more steps under load)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
