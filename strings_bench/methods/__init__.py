"""Methods behind one adapter interface, and the registry of method specs with presets."""

from strings_bench.core.method import CheckpointResult, MethodAdapter
from strings_bench.methods.registry import MethodSpec, get_method, list_methods, register_method

__all__ = ["CheckpointResult", "MethodAdapter", "MethodSpec", "get_method", "list_methods", "register_method"]
