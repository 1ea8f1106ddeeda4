"""Dataset card types and the user's index of local copies.

A card (`DatasetCard`) lists a dataset's scenes (`SceneCard`) with their per-scene settings, where
the data comes from and how to locate a scene folder. This module holds the types and the helpers
that cards need (the index written by `strings-bench datasets add`); it imports nothing of the
registry, so card modules (`datasets/cards.py`, `datasets/synthetic/`) define their cards as plain
data and `datasets/registry.py` registers them in one place (docs/architecture.md).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

from strings_bench.core.draws import draw_name, parse_draw, split_draw
from strings_bench.core.errors import DatasetError
from strings_bench.core.io import atomic_write_json, cache_root

# The `notes` of a card made for a user-registered folder; how such a card is told from a built-in one.
LOCAL_CARD_NOTES = "registered with `datasets add` or `prepare`"


@dataclass(frozen=True)
class SceneCard:
    """One scene of a dataset: its name, its per-scene settings and a one-line description."""

    name: str
    settings: dict = field(default_factory=dict)  # facts of the scene's data, e.g. {"masks_dilated": True}
    description: str = ""


@dataclass
class DatasetCard:
    """A dataset: its scenes, provenance, licence, expected layout and how to find its scene folders."""

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
    # Scene draws (core/draws.py): the draws this card registers (listed by `datasets list` and the card's notes);
    # () when its scenes have no draws. A card with draws accepts SCENE@N for every N >= 0 and its `locate`
    # builds it; `scenes` stays the draw-0 scenes.
    draws: tuple[int, ...] = ()

    def scene(self, name: str) -> SceneCard:
        """The scene card called `name` (ROOM@N: draw N of a room, where the card has draws; ROOM@0 is ROOM);
        DatasetError naming the card's scenes when there is none."""
        room, draw = split_draw(name) if self.draws else (name, 0)
        for s in self.scenes:
            if s.name == room:
                if draw == 0:
                    return s
                desc = f"{s.description} [draw {draw}: generator seed {draw}]" if s.description else f"draw {draw}"
                return SceneCard(draw_name(room, draw), settings=dict(s.settings), description=desc)
        hint = f"its scenes: {', '.join(s.name for s in self.scenes)}"
        if "@" in str(name) and not self.draws:
            raise DatasetError(f"dataset {self.id} has no scene draws ({name!r})", hint=hint + "; draws (SCENE@N) are "
                               "scenes of the synthetic360 datasets (docs/guide/datasets.md, 'Scene draws')")
        raise DatasetError(f"dataset {self.id} has no scene {name!r}", hint=hint)

    def select(self, part: str = "", draw: str | None = None) -> list[SceneCard]:
        """The scenes a spec names: `part` '' (every scene) or a scene name, `draw` the N of a DATASET@N spec
        (every scene at draw N) or None."""
        if draw is not None:
            if not self.draws:
                raise DatasetError(f"dataset {self.id} has no scene draws ({self.id}@{draw})",
                                   hint="draws (DATASET@N, SCENE@N) are scenes of the synthetic360 datasets")
            if part:
                raise DatasetError(f"{self.id}@{draw}/{part}: put the draw on the scene", hint=f"{self.id}/{part}@{draw}")
            n = parse_draw(draw, f"the draw of {self.id}@{draw},")
            return [self.scene(draw_name(s.name, n)) for s in self.scenes]
        return [self.scene(part)] if part else list(self.scenes)


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

    def load(self):
        """The scene itself (`scene.Scene`), named and set up as a run loads it."""
        from strings_bench.scene.scene import Scene

        return Scene.load(self.path, name=self.scene, settings=dict(self.settings))


# ---- the user's index of local copies (`datasets add`) ---------------------------------------
def index_path() -> Path:
    """Where the index of local copies lives: `cache_root()/datasets.json`."""
    return cache_root() / "datasets.json"


def read_index() -> dict[str, str]:
    """The index of local copies: dataset name -> folder ({} when none is registered)."""
    p = index_path()
    if not p.exists():
        return {}
    try:
        return dict(json.loads(p.read_text()))
    except ValueError as exc:
        raise DatasetError(f"the dataset index {p} is corrupt: {exc}", hint="delete it and re-run `strings-bench datasets add`") from exc


def write_index(index: dict[str, str]) -> None:
    """Replace the index of local copies (atomically)."""
    atomic_write_json(index_path(), index)


def local_root(dataset_id: str) -> Path:
    """The folder registered for `dataset_id`; DatasetError when it has no local copy."""
    index = read_index()
    if dataset_id not in index:
        raise DatasetError(f"dataset {dataset_id!r} has no local copy registered",
                           hint=f"download it, then `strings-bench datasets add {dataset_id} PATH`")
    return Path(index[dataset_id])


def locate_scene(card: DatasetCard, scene: str) -> Path:
    """The folder of one scene of `card`: its own `locate`, else ROOT/<scene> of its local copy."""
    if card.locate is not None:
        return card.locate(scene)
    return local_root(card.id) / scene
