"""Mip-Splatting (Yu et al., CVPR 2024) on the suite's engine: the 3D smoothing filter (applied in
torch before rasterisation, recomputed from the training cameras at every densification step) and the
rasterizer's 2D mip filter (engine/strategies/mip.py; docs/baselines.md).

Training renders go through `strategies.mip.render_filtered`; checkpoint renders and saved models
(`--keep-models`) use the model with the filter folded into scales and opacities (`fold_3d_filter`),
so a saved PLY renders the same in any 3DGS viewer that applies the 2D filter.

Settings: as 3dgs, plus MipStrategy fields (mip_2d, filter_every, near, frustum_margin, sigma_scale,
and the DefaultStrategy ones).
"""

from __future__ import annotations

from strings_bench.engine.splatting import GaussianSplatting
from strings_bench.engine.strategies.mip import FILTER_KEY, MipStrategy, fold_3d_filter, render_filtered



class MipSplatting(GaussianSplatting):
    strategy_cls = MipStrategy

    def set_model(self, model) -> None:
        super().set_model(model)  # the strategy receives the training cameras in initialize_state
        self.strategy.update_filter(self.model, self.strategy_state)

    def render_raster(self, view_idx, sh_degree=None, model=None, **kw):
        # the strategy's raster options (the 2D mip filter) apply to every render, checkpoints too
        model = self.model if model is None else model
        kw = {**self.strategy.get_raster_kwargs(0), **kw}
        if FILTER_KEY not in model.extras:  # a folded model renders as is
            return super().render_raster(view_idx, sh_degree=sh_degree, model=model, **kw)
        return render_filtered(model, self.camera(view_idx), self.background, sh_degree=sh_degree,
                               backend=self.config.backend, **kw)

    def model_to_render(self):
        # checkpoint renders are of the folded model, the one a saved PLY holds
        return fold_3d_filter(self.model)

    def save_model(self, path) -> None:
        from strings_bench.engine.ply import write_ply

        write_ply(path, fold_3d_filter(self.model))
