"""Cards for the real datasets of the paper, and cards for the user's own local scenes.

A card lists a dataset's scenes with what is true of their data (e.g. masks shipped already dilated),
where the data comes from, its licence and the folder layout it expects.
The cards are plain data; `strings_bench.datasets.registry` registers them, and the user's local
copies through `local_card`. The data itself is never shipped: `strings-bench datasets download
NAME` fetches what has a direct URL and prints the steps for the rest; `strings-bench datasets add
NAME PATH` records a local copy.

Layout of a local copy (ROOT is what `datasets add NAME ROOT` records):

    ROOT/<scene>/images/      undistorted photos (PINHOLE / SIMPLE_PINHOLE cameras)
    ROOT/<scene>/sparse/0/    COLMAP model (.bin or .txt)
    ROOT/<scene>/masks/       optional text masks, <image stem>.png
    ROOT/scenes.json          optional {"<scene name>": "<folder name>"} when the folders are named
                              differently (e.g. DL3DV folders named by hash)
"""

from __future__ import annotations

import json
from pathlib import Path

from strings_bench.core.errors import DatasetError
from strings_bench.datasets.card import LOCAL_CARD_NOTES, DatasetCard, SceneCard, local_root

SCENE_MAP_FILE = "scenes.json"
STRINGS_PROJECT_PAGE = "https://strings-official.github.io/"


def find_scene_folder(root: Path, scene: str, dataset_id: str = "") -> Path:
    """ROOT/<scene>: the exact name, then ROOT/scenes.json, then the name in any letter case."""
    root = Path(root)
    exact = root / scene
    if exact.is_dir():
        return exact
    mapping_file = root / SCENE_MAP_FILE
    if mapping_file.exists():
        try:
            mapping = json.loads(mapping_file.read_text())
        except ValueError as exc:
            raise DatasetError(f"cannot read {mapping_file}: {exc}",
                               hint='expected {"scene name": "folder name", ...}') from exc
        if scene in mapping and (root / str(mapping[scene])).is_dir():
            return root / str(mapping[scene])
    if root.is_dir():
        folded = sorted(p for p in root.iterdir() if p.is_dir() and p.name.lower() == scene.lower())
        if folded:
            return folded[0]
    raise DatasetError(
        f"scene {scene!r}{' of ' + dataset_id if dataset_id else ''} is not in {root}",
        hint=f"expected the folder {root / scene} (images/, sparse/0/), or a {SCENE_MAP_FILE} in {root} "
        f"mapping {scene!r} to its folder name",
    )


def _locate_in_local_copy(dataset_id: str):
    def locate(scene: str) -> Path:
        root = local_root(dataset_id)
        if not root.is_dir():
            raise DatasetError(f"the registered copy of {dataset_id} at {root} does not exist any more",
                               hint=f"re-run `strings-bench datasets add {dataset_id} PATH` with its new place")
        return find_scene_folder(root, scene, dataset_id)

    return locate


# The release's masks/ are its Hi-SAM script's output, already dilated (20 % of the width "for all
# experiments"); its training and its OCR-CER read them as they are (eval/text_masks.py).
_RELEASE_MASKS = {"masks_dilated": True}

STRINGS360 = DatasetCard(
    id="strings360",
    locate=_locate_in_local_copy("strings360"),
    title="STRinGS-360 (text-rich indoor 360-degree captures, the paper's own dataset)",
    scenes=[
        SceneCard("extinguisher", dict(_RELEASE_MASKS), "instructional text on a curved cylinder"),
        SceneCard("books", dict(_RELEASE_MASKS), "flat, densely packed book titles and author names"),
        SceneCard("chemicals", dict(_RELEASE_MASKS), "chemical compositions on bottle labels on a lab shelf"),
        SceneCard("globe", dict(_RELEASE_MASKS), "place names on a sphere"),
        SceneCard("shelf", dict(_RELEASE_MASKS), "stacked academic books, repeated titles, occlusion"),
    ],
    source=f"released by the STRinGS authors via Google Drive, linked from the project page {STRINGS_PROJECT_PAGE}",
    licence=f"see the paper's project page ({STRINGS_PROJECT_PAGE})",
    layout="<scene>/images/, <scene>/sparse/0/, <scene>/masks/ (Hi-SAM text masks), plus the Hi-SAM polygons",
    notes="STRinGS' N_max is 25 on every scene (its spec's preset n-max-strings360). Its masks/ are already dilated "
    "(the release's Hi-SAM output): STRinGS trains with them and OCR-CER reads through them as they are.",
    download={
        "manual": True,
        "steps": [
            f"Open the project page {STRINGS_PROJECT_PAGE} and follow its dataset link (a Google Drive folder).",
            "Download the folder in a browser (Google Drive zips large folders into several parts; download all parts).",
            "Unzip everything into one folder ROOT so that ROOT/extinguisher/images, ROOT/extinguisher/sparse/0, "
            "... exist (folder names may be capitalised; that is fine).",
            "Register it: strings-bench datasets add strings360 ROOT",
            "Check it: strings-bench datasets check strings360",
        ],
    },
)

TANDT = DatasetCard(
    id="tandt",
    locate=_locate_in_local_copy("tandt"),
    title="Tanks and Temples: Truck and Train (the 3DGS authors' COLMAP-processed copy)",
    scenes=[
        SceneCard("truck", {}, "a truck with lettering, outdoor 360"),
        SceneCard("train", {}, "a locomotive with lettering, outdoor 360"),
    ],
    source="Knapitsch et al. 2017 (tanksandtemples.org); preprocessed with COLMAP by the 3DGS authors (tandt_db.zip)",
    licence="Tanks and Temples licence, https://www.tanksandtemples.org/license/ (read it before use)",
    layout="tandt/<scene>/images/, tandt/<scene>/sparse/0/ (no masks: make them with the OCR detector or Hi-SAM)",
    notes="STRinGS' N_max: Truck 20, Train 15 (its spec's presets). The zip also holds Deep Blending (db/), unused here.",
    download={
        "url": "https://repo-sam.inria.fr/fungraph/3d-gaussian-splatting/datasets/input/tandt_db.zip",
        "sha256": None,  # not published by the host; the computed hash is printed
        "archive_subdir": "tandt",
        "filename": "tandt_db.zip",
    },
)

DL3DV = DatasetCard(
    id="dl3dv",
    locate=_locate_in_local_copy("dl3dv"),
    title="DL3DV-10K benchmark: the 7 text-bearing scenes used in the paper",
    scenes=[SceneCard(str(i), {}, "benchmark scene index")
            for i in (3, 21, 80, 92, 107, 132, 136)],
    source="DL3DV-10K benchmark (Ling et al. 2024), Hugging Face dataset DL3DV/DL3DV-Benchmark (gated)",
    licence="DL3DV-10K Terms of Use (https://github.com/DL3DV-10K/Dataset/blob/main/DL3DV-10K_term_of_use.pdf)",
    layout="<scene>/images/, <scene>/sparse/0/; the benchmark names folders by hash: map them in ROOT/scenes.json",
    notes="STRinGS' N_max per scene is the release's full_eval.py (--max_densify): 3, 21, 92, 107 20; 80, 132, 136 15 "
    "(its spec's presets n-max-dl3dv-20 / -15). "
    "The paper numbers scenes by their index in the benchmark; which hash each index is must be read from "
    "the benchmark's scene list (see the paper's project page).",
    download={
        "manual": True,
        "steps": [
            "Create a Hugging Face account, open https://huggingface.co/datasets/DL3DV/DL3DV-Benchmark "
            "and accept the terms of use (the dataset is gated).",
            "Log in on this machine: `huggingface-cli login` (or set HF_TOKEN).",
            "Download only the 7 scenes (the full benchmark is about 2 TB) with the download script from that page, "
            "selecting scenes by hash; the paper's scene numbers 3, 21, 80, 92, 107, 132, 136 are indices into the "
            "benchmark's scene list (see the paper's project page, " + STRINGS_PROJECT_PAGE + ").",
            "Put the scene folders under one ROOT and write ROOT/scenes.json mapping each number to its folder, "
            'e.g. {"3": "<hash>", "21": "<hash>", ...}. Each folder needs images/ and sparse/0/ '
            "(undistorted; run `strings-bench prepare` on the frames if only distorted frames are present).",
            "Register it: strings-bench datasets add dl3dv ROOT",
            "Check it: strings-bench datasets check dl3dv",
        ],
    },
)

BUILTIN_REAL_CARDS = (STRINGS360, TANDT, DL3DV)


# ---- the user's own scenes (`prepare`, `datasets add NAME PATH` with a new NAME) -------------
def _is_scene_dir(p: Path) -> bool:
    return (p / "sparse").exists() or (p / "images").is_dir()


def local_card(name: str, path: Path) -> DatasetCard:
    """A card for a user-registered folder: one scene (the folder) or a folder of scene folders."""
    path = Path(path)
    if _is_scene_dir(path) or not path.is_dir():
        scenes = [SceneCard(path.name, {}, f"local scene at {path}")]
        locate = lambda scene, _p=path: _p  # noqa: E731
    else:
        subs = sorted(p for p in path.iterdir() if p.is_dir() and _is_scene_dir(p))
        scenes = [SceneCard(p.name, {}, f"local scene at {p}") for p in subs]
        locate = lambda scene, _p=path: _p / scene  # noqa: E731
    return DatasetCard(id=name, title=f"local copy at {path}", scenes=scenes, source=str(path),
                       licence="(your own data)", locate=locate, notes=LOCAL_CARD_NOTES)
