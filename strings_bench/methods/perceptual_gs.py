"""Perceptual-GS (Zhou, Ni, ICML 2025) on the suite's engine: a learned per-Gaussian perceptual
sensitivity (BCE against each view's sensitivity map) drives extra densification of high- and
medium-sensitivity Gaussians (engine/strategies/perceptual.py; docs/baselines.md).

Learning rates and schedule: 3DGS' (the release's arguments/__init__.py), plus the sensitivity LR 0.05.

Settings: as 3dgs, plus PerceptualGSStrategy fields (lambda_bce, sensitivity_lr, hd_interval,
md_interval, threshold_high / low, complex_transaction, mix_transaction, od_factor, ...) and
PerceptualGSSettings (the sensitivity maps' preprocessing).
"""

from __future__ import annotations

from dataclasses import dataclass

from strings_bench.core.errors import StringsBenchError
from strings_bench.engine.splatting import GaussianSplatting
from strings_bench.engine.strategies.perceptual import PerceptualGSStrategy, resize_map, sensitivity_map


@dataclass(frozen=True)
class PerceptualGSSettings:
    map_gamma: float = 1.5  # sensitivity maps: grey level ^ (1 / this) (release preprocess.py GAMMA)
    map_edge_threshold: float = 0.05  # Sobel magnitude above this is an edge (THRED_E)
    map_smooth_threshold: float = 0.3  # pooled edge density above this is sensitive (THRED_S)
    map_pool: int = 5  # pooling block, pixels (POOLING_KERNAL_SIZE)

    def __post_init__(self):
        if not self.map_gamma > 0 or self.map_pool < 1:
            raise StringsBenchError("perceptual-gs map_gamma must be > 0 and map_pool >= 1")


class PerceptualGS(GaussianSplatting):
    """Perceptual-GS: sensitivity maps made in `prepare` (from the full-resolution images, as the
    release's preprocessing, then resized to the training size) and attached to the strategy; the
    3DGS loss weighted by 1 - lambda_bce while the strategy adds the BCE term."""

    strategy_cls = PerceptualGSStrategy
    method_settings_cls = PerceptualGSSettings

    def prepare(self, scene) -> None:
        s = self.method_settings
        views = self.train_views()
        cameras = {v: self.camera(v) for v in views}
        maps = {}
        for v in views:
            full = sensitivity_map(scene.load_image(v, 1), s.map_gamma, s.map_edge_threshold,
                                   s.map_smooth_threshold, s.map_pool)
            maps[v] = resize_map(full, cameras[v].width, cameras[v].height)
        self.strategy.attach_views(cameras, maps, background=self.config.background, backend=self.config.backend)

    def loss(self, out, gt, view_idx: int, step: int):
        base = super().loss(out, gt, view_idx, step)
        weight = self.strategy.rgb_weight(self.strategy_step(step))
        return base if weight == 1.0 else base * weight
