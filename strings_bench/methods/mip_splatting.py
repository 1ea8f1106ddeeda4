"""Mip-Splatting (Yu et al., CVPR 2024) on the suite's engine: the 3D smoothing filter (applied in
torch before rasterisation, recomputed from the training cameras at every densification step) and the
rasterizer's 2D mip filter (strategies/mip.py; docs/baselines.md).

The engine's Trainer renders `model.render(...)`; Mip-Splatting needs the filtered scales and
opacities in that path, so it trains with `MipTrainer`, a Trainer whose `render` goes through
`strategies.mip.render_filtered`. Checkpoint renders use the same path, and a checkpoint PLY
(`ply_dir`) is written with the filter folded into scales and opacities (`fold_3d_filter`).

Settings: as 3dgs, plus MipStrategy fields (mip_2d, filter_every, near, frustum_margin, sigma_scale,
and the DefaultStrategy ones).
"""

from __future__ import annotations

import copy

from strings_bench.engine.strategies.mip import FILTER_KEY, MipStrategy, fold_3d_filter, render_filtered
from strings_bench.methods.gs3d import SPEC as GS3D_SPEC
from strings_bench.methods.gs3d import GS3DAdapter
from strings_bench.methods.registry import MethodSpec, register_method

PAPER = "Yu, Chen, Huang, Sattler, Geiger: Mip-Splatting: Alias-free 3D Gaussian Splatting (CVPR 2024)"


def _trainer_cls():
    from strings_bench.engine.trainer import Trainer

    class MipTrainer(Trainer):
        def set_model(self, model) -> None:
            super().set_model(model)
            cams = [self.camera(i) for i in self.train_views()]
            self.strategy_state["train_cameras"] = cams
            self.strategy.update_filter(self.model, self.strategy_state)

        def render(self, view_idx, sh_degree=None, **kw):
            # the strategy's raster options (the 2D mip filter) also apply to checkpoint renders,
            # which the base Trainer renders without them
            kw = {**self.strategy.get_raster_kwargs(0), **kw}
            if FILTER_KEY not in self.model.extras:  # a folded model (checkpoint) renders as is
                return super().render(view_idx, sh_degree=sh_degree, **kw)
            return render_filtered(self.model, self.camera(view_idx), self.background, sh_degree=sh_degree,
                                   backend=self.config.backend, **kw)

        def checkpoint(self, *args, **kwargs):
            live = self.model
            self.model = fold_3d_filter(live)  # PLY export and renders see the baked-in filter
            try:
                return super().checkpoint(*args, **kwargs)
            finally:
                self.model = live

    return MipTrainer


class MipSplattingAdapter(GS3DAdapter):
    name = "mip-splatting"
    paper = PAPER
    strategy_cls = MipStrategy

    def make_trainer(self, scene, checkpoints, downscale):
        from strings_bench.engine.trainer import config_from_settings

        config, strategy = config_from_settings(self.settings, checkpoints, downscale, self.strategy_cls)
        config.progress = config.progress and self.progress
        return _trainer_cls()(scene, config, strategy)


SPEC = register_method(MethodSpec(
    name="mip-splatting",
    factory=MipSplattingAdapter,
    description="Mip-Splatting: 3D smoothing filter from the training cameras' sampling rate + 2D mip filter",
    paper=PAPER,
    defaults={"steps_scale": 1.0},
    presets=copy.deepcopy(GS3D_SPEC.presets),
))
