"""The specs of STRinGS, its paper's ablations and this suite's STRinGS + AbsGS criterion (the method: method.py)."""

from strings_bench.methods.spec import MethodSpec, PaperFigures

STRINGS_PAPER = "STRinGS: Selective Text Refinement in Gaussian Splatting (WACV 2026)"


def _n_max(dataset: str, value: int, scenes=None) -> dict:
    """A preset that sets STRinGS' Eq. 1 N_max (the most children of a text point) on `dataset` (its `scenes`, or all of them)."""
    conds = [{"dataset": dataset}] if scenes is None else [{"dataset": dataset, "scene": s} for s in scenes]
    return {"@apply": conds, "n_max": value}


# N_max per scene, as the release's full_eval.py passes it (--max_densify): STRinGS-360 25, Truck 20, Train 15,
# DL3DV scene_3/21/92/107 20 and scene_80/132/136 15. Elsewhere (synthetic, the user's scenes) the release's
# CLI default, 15 (methods/strings/densify.py DEFAULT_N_MAX).
_STRINGS_PRESETS = {
    # The release: gamma 12000 on its phase-2 counter (= the paper's 15000 at T1 = 3000), its script's
    # 225 px mask dilation (masks shipped dilated, as its datasets' are, are used as they are), Eq. 1 on
    # mask hits over all SfM points, the render clamped before the loss, opacity LR 0.025 (docs/strings.md,
    # "Phase 1 against the release").
    "release": {"gamma": 12000, "gamma_counter": "phase2", "mask_dilation_px": 225.0, "phase2_schedules": "restart",
                "eq1_counts": "mask_hits", "eq1_range": "all", "clamp_render": True, "lr_opacity_logits": 0.025,
                "@description": "the authors' release where it differs from the paper"},
    "n-max-strings360": _n_max("strings360", 25),
    "n-max-truck": _n_max("tandt", 20, ["truck"]),
    "n-max-train": _n_max("tandt", 15, ["train"]),
    "n-max-dl3dv-20": _n_max("dl3dv", 20, ["3", "21", "92", "107"]),
    "n-max-dl3dv-15": _n_max("dl3dv", 15, ["80", "132", "136"]),
}


SPECS = [
    MethodSpec(
        name="strings", title="STRinGS", group="ours", implementation="strings_bench.methods.strings.method:Strings",
        description="STRinGS: text-first two-phase 3DGS (text segmentation in 3D, visibility densification, "
                    "masked phase-1 loss, region-dependent position LR)",
        paper=STRINGS_PAPER, presets=dict(_STRINGS_PRESETS),
        paper_figures=PaperFigures.table1(tandt=(.122, .099), dl3dv=(.187, .123), strings360=(.177, .106),
                                          minutes=(1.9, 12.6))),
    # The paper's ablations (its Table "Ablations"): each against STRinGS at the iteration the paper reads it.
    MethodSpec(
        name="strings-no-densify", title="STRinGS w/o text densification",
        implementation="strings_bench.methods.strings.method:StringsNoDensify",
        description="STRinGS ablation: without the one-time text densification (Eq. 1)", paper=STRINGS_PAPER,
        presets=dict(_STRINGS_PRESETS), ablation_of="strings", ablation_at=7000, ablation_effect="text densification"),
    MethodSpec(
        name="strings-pos-lr", title="STRinGS with phase-1 position LR",
        implementation="strings_bench.methods.strings.method:StringsPosLR",
        description="STRinGS ablation: non-zero position LR (the 3DGS schedule) in phase 1", paper=STRINGS_PAPER,
        presets=dict(_STRINGS_PRESETS), ablation_of="strings", ablation_at=3000,
        ablation_effect="zero position LR of Gaussians"),
    # This suite's variant, not the paper's: STRinGS on AbsGS' absolute-gradient densification.
    MethodSpec(
        name="strings-absgrad", title="STRinGS + AbsGS criterion",
        implementation="strings_bench.methods.strings.method:StringsAbsGrad",
        description="this suite's variant (not the paper's): STRinGS with AbsGS' absolute-gradient densification "
                    "criterion (splits on the absolute gradient >= 4e-4, clones on the ordinary one >= 2e-4) in both phases",
        paper=STRINGS_PAPER + "; densification criterion of Ye et al., AbsGS (ACM MM 2024); the combination is "
                              "strings-bench's", presets=dict(_STRINGS_PRESETS)),
]
