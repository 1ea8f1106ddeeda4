"""Methods behind one adapter interface, and the registry of method specs with presets."""

from .base import CheckpointResult, MethodAdapter
from .registry import MethodSpec, get_method, list_methods, register_method

__all__ = ["CheckpointResult", "MethodAdapter", "MethodSpec", "get_method", "list_methods", "register_method"]
