"""The paper's phase-1 mechanism, measured: does "drift away from text" happen without the lock?

On a synthetic scene, whose surfaces are known exactly, trains STRinGS' phase 1 (T1 = 3000 x scale
steps) with the position lock (`strings`) and without it (`strings-pos-lr`), and every `--every`
steps measures, over the text Gaussians:

- drift: the distance of each Gaussian's centre from the first surface along a viewing ray (the ray
  from a training camera that sees its SfM point), in training pixels at that depth: median, p90 and
  the share further than 1 px;
- stroke coverage: over the test views, the share of ground-truth text pixels whose rendered alpha
  is above 0.5, and the text-region PSNR;
- clones that cannot move: the share of Gaussians whose centre equals another's exactly.

    python studies/strings_phase1_drift/strings_phase1_drift.py                                     # storeroom, x0.2
    python studies/strings_phase1_drift/strings_phase1_drift.py --scene synthetic/extinguisher --scale 0.1
    python studies/strings_phase1_drift/strings_phase1_drift.py --set init_scales_from=text --set prune_outside_masks=false
    python studies/strings_phase1_drift/strings_phase1_drift.py --csv out.csv                       # every sample as a row

`--set KEY=VALUE` is given to both runs (e.g. an older phase 1's settings). Runs start from the same
seed; the CSV has one row per run and sampled step.
"""

from __future__ import annotations

import argparse
import csv
import sys

import numpy as np


def off_surface_px(world, scene, xyz: np.ndarray, views: np.ndarray, downscale: float) -> np.ndarray:
    """|distance along the ray from camera views[i] through xyz[i] to the first surface| in training
    pixels at xyz[i]'s depth (inf where the ray hits nothing)."""
    out = np.full(len(xyz), np.inf)
    for v in np.unique(views):
        sel = np.nonzero(views == v)[0]
        cam = scene.camera(int(v), downscale)
        origin = cam.center
        d = xyz[sel] - origin
        dist = np.linalg.norm(d, axis=1)
        err = np.abs(dist - world.first_hit(origin, d / dist[:, None]))
        depth = (xyz[sel] - origin) @ cam.R[2]  # camera-space z
        out[sel] = err * cam.fx / np.maximum(depth, 1e-9)
    return out


def measure(method, scene, world, downscale: float) -> dict:
    """Drift, coverage and shared positions of the method's text Gaussians now."""
    import torch

    sfm = scene.model
    model = method.model
    text = model.extras["is_text"].cpu().numpy()
    xyz = model.params["means"].detach().cpu().numpy().astype(np.float64)[text]
    points = model.extras["sfm_point"].cpu().numpy()[text]
    first_view = sfm.track_view[sfm.track_ptr[points]]  # a view that sees the Gaussian's SfM point
    drift = off_surface_px(world, scene, xyz, first_view, downscale)
    drift = drift[np.isfinite(drift)]
    _, counts = np.unique(xyz, axis=0, return_counts=True)
    shared = float(counts[counts > 1].sum()) / max(1, len(xyz))
    covered = total = 0
    se = n = 0.0
    with torch.no_grad():
        for i in scene.test_idx:
            mask = scene.load_mask(i, downscale)
            if mask is None or not mask.any():
                continue
            out = method.render_raster(i, sh_degree=method.sh_degree_for_step(method.step))
            alpha = out.alpha.detach().cpu().numpy().reshape(mask.shape)
            covered += int((alpha[mask] > 0.5).sum())
            total += int(mask.sum())
            gt = np.asarray(scene.load_image(i, downscale), np.float64)
            diff = out.color.detach().clamp(0, 1).cpu().numpy().astype(np.float64) - gt
            se += float((diff[mask] ** 2).sum())
            n += int(mask.sum()) * 3
    return {"text_gaussians": int(len(xyz)), "drift_median_px": float(np.median(drift)),
            "drift_p90_px": float(np.percentile(drift, 90)), "drift_over_1px": float(np.mean(drift > 1)),
            "shared_position": shared, "coverage": covered / max(1, total),
            "text_psnr": float("nan") if n == 0 else float(-10 * np.log10(se / n))}


def run_phase1(name: str, scene, world, scale: float, downscale: float, every: int, settings: dict):
    """Yield (step, measurements) over phase 1 of method `name`, from step 0 (after Eq. 1) to T1."""
    from strings_bench.engine.trainer import seed_everything
    from strings_bench.methods.registry import get_method

    method = get_method(name).build(steps_scale=scale, **settings)
    method.progress = False
    seed_everything(method.config.seed)
    method.setup(scene, downscale=downscale, device="cpu")
    yield 0, measure(method, scene, world, downscale)
    for step in range(1, method.t1 + 1):
        method.train_step(step)
        if step % every == 0 or step == method.t1:
            yield step, measure(method, scene, world, downscale)
        method.refine(step)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scene", default="synthetic360-cpu/storeroom", help="a synthetic scene (registry id)")
    ap.add_argument("--scale", type=float, default=0.2, help="steps_scale (phase 1 = 3000 x scale steps)")
    ap.add_argument("--downscale", type=float, default=1)
    ap.add_argument("--every", type=int, default=100, help="sample every this many steps")
    ap.add_argument("--runs", default="strings,strings-pos-lr")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="a STRinGS setting for every run")
    ap.add_argument("--csv", help="write every sample here")
    args = ap.parse_args(argv)

    from strings_bench.cli.run import parse_settings
    from strings_bench.datasets.registry import resolve_scenes
    from strings_bench.datasets.synthetic import default_settings
    from strings_bench.datasets.synthetic.generate import make_spec
    from strings_bench.scene.scene import Scene

    ref = resolve_scenes([args.scene])[0]
    scene = Scene.load(ref.path, settings=ref.settings)
    synth = default_settings(ref.scene, ref.dataset)
    if ref.settings:
        raise SystemExit(f"{args.scene}: scenes with per-scene settings are not supported here")
    world = make_spec(ref.scene, synth.seed, synth).world
    settings = parse_settings(args.set).get("*", {})
    rows = []
    print(f"{args.scene}, scale {args.scale:g}, downscale {args.downscale:g}, settings {settings or 'default'}")
    print("| run | step | text Gaussians | drift median (px) | p90 (px) | > 1 px | shared position | coverage (alpha > 0.5) | text PSNR (dB) |")
    print("|---|---|---|---|---|---|---|---|---|")
    for name in args.runs.split(","):
        for step, m in run_phase1(name, scene, world, args.scale, args.downscale, args.every, settings):
            rows.append({"run": name, "step": step, **m})
            print(f"| {name} | {step} | {m['text_gaussians']} | {m['drift_median_px']:.2f} | {m['drift_p90_px']:.2f} | "
                  f"{m['drift_over_1px']:.1%} | {m['shared_position']:.1%} | {m['coverage']:.1%} | {m['text_psnr']:.2f} |",
                  flush=True)
    if args.csv:
        with open(args.csv, "w", newline="") as fh:
            w = csv.DictWriter(fh, fieldnames=list(rows[0]))
            w.writeheader()
            w.writerows(rows)
    return 0


if __name__ == "__main__":
    sys.exit(main())
