"""Methods behind one interface, each with its spec beside it (`<name>_spec.py`), and the registry that finds them
(`registry.py`; the spec machinery: `spec.py`).

Adding a method
===============

A worked example, step by step: docs/guide/adding-a-method.md, whose code is examples/opacity-splat/.

A method is one keyword `MethodSpec` (`spec.py`): its name (the one place it is written: a built method
gets it), a lazy `"module:Class"` implementation (imported only when the method is built or shown), a
description, the paper, a title and group for the tables, `defaults`, `presets` (named variants of its settings:
chosen with `run --presets NAME=PRESET`, or applied by themselves on the scenes their `"@apply"` conditions
match, as nerfbaselines does), its published figures (`paper_figures=PaperFigures({(dataset, metric, iteration):
value})`, shown beside the
measured ones), and, for an ablation, `ablation_of=`, `ablation_at=` (the paper iteration it is compared at) and
`ablation_effect=` (what it takes away), which the ablation tables and `strings-bench compare` read. The run's
schedule scale reaches every method with a `steps_scale` setting (every Gaussian method has it; bench/plan.py adds
it); a spec needs no entry for it. A built-in method's spec is a module beside it (`gs3d_spec.py` beside `gs3d.py`,
`strings/spec.py`), listed in `registry.BUILTIN_SPEC_MODULES`; a method in your own package is found through an
entry point in its `pyproject.toml` (it names a `MethodSpec`, or a callable returning one):

    [project.entry-points."strings_bench.methods"]
    my-splat = "my_pkg.splat:SPEC"

There are three kinds of implementation.

1. A variant of 3DGS: subclass `engine.splatting.GaussianSplatting` and override only its hooks (`loss`,
   `initial_model`, `position_lr`, `position_lr_scale`, `views_for_step`, `on_step_start`, `render_raster`,
   `checkpoint_extra`, ...; docs/engine.md), or set `strategy_cls` to another densification strategy
   (`engine/strategies/`). Your own settings are a dataclass named by `method_settings_cls`; the comment beside
   each field is its meaning (`strings-bench methods show NAME` prints it):

       @dataclass
       class MySettings:
           opacity_reg: float = 0.01  # weight of the mean-opacity penalty

       class MySplat(GaussianSplatting):
           method_settings_cls = MySettings  # its fields become flat settings next to 3DGS' own

           def loss(self, out, gt, view_idx, step):
               base = super().loss(out, gt, view_idx, step)
               return base + self.method_settings.opacity_reg * self.model.opacities.mean()

       SPEC = MethodSpec(name="my-splat", implementation="my_pkg.splat:MySplat",
                         description="3DGS with an opacity penalty", paper="Me: My Splatting (CVPR 2026)")

   The spec builds it with `MySplat.from_settings(**settings)`: the defaults, then the presets, then the run's
   steps scale, then `--set`; every key is flat (`--set my-splat.opacity_reg=0.05`) and an unknown one is refused
   when the run is planned, naming the valid ones.

2. Anything else the suite trains: implement `core.method.Method` (`setup`, `train_step`, `refine`, `render`,
   `num_gaussians`, `state_dict` / `load_state_dict`; the table in docs/guide/running.md). The framework's loop
   (`engine.trainer.Trainer`) owns the steps, the device, the timing, checkpoint evaluation and the resumable
   state. Give it a `from_settings(**settings)` class method or a constructor taking the settings as keywords,
   and a `settings_schema()` class method so that `methods show` lists them and `--set` is checked.

3. Models trained elsewhere: a `core.method.MethodAdapter`, built with the settings as keywords, whose
   `train(scene, checkpoints, downscale)` yields one `CheckpointResult` per checkpoint (the built-in `ply` and
   `external` methods; docs/guide/running.md).

In every case the runner does the metrics, OCR, CER and files. Check a new method with
`strings-bench methods check NAME` (docs/guide/methods.md, "Checking a method").
"""

from strings_bench.core.method import CheckpointResult, MethodAdapter
from strings_bench.methods.registry import MethodSpec, PaperFigures, get_method, list_methods, register_method

__all__ = ["CheckpointResult", "MethodAdapter", "MethodSpec", "PaperFigures", "get_method", "list_methods",
           "register_method"]
