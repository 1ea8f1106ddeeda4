"""Registry of dataset cards and resolution of `--datasets` specs to scene folders.

A spec is a registry id (`synthetic`, `synthetic/books`, `synthetic360/office`, `strings360/globe`) or a path to a scene
folder in the COLMAP layout. On a card with scene draws (core/draws.py) `synthetic360-cpu/pantry@1` is draw 1 of a
room and `synthetic360-cpu@1` every room at draw 1. Cards describe scenes and their per-scene settings; where a card's
data lives on disk is either built in (synthetic scenes are generated into the cache) or recorded
by `strings-bench datasets add NAME PATH` in the user's dataset index.

Registration is explicit and happens here only: the card modules (`cards.py`, `synthetic/`) define
their cards as data and import nothing of this module; `_register_builtin_cards` registers them on
first use (lazily, because importing the synthetic generator costs ~0.3 s).
"""

from __future__ import annotations

from pathlib import Path

from strings_bench.core.errors import DatasetError
from strings_bench.datasets.card import (LOCAL_CARD_NOTES, DatasetCard, SceneCard, SceneRef, index_path, local_root,
                                         locate_scene, read_index, write_index)

__all__ = ["DatasetCard", "SceneCard", "SceneRef", "get_dataset", "index_path", "list_datasets", "local_root",
           "locate_scene", "read_index", "register_dataset", "register_local_copies", "resolve_scenes", "select_scenes",
           "write_index"]

_REGISTRY: dict[str, DatasetCard] = {}
_BUILTINS_REGISTERED = False


def register_dataset(card: DatasetCard) -> DatasetCard:
    """Make `card` resolvable as `--datasets card.id` (replacing a card of the same id)."""
    _REGISTRY[card.id] = card
    return card


def _register_builtin_cards() -> None:
    """Register the built-in cards (the paper's real datasets, then the synthetic benchmark) and the
    user's local copies, once. An ImportError in a card module is a bug and surfaces."""
    global _BUILTINS_REGISTERED
    if _BUILTINS_REGISTERED:
        return
    import strings_bench.datasets.captures as captures
    import strings_bench.datasets.cards as cards
    import strings_bench.datasets.synthetic as synthetic

    for card in (*cards.BUILTIN_REAL_CARDS, synthetic.CARD, synthetic.CARD_360, synthetic.CARD_360_CPU,
                 synthetic.CARD_MULTI, captures.card()):
        register_dataset(card)
    _BUILTINS_REGISTERED = True
    try:
        register_local_copies()
    except DatasetError:
        pass  # a corrupt index is reported by the command that reads it, not when cards are loaded


def register_local_copies() -> list[str]:
    """Make every index entry that is not a built-in card usable as `--datasets NAME`; returns the
    names registered."""
    _register_builtin_cards()  # built-in cards first, so that no index entry can shadow one
    from strings_bench.datasets.cards import local_card

    added = []
    for name, path in read_index().items():
        existing = _REGISTRY.get(name)
        if existing is not None and existing.notes != LOCAL_CARD_NOTES:
            continue  # never shadow a built-in card (strings360, synthetic, ...) with an index entry
        register_dataset(local_card(name, Path(path)))
        added.append(name)
    return added


def _refresh_local_copies() -> None:
    """Register index entries written since the cards were loaded (`prepare` records its scene in the index)."""
    try:
        register_local_copies()
    except DatasetError:
        pass  # a corrupt index is reported by the command that reads it


def list_datasets() -> list[DatasetCard]:
    """Every registered card: the built-in ones, the user's local copies, and any registered in code."""
    _register_builtin_cards()
    _refresh_local_copies()
    return list(_REGISTRY.values())


def find_dataset(dataset_id: str) -> DatasetCard | None:
    """The card registered as `dataset_id`, None when there is none."""
    _register_builtin_cards()
    if dataset_id not in _REGISTRY:
        _refresh_local_copies()
    return _REGISTRY.get(dataset_id)


def get_dataset(dataset_id: str) -> DatasetCard:
    """The card registered as `dataset_id`; DatasetError naming the known ids when there is none."""
    _register_builtin_cards()
    if dataset_id not in _REGISTRY:
        _refresh_local_copies()
    if dataset_id not in _REGISTRY:
        raise DatasetError(f"unknown dataset {dataset_id!r}",
                           hint=f"known: {', '.join(sorted(_REGISTRY))}; or pass a path to a scene folder")
    return _REGISTRY[dataset_id]


def select_scenes(spec: str) -> tuple[DatasetCard, list[SceneCard]]:
    """The card and scenes a registry spec names: DATASET, DATASET/SCENE, DATASET/SCENE@N (draw N of a scene) or
    DATASET@N (every scene at draw N); DatasetError for an unknown dataset, scene or a malformed draw."""
    dataset_id, _, scene = spec.partition("/")
    dataset_id, sep, draw = dataset_id.partition("@")
    card = get_dataset(dataset_id)
    return card, card.select(scene, draw if sep else None)


def resolve_scenes(specs: list[str]) -> list[SceneRef]:
    """Turn `--datasets` entries into scene references (building synthetic scenes if needed)."""
    refs: list[SceneRef] = []
    for spec in specs:
        path = Path(spec)
        if path.is_dir():
            # A scene folder, or a folder of scene folders.
            if (path / "sparse").exists() or (path / "images").exists():
                # Labelled by the scene folder itself: its parent is often a generic folder ("scenes", "data").
                here = path.resolve()
                from strings_bench.datasets.synthetic.generate import ensure_rho_record

                ensure_rho_record(here)  # a synthetic room of the cache named by its folder: rho as its build keeps it
                refs.append(SceneRef(dataset=here.name or "local", scene=here.name, path=here))
            else:
                subs = sorted(p for p in path.iterdir() if (p / "sparse").exists())
                if not subs:
                    raise DatasetError(f"{path} is neither a scene folder nor a folder of scenes",
                                       hint="a scene folder holds images/ and sparse/0/")
                refs.extend(SceneRef(dataset=path.name, scene=p.name, path=p.resolve()) for p in subs)
            continue
        card, scenes = select_scenes(spec)
        for sc in scenes:
            refs.append(SceneRef(dataset=card.id, scene=sc.name, path=locate_scene(card, sc.name), settings=dict(sc.settings)))
    return refs
