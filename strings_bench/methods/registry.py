"""Method specs as data, in the style of nerfbaselines.

A `MethodSpec` names its implementation lazily (`"module:Class"`: nothing is imported until a
method is built or described), its defaults, its presets, and the paper's own results where they
are published (the STRinGS paper, Table 1), so reports can show the paper's figure next to the measured one.
The built-in methods are the table `BUILTIN_SPECS` below: registration is explicit, never an import
side effect. A user's package adds more through the entry-point group `strings_bench.methods`,
whose entries point at a MethodSpec (or a callable returning one).

Implementations are either a `Method` (trained by the framework's loop; settings from
`cls.from_settings(**settings)` and described by `cls.settings_schema()`) or a `MethodAdapter`
(models trained elsewhere; built with `cls(**settings)`).
"""

from __future__ import annotations

import contextlib
import importlib
import logging
from dataclasses import dataclass, field, fields
from importlib.metadata import entry_points
from typing import Any, Callable

from strings_bench.core.errors import StringsBenchError
from strings_bench.core.schedules import iteration_label
from strings_bench.core.settings import Setting, format_settings

log = logging.getLogger(__name__)

ENTRY_POINT_GROUP = "strings_bench.methods"


@dataclass(frozen=True, kw_only=True)
class PaperFigures:
    """A method's figures in the STRinGS paper (Table 1), by name: OCR-CER at 7K and 30K on Tanks and
    Temples, DL3DV and STRinGS-360 (Google Cloud Vision OCR), and training minutes on STRinGS-360 (RTX 3090 Ti)."""

    tandt_cer_7k: float
    tandt_cer_30k: float
    dl3dv_cer_7k: float
    dl3dv_cer_30k: float
    strings360_cer_7k: float
    strings360_cer_30k: float
    strings360_minutes_7k: float
    strings360_minutes_30k: float

    def by_dataset(self) -> dict:
        """{dataset: {"cer": {iteration: value}, "minutes": {iteration: value}}}, as the reports look them up."""
        out: dict = {}
        for f in fields(self):
            dataset, what, label = f.name.rsplit("_", 2)
            out.setdefault(dataset, {}).setdefault(what, {})[int(label[:-1]) * 1000] = getattr(self, f.name)
        return out


@dataclass(kw_only=True)
class MethodSpec:
    """A method as data; every field by keyword.

    Args:
        name: the method's one name: `--methods`, `--set NAME.key=value`, results.csv (a built method gets it).
        implementation: `"module:Class"` (imported on first use), or the class / a factory itself.
        description: one line for `methods list`.
        paper: the citation.
        title: the name tables and figures print ("3DGS-MCMC"); default: `name`.
        group: "baseline", "ours" (STRinGS), "ablation" (the default when `ablation_of` is given: rows of the
            ablation tables, dashed in figures) or "adapter"; tables list methods by group, then in registry order.
        defaults: settings over the implementation's own defaults. The run's schedule scale needs no entry here:
            it reaches every method with a `steps_scale` setting (`with_steps_scale`).
        presets: preset name -> settings over `defaults`. A preset is chosen by name (`run --presets
            strings=release`), or applies by itself where its "@apply" conditions match the scene, as in
            nerfbaselines: {"@apply": [{"dataset": "tandt", "scene": "truck"}], "n_max": 20} (a condition
            matches when all its keys equal the scene's; any condition is enough). Keys starting with "@"
            are not settings ("@description" says what the preset is).
        paper_figures: the method's published figures (`PaperFigures`), shown next to the measured ones.
        ablation_of: the method this one is an ablation of ("strings"); the ablation tables and `compare` pair them.
        ablation_at: the paper iteration the ablation is compared at (the paper: 7000 for text densification,
            3000, the end of phase 1, for the position LR).
        ablation_effect: what the ablation takes away, as the tables title it ("text densification").
    """

    name: str
    implementation: str | Callable[..., Any]
    description: str = ""
    paper: str = ""
    title: str = ""
    group: str = ""
    defaults: dict = field(default_factory=dict)
    presets: dict[str, dict] = field(default_factory=dict)
    paper_figures: PaperFigures | None = None
    ablation_of: str | None = None
    ablation_at: int | None = None
    ablation_effect: str = ""

    def __post_init__(self):
        if not self.group:
            self.group = "ablation" if self.ablation_of else "baseline"
        if self.ablation_of and not self.ablation_at:
            raise StringsBenchError(f"method {self.name}: ablation_of={self.ablation_of!r} needs ablation_at",
                                    hint="the paper iteration the ablation is compared at, e.g. ablation_at=7000")

    @property
    def paper_results(self) -> dict:
        """The published figures by dataset ({dataset: {"cer": {iteration: value}, ...}}), {} when none."""
        return self.paper_figures.by_dataset() if self.paper_figures else {}

    def load(self) -> Any:
        """The implementation class (or factory)."""
        impl = self.implementation
        if not isinstance(impl, str):
            return impl
        module, _, attr = impl.partition(":")
        try:
            return getattr(importlib.import_module(module), attr)
        except (ImportError, AttributeError) as exc:
            raise StringsBenchError(f"method {self.name}: cannot load its implementation {impl!r}: {exc}",
                                    hint="check the spec's implementation string (module:Class)") from exc

    def settings(self) -> list[Setting] | None:
        """Every setting with its default (the spec's defaults applied) and meaning; None when the
        implementation does not describe its settings (then any key is passed on)."""
        impl = self.load()
        schema = getattr(impl, "settings_schema", None)
        if schema is None:
            return None
        return [Setting(s.name, self.defaults.get(s.name, s.default), s.help, s.group) for s in schema()]

    def check_keys(self, keys) -> None:
        """Refuse unknown setting names, naming the valid ones (before anything is built or trained)."""
        schema = self.settings()
        if schema is None:
            return
        valid = {s.name for s in schema}
        unknown = sorted(set(keys) - valid)
        if unknown:
            raise StringsBenchError(f"method {self.name} has no setting(s) {', '.join(unknown)}",
                                    hint=f"valid settings: {', '.join(sorted(valid))} "
                                         f"(`strings-bench methods show {self.name}`)")

    def presets_for(self, dataset: str, scene: str) -> list[str]:
        """The presets that apply by themselves to `dataset`/`scene` (their "@apply" conditions), in spec order."""
        here = {"dataset": dataset, "scene": scene}
        return [name for name, p in self.presets.items()
                if any(all(here.get(k) == v for k, v in cond.items()) for cond in p.get("@apply", []))]

    def check_presets(self, names) -> list[str]:
        """`names` (a name, a list, or None) as a list, refusing names this spec has no preset of."""
        names = [] if names is None else [names] if isinstance(names, str) else list(names)
        unknown = [n for n in names if n not in self.presets]
        if unknown:
            raise StringsBenchError(f"method {self.name} has no preset {', '.join(map(repr, unknown))}",
                                    hint=f"presets of {self.name}: {', '.join(self.presets) or 'none'} "
                                         f"(`strings-bench methods show {self.name}`)")
        return names

    def takes_steps_scale(self) -> bool:
        """Whether the run's schedule scale reaches this method as its `steps_scale` setting: every method whose
        implementation describes that setting (every Gaussian method: engine TrainConfig); an implementation that
        describes no settings takes it when the spec names it (defaults or a preset). Adapters (ply, external)
        train nothing and have no steps to scale."""
        schema = self.settings()
        if schema is not None:
            return any(s.name == "steps_scale" for s in schema)
        return "steps_scale" in self.defaults or any("steps_scale" in p for p in self.presets.values())

    def with_steps_scale(self, steps_scale: float, overrides: dict | None = None) -> dict:
        """`overrides` (`--set` values) with the run's `steps_scale` added where this method takes one
        (`takes_steps_scale`); a `steps_scale` in `overrides` wins. The one way a schedule reaches a method."""
        overrides = dict(overrides or {})
        if self.takes_steps_scale():
            overrides.setdefault("steps_scale", float(steps_scale))
        return overrides

    def resolve(self, presets=None, **overrides) -> dict:
        """The settings a build uses: defaults, then each preset in order, then the overrides (where a run's
        schedule scale is one: `with_steps_scale`)."""
        settings = dict(self.defaults)
        for name in self.check_presets(presets):
            settings.update({k: v for k, v in self.presets[name].items() if not k.startswith("@")})
        settings.update(overrides)
        return settings

    def fixed_checkpoints(self, settings: dict) -> list[int] | None:
        """The iterations this method is evaluated at whatever the schedule says, from its resolved settings
        (the ply adapter: the model's own iteration); None: the schedule's. Read without building the method."""
        fixed = getattr(self.load(), "fixed_checkpoints", None)
        its = fixed(settings) if fixed is not None else None
        return sorted(int(i) for i in its) if its else None

    def build(self, presets=None, *, default_steps_scale: float | None = None, **overrides):
        """A configured method object (a `Method` or a `MethodAdapter`); `presets`: a preset name or a list;
        `default_steps_scale`: train at that steps scale where the method takes one (`with_steps_scale`), as a run
        of a schedule does (`build(default_steps_scale=get_schedule("tiny").steps_scale)`); a `steps_scale` in
        `overrides` (`--set steps_scale=S`) wins."""
        if default_steps_scale is not None:
            overrides = self.with_steps_scale(default_steps_scale, overrides)
        settings = self.resolve(presets, **overrides)
        impl = self.load()
        self.check_keys(settings)
        from_settings = getattr(impl, "from_settings", None)
        obj = from_settings(**settings) if from_settings is not None else impl(**settings)
        for attr, value in (("name", self.name), ("paper", self.paper)):
            # a spec may reuse a class under another name; its citation lives on the spec only
            if value and getattr(obj, attr, None) != value:
                try:
                    setattr(obj, attr, value)
                except AttributeError:
                    pass
        return obj

    def show(self) -> str:
        """Human-readable description: what `strings-bench methods show NAME` prints."""
        lines = [f"{self.name}: {self.description}".rstrip(": ")]
        if self.paper:
            lines.append(f"paper: {self.paper}")
        lines.append(f"title: {self.title or self.name} (group {self.group})")
        if self.ablation_of:
            lines.append(f"ablation of {self.ablation_of} (without {self.ablation_effect or 'a component'}), compared at "
                         f"{iteration_label(self.ablation_at)}")
        lines.append(f"implementation: {self.implementation if isinstance(self.implementation, str) else self.implementation!r}")
        if self.presets:
            lines.append("presets (`run --presets NAME=PRESET`; @apply: applied by itself on those scenes):")
            for k, v in self.presets.items():
                applies = "; ".join(",".join(f"{a}={b}" for a, b in c.items()) for c in v.get("@apply", []))
                values = {a: b for a, b in v.items() if not a.startswith("@")}
                lines.append(f"  {k}: {values}" + (f"  @apply {applies}" if applies else "")
                             + (f"  ({v['@description']})" if "@description" in v else ""))
        for dataset, figures in self.paper_results.items():
            parts = [f"{what} " + ", ".join(f"{iteration_label(it)} {v:g}" for it, v in sorted(vals.items()))
                     for what, vals in figures.items()]
            lines.append(f"paper's results on {dataset}: " + "; ".join(parts))
        schema = self.settings()
        lines.append("")
        lines.append("settings (default, meaning):" if schema is not None
                     else "settings: not described by the implementation (any key is passed on)")
        if schema:
            lines.append(format_settings(schema))
        return "\n".join(lines)


# ---- the built-in methods ----------------------------------------------------------------------------
STRINGS_PAPER = "STRinGS: Selective Text Refinement in Gaussian Splatting (WACV 2026)"


def _n_max(dataset: str, value: int, scenes=None) -> dict:
    """A preset that sets STRinGS' Eq. 1 cap N_max on `dataset` (its `scenes`, or all of them)."""
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

BUILTIN_SPECS: list[MethodSpec] = [
    # In the paper's row order (Table 1): the reports list methods in this order.
    MethodSpec(
        name="3dgs", title="3DGS", implementation="strings_bench.methods.gs3d:GS3D",
        description="vanilla 3DGS: SfM init, Adam, adaptive density control (clone/split/prune, opacity reset)",
        paper="Kerbl, Kopanas, Leimkuehler, Drettakis: 3D Gaussian Splatting for Real-Time Radiance Field "
              "Rendering (SIGGRAPH 2023)",
        paper_figures=PaperFigures(tandt_cer_7k=.209, tandt_cer_30k=.121, dl3dv_cer_7k=.392, dl3dv_cer_30k=.157,
                                   strings360_cer_7k=.736, strings360_cer_30k=.148,
                                   strings360_minutes_7k=2.5, strings360_minutes_30k=17.2)),
    MethodSpec(
        name="mip-splatting", title="Mip-Splatting", implementation="strings_bench.methods.mip_splatting:MipSplatting",
        description="Mip-Splatting: 3D smoothing filter from the training cameras' sampling rate + 2D mip filter",
        paper="Yu, Chen, Huang, Sattler, Geiger: Mip-Splatting: Alias-free 3D Gaussian Splatting (CVPR 2024)",
        paper_figures=PaperFigures(tandt_cer_7k=.222, tandt_cer_30k=.125, dl3dv_cer_7k=.392, dl3dv_cer_30k=.149,
                                   strings360_cer_7k=.748, strings360_cer_30k=.129,
                                   strings360_minutes_7k=5.7, strings360_minutes_30k=31.7)),
    MethodSpec(
        name="mcmc", title="3DGS-MCMC", implementation="strings_bench.methods.mcmc:MCMC",
        description="3DGS-MCMC: dead-Gaussian relocation (eq. 9), 5% growth to a cap, opacity/scale L1, SGLD "
                    "position noise",
        paper="Kheradmand, Rebain, Sharma, Sun, Tseng, Isack, Kar, Tagliasacchi, Yi: "
              "3D Gaussian Splatting as Markov Chain Monte Carlo (NeurIPS 2024)",
        defaults={"init_opacity": 0.5, "init_scale_factor": 0.1},
        paper_figures=PaperFigures(tandt_cer_7k=.272, tandt_cer_30k=.120, dl3dv_cer_7k=.511, dl3dv_cer_30k=.142,
                                   strings360_cer_7k=.927, strings360_cer_30k=.110,
                                   strings360_minutes_7k=5.6, strings360_minutes_30k=34.0)),
    MethodSpec(
        name="absgs", title="AbsGS", implementation="strings_bench.methods.absgs:AbsGS",
        description="AbsGS: 3DGS densification with splits selected on the absolute (per-pixel |dL/dmean2d| summed) "
                    "gradient",
        paper="Ye, Li, Zhang, Huang, Ma, Zhou: AbsGS: Recovering Fine Details for 3D Gaussian Splatting (ACM MM 2024)",
        paper_figures=PaperFigures(tandt_cer_7k=.249, tandt_cer_30k=.137, dl3dv_cer_7k=.411, dl3dv_cer_30k=.160,
                                   strings360_cer_7k=.768, strings360_cer_30k=.143,
                                   strings360_minutes_7k=5.4, strings360_minutes_30k=22.5)),
    MethodSpec(
        name="edc-absgs", title="EDC-AbsGS", implementation="strings_bench.methods.edc_absgs:EDCAbsGS",
        description="EDC-AbsGS: long-axis split (no clone) on the absolute gradient, recovery-aware pruning, "
                    "position LR 4e-5 -> 2e-6",
        paper="Deng, Diao, Li, Chen, Zhang: Efficient Density Control for 3D Gaussian Splatting (arXiv 2024), on AbsGS",
        defaults={"lr_means": 4e-5, "lr_means_final": 2e-6},
        paper_figures=PaperFigures(tandt_cer_7k=.142, tandt_cer_30k=.118, dl3dv_cer_7k=.239, dl3dv_cer_30k=.162,
                                   strings360_cer_7k=.328, strings360_cer_30k=.116,
                                   strings360_minutes_7k=5.5, strings360_minutes_30k=23.2)),
    # Newer methods beyond the paper's table; no published figures on the STRinGS datasets.
    MethodSpec(
        name="improved-gs", title="Improved-GS", implementation="strings_bench.methods.improved_gs:ImprovedGS",
        description="Improved-GS: edge-aware score, growth control to a Gaussian budget, long-axis split, "
                    "recovery-aware pruning, multi-step update",
        paper="Deng, Diao, Li, Yu, Xu: Improving Densification in 3D Gaussian Splatting for High-Fidelity "
              "Rendering (arXiv 2508.12313, 2025); release github.com/XiaoBin2001/Imporved-GS",
        # the release's arguments/__init__.py: position 4e-5 -> 2e-6, opacity 0.025, SH rest 0.005 / 20
        defaults={"lr_means": 4e-5, "lr_means_final": 2e-6, "lr_opacity_logits": 0.025, "lr_shN": 0.005 / 20}),
    MethodSpec(
        name="perceptual-gs", title="Perceptual-GS", implementation="strings_bench.methods.perceptual_gs:PerceptualGS",
        description="Perceptual-GS: learned per-Gaussian perceptual sensitivity (BCE to Sobel-based maps) drives "
                    "extra densification of high/medium-sensitivity Gaussians, opacity decline of clones",
        paper="Zhou, Ni: Perceptual-GS: Scene-adaptive Perceptual Densification for Gaussian Splatting (ICML 2025, "
              "arXiv 2506.12400); release github.com/eezkni/Perceptual-GS"),
    MethodSpec(
        name="strings", title="STRinGS", group="ours", implementation="strings_bench.methods.strings.method:Strings",
        description="STRinGS: text-first two-phase 3DGS (text segmentation in 3D, visibility densification, "
                    "masked phase-1 loss, region-dependent position LR)",
        paper=STRINGS_PAPER, presets=dict(_STRINGS_PRESETS),
        paper_figures=PaperFigures(tandt_cer_7k=.122, tandt_cer_30k=.099, dl3dv_cer_7k=.187, dl3dv_cer_30k=.123,
                                   strings360_cer_7k=.177, strings360_cer_30k=.106,
                                   strings360_minutes_7k=1.9, strings360_minutes_30k=12.6)),
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
    MethodSpec(
        name="ply", title="PLY models", group="adapter", implementation="strings_bench.methods.ply_adapter:PlyAdapter",
        description="evaluate existing 3DGS PLY models (setting ply_path, may use {scene}/{dataset}/{iteration}); "
                    "no training",
        defaults={"iteration": 30000}),
    MethodSpec(
        name="external", title="External", group="adapter",
        implementation="strings_bench.methods.external:ExternalCommandAdapter",
        description="run any training program (setting command) and evaluate the test-view renders it writes"),
]

_METHODS: dict[str, MethodSpec] = {}
_loaded = False


def register_method(spec: MethodSpec) -> MethodSpec:
    """Make `spec` a method of this process (`run`, `methods list`) under its name, replacing one of that name.

    A method in a package of your own needs no call: the `strings_bench.methods` entry point of its pyproject.toml
    registers it in every process. For the duration of a block only: `registered(spec)`.

    Returns:
        `spec` (so that it can be used as `SPEC = register_method(MethodSpec(...))`).
    """
    _METHODS[spec.name] = spec
    return spec


@contextlib.contextmanager
def registered(spec: MethodSpec):
    """`spec` registered under its name for the duration (e.g. `methods check` of a spec not registered),
    then whatever was registered under that name before."""
    _load()
    previous = _METHODS.get(spec.name)
    register_method(spec)
    try:
        yield spec
    finally:
        if previous is None:
            _METHODS.pop(spec.name, None)
        else:
            _METHODS[spec.name] = previous


def _load() -> None:
    global _loaded
    if _loaded:
        return
    _loaded = True
    for spec in BUILTIN_SPECS:
        register_method(spec)
    for ep in entry_points(group=ENTRY_POINT_GROUP):
        try:
            obj = ep.load()
            spec = obj() if callable(obj) and not isinstance(obj, MethodSpec) else obj
            if not isinstance(spec, MethodSpec):
                raise TypeError(f"entry point {ep.name} gave {type(spec).__name__}, not MethodSpec")
            register_method(spec)
        except Exception as exc:  # a broken plug-in must not break the suite
            log.warning("could not load method plug-in %s: %s", ep.name, exc)


def list_methods() -> list[MethodSpec]:
    _load()
    return list(_METHODS.values())


def get_method(name: str) -> MethodSpec:
    _load()
    if name not in _METHODS:
        raise StringsBenchError(f"unknown method {name!r}", hint=f"known methods: {', '.join(sorted(_METHODS))}")
    return _METHODS[name]


def show_method(name: str) -> str:
    """What `strings-bench methods show NAME` prints: every setting with its default and meaning."""
    return get_method(name).show()
