"""tools/blend_ab.py's parts that time nothing: the ratios of its table, and the arms' alternation."""

from __future__ import annotations

import numpy as np
import pytest

from _scripts import load_tool  # noqa: E402


@pytest.fixture(scope="module")
def blend_ab():
    return load_tool("blend_ab")


def test_the_ratio_is_the_median_of_each_repetitions_new_over_old(blend_ab):
    times = {("forward", "old"): [1.0, 2.0, 4.0], ("forward", "new"): [0.5, 1.0, 4.0],
             ("backward", "old"): [2.0, 2.0, 2.0], ("backward", "new"): [3.0, 1.0, 2.0]}
    s = blend_ab.summary(times)
    assert s["forward"]["old_ms"] == 2000.0 and s["forward"]["new_ms"] == 1000.0
    assert s["forward"]["new_over_old"] == 0.5  # per repetition 0.5, 0.5, 1.0 (not the ratio of the medians)
    assert s["backward"]["new_over_old"] == 1.0
    assert s["backward"]["q25"] == pytest.approx(0.75) and s["backward"]["q75"] == pytest.approx(1.25)


def test_the_arms_alternate_and_each_is_timed_every_repetition(blend_ab, monkeypatch):
    calls = []

    class Arm:
        def __init__(self, name):
            self.name = name

        def forward(self):
            calls.append(("forward", self.name))
            return 1.0

        def backward(self):
            calls.append(("backward", self.name))
            return 2.0

    times = blend_ab.compare(Arm("old"), Arm("new"), reps=2)
    assert calls[:4] == [("forward", "old"), ("backward", "old"), ("forward", "new"), ("backward", "new")]  # first calls
    assert calls[4:] == [("forward", "old"), ("forward", "new"), ("backward", "old"), ("backward", "new"),
                         ("forward", "new"), ("forward", "old"), ("backward", "new"), ("backward", "old")]
    assert all(len(v) == 2 for v in times.values()) and np.all(np.array(times["backward", "new"]) == 2.0)
