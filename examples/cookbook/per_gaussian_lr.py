"""Cookbook: a per-Gaussian value of your own. Each Gaussian carries a position learning-rate factor, set at
initialisation from its distance to the cameras, inherited by its clones and split children, and applied to its
own position step (docs/cookbook/per-gaussian.md).

Run it:  python examples/cookbook/per_gaussian_lr.py
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from strings_bench.engine.splatting import GaussianSplatting
from strings_bench.methods import MethodSpec


@dataclass
class DepthLRSettings:
    far_gain: float = 0.25  # position-LR factor of the Gaussians farthest from the cameras (the nearest get 1)


class DepthLRSplat(GaussianSplatting):
    """3DGS whose far Gaussians move more slowly: a per-Gaussian factor on the position step."""

    method_settings_cls = DepthLRSettings

    def initial_model(self, scene):
        model = super().initial_model(scene)  # 3DGS: one Gaussian per SfM point
        centres = torch.stack([torch.as_tensor(scene.camera(i).center, dtype=torch.float32)
                               for i in scene.train_idx]).mean(0).to(model.device)
        dist = (model.means.detach() - centres).norm(dim=1)  # (N,) world units
        near_far = (dist - dist.min()) / (dist.max() - dist.min()).clamp_min(1e-12)  # 0 nearest .. 1 farthest
        # An extra: (N,) with the model's rows, not optimised; every densification op keeps it aligned
        # (a clone or a split child copies its parent's value, a pruned Gaussian's row goes with it).
        model.extras["lr_gain"] = 1.0 - (1.0 - self.method_settings.far_gain) * near_far
        return model

    def position_lr_scale(self, step):
        return self.model.extras["lr_gain"]  # (N,): each Gaussian's own factor on its position step


SPEC = MethodSpec(name="depth-lr", implementation=DepthLRSplat,
                  description="3DGS with a per-Gaussian position-LR factor by distance (a cookbook recipe)")


def main() -> None:
    from strings_bench.bench.check import tiny_scene
    from strings_bench.engine.trainer import Trainer
    from strings_bench.scene.scene import Scene

    scene = Scene.load(tiny_scene())
    method = SPEC.build(steps_scale=0.01)
    before = None
    for result in Trainer(method, scene, checkpoints=[1, 100], device="cpu", seed=0, progress=False).train():
        gain = method.model.extras["lr_gain"]
        print(f"step {result.iteration:3d}: {result.gaussians:4d} Gaussians, {len(gain):4d} factors, "
              f"from {gain.min().item():.2f} to {gain.max().item():.2f}")
        before = before or len(gain)
    assert len(method.model.extras["lr_gain"]) == len(method.model) != before  # densified, still one factor each


if __name__ == "__main__":
    main()
