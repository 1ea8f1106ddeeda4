"""The ply adapter's spec (the adapter: ply_adapter.py)."""

from strings_bench.methods.spec import MethodSpec

SPEC = MethodSpec(
    name="ply", title="PLY models", group="adapter", implementation="strings_bench.methods.ply_adapter:PlyAdapter",
    description="evaluate existing 3DGS PLY models (setting ply_path, may use {scene}/{dataset}/{iteration}); "
                "no training",
    defaults={"iteration": 30000})
