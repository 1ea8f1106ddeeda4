"""STRinGS (WACV 2026): two-phase, text-first training of 3D Gaussian Splatting.

Phase 1 (steps 1..T1): text Gaussians only (SfM points that Algorithm 1 marks as text, densified
once by visibility, Eq. 1), trained on the views whose text mask is non-empty with a masked L1
loss and the position learning rate locked at 0; the standard 3DGS densification keeps running.
Phase 2 (T1+1..end): the non-text SfM points are initialised as in 3DGS and joined to the refined
text Gaussians; standard 3DGS loss and densification; position LR = eta_r(t) * eta_opt(t) with
eta_opt the 3DGS schedule shifted by T1 and eta_r = alpha (non-text) or
alpha / (1 + exp(-beta (t - gamma))) (text). See docs/strings.md for settings and choices.

Registered method names: "strings", the paper's ablations "strings-no-densify" (no text
densification) and "strings-pos-lr" (3DGS position LR in phase 1 instead of 0), and this suite's variant
"strings-absgrad" (AbsGS' absolute-gradient densification criterion in both phases; not the paper's).
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import torch

from strings_bench.core.errors import StringsBenchError
from strings_bench.engine.splatting import GaussianSplatting
from strings_bench.engine.strategies.absgs import AbsGSStrategy

if TYPE_CHECKING:
    from strings_bench.scene.scene import Scene

log = logging.getLogger(__name__)



@dataclass(frozen=True)
class StringsSettings:
    """STRinGS-specific settings (iteration numbers nominal, for the 30 000-step schedule)."""

    t1: int = 3000  # length of phase 1
    alpha: float = 0.5  # eta_r plateau: non-text factor, text factor's limit
    beta: float = 0.0005  # steepness of the text factor's sigmoid
    gamma: float = 15000  # paper (global counter); the release: 12000 on the phase-2 counter
    # Which step counter gamma (and t in eta_r) is on: "global" (paper: t counts from the start of
    # phase 1) or "phase2" (release: t = step - T1, i.e. 1 at the first phase-2 step), see docs/strings.md.
    gamma_counter: str = "global"  # counter of gamma: "global" (paper) or "phase2" (release)
    tau: int = 1  # text point: mask hits >= tau
    n_max: int | None = None  # Eq. 1's N_max, the most children of a text point; None: 15 (the release's default); per dataset: the spec's presets
    equal_counts: str = "n_max"  # Eq. 1 with all counts equal: "n_max" or "one" (docs/strings.md)
    text_densify: bool = True  # False = ablation "without text densification"
    max_text_gaussians: int = 10_000_000  # memory guard on Eq. 1's children (not the budget: more is an error)
    phase1_position_lr: float = 0.0  # x the 3DGS schedule in phase 1; 0 = locked (paper), 1 = ablation
    # This suite's variant, not the paper's: the phase-1 position LR follows the scene's rho (one early position step
    # in text strokes, docs/difficulty.md): min(1, phase1_step_strokes / (rho x position_lr_gain)) x the 3DGS
    # schedule, so that an early step, as taken (the gain multiplies every step), moves text at most this many
    # strokes. None: phase1_position_lr as given. A scene whose rho cannot be measured (no known words, no masks)
    # keeps phase1_position_lr (result extra['phase1_rho'] is then None).
    phase1_step_strokes: float | None = None  # the longest phase-1 text position step, in text strokes (None: off)
    # "restart" (default, as the release): densification, opacity-reset and SH schedules count from the
    # start of phase 2, so the fresh non-text Gaussians get 3DGS' early iterations; "global" keeps the global
    # counter (why not: docs/strings.md, "Why phase-2 schedules restart by default").
    phase2_schedules: str = "restart"  # "restart" (release) or "global" schedules in phase 2 (see above)
    mask_source: str = "dataset"  # text masks: "dataset" (masks/), "ocr" (detector polygons), "gt" (synthetic)
    mask_dilation_fraction: float = 0.05  # dilation kernel diameter / image width (paper 5 %)
    mask_dilation_px: float | None = None  # dilation diameter in px at full size (release 225); overrides the fraction
    mask_ocr_backend: str = "rapidocr"  # detector for mask_source "ocr"
    # "auto": masks/ shipped already dilated (the STRinGS release's layout, or the card's masks_dilated) are
    # trained with as they are, as the release does; others are dilated. "yes"/"no" force either.
    mask_predilated: str = "auto"  # are the dataset's masks/ already dilated: "auto", "yes" or "no"
    segmentation_downscale: float | None = None  # None: the training downscale
    # ---- phase 1 as the release does it where the paper is silent (docs/history/strings.md, "Phase 1 against the release")
    # Initial scales of the text Gaussians: 3-NN over "all" SfM points, then the text subset (the release's
    # create_from_pcd; the paper takes G_text from 3DGS' initialisation of P), or over the "text" points alone.
    init_scales_from: str = "all"  # 3-NN initial scales over "all" SfM points (release) or "text" points only
    eq1_counts: str = "track"  # c_i of Eq. 1: "track" (paper: |V_i|) or "mask_hits" (release: get_vis_counts)
    eq1_range: str = "text"  # min/max of 1/c in Eq. 1 over the "text" points (paper) or "all" SfM points (release)
    # The release re-localises every Gaussian after Eq. 1 at its own position, with its parent's track, and
    # removes those that land in fewer than tau masks (prune_non_text): children sampled off the text go.
    prune_outside_masks: bool = True  # after Eq. 1, remove Gaussians whose own position is in < tau masks (release)
    # The release saves phase 1 at T1 before that iteration's densification and opacity reset, and phase 2
    # starts from the save; "after_refine" hands over the model after them.
    handoff: str = "before_refine"  # phase 2 starts from phase 1 "before_refine" at T1 (release) or "after_refine"
    # The release recomputes the text flag at the start of phase 2 from the current positions and the
    # inherited tracks (localize_gaussians); "inherit" keeps phase 1's flags (every phase-1 Gaussian is text).
    phase2_text: str = "relocalise"  # phase 2's text flag: "relocalise" (release) or "inherit"
    clamp_render: bool = False  # clamp the render to [0, 1] before the loss (the release's renderer; 3DGS' paper does not)

    def __post_init__(self):
        if self.phase2_schedules not in ("global", "restart"):
            raise StringsBenchError(f"phase2_schedules must be 'global' or 'restart', got {self.phase2_schedules!r}")
        if self.gamma_counter not in ("global", "phase2"):
            raise StringsBenchError(f"gamma_counter must be 'global' or 'phase2', got {self.gamma_counter!r}",
                                    hint="'global' = the paper's counter, 'phase2' = the release's (starts at 1 after T1)")
        if self.t1 < 0:
            raise StringsBenchError(f"t1 must be >= 0, got {self.t1}")
        if self.phase1_position_lr < 0:
            raise StringsBenchError(f"phase1_position_lr must be >= 0, got {self.phase1_position_lr}")
        if self.phase1_step_strokes is not None and not self.phase1_step_strokes >= 0:
            raise StringsBenchError(f"phase1_step_strokes must be >= 0 (strokes per step) or None, "
                                    f"got {self.phase1_step_strokes}")
        for name, allowed in (("init_scales_from", ("all", "text")), ("eq1_counts", ("track", "mask_hits")),
                              ("eq1_range", ("text", "all")), ("handoff", ("before_refine", "after_refine")),
                              ("phase2_text", ("relocalise", "inherit"))):
            if getattr(self, name) not in allowed:
                raise StringsBenchError(f"{name} must be one of {', '.join(map(repr, allowed))}, got {getattr(self, name)!r}")

    def mask_settings(self):
        """The text-mask settings (eval.text_masks.MaskSettings) these settings ask for."""
        from strings_bench.eval.text_masks import MaskSettings

        return MaskSettings(source=self.mask_source, dilation_fraction=self.mask_dilation_fraction,
                            dilation_px=self.mask_dilation_px, ocr_backend=self.mask_ocr_backend,
                            predilated=self.mask_predilated)


def text_lr_factor(step: float, alpha: float, beta: float, gamma: float) -> float:
    """eta_r(t) for text Gaussians: alpha / (1 + exp(-beta (t - gamma))), overflow-safe."""
    x = -beta * (step - gamma)
    if x > 700:
        return 0.0
    return alpha / (1.0 + math.exp(x))


def resolve_n_max(st: StringsSettings, scene: "Scene") -> int:
    """Eq. 1's N_max for `scene`: the setting n_max, else DEFAULT_N_MAX (15, the release's default); the
    per-dataset values come as presets of methods/strings/spec.py."""
    from strings_bench.methods.strings.densify import DEFAULT_N_MAX

    # The per-dataset values are the spec's @apply presets (methods/strings/spec.py); scenes carry none.
    return int(st.n_max) if st.n_max is not None else DEFAULT_N_MAX


# ---- the method ------------------------------------------------------------------------------------
class Strings(GaussianSplatting):
    """STRinGS' two phases on the engine's hooks. Settings: StringsSettings fields, plus everything
    3dgs takes (TrainConfig fields, lr_<group>, DefaultStrategy fields), flat."""

    method_settings_cls = StringsSettings

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        # Made by prepare() (masks and Algorithm 1, before training); declared here with their types.
        self.masks: dict[int, np.ndarray] = {}  # train view -> dilated text mask
        self.segmentation = None  # segmentation.TextSegmentation of the SfM points
        self.masks_segmentation_seconds = 0.0
        self.t1 = 0  # phase 1's last step at this schedule
        self.n_max = 15  # Eq. 1's N_max in effect (resolve_n_max)
        self.text_views: list[int] = []  # train views with text: phase 1 trains on these
        self.fallback: str | None = None  # why STRinGS ran as 3DGS ("no_text_points", ...), or None
        self.phase = 1
        self.densify_stats: dict = {}
        self._mask_tensors: dict[int, torch.Tensor] = {}

    @property
    def st(self) -> StringsSettings:
        """The STRinGS settings (`method_settings`)."""
        return self.method_settings

    # ---- preprocessing: masks and Algorithm 1 (timed as preprocess_seconds by the loop) ---------
    def prepare(self, scene: "Scene") -> None:
        """Preprocessing, timed as preprocess_seconds: the training views' text masks, Algorithm 1 over the SfM points
        (`segmentation`), T1 and N_max at this schedule, phase 1's views and position factor; the 3DGS fallback when no
        SfM point is text."""
        from strings_bench.eval.text_masks import text_masks
        from strings_bench.methods.strings.segmentation import segment_text_points

        st, ds = self.st, self.downscale
        t0 = time.perf_counter()
        mask_settings = st.mask_settings()
        progress = getattr(self, "progress", True)
        self.masks = text_masks(scene, scene.train_idx, ds, mask_settings, progress=progress)
        seg_ds = st.segmentation_downscale or ds
        seg_masks = self.masks if seg_ds == ds else text_masks(scene, scene.train_idx, seg_ds, mask_settings,
                                                               progress=progress)
        self.segmentation = segment_text_points(scene, seg_masks, seg_ds, st.tau)
        self._seg_masks, self._seg_downscale = seg_masks, seg_ds  # re-localisation after Eq. 1 and at phase 2
        self.masks_segmentation_seconds = time.perf_counter() - t0
        self.t1 = self.at(st.t1)
        self.n_max = resolve_n_max(st, scene)
        self.text_views = [i for i in scene.train_idx if i in self.masks and self.masks[i].any()]
        self.fallback = None
        if self.segmentation.num_text == 0:
            self.fallback = "no_text_points"
            log.warning("STRinGS: no SfM point of scene %s lands in a text mask (%d points, %d views with text); "
                        "training plain 3DGS instead (result extra['fallback'] = 'no_text_points')",
                        scene.name, scene.model.num_points, len(self.text_views))
        elif not self.text_views:  # masks too coarse at the training resolution to keep any text pixel
            log.warning("STRinGS: scene %s has text points but no training mask is non-empty at downscale %s; "
                        "phase 1 uses every training view", scene.name, ds)
            self.text_views = list(scene.train_idx)
        self.phase = 2 if self.fallback else 1
        self.phase1_rho, self.phase1_factor = None, float(st.phase1_position_lr)
        if st.phase1_step_strokes is not None:
            from strings_bench.scene.difficulty import recorded_difficulty

            self.phase1_rho = recorded_difficulty(scene).rho
            if self.phase1_rho:
                # the step as taken: rho strokes x the gain on every position step (a miniature's, a stand-in's)
                step_strokes = self.phase1_rho * float(self.config.position_lr_gain)
                self.phase1_factor = min(1.0, float(st.phase1_step_strokes) / step_strokes)
            else:
                log.warning("STRinGS: rho of scene %s cannot be measured; phase 1 keeps phase1_position_lr %g",
                            scene.name, st.phase1_position_lr)
        self.densify_stats: dict = {}
        self._mask_tensors: dict[int, torch.Tensor] = {}

    # ---- phases --------------------------------------------------------------------------------
    def in_phase1(self, step: int) -> bool:
        """Whether `step` (1-based, actual) is in phase 1 (step <= T1), the fallback never being."""
        return self.fallback is None and step <= self.t1

    def initial_model(self, scene: "Scene"):
        """Phase 1's model: the text SfM points' Gaussians (scales per init_scales_from), densified by Eq. 1 (text_densify)
        and pruned outside the masks (prune_outside_masks); in the fallback, the 3DGS initial model, no Gaussian text."""
        from strings_bench.engine.gaussians import GaussianModel
        from strings_bench.engine.strategies import ops
        from strings_bench.methods.strings.densify import densification_factors, densify_text_model

        if self.fallback:
            model = super().initial_model(scene)
            model.extras["is_text"] = torch.zeros(len(model), dtype=torch.bool, device=self.device)
            return model
        st = self.st
        is_text = self.segmentation.is_text
        sfm = scene.model
        point_ids = torch.arange(sfm.num_points, dtype=torch.int64, device=self.device)
        # "sfm_point": the SfM point a Gaussian descends from; children inherit it (ops copy extras), and
        # its track is where a Gaussian is re-localised, as the release's point_track_ids.
        if st.init_scales_from == "all":
            model = GaussianModel.from_points(
                sfm.xyz, sfm.rgb, sh_degree=self.config.sh_degree, init_opacity=self.config.init_opacity,
                device=self.device, extras={"sfm_point": point_ids}).subset(torch.from_numpy(is_text).to(self.device))
        else:
            model = GaussianModel.from_points(
                sfm.xyz[is_text], sfm.rgb[is_text], sh_degree=self.config.sh_degree,
                init_opacity=self.config.init_opacity, device=self.device,
                extras={"sfm_point": point_ids[torch.from_numpy(is_text).to(self.device)]})
        model.extras["is_text"] = torch.ones(len(model), dtype=torch.bool, device=self.device)
        n0 = len(model)
        stats = {"text_points": n0}
        if st.text_densify:
            counts = sfm.visibility_counts() if st.eq1_counts == "track" else self.segmentation.hits
            if st.eq1_range == "all":  # the release: Eq. 1 over every SfM point, non-text ones get N = 1
                factors = densification_factors(counts, self.n_max, st.equal_counts)[is_text]
            else:
                factors = densification_factors(counts[is_text], self.n_max, st.equal_counts)
            # the children are sampled on the model's device, so the generator must live there too
            gen = torch.Generator(device=self.device).manual_seed(self.config.seed)
            # Under a budget Eq. 1 leaves the non-text points that join at T1 their share (budget_reserved)
            budget_now = self.context.budget_now()
            densify_text_model(model, factors, gen, memory_limit=st.max_text_gaussians, budget=budget_now)
            if budget_now is not None:
                stats["text_densify_budget"] = budget_now
        stats["text_gaussians_after_densify"] = len(model)
        if st.prune_outside_masks:
            outside = self.mask_hits(model) < st.tau
            if bool(outside.all()):
                # The release would be left with no Gaussian at all; keep them, say so, and record it.
                log.warning("STRinGS: every text Gaussian of scene %s lands outside the text masks after Eq. 1; "
                            "none is pruned (prune_outside_masks skipped)", scene.name)
                stats["prune_outside_masks_skipped"] = True
                outside = torch.zeros_like(outside)
            ops.remove(model, None, outside)
            stats["text_gaussians_pruned_outside_masks"] = int(outside.sum())
        self.densify_stats = {**stats, "n_max": self.n_max}
        return model

    def mask_hits(self, model) -> torch.Tensor:
        """(N,) int64: per Gaussian, how many images of its SfM point's track have the Gaussian's own
        position inside their text mask (the release's localize_gaussians, on the voting views' masks)."""
        from strings_bench.methods.strings.segmentation import count_mask_hits, inherited_tracks

        sfm = self.scene.model
        points = model.extras["sfm_point"].cpu().numpy()
        ptr, views = inherited_tracks(sfm.track_ptr, sfm.track_view, points)
        cameras = {j: self.scene.camera(j, self._seg_downscale) for j in self._seg_masks}
        xyz = model.params["means"].detach().cpu().numpy()
        hits = count_mask_hits(xyz, ptr, views, cameras, self._seg_masks)
        return torch.from_numpy(hits).to(model.device)

    def budget_reserved(self) -> int:
        """Under a budget, phase 1 keeps free of it the non-text SfM points that join at T1 (`_start_phase2`), so
        phase 1's growth (Eq. 1 and 3DGS densification) stops at the budget less their number."""
        if self.fallback or self.phase != 1 or self.segmentation is None:
            return 0
        return int((~self.segmentation.is_text).sum())

    def _start_phase2(self) -> None:
        from strings_bench.engine.gaussians import GaussianModel

        self.phase = 2
        if self.st.phase2_text == "relocalise":
            text = self.model.extras["is_text"]
            text &= self.mask_hits(self.model) >= self.st.tau
            self.densify_stats["text_gaussians_at_phase2"] = int(text.sum())
        sfm = self.scene.model
        non_text = ~self.segmentation.is_text
        if not non_text.any():
            return
        extra = GaussianModel.from_points(
            sfm.xyz[non_text], sfm.rgb[non_text], sh_degree=self.config.sh_degree, init_opacity=self.config.init_opacity,
            device=self.device, extras={"is_text": torch.zeros(int(non_text.sum()), dtype=torch.bool, device=self.device),
                                        "sfm_point": torch.from_numpy(np.nonzero(non_text)[0]).to(self.device)})
        # A fresh optimizer and strategy state for the joined model, as a new training setup would.
        self.set_model(GaussianModel.concat([self.model, extra]))

    def on_step_start(self, step: int) -> None:
        """At the first step after T1, phase 2 starts: the non-text Gaussians join (`_start_phase2`)."""
        if self.phase == 1 and step > self.t1:
            self._start_phase2()

    def train_views(self) -> list[int]:
        """Phase 1: the training views whose text mask is non-empty; phase 2: every training view."""
        if self.phase == 1:
            return self.text_views
        return super().train_views()

    def loss(self, out, gt: torch.Tensor, view_idx: int, step: int) -> torch.Tensor:
        """Phase 1: L1 inside the view's text mask, a mean over the whole image, no SSIM; phase 2: the 3DGS loss. A scalar in
        the graph (the render clamped to [0, 1] first with clamp_render)."""
        from strings_bench.engine.losses import gs_loss, masked_l1

        pred = out.color.clamp(0, 1) if self.st.clamp_render else out.color
        if self.in_phase1(step):
            return masked_l1(pred, gt, self._mask_tensor(view_idx))  # mean over the whole image, no SSIM
        return gs_loss(pred, gt, self.config.lambda_dssim)

    def skips_refinement(self, step: int) -> bool:
        """The phase switch: with handoff before_refine, T1's refinement is skipped, as the release saves phase 1
        at T1 before that iteration's densify_and_prune and reset_opacity, and phase 2 starts from the save."""
        return self.st.handoff == "before_refine" and self.phase == 1 and step == self.t1 and not self.fallback

    def _mask_tensor(self, view_idx: int) -> torch.Tensor:
        if view_idx not in self._mask_tensors:
            self._mask_tensors[view_idx] = torch.from_numpy(
                np.asarray(self.masks[view_idx], dtype=np.float32))[:, :, None].to(self.device)
        return self._mask_tensors[view_idx]

    # ---- learning rates ---------------------------------------------------------------------------
    def position_lr(self, step: int) -> float:
        """The position LR at `step`: phase 1, the phase-1 factor (phase1_position_lr, or from rho with
        phase1_step_strokes) x the 3DGS schedule; phase 2, the 3DGS schedule shifted by T1 (eta_opt); the fallback, 3DGS'."""
        if self.fallback:
            return super().position_lr(step)
        if self.in_phase1(step):
            return self.phase1_factor * super().position_lr(step)
        return super().position_lr(step - self.t1)  # eta_opt: the 3DGS schedule shifted by T1

    def lr_factors(self, step: int) -> tuple[float, float]:
        """(eta_r for text, eta_r for non-text) at actual (global) step `step` (phase 2). With
        gamma_counter "phase2", t is the phase-2 counter step - T1 (1 at the first phase-2 step)."""
        s = self.config.steps_scale
        t = step - self.t1 if self.st.gamma_counter == "phase2" else step
        text = text_lr_factor(t, self.st.alpha, self.st.beta / s, self.st.gamma * s)
        return text, float(self.st.alpha)

    def position_lr_scale(self, step: int):
        """Phase 2's per-row factor eta_r on the position step, (N,): alpha for non-text Gaussians, the text factor
        `text_lr_factor` for text ones; None in phase 1."""
        if self.fallback or self.in_phase1(step):
            return None
        text, non_text = self.lr_factors(step)
        is_text = self.model.extras["is_text"]
        return torch.where(is_text, torch.tensor(text, device=self.device), torch.tensor(non_text, device=self.device))

    # ---- schedules ------------------------------------------------------------------------------
    def _schedule_step(self, step: int) -> int:
        if self.st.phase2_schedules == "restart" and not self.fallback and step > self.t1:
            return step - self.t1
        return step

    def strategy_step(self, step: int) -> int:
        """The step the strategy sees: in phase 2 with `phase2_schedules="restart"`, counted from T1; else `step`."""
        return self._schedule_step(step)

    def sh_degree_for_step(self, step: int) -> int:
        """The SH degree at `step`, on the same counter as the strategy (`strategy_step`)."""
        return super().sh_degree_for_step(self._schedule_step(step))

    def checkpoint_extra(self, step: int) -> dict:
        """`GaussianSplatting.checkpoint_extra` plus STRinGS' record: the phase, T1, N_max, the segmentation and
        densification statistics, the fallback, masks_segmentation_seconds."""
        extra = {
            **super().checkpoint_extra(step),
            "phase": self.phase,
            **({"phase1_rho": self.phase1_rho, "phase1_position_factor": self.phase1_factor}
               if self.st.phase1_step_strokes is not None else {}),
            "t1_steps": self.t1,
            "text_gaussians": int(self.model.extras["is_text"].sum()),
            "sfm_points": int(self.scene.model.num_points),
            "text_points": int(self.segmentation.num_text),
            "text_views": len(self.text_views),
            "masks_segmentation_seconds": self.masks_segmentation_seconds,  # part of preprocess_seconds
            **self.densify_stats,
        }
        if self.fallback:
            extra["fallback"] = self.fallback
        return extra

    # ---- resumable state: the phase (the model, optimizer and generators are the base's) ---------
    def extra_state(self) -> dict:
        """The resumable state of the method itself: {"phase": 1 or 2, "densify_stats": Eq. 1's record}."""
        return {"phase": self.phase, "densify_stats": dict(self.densify_stats)}

    def load_extra_state(self, state: dict) -> None:
        """Restore the phase and Eq. 1's record saved by `extra_state`."""
        self.phase = int(state.get("phase", self.phase))
        self.densify_stats = dict(state.get("densify_stats", self.densify_stats))


class StringsNoDensify(Strings):
    """Ablation of the paper: without the one-time text densification (Eq. 1)."""

    forced_settings = {"text_densify": False}


class StringsPosLR(Strings):
    """Ablation of the paper: the 3DGS position LR in phase 1 instead of 0."""

    forced_settings = {"phase1_position_lr": 1.0}


class StringsAbsGrad(Strings):
    """This suite's variant (not the paper's): STRinGS with AbsGS' densification criterion in both phases (clone on
    the ordinary screen-space gradient >= grow_grad2d, split on the absolute gradient >= grow_grad2d_abs, AbsGS'
    thresholds 2e-4 / 4e-4). Phase 1 too: it runs 3DGS densification on the text Gaussians with their positions
    locked, so clones stay on their parent and splits (children sampled off the parent) are the only growth that
    places new Gaussians; AbsGS changes exactly the split rule, on the strokes where per-pixel gradients cancel
    (docs/strings.md, "strings-absgrad")."""

    strategy_cls = AbsGSStrategy
