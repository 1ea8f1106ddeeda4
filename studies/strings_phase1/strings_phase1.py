"""Where STRinGS' text stands at the end of phase 1, against 3DGS at the same step (diagnostics).

On one synthetic scene (whose ray-traced geometry is known) and one schedule scale, prints:

1. geometry: distance to the true surface, along a viewing ray, of the SfM text points and of the
   Gaussians made from them by the one-time text densification (Eq. 1);
2. the text-region PSNR (inside the ground-truth text masks, over the test views) at the end of
   phase 1 (T1 = 3000 x scale) of
   - `strings` as in the paper (positions locked in phase 1),
   - `strings-pos-lr` (the paper's ablation: the 3DGS position LR in phase 1),
   - `strings` with the Eq. 1 children moved onto the true surface (an oracle, diagnostic only),
   - `3dgs` after the same number of steps,
   with the share of elongated Gaussians (largest / smallest scale > 10) and the median largest
   scale in training pixels.

    python studies/strings_phase1/strings_phase1.py                                  # extinguisher, scale 0.1
    python studies/strings_phase1/strings_phase1.py --scene books --scale 0.2
    python studies/strings_phase1/strings_phase1.py --width 640 --downscale 2        # SfM on 640x480, train at 320x240

Text-region PSNR is a continuous signal where OCR-CER saturates (short CPU schedules read nothing).
Every run starts from the same seed; timings are the trainer's optimisation time.
"""

from __future__ import annotations

import argparse
import sys

import numpy as np


def text_psnr(scene, renders: dict, downscale: float) -> float:
    """PSNR over the ground-truth text pixels of all test views pooled."""
    se, n = 0.0, 0
    for i in scene.test_idx:
        mask = scene.load_mask(i, downscale)
        if mask is None or not mask.any():
            continue
        gt = np.asarray(scene.load_image(i, downscale), np.float64)
        diff = renders[scene.names[i]].astype(np.float64) - gt
        se += float((diff[mask] ** 2).sum())
        n += int(mask.sum()) * diff.shape[-1]
    return float("nan") if n == 0 else -10 * np.log10(se / n)


def off_surface(world, cameras, xyz: np.ndarray, view_of: np.ndarray) -> np.ndarray:
    """Signed distance along the ray from camera view_of[i] through xyz[i] to the first surface hit
    (> 0: behind the surface)."""
    out = np.empty(len(xyz))
    for v in np.unique(view_of):
        sel = np.nonzero(view_of == v)[0]
        cam = cameras[v]
        origin = -cam.R.T @ cam.t
        d = xyz[sel] - origin
        dist = np.linalg.norm(d, axis=1)
        out[sel] = dist - world.first_hit(origin, d / dist[:, None])
    return out


def nearest_text_point_view(sfm, is_text: np.ndarray, xyz: np.ndarray) -> np.ndarray:
    """The first track view of the text point nearest to each of `xyz` (a view that sees that spot)."""
    from scipy.spatial import cKDTree

    text_idx = np.nonzero(is_text)[0]
    _, nn = cKDTree(sfm.xyz[text_idx]).query(xyz)
    return sfm.track_view[sfm.track_ptr[text_idx[nn]]]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scene", default="extinguisher", help="a synthetic scene name")
    ap.add_argument("--scale", type=float, default=0.1, help="steps_scale (phase 1 = 3000 x scale steps)")
    ap.add_argument("--width", type=int, default=320, help="synthetic image width (height = 3/4)")
    ap.add_argument("--downscale", type=float, default=1)
    ap.add_argument("--runs", default="strings,strings-pos-lr,oracle,3dgs")
    args = ap.parse_args(argv)

    from strings_bench.datasets.synthetic import SyntheticSettings, build_scene
    from strings_bench.datasets.synthetic.generate import make_spec
    from strings_bench.engine.trainer import Trainer, seed_everything
    from strings_bench.methods.registry import get_method
    from strings_bench.scene.scene import Scene

    settings = SyntheticSettings() if args.width == 320 else SyntheticSettings(
        width=args.width, height=args.width * 3 // 4, max_features=2048 * (args.width // 320) ** 2)
    scene = Scene.load(build_scene(args.scene, settings, progress=True), name=args.scene)
    world = make_spec(args.scene, settings.seed).world
    sfm = scene.model
    t1 = round(3000 * args.scale)

    # ---- geometry ------------------------------------------------------------------------------
    probe = get_method("strings").build(steps_scale=args.scale)
    probe.progress = False
    seed_everything(probe.config.seed)
    probe.setup(scene, downscale=args.downscale, device="cpu")  # masks, Algorithm 1, Eq. 1
    dense = probe.model
    is_text = probe.segmentation.is_text
    first_view = sfm.track_view[sfm.track_ptr[:-1]]
    children = dense.params["means"].detach().cpu().numpy().astype(np.float64)
    child_views = nearest_text_point_view(sfm, is_text, children)
    e_points = np.abs(off_surface(world, sfm.cameras, sfm.xyz[is_text], first_view[is_text]))
    e_children = np.abs(off_surface(world, sfm.cameras, children, child_views))
    cam = scene.camera(0, args.downscale)
    depth = np.median(np.linalg.norm(sfm.xyz[is_text] - (-cam.R.T @ cam.t), axis=1))
    pixel = depth / cam.fx  # world size of a training pixel at the text's median depth
    print(f"\n{args.scene}: {sfm.num_points} SfM points, {int(is_text.sum())} text points, "
          f"{len(children)} text Gaussians after Eq. 1 (N_max {probe.n_max}); training pixel = {pixel:.4f} world units")
    print("| what | median off-surface | p90 | median (training px) |")
    print("|---|---|---|---|")
    for label, e in (("SfM text points", e_points), ("Eq. 1 children", e_children)):
        e = e[np.isfinite(e)]
        print(f"| {label} | {np.median(e):.4f} | {np.percentile(e, 90):.4f} | {np.median(e) / pixel:.2f} |")

    # ---- phase 1 -------------------------------------------------------------------------------
    print(f"\nEnd of phase 1 = step {t1} (scale {args.scale:g}, training {cam.width}x{cam.height}):\n")
    print("| run | text-region PSNR (dB) | Gaussians | elongated (max/min scale > 10) | median largest scale (px) | train s |")
    print("|---|---|---|---|---|---|")
    for run in args.runs.split(","):
        method = "strings" if run == "oracle" else run
        trainer = get_method(method).build(steps_scale=args.scale)
        if run == "oracle":
            trainer.initial_model = _snapped(trainer, world)
        for r in Trainer(trainer, scene, [t1], downscale=args.downscale, device="cpu", progress=False).train():
            scales = trainer.model.scales.detach().cpu().numpy()
            elongated = float(np.mean(scales.max(1) > 10 * scales.min(1)))
            print(f"| {run} | {text_psnr(scene, r.renders, args.downscale):.2f} | {r.gaussians} | {elongated:.1%} | "
                  f"{np.median(scales.max(1)) / pixel:.2f} | {r.train_seconds:.1f} |", flush=True)
    return 0


def _snapped(trainer, world):
    """initial_model that moves every text Gaussian onto the true surface along a viewing ray."""
    import torch

    original = trainer.initial_model

    def initial_model(scene):
        model = original(scene)
        sfm = scene.model
        xyz = model.params["means"].detach().cpu().numpy().astype(np.float64)
        views = nearest_text_point_view(sfm, trainer.segmentation.is_text, xyz)
        err = off_surface(world, sfm.cameras, xyz, views)
        origins = np.stack([-sfm.cameras[v].R.T @ sfm.cameras[v].t for v in views])
        d = xyz - origins
        dist = np.linalg.norm(d, axis=1, keepdims=True)
        ok = np.isfinite(err)[:, None]
        moved = np.where(ok, origins + d / dist * (dist - np.where(ok, err[:, None], 0)), xyz)
        with torch.no_grad():
            model.params["means"].copy_(torch.as_tensor(moved, dtype=model.params["means"].dtype))
        return model

    return initial_model


if __name__ == "__main__":
    sys.exit(main())
