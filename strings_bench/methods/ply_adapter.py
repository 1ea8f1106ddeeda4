"""Method "ply": evaluate 3DGS models trained elsewhere, saved as PLY files in the 3DGS layout.

Nothing is trained: the PLY is read (`strings_bench.engine.ply.read_ply`) and the scene's test views are
rendered with our rasterizer (`GaussianModel.render`). Settings:

- `ply_path` (required): the PLY file, or a template with `{scene}`, `{dataset}` and `{iteration}`
  placeholders so one setting covers several scenes, e.g.
  `/models/{scene}/point_cloud/iteration_{iteration}/point_cloud.ply` (the 3DGS output layout).
- `iteration` (default 30000): the checkpoint iteration the model stands for; the run records one
  cell at this iteration (labelled e.g. "30K"). A list in `iterations` gives several checkpoints.
- `background` (default black, as 3DGS), `sh_degree` (default: the file's), `backend` (raster backend).
- `train_seconds` (optional): the training time to report; otherwise NaN (tables show n/a).
- `preprocess_seconds` (optional, default 0): preprocessing time of that training, added to the total.

    strings-bench run --methods ply --set ply.ply_path=/models/{scene}/point_cloud.ply --datasets strings360
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Iterator

import numpy as np

from strings_bench.core.errors import StringsBenchError
from strings_bench.core.method import CheckpointResult, MethodAdapter
from strings_bench.core.settings import Setting


class PlyAdapter(MethodAdapter):
    name = "ply"
    paper = ""

    @classmethod
    def settings_schema(cls) -> list[Setting]:
        g = "ply"
        return [Setting("ply_path", None, "PLY file or template with {scene}, {dataset}, {iteration} (required)", g),
                Setting("iteration", 30000, "the checkpoint iteration the model stands for", g),
                Setting("iterations", None, "several checkpoint iterations (a list), instead of iteration", g),
                Setting("background", (0.0, 0.0, 0.0), "render background (3DGS: black)", g),
                Setting("sh_degree", None, "SH degree to render with (None: the file's)", g),
                Setting("backend", "auto", "rasterizer backend", g),
                Setting("train_seconds", None, "training time to report (None: n/a)", g),
                Setting("preprocess_seconds", 0.0, "preprocessing time to report", g)]

    @classmethod
    def fixed_checkpoints(cls, settings: dict) -> list[int]:
        """The runner evaluates these iterations instead of the schedule's (nothing is trained)."""
        its = settings.get("iterations") or [settings.get("iteration", 30000)]
        return sorted(int(i) for i in its)

    def resolve_path(self, scene, iteration: int) -> Path:
        template = self.settings.get("ply_path")
        if not template:
            raise StringsBenchError("method ply needs the setting ply_path",
                                    hint="e.g. --set ply.ply_path=/models/{scene}/point_cloud.ply")
        dataset = scene.root.parent.name
        try:
            path = Path(str(template).format(scene=scene.name, dataset=dataset, iteration=iteration))
        except (KeyError, IndexError) as exc:
            raise StringsBenchError(f"ply_path {template!r} has an unknown placeholder {exc}",
                                    hint="placeholders: {scene}, {dataset}, {iteration}") from exc
        if not path.is_file():
            raise StringsBenchError(f"PLY model {path} (scene {scene.name}, iteration {iteration}) does not exist",
                                    hint="check ply_path; it may use {scene}, {dataset} and {iteration}")
        return path

    def train(self, scene, checkpoints: list[int], downscale: float = 1) -> Iterator[CheckpointResult]:
        import torch

        from strings_bench.engine.ply import read_ply

        bg = tuple(float(x) for x in self.settings.get("background", (0.0, 0.0, 0.0)))
        for it in sorted(checkpoints):
            path = self.resolve_path(scene, it)
            model = read_ply(path)
            renders = {}
            with torch.no_grad():
                for i in scene.test_idx:
                    out = model.render(scene.camera(i, downscale), bg, sh_degree=self.settings.get("sh_degree"),
                                       **({"backend": self.settings["backend"]} if "backend" in self.settings else {}))
                    renders[scene.names[i]] = np.clip(out.color.detach().cpu().numpy(), 0, 1).astype(np.float32)
            yield CheckpointResult(iteration=it, renders=renders,
                                   train_seconds=float(self.settings.get("train_seconds", math.nan)),
                                   gaussians=int(model.params["means"].shape[0]), extra={"ply_path": str(path)},
                                   preprocess_seconds=float(self.settings.get("preprocess_seconds", 0.0)))
