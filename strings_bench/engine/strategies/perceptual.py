"""Perceptual-GS (Zhou, Ni: "Perceptual-GS: Scene-adaptive Perceptual Densification for Gaussian
Splatting", ICML 2025, arXiv 2506.12400): 3DGS densification plus densification driven by a learned
per-Gaussian perceptual sensitivity.

Values from the authors' release (github.com/eezkni/Perceptual-GS: preprocess.py, train.py,
scene/gaussian_model.py, arguments/__init__.py). Iteration numbers are nominal (x steps_scale).

- Perceptual sensitivity map of each training image (preprocess.py, `sensitivity_map`): grey level,
  gamma 1/1.5, Sobel magnitude > 0.05 ("enhancement"), 5x5 average pooling, nearest upsampling, > 0.3
  ("smoothing"); binary at the image's own resolution, resized to the training resolution.
- Every Gaussian carries a sensitivity s = sigmoid(logit) (init 0.1, Adam LR 0.05), kept in
  `model.extras["sensitivity_logit"]`. Up to iteration 15 000 each step also renders the colour 1 - s
  and adds the binary cross-entropy between 1 - render and the view's map; the loss is
  0.9 x (3DGS loss) + 0.1 x BCE (`lambda_bce`; the method scales the 3DGS part, `rgb_weight`). The BCE
  gradient reaches the geometry too, as in the release (one loss, one backward).
- "trans": at iterations that are multiples of 1 000 or 1 500 (from 1 000, up to 15 000), every
  training view is rendered and each Gaussian's largest sum over pixels of alpha T
  (`contrib.blend_weight_sums`) is kept.
- Densification (every 100 in (500, 15 000)): 3DGS clone/split on the mean gradient >= 2e-4, plus
  - high-sensitivity densification (HD, at multiples of 1 000 from 1 000): s >= 0.9 and trans > 25
    px: cloned when small (<= 0.01 x extent), split when large; in "split only" scenes split
    whatever the size;
  - medium-sensitivity densification (MD, at multiples of 1 500 from 1 500): 0.3 < s < 0.9 and
    trans > 10 px: split whatever the size;
  - opacity decline of every cloned Gaussian (and its clone): o <- o^1.2 / (1 + sqrt(1 - o^1.2)).
  A Gaussian cloned on its gradient and split by HD/MD in the same round keeps its clone, as in the
  release (clone first, then split over the originals). trans is cleared after these rounds. Pruning and opacity reset as 3DGS.
- Scene classification at iteration 600: "split only" when on average more than 85 % of a view's
  pixels have a non-zero map value; "sparse" when, among the 25 % largest Gaussians, more than 55 %
  have 0.3 < s < 0.9. The release reinitialises sparse scenes from rendered depth (5 000, 10 000,
  15 000) and skips their opacity resets; that is not implemented here: the classification is kept in
  the state and a warning names it (docs/baselines.md).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F

from strings_bench.core.errors import StringsBenchError
from strings_bench.engine.gaussians import GaussianModel
from strings_bench.engine.optim import ADAM_EPS, GaussianAdam
import strings_bench.engine.strategies.ops as ops
from strings_bench.engine.strategies.contrib import blend_weight_sums
from strings_bench.engine.strategies.default import DefaultStrategy
from strings_bench.raster.sh import SH_C0

log = logging.getLogger(__name__)

SENSITIVITY_KEY = "sensitivity_logit"


def sensitivity_map(image: np.ndarray, gamma: float = 1.5, edge_threshold: float = 0.05,
                    smooth_threshold: float = 0.3, pool: int = 5) -> torch.Tensor:
    """Perceptual-GS' perceptual sensitivity map of one image (release preprocess.py).

    The (H, W, 3) float image in [0, 1] becomes 8-bit (x 255, rounded: the release reads the image
    files), grey (PIL "L"), gamma-corrected through PIL's point table 255 (x / 255)^(1 / gamma); then,
    on x / 255: Sobel magnitude (3x3, zero padding), > edge_threshold, average pooling over
    non-overlapping pool x pool blocks, nearest upsampling to (H, W), > smooth_threshold.

    Returns:
        (H, W) float32 tensor of 0 and 1.
    """
    from PIL import Image

    arr = np.asarray(image, dtype=np.float32)
    if arr.ndim != 3 or arr.shape[2] != 3:
        raise StringsBenchError(f"sensitivity_map expects an (H, W, 3) image, got shape {arr.shape}")
    h, w = arr.shape[:2]
    if h < pool or w < pool:
        raise StringsBenchError(f"sensitivity_map: image {w}x{h} is smaller than the {pool}x{pool} pooling")
    rgb8 = np.round(np.clip(arr, 0.0, 1.0) * 255.0).astype(np.uint8)
    grey = Image.fromarray(rgb8, mode="RGB").convert("L").point(lambda x: 255 * (x / 255) ** (1 / gamma))
    x = torch.from_numpy(np.asarray(grey, dtype=np.float32) / 255.0)[None, None]
    sobel_x = torch.tensor([[-1.0, 0.0, 1.0], [-2.0, 0.0, 2.0], [-1.0, 0.0, 1.0]], device=x.device)[None, None]
    gx = F.conv2d(x, sobel_x, padding=1)
    gy = F.conv2d(x, sobel_x.transpose(2, 3), padding=1)
    edges = (torch.sqrt(gx ** 2 + gy ** 2) > edge_threshold).to(torch.float32)
    pooled = F.avg_pool2d(edges, kernel_size=pool)
    smoothed = F.interpolate(pooled, size=(h, w), mode="nearest")
    return (smoothed > smooth_threshold).to(torch.float32)[0, 0]


def resize_map(sens: torch.Tensor, width: int, height: int) -> torch.Tensor:
    """A [0, 1] map resized as the release loads it (8-bit grey PNG, PIL's default resampling), in [0, 1]."""
    from PIL import Image

    if tuple(sens.shape) == (height, width):
        return sens.to(torch.float32)
    img = Image.fromarray(np.round(sens.cpu().numpy() * 255).astype(np.uint8), mode="L").resize((width, height))
    return torch.from_numpy(np.asarray(img, dtype=np.float32) / 255.0).clamp(0.0, 1.0)


def opacity_decline(opacity: torch.Tensor, factor: float = 1.2) -> torch.Tensor:
    """Perceptual-GS' opacity decline of cloned Gaussians: o^f / (1 + sqrt(1 - o^f))."""
    of = opacity.clamp(0.0, 1.0) ** factor
    return of / (1.0 + torch.sqrt(1.0 - of))


@dataclass
class PerceptualGSStrategy(DefaultStrategy):
    """Perceptual-GS (see the module docstring). The method attaches its training views' sensitivity
    maps with `attach_views`; fields are nominal settings."""

    lambda_bce: float = 0.1  # loss = (1 - this) 3DGS loss + this BCE(1 - rendered (1 - s), map)
    sensitivity_lr: float = 0.05  # Adam learning rate of the sensitivity logits
    sensitivity_init: float = 0.1  # initial sensitivity of every Gaussian
    sensitivity_until: int = 15_000  # the BCE term and the trans statistic up to this step (nominal)
    hd_interval: int = 1_000  # high-sensitivity densification at multiples of this (nominal)
    md_interval: int = 1_500  # medium-sensitivity densification at multiples of this (nominal)
    hd_md_from: int = 1_000  # HD / MD from this step (nominal)
    threshold_high: float = 0.9  # sensitivity >= this: high ("complex")
    threshold_low: float = 0.3  # sensitivity <= this: low; in between: medium ("mix")
    complex_transaction: float = 25.0  # HD needs trans (max over views of sum alpha T, pixels) > this
    mix_transaction: float = 10.0  # MD needs trans > this
    opacity_decline: bool = True  # cloned Gaussians' opacity o <- o^f / (1 + sqrt(1 - o^f))
    od_factor: float = 1.2  # f of the opacity decline
    classify_iter: int = 600  # scene classification (split-only, sparse) at this step (nominal)
    split_only_fraction: float = 0.85  # split-only scene: mean fraction of non-zero map pixels > this
    sparse_mix_rate: float = 0.55  # sparse scene: medium-sensitivity share of the largest Gaussians > this
    sparse_large_fraction: float = 0.25  # ... among this fraction of largest Gaussians

    def __post_init__(self):
        if not 0.0 <= self.lambda_bce < 1.0:
            raise StringsBenchError(f"perceptual-gs lambda_bce must be in [0, 1), got {self.lambda_bce}")
        if not 0.0 < self.sensitivity_init < 1.0:
            raise StringsBenchError(f"perceptual-gs sensitivity_init must be in (0, 1), got {self.sensitivity_init}")
        self._views: dict | None = None
        self._leaf: tuple | None = None  # (model, leaf) of this step's sensitivity render, for its Adam step

    def attach_views(self, cameras: dict, maps: dict, background=(0.0, 0.0, 0.0), backend: str = "auto") -> None:
        """The training views: {view_idx: Camera}, {view_idx: (H, W) sensitivity map at the training size}."""
        missing = sorted(set(cameras) - set(maps))
        if missing:
            raise StringsBenchError(f"perceptual-gs: no sensitivity map for training view(s) {missing[:5]}")
        self._views = {"order": sorted(cameras), "cameras": dict(cameras), "maps": dict(maps),
                       "background": torch.as_tensor(background, dtype=torch.float32, device="cpu"), "backend": backend}

    def _require_views(self) -> dict:
        if self._views is None:
            raise StringsBenchError("perceptual-gs: no sensitivity maps attached",
                                    hint="the perceptual-gs method attaches them in prepare(); a strategy used "
                                         "alone needs strategy.attach_views(cameras, maps)")
        return self._views

    def initialize_state(self, scene_extent: float, cameras=None) -> dict:
        """`DefaultStrategy.initialize_state` plus trans, the sensitivity's Adam moments and step, the scene's class
        (split_only, sparse, classified) and the HD / MD counters."""
        state = super().initialize_state(scene_extent, cameras)
        state.update(trans=None, sens_exp_avg=None, sens_exp_avg_sq=None, sens_step=0, split_only=False,
                     sparse=False, classified=False, n_hd=0, n_md=0)
        return state

    # ---- the sensitivity and its loss ----------------------------------------------------------
    def sensitivity_logits(self, model: GaussianModel) -> torch.Tensor:
        """The (N,) sensitivity logits (created at `sensitivity_init` when the model has none)."""
        sens = model.extras.get(SENSITIVITY_KEY)
        if sens is None or sens.shape[0] != len(model):
            sens = torch.full((len(model),), math.log(self.sensitivity_init / (1 - self.sensitivity_init)),
                              dtype=torch.float32, device=model.device)
            model.extras[SENSITIVITY_KEY] = sens
        return sens

    def bce_active(self, step: int) -> bool:
        """Whether the BCE term is on at `step` (the strategy's step): up to `sensitivity_until`, scaled."""
        return self.lambda_bce > 0 and step <= round(self.sensitivity_until * self.context.steps_scale)

    def rgb_weight(self, step: int) -> float:
        """The factor on the 3DGS loss at `step`: 1 - lambda_bce while the BCE term is on, else 1."""
        return 1.0 - self.lambda_bce if self.bce_active(step) else 1.0

    def loss_terms(self, model: GaussianModel, info: dict, step: int):
        """lambda_bce x BCE(1 - render of (1 - s), the view's map) while the BCE term is on."""
        self._leaf = None
        if not self.bce_active(step):
            return 0.0
        views = self._require_views()
        leaf = self.sensitivity_logits(model).detach().requires_grad_(True)
        colour = 1.0 - torch.sigmoid(leaf)
        dc = ((colour - 0.5) / SH_C0)[:, None, None].expand(-1, 1, 3)
        from strings_bench.raster import rasterize

        p = model.params
        out = rasterize(p["means"], p["quats"], p["log_scales"], p["opacity_logits"], dc, info["camera"],
                        views["background"].to(model.device), sh_degree=0, backend=views["backend"])
        target = views["maps"][info["view_idx"]].to(out.color.device)
        # torch's BCE needs inputs in [0, 1]; rounding can leave the render a hair outside
        pred = (1.0 - out.color[..., 0]).clamp(0.0, 1.0)
        self._leaf = (model, leaf)
        return self.lambda_bce * F.binary_cross_entropy(pred, target)

    @torch.no_grad()
    def _sensitivity_adam_step(self, model: GaussianModel, state: dict) -> None:
        """One Adam step (LR sensitivity_lr, the engine's betas and eps) on the sensitivity logits."""
        held, self._leaf = self._leaf, None
        if held is None or held[0] is not model or held[1].grad is None:
            return
        grad = held[1].grad
        sens = self.sensitivity_logits(model)
        if grad.shape != sens.shape:
            return
        if state.get("sens_exp_avg") is None or state["sens_exp_avg"].shape != sens.shape:
            state["sens_exp_avg"] = torch.zeros_like(sens)
            state["sens_exp_avg_sq"] = torch.zeros_like(sens)
        b1, b2 = 0.9, 0.999
        state["sens_step"] += 1
        m, v = state["sens_exp_avg"], state["sens_exp_avg_sq"]
        m.mul_(b1).add_(grad, alpha=1 - b1)
        v.mul_(b2).addcmul_(grad, grad, value=1 - b2)
        bc1, bc2 = 1 - b1 ** state["sens_step"], 1 - b2 ** state["sens_step"]
        sens.sub_(self.sensitivity_lr / bc1 * m / ((v.sqrt() / math.sqrt(bc2)).add_(ADAM_EPS)))

    # ---- statistics and schedule ---------------------------------------------------------------
    def is_hd_round(self, state: dict, step: int) -> bool:
        """Whether `step` is a high-sensitivity densification round (every `hd_interval` from `hd_md_from`)."""
        return step >= self.at(self.hd_md_from) and step % self.every(self.hd_interval) == 0

    def is_md_round(self, state: dict, step: int) -> bool:
        """Whether `step` is a medium-sensitivity densification round (every `md_interval` from `hd_md_from`)."""
        return step >= self.at(self.hd_md_from) and step % self.every(self.md_interval) == 0

    def step_post_backward(self, model: GaussianModel, optimizer: GaussianAdam, state: dict, step: int,
                           info: dict) -> None:
        """The sensitivity's Adam step, trans before HD / MD rounds, the scene classification at `classify_iter`,
        then 3DGS' refinement with the HD / MD densification (`densify`)."""
        self._sensitivity_adam_step(model, state)
        self.sensitivity_logits(model)
        if step <= self.at(self.sensitivity_until) and (self.is_hd_round(state, step)
                                                               or self.is_md_round(state, step)):
            self.update_trans(model, state)
        if not state["classified"] and step >= self.at(self.classify_iter):
            self.classify_scene(model, state)
        super().step_post_backward(model, optimizer, state, step, info)

    @torch.no_grad()
    def update_trans(self, model: GaussianModel, state: dict) -> None:
        """trans = max(trans, largest over the training views of sum over pixels of alpha T)."""
        views = self._require_views()
        trans = state.get("trans")
        if trans is None or trans.shape[0] != len(model):
            trans = torch.zeros(len(model), device=model.device)
        with torch.enable_grad():
            for v in views["order"]:
                trans = torch.maximum(trans, blend_weight_sums(model, views["cameras"][v], backend=views["backend"]))
        state["trans"] = trans

    @torch.no_grad()
    def classify_scene(self, model: GaussianModel, state: dict) -> None:
        """The release's scene classification at iteration 600 (split-only and sparse)."""
        views = self._require_views()
        state["classified"] = True
        fractions = [float((m > 0).float().mean()) for m in views["maps"].values()]
        state["split_only"] = bool(np.mean(fractions) > self.split_only_fraction) if fractions else False
        s = torch.sigmoid(self.sensitivity_logits(model))
        size = model.scales.max(dim=-1).values
        k = max(1, int(len(model) * self.sparse_large_fraction))
        large = size >= torch.topk(size, k).values.min()
        mixed = (s[large] > self.threshold_low) & (s[large] < self.threshold_high)
        state["mix_rate"] = float(mixed.float().mean()) if large.any() else 0.0
        state["sparse"] = state["mix_rate"] > self.sparse_mix_rate
        if state["sparse"]:
            log.warning("perceptual-gs: the scene is classified sparse (mixed-sensitivity share %.2f of the largest "
                        "Gaussians > %.2f); the release would reinitialise it from rendered depth and skip opacity "
                        "resets, which this implementation does not (docs/baselines.md)",
                        state["mix_rate"], self.sparse_mix_rate)

    # ---- densification ---------------------------------------------------------------------------
    def _select(self, model: GaussianModel, state: dict, step: int) -> tuple[torch.Tensor, torch.Tensor]:
        """(clone, split): 3DGS' gradient rule, plus HD and MD at their rounds (module docstring)."""
        clone, split = super()._select(model, state, step)
        trans = state.get("trans")
        if trans is None or trans.shape[0] != len(model):
            return clone, split
        s = torch.sigmoid(self.sensitivity_logits(model))
        is_small = model.scales.max(dim=-1).values <= self.grow_scale3d * state["scene_extent"]
        if self.is_hd_round(state, step):
            hd = (s >= self.threshold_high) & (trans > self.complex_transaction)
            if state["split_only"]:
                split = split | hd
            else:
                clone, split = clone | (hd & is_small), split | (hd & ~is_small)
            state["n_hd"] += int(hd.sum())
        if self.is_md_round(state, step):
            md = (s > self.threshold_low) & (s < self.threshold_high) & (trans > self.mix_transaction)
            split = split | md  # a Gaussian may be cloned and split in one round, as in the release
            state["n_md"] += int(md.sum())
        return clone, split

    @torch.no_grad()
    def _grow(self, model: GaussianModel, optimizer: GaussianAdam, state: dict, clone: torch.Tensor,
              split: torch.Tensor) -> None:
        """Opacity decline of the clones' parents, clone, split; new rows get fresh sensitivity moments and trans 0."""
        if self.opacity_decline and clone.any():
            o = model.opacities.detach()[clone]
            declined = torch.logit(opacity_decline(o, self.od_factor).clamp(1e-7, 1 - 1e-7))
            model.params["opacity_logits"].data[clone] = declined.to(model.params["opacity_logits"].dtype)
        n0, n_split = len(model), int(split.sum())
        self.sensitivity_logits(model)
        ops.duplicate(model, optimizer, clone, state=state)
        if state.get("trans") is not None:
            state["trans"][n0:] = 0  # clones are new: not split in this round
        split = torch.cat([split, torch.zeros(int(clone.sum()), dtype=torch.bool, device=model.device)])
        ops.split(model, optimizer, split, n_children=self.n_split, state=state)
        first_new = n0 - n_split  # kept originals, then clones, then children
        for key in ("sens_exp_avg", "sens_exp_avg_sq"):
            if state.get(key) is not None and state[key].shape[0] == len(model):
                state[key][first_new:] = 0

    @torch.no_grad()
    def densify(self, model: GaussianModel, optimizer: GaussianAdam, state: dict, step: int) -> None:
        """A 3DGS round with HD / MD densification (`_grow`); trans is cleared after an HD or MD round."""
        super().densify(model, optimizer, state, step)
        if self.is_hd_round(state, step) or self.is_md_round(state, step):
            state["trans"] = None
