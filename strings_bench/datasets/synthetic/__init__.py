"""The embedded synthetic benchmarks: `synthetic` (five object-centred scenes mirroring the text
configurations of STRinGS-360; easy) and `synthetic360` (room-scale scenes with difficulty controls).

`synthetic/<scene>` and `synthetic360/<scene>` specs build the scene on first use (320x240, 48
views, seed 0; synthetic360 with the photometric settings of `SYNTHETIC360_DEFAULTS`) into
`cache_root()/synthetic/<scene>-<key>/` and reuse it afterwards. See docs/synthetic.md for what
each scene holds, the difficulty controls, and how its point cloud is made.

Every synthetic360 card (synthetic360, its configurations such as synthetic360-cpu, the calibration's grid
points) has scene draws (core/draws.py): `<card>/pantry@N` is the room built with generator seed N (`with_draw`);
`pantry` and `pantry@0` are the seed-0 scene, with the cache key it had before draws existed.
"""

from __future__ import annotations

from pathlib import Path

from dataclasses import replace

from strings_bench.core.progress import progress_shown
from strings_bench.core.draws import REGISTERED_DRAWS, split_draw
from strings_bench.core.errors import DatasetError
from strings_bench.datasets.card import DatasetCard, SceneCard
from strings_bench.core.scripts import LANGUAGES
from strings_bench.datasets.synthetic.multiscript import SCENE_NAMES_MULTI, WORDS, scene_script
from strings_bench.datasets.synthetic.generate import (GENERATOR_VERSION, SCENE_NAMES, SCENE_NAMES_360, SyntheticSettings,
                                                       build_scene, is_built, read_meta, scene_dir, settings_with)

__all__ = ["GENERATOR_VERSION", "SCENE_NAMES", "SCENE_NAMES_360", "SYNTHETIC360_DEFAULTS", "SyntheticSettings",
           "build_scene", "default_settings", "SYNTHETIC360_CPU", "CONFIGURATIONS", "CARD_360_CPU", "is_built",
           "read_meta", "scene_dir", "settings_with", "CARD", "CARD_360", "CARD_MULTI", "SCENE_NAMES_MULTI",
           "synthetic360_card", "with_draw", "REGISTERED_DRAWS", "TINY_SCENE", "TINY_SCENE_SETTINGS", "tiny_scene"]

# The tiny scene of `methods check` (bench/check.py), the kernel warm-up (bench/warmup.py) and the cookbook: big
# enough for a real (if blurry) render and a real OCR pass, small enough that a method's whole check takes seconds.
TINY_SCENE = "books"
TINY_SCENE_SETTINGS = {"width": 96, "height": 72, "n_views": 8}


def tiny_scene() -> Path:
    """The tiny scene's folder (`TINY_SCENE` at `TINY_SCENE_SETTINGS`, built into the cache on first use, about a
    second)."""
    import logging

    # At this size SfM finds too few points and the generator falls back to depth samples, which is what its users
    # want (a valid point cloud); its warning about that is not the user's concern here.
    gen_log = logging.getLogger("strings_bench.datasets.synthetic.generate")
    level = gen_log.level
    gen_log.setLevel(logging.ERROR)
    try:
        return build_scene(TINY_SCENE, settings_with(**TINY_SCENE_SETTINGS), progress=False)
    finally:
        gen_log.setLevel(level)

DESCRIPTIONS = {
    "books": "packed book spines: vertical titles and authors, lying books with horizontal text, printed covers",
    "extinguisher": "instruction labels on a cylinder (curved text), small product codes",
    "globe": "place names on a tilted sphere (oceans, continents, small city names)",
    "chemicals": "labelled bottles on a lab table: names, formulas, CAS numbers",
    "shelf": "stacked lying books with repeated titles, partly occluded by boards and upright books",
}


DESCRIPTIONS_360 = {
    "pantry": "kitchen island with labelled canisters (curved text), cereal boxes, a double-sided menu board, "
              "wall posters, textured clutter around the room",
    "office": "desk with back-to-back binder rows (vertical spine text), nameplate, double-sided whiteboard, "
              "recycling bin, wall posters, clutter",
    "storeroom": "pallet of stencilled crates, an oil drum with curved hazard labels, a double-sided safety sign, "
                 "wall signs, clutter",
}

# The CPU default of `synthetic360`: the room at scale 1 with mild per-view camera variation. Not
# calibrated against the paper yet (that needs the GPU; docs/synthetic.md, "Calibration").
SYNTHETIC360_DEFAULTS = {"exposure_sd": 0.15, "white_balance_sd": 0.03, "vignetting": 0.15, "noise_sigma": 1.5}

# The CPU configuration `synthetic360-cpu`: the settings frozen by the blind calibration on
# 3DGS alone at the CPU regime (320x240, 48 views, schedule x0.05; docs/synthetic.md, "Calibration on
# the CPU", which gives the measured points, the one chosen and why). Its cache keys are pinned by a test.
SYNTHETIC360_CPU = {**SYNTHETIC360_DEFAULTS, "width": 320, "height": 240, "n_views": 48, "room_scale": 0.6,
                    "text_px": (10.0, 16.0)}
# Registered configurations of synthetic360 other than the card's defaults: dataset id -> settings.
CONFIGURATIONS = {"synthetic360-cpu": SYNTHETIC360_CPU}


def default_settings(scene: str, dataset: str | None = None) -> SyntheticSettings:
    """The settings `synthetic/<scene>`, `synthetic360/<scene>` or a configuration's scene (`dataset`, e.g.
    synthetic360-cpu) builds with when none are given; a draw (pantry@N) at generator seed N."""
    room = split_draw(scene)[0]
    if dataset in CONFIGURATIONS:
        base = settings_with(**CONFIGURATIONS[dataset])
    else:
        base = settings_with(**SYNTHETIC360_DEFAULTS) if room in SCENE_NAMES_360 else SyntheticSettings()
    return with_draw(scene, base)[1]


def with_draw(scene: str, settings: SyntheticSettings) -> tuple[str, SyntheticSettings]:
    """(room, settings) a scene name builds with: ROOM@N is the room at generator seed N (every other setting as
    given); ROOM (= ROOM@0) is the settings as given. A draw needs settings whose own seed is 0: otherwise ROOM and
    ROOM@0 would be two scenes (DatasetError)."""
    room, draw = split_draw(scene)
    if scene == room:
        return room, settings
    if settings.seed != 0:
        raise DatasetError(f"{scene}: a draw sets the generator seed, and these settings already have seed "
                           f"{settings.seed}", hint=f"give {room}@{settings.seed}, or leave the seed at 0")
    return room, replace(settings, seed=draw)


def _locate(scene: str) -> Path:
    return build_scene(scene, default_settings(scene), progress=progress_shown())


# Registered by strings_bench.datasets.registry (this package imports nothing of the registry).
CARD = DatasetCard(
    id="synthetic",
    title="Synthetic STRinGS-360-like scenes (generated, ray-traced, SfM points from pycolmap)",
    scenes=[SceneCard(name, description=DESCRIPTIONS[name]) for name in SCENE_NAMES],
    source="generated in code by strings_bench.datasets.synthetic",
    licence="MIT (generated by this suite); fonts: DejaVu (Bitstream Vera licence) shipped with matplotlib",
    layout="images/, sparse/0/, masks/ (GT text), text_annotations.json, scene_meta.json",
    locate=_locate,
    notes="built on first use into the cache; `strings-bench datasets prepare synthetic --all` builds all five",
)


def synthetic360_card(card_id: str = "synthetic360", settings: SyntheticSettings | None = None,
                      title: str | None = None) -> DatasetCard:
    """A `synthetic360` card whose scenes build with `settings` (default: SYNTHETIC360_DEFAULTS);
    strings-bench calibrate registers one per point of its difficulty grid. Its scenes have draws (ROOM@N: the
    room at generator seed N; `with_draw`) unless `settings` set a generator seed of their own."""
    chosen = settings

    def locate(scene: str) -> Path:
        room, st = with_draw(scene, chosen if chosen is not None else default_settings(split_draw(scene)[0]))
        return build_scene(room, st, progress=progress_shown())

    draws = () if chosen is not None and chosen.seed != 0 else REGISTERED_DRAWS
    registered = ", ".join(f"@{d}" for d in draws)

    return DatasetCard(
        id=card_id,
        title=title or "Synthetic room-scale 360-degree scenes with difficulty controls (generated, ray-traced, SfM points)",
        scenes=[SceneCard(name, description=DESCRIPTIONS_360[name]) for name in SCENE_NAMES_360],
        source="generated in code by strings_bench.datasets.synthetic (scenes360.py)",
        licence="MIT (generated by this suite); fonts: DejaVu (Bitstream Vera licence) shipped with matplotlib",
        layout="images/, sparse/0/, masks/ (GT text), text_annotations.json, scene_meta.json",
        locate=locate,
        notes="built on first use into the cache; `strings-bench datasets prepare synthetic360` builds all three; "
              "difficulty settings: `datasets prepare --help`, docs/synthetic.md"
              + (f"; scene draws: SCENE@N is the room at generator seed N (any N >= 0; registered: {registered}; "
                 f"SCENE@0 = SCENE), {card_id}@N every room at draw N" if draws else ""),
        draws=draws,
    )


CARD_360 = synthetic360_card()
CARD_360_CPU = synthetic360_card(
    "synthetic360-cpu", default_settings("pantry", "synthetic360-cpu"),
    title="synthetic360 at its CPU configuration (calibrated blind on 3DGS at 320x240, 48 views, schedule x0.05)")


def _locate_multi(scene: str) -> Path:
    return build_scene(scene, SyntheticSettings(), progress=progress_shown())


# One scene per script (multiscript.py): the same geometry families, real words of the language,
# Noto fonts from Debian (without them the scene is refused with the reason, never drawn with tofu).
CARD_MULTI = DatasetCard(
    id="synthetic-multi",
    title="Synthetic multilingual scenes: Cyrillic, Greek, Devanagari, Arabic (RTL), Simplified Chinese",
    scenes=[SceneCard(name, description=f"{LANGUAGES[WORDS[name].lang].name} ({scene_script(name)}; Tesseract lang "
                                        f"{WORDS[name].lang}): book spines, labelled jars, a double-sided sign")
            for name in SCENE_NAMES_MULTI],
    source="generated in code by strings_bench.datasets.synthetic (multiscript.py)",
    licence="MIT (generated by this suite); fonts: Noto (SIL Open Font License) from Debian fonts-noto-core, fonts-noto-cjk",
    layout="images/, sparse/0/, masks/ (GT text), text_annotations.json (with lang and script per word), scene_meta.json",
    locate=_locate_multi,
    notes="built on first use into the cache; needs fonts-noto-core and fonts-noto-cjk (scripts/system_deps.sh); "
          "OCR with --ocr tesseract:lang=<code> (docs/ocr.md, 'Other scripts')",
)
