"""Method specs as data, in the style of nerfbaselines: `MethodSpec` and `PaperFigures`.

A `MethodSpec` names its implementation lazily (`"module:Class"`: nothing is imported until a method is built or
described), its defaults, its presets, and its published figures (`PaperFigures`), so reports can show the
paper's figure next to the measured one. Each built-in method's spec lives beside its code (`methods/<name>_spec.py`,
`methods/strings/spec.py`); methods/registry.py finds them.

Implementations are either a `Method` (trained by the framework's loop; settings from
`cls.from_settings(**settings)` and described by `cls.settings_schema()`) or a `MethodAdapter`
(models trained elsewhere; built with `cls(**settings)`).
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass, field
from typing import Any, Callable, Mapping

from strings_bench.core.errors import StringsBenchError
from strings_bench.core.schedules import iteration_label
from strings_bench.core.settings import Setting, format_settings


@dataclass(frozen=True)
class PaperFigures:
    """A method's published figures, keyed by (dataset, metric, iteration): e.g. ("tandt", "cer", 7000) -> 0.209
    (the STRinGS paper's Table 1: OCR-CER by Google Cloud Vision; "minutes": training minutes on an RTX 3090 Ti).

    Example:
        >>> from strings_bench.methods.spec import PaperFigures
        >>> f = PaperFigures.table1(tandt=(.2, .1), dl3dv=(.4, .2), strings360=(.7, .1), minutes=(2.5, 17.2))
        >>> f.get("tandt", "cer", 30000), f.by_dataset()["strings360"]["minutes"]
        (0.1, {7000: 2.5, 30000: 17.2})
    """

    values: Mapping[tuple[str, str, int], float]

    @classmethod
    def table1(cls, *, tandt: tuple[float, float], dl3dv: tuple[float, float], strings360: tuple[float, float],
               minutes: tuple[float, float]) -> "PaperFigures":
        """A row of the paper's Table 1: OCR-CER at (7K, 30K) on Tanks and Temples, DL3DV and STRinGS-360, and
        training minutes at (7K, 30K) on STRinGS-360."""
        values = {}
        for dataset, metric, pair in (("tandt", "cer", tandt), ("dl3dv", "cer", dl3dv),
                                      ("strings360", "cer", strings360), ("strings360", "minutes", minutes)):
            values.update({(dataset, metric, it): float(v) for it, v in zip((7000, 30000), pair)})
        return cls(values)

    def get(self, dataset: str, metric: str, iteration: int) -> float | None:
        """The figure published for (dataset, metric, iteration), or None."""
        return self.values.get((dataset, metric, int(iteration)))

    def by_dataset(self) -> dict:
        """{dataset: {metric: {iteration: value}}}, as the reports look them up."""
        out: dict = {}
        for (dataset, metric, iteration), value in self.values.items():
            out.setdefault(dataset, {}).setdefault(metric, {})[int(iteration)] = value
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
            the plan gives it to every method with a `steps_scale` setting (bench/plan.py, `with_steps_scale`).
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

    def resolve(self, presets=None, **overrides) -> dict:
        """The settings a build uses: defaults, then each preset in order, then the overrides."""
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

    def build(self, presets=None, **overrides):
        """A configured method object (a `Method` or a `MethodAdapter`) from `resolve(presets, **overrides)`;
        `presets`: a preset name or a list. A run builds its methods with `instantiate` from the settings its plan
        resolved (bench/plan.py, where a schedule's steps scale is added)."""
        return self.instantiate(self.resolve(presets, **overrides))

    def instantiate(self, settings: dict):
        """A configured method object from final settings (every key checked, none added), named and cited as
        this spec says."""
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
