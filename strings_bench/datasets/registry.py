"""Registry of dataset cards and resolution of `--datasets` specs to scene folders.

A spec is a registry id (`synthetic`, `synthetic/books`, `strings360/globe`) or a path to a scene
folder in the COLMAP layout. Cards describe scenes and their per-scene settings; where a card's
data lives on disk is either built in (synthetic scenes are generated into the cache) or recorded
by `strings-bench datasets add NAME PATH` in the user's dataset index.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

from strings_bench.core.errors import DatasetError
from strings_bench.core.io import atomic_write_json, cache_root


@dataclass(frozen=True)
class SceneCard:
    name: str
    settings: dict = field(default_factory=dict)  # e.g. {"n_max": 25}
    description: str = ""


@dataclass
class DatasetCard:
    id: str
    title: str
    scenes: list[SceneCard]
    source: str = ""
    licence: str = ""
    layout: str = "images/, sparse/0/, optional masks/"
    # Builds or locates the scene folder for a scene name; None means "look in the user's index".
    locate: Callable[[str], Path] | None = None
    notes: str = ""
    download: dict | None = None  # optional: how to obtain the data (urls, sha256, steps)

    def scene(self, name: str) -> SceneCard:
        for s in self.scenes:
            if s.name == name:
                return s
        raise DatasetError(f"dataset {self.id} has no scene {name!r}",
                           hint=f"its scenes: {', '.join(s.name for s in self.scenes)}")


@dataclass(frozen=True)
class SceneRef:
    """One resolved scene: where it is and which settings apply."""

    dataset: str
    scene: str
    path: Path
    settings: dict = field(default_factory=dict)

    @property
    def id(self) -> str:
        return f"{self.dataset}/{self.scene}"


_REGISTRY: dict[str, DatasetCard] = {}


def register_dataset(card: DatasetCard) -> DatasetCard:
    _REGISTRY[card.id] = card
    return card


def _load_builtin_cards() -> None:
    # Importing the card modules registers them. cards.py needs no optional dependency, so an
    # ImportError there is a bug and must surface (swallowing it silently removed the real datasets).
    import strings_bench.datasets.cards as cards
    import strings_bench.datasets.synthetic as synthetic


def list_datasets() -> list[DatasetCard]:
    _load_builtin_cards()
    return list(_REGISTRY.values())


def get_dataset(dataset_id: str) -> DatasetCard:
    _load_builtin_cards()
    if dataset_id not in _REGISTRY:
        raise DatasetError(f"unknown dataset {dataset_id!r}",
                           hint=f"known: {', '.join(sorted(_REGISTRY))}; or pass a path to a scene folder")
    return _REGISTRY[dataset_id]


# ---- the user's index of local copies (`datasets add`) ---------------------------------------
def index_path() -> Path:
    return cache_root() / "datasets.json"


def read_index() -> dict[str, str]:
    p = index_path()
    if not p.exists():
        return {}
    try:
        return dict(json.loads(p.read_text()))
    except ValueError as exc:
        raise DatasetError(f"the dataset index {p} is corrupt: {exc}", hint="delete it and re-run `strings-bench datasets add`") from exc


def write_index(index: dict[str, str]) -> None:
    atomic_write_json(index_path(), index)


def local_root(dataset_id: str) -> Path:
    index = read_index()
    if dataset_id not in index:
        raise DatasetError(f"dataset {dataset_id!r} has no local copy registered",
                           hint=f"download it, then `strings-bench datasets add {dataset_id} PATH`")
    return Path(index[dataset_id])


def locate_scene(card: DatasetCard, scene: str) -> Path:
    if card.locate is not None:
        return card.locate(scene)
    return local_root(card.id) / scene


def resolve_scenes(specs: list[str]) -> list[SceneRef]:
    """Turn `--datasets` entries into scene references (building synthetic scenes if needed)."""
    refs: list[SceneRef] = []
    for spec in specs:
        path = Path(spec)
        if path.is_dir():
            # A scene folder, or a folder of scene folders.
            if (path / "sparse").exists() or (path / "images").exists():
                refs.append(SceneRef(dataset=path.parent.name or "local", scene=path.name, path=path.resolve()))
            else:
                subs = sorted(p for p in path.iterdir() if (p / "sparse").exists())
                if not subs:
                    raise DatasetError(f"{path} is neither a scene folder nor a folder of scenes",
                                       hint="a scene folder holds images/ and sparse/0/")
                refs.extend(SceneRef(dataset=path.name, scene=p.name, path=p.resolve()) for p in subs)
            continue
        dataset_id, _, scene = spec.partition("/")
        card = get_dataset(dataset_id)
        scenes = [card.scene(scene)] if scene else card.scenes
        for sc in scenes:
            refs.append(SceneRef(dataset=card.id, scene=sc.name, path=locate_scene(card, sc.name), settings=dict(sc.settings)))
    return refs
