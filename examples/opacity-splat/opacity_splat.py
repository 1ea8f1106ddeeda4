"""OpacitySplat: 3DGS with a penalty on the mean opacity, as a method of strings-bench.

The method of the tutorial docs/guide/adding-a-method.md. It changes one hook of 3DGS (the loss) and adds one
setting; everything else (initialisation, densification, the schedules, checkpoints, evaluation) is 3DGS'.

Check it:   PYTHONPATH=examples/opacity-splat strings-bench methods check opacity_splat:OpacitySplat
Install it: pip install -e examples/opacity-splat   (then it is the method `opacity-splat` of every command)
"""

from __future__ import annotations

from dataclasses import dataclass

from strings_bench.engine.splatting import GaussianSplatting
from strings_bench.methods import MethodSpec


@dataclass
class OpacitySettings:
    # The comment beside each field is its meaning: `strings-bench methods show opacity-splat` prints it.
    opacity_reg: float = 0.01  # weight of the mean-opacity penalty added to the 3DGS loss


class OpacitySplat(GaussianSplatting):
    """3DGS whose loss also penalises the mean opacity, pushing unneeded Gaussians towards transparency."""

    method_settings_cls = OpacitySettings  # its fields become settings next to 3DGS' own

    def loss(self, out, gt, view_idx, step):
        base = super().loss(out, gt, view_idx, step)  # 0.8 L1 + 0.2 (1 - SSIM)
        return base + self.method_settings.opacity_reg * self.model.opacities.mean()


# What `strings-bench` knows about the method: its name, where the class is, and what the tables show.
SPEC = MethodSpec(
    name="opacity-splat",
    implementation="opacity_splat:OpacitySplat",
    description="3DGS with a mean-opacity penalty (the tutorial's example method)",
    title="OpacitySplat",
)
