"""Cookbook: a method that is not 3DGS, through `Method`. "Nearest view" renders a test view as the training image
whose camera is closest: an image-based baseline with nothing to optimise (docs/cookbook/not-3dgs.md).

Run it:  python examples/cookbook/nearest_view.py
"""

from __future__ import annotations

import numpy as np

from strings_bench.core.method import Method
from strings_bench.core.settings import Setting
from strings_bench.methods import MethodSpec


class NearestView(Method):
    """Render = the training image nearest to the view, by camera-centre distance (plus `view_weight` x the angle
    between the viewing directions, in radians)."""

    def __init__(self, view_weight: float = 0.0):
        self.settings = {"view_weight": view_weight}

    @classmethod
    def settings_schema(cls):
        return [Setting("view_weight", 0.0, "weight of the viewing-direction angle (radians) against distance", "nearest-view")]

    def setup(self, scene, *, downscale=1.0, device="cpu", seed=None):
        self.scene, self.downscale = scene, downscale
        self.train = list(scene.train_idx)
        self.centres = np.stack([scene.camera(i).center for i in self.train])  # (T, 3) world units
        self.dirs = np.stack([scene.camera(i).R[2] for i in self.train])  # (T, 3) optical axes in world coordinates

    def train_step(self, step):
        return 0.0  # nothing to optimise

    def render(self, view_idx):
        cam = self.scene.camera(view_idx)
        cost = np.linalg.norm(self.centres - cam.center, axis=1)
        cost += self.settings["view_weight"] * np.arccos(np.clip(self.dirs @ cam.R[2], -1, 1))
        nearest = self.train[int(np.argmin(cost))]
        return self.scene.load_image(nearest, self.downscale)  # (H, W, 3) float32 in [0, 1]

    def num_gaussians(self):
        return -1  # not a Gaussian method: n/a in the tables

    def state_dict(self):
        return {}  # no training state

    def load_state_dict(self, state):
        pass


SPEC = MethodSpec(name="nearest-view", implementation=NearestView,
                  description="the nearest training image as the render (a cookbook recipe)")


def main() -> None:
    from strings_bench.bench.check import tiny_scene
    from strings_bench.engine.trainer import Trainer
    from strings_bench.scene.scene import Scene

    scene = Scene.load(tiny_scene())
    method = SPEC.build()
    for result in Trainer(method, scene, checkpoints=[1], device="cpu", progress=False).train():
        for name, image in result.renders.items():
            gt = scene.load_image(scene.names.index(name))
            psnr = -10 * np.log10(np.mean((image - gt) ** 2))
            print(f"{name}: render {image.shape[1]}x{image.shape[0]}, PSNR {psnr:.2f} dB against its ground truth")


if __name__ == "__main__":
    main()
