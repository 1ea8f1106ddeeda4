"""Dataset registry: embedded synthetic scenes and cards for real datasets on disk."""

from strings_bench.datasets.registry import DatasetCard, SceneCard, SceneRef, get_dataset, list_datasets, register_dataset, resolve_scenes

__all__ = ["DatasetCard", "SceneCard", "SceneRef", "get_dataset", "list_datasets", "register_dataset", "resolve_scenes"]
