"""Each scene of the captures dataset built whole from ../shared/data through the registry, as a run builds it
(slow; opt-in):

    pytest -m slow tests/datasets/test_captures_slow.py -s          # -k bundler_et for one capture

Per capture: the scene passes `datasets check`; photos SfM did not register are listed in the record, not fatal;
the split holds out at least 3 views; the record counts the characters OCR reads on the held-out GT and measures
rho; the GT scored against itself gives OCR-CER 0 where the GT clears the floor and "not scored" (with the
reason) where it does not, and no known-text CER (nothing is known of a photo's text). Builds take 1-8 minutes
each on 2 shared cores (docs/results/captures.md).
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from strings_bench.datasets import captures

DATA = Path(os.environ.get(captures.CAPTURES_ENV, captures.DEFAULT_DATA_ROOT))
pytestmark = [pytest.mark.slow, pytest.mark.skipif(not DATA.is_dir(), reason=f"the captures' photos are not at {DATA}")]


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    root = tmp_path_factory.mktemp("captures")
    old = os.environ.get("STRINGS_BENCH_CACHE")
    os.environ["STRINGS_BENCH_CACHE"] = str(root / "cache")
    yield root
    if old is None:
        os.environ.pop("STRINGS_BENCH_CACHE", None)
    else:
        os.environ["STRINGS_BENCH_CACHE"] = old


@pytest.mark.parametrize("name", list(captures.CAPTURES))
def test_capture_builds_and_its_gt_is_scored_by_the_floor(name, cache):
    from strings_bench.datasets.check import check_scene
    from strings_bench.datasets.registry import resolve_scenes
    from strings_bench.eval.ocr import get_engine
    from strings_bench.eval.protocol import Evaluator

    if not (DATA / captures.CAPTURES[name].folder).is_dir():
        pytest.skip(f"{name} is not in {DATA}")
    ref = resolve_scenes([f"captures/{name}"])[0]  # built on first use
    assert ref.path == captures.scene_dir(name) and captures.is_built(name)
    report = check_scene(ref.path)
    assert report.ok, report.format()
    rec = captures.read_record(ref.path)
    prep = rec["prepare"]
    print(f"\n{name}: registered {prep['num_registered']}/{prep['num_photos']}, left out {prep['unregistered']}, "
          f"test views {len(rec['test_views'])}, GT characters {({k: v['chars'] for k, v in rec['gt_characters'].items()})}"
          f", rho {rec['difficulty']['rho']}, prepare {rec['prepare_seconds']:.0f} s")
    assert prep["num_registered"] + len(prep["unregistered"]) == prep["num_photos"]
    assert prep["num_registered"] >= 0.8 * prep["num_photos"]
    assert len(rec["test_views"]) >= 3 and rec["train_views"] >= 2 * len(rec["test_views"])
    assert rec["difficulty"]["rho"] is not None and rec["difficulty"]["words"] > 0
    scene = ref.load()
    if name == "saharov32":  # stored sideways (EXIF 8): upright portrait views
        assert all(c.height > c.width for c in scene.model.cameras)

    evaluator = Evaluator.for_scene(scene, get_engine(captures.CAPTURES[name].gt_ocr), 1, with_lpips=False,
                                    with_readability=False)
    res = evaluator.evaluate("gt", {n: evaluator.gt(n) for n in evaluator.names})
    assert res["cer_known"] is None  # no known text on photographs
    chars = rec["gt_characters"]["1"]["chars"]
    assert res["cer"]["chars"] == chars  # the record counts what the evaluation reads
    if chars >= captures.MIN_GT_CHARS:
        assert res["cer"]["cer"] == 0.0 and "not_scored" not in res["cer"]
    else:
        assert res["cer"]["cer"] is None and "below this scene's floor" in res["cer"]["not_scored"]
