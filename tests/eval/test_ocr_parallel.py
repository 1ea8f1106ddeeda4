"""read_many: OCR of many images in a thread pool (issue 13, item 5: evaluation time).

The reference is one-at-a-time `read` of the same images by a fresh backend: the words (text,
polygon, confidence) must be identical whatever the number of workers, in the same order, with
failures kept in their place.
"""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

from strings_bench.core.errors import OCRError
from strings_bench.eval.ocr import OCRBackend, Word, read_many
from strings_bench.core.cpus import usable_cores
from strings_bench.eval.ocr.base import OCR_WORKERS_ENV, BackendStatus, default_workers
from strings_bench.eval.ocr.rapid import RapidOCRBackend
from strings_bench.eval.ocr.sample import random_text_image


class SlowBackend(OCRBackend):
    """Sleeps in `_recognize` (as an engine that releases the GIL would), records how many reads ran
    at once, and fails on images whose first pixel is 13."""

    name = "slow"
    parallel_reads = True

    def __init__(self, delay=0.05, cache=None):
        super().__init__({}, cache)
        self.calls = 0
        self.delay = delay
        self.running = 0
        self.most_at_once = 0
        self._lock = threading.Lock()

    @property
    def version(self):
        return "1"

    @classmethod
    def status(cls):
        return BackendStatus(cls.name, True, "1")

    def _recognize(self, rgb):
        with self._lock:
            self.calls += 1
            self.running += 1
            self.most_at_once = max(self.most_at_once, self.running)
        try:
            time.sleep(self.delay)
            return self.words(rgb)
        finally:
            with self._lock:
                self.running -= 1

    def words(self, rgb):
        if rgb[0, 0, 0] == 13:
            raise OCRError("unlucky image", hint="test")
        return [Word.from_box(f"v{int(rgb[1, 1, 0])}", 0, 0, 4, 4, 0.9)]


def _images(values):
    out = []
    for v in values:
        img = np.full((8, 8, 3), 200, np.uint8)
        img[0, 0, 0] = 13 if v == "fail" else 0
        img[1, 1, 0] = 0 if v == "fail" else v
        out.append(img)
    return out


def test_order_failures_and_concurrency():
    b = SlowBackend()
    imgs = _images([1, 2, "fail", 4, 5, 6, 7, 8])
    got = read_many(b, imgs, workers=4)
    assert [g[0].text if isinstance(g, list) else "ERR" for g in got] == ["v1", "v2", "ERR", "v4", "v5", "v6", "v7", "v8"]
    assert isinstance(got[2], OCRError) and "unlucky" in str(got[2])
    assert 2 <= b.most_at_once <= 4  # the pool really ran reads together, never more than asked


def test_engines_that_do_not_say_thread_safe_read_one_at_a_time():
    class Unsafe(SlowBackend):
        parallel_reads = False

    b = Unsafe(delay=0.01)
    got = read_many(b, _images([1, 2, 3, 4]), workers=8)
    assert b.most_at_once == 1 and [g[0].text for g in got] == ["v1", "v2", "v3", "v4"]

    class DuckTyped:  # a user's engine: only read(), no parallel_reads
        name = "duck"

        def read(self, image, mask=None):
            return [Word.from_box("x", 0, 0, 1, 1)] if mask is None else []

    assert default_workers(DuckTyped()) == 1
    got = read_many(DuckTyped(), _images([1, 2]), masks=[None, np.ones((8, 8), bool)])
    assert [len(g) for g in got] == [1, 0]


def test_lazy_images_masks_and_argument_errors():
    b = SlowBackend(delay=0)
    loaded = []

    def loader(v):
        def load():
            loaded.append(v)
            return _images([v])[0]
        return load

    got = read_many(b, [loader(3), loader(4)], masks=[None, np.zeros((8, 8), bool)], workers=2)
    assert sorted(loaded) == [3, 4]
    assert got[0][0].text == "v3" and got[1][0].text == "v0"  # the mask blacked the second image out
    with pytest.raises(OCRError, match="2 images but 1 masks"):
        read_many(b, _images([1, 2]), masks=[None])
    with pytest.raises(OCRError, match="at least 1"):
        read_many(b, _images([1]), workers=0)


def test_default_workers(monkeypatch):
    b = SlowBackend()
    monkeypatch.delenv(OCR_WORKERS_ENV, raising=False)
    b.threads = 2
    assert default_workers(b) == max(1, usable_cores() // 2)
    monkeypatch.setenv(OCR_WORKERS_ENV, "3")
    assert b.default_workers() == 3
    monkeypatch.setenv(OCR_WORKERS_ENV, "many")
    with pytest.raises(OCRError, match="positive whole number"):
        default_workers(b)


def test_rapidocr_threads_read_exactly_what_one_at_a_time_reads():
    """The shared ONNX sessions and RapidOCR's pipeline are used from 4 threads at once: every word,
    box and confidence must equal a fresh backend's one-at-a-time reads (no state leaks across
    threads, e.g. the 180-degree flags of OrientedWordBoxesRapidOCR)."""
    imgs = []
    for seed in range(4):  # one image per thread, all four reading at once
        img, _ = random_text_image(np.random.default_rng(500 + seed))
        imgs.append(np.ascontiguousarray(img[::-1, ::-1]) if seed % 2 == 1 else img)  # half of them upside down
    sequential = [RapidOCRBackend(cache=None, threads=1).read(im) for im in imgs]
    assert sum(len(w) for w in sequential) > 20  # the images do have text to read
    threaded = read_many(RapidOCRBackend(cache=None, threads=1), imgs, workers=4)
    assert threaded == sequential


def test_rapidocr_memory_arena_reads_what_fresh_buffers_read():
    """ONNX Runtime's memory arena (on by default; RapidOCR's own config turns it off) changes where a call's
    buffers live, not what it computes: every word, box and confidence the same as with the arena off, on
    images read one after another (so the arena's buffers are reused) and from two threads at once."""
    imgs = []
    for seed in range(2):
        img, _ = random_text_image(np.random.default_rng(701 + seed), n_lines=2, size=(240, 240))
        imgs.append(np.ascontiguousarray(img[::-1, ::-1]) if seed == 1 else img)
    off = RapidOCRBackend(cache=None, threads=1, memory_arena=False)
    on = RapidOCRBackend(cache=None, threads=1)
    assert on.memory_arena and on._get_engine() is not off._get_engine()  # two engines: the setting is not shared
    fresh = [off.read(im) for im in imgs]
    assert sum(len(w) for w in fresh) >= 6
    assert read_many(on, imgs + imgs, workers=2) == fresh + fresh  # the second pass reuses the arena's buffers
    for backend, arena in ((on, True), (off, False)):  # the setting reached ONNX Runtime (RapidOCR 3.10's sessions)
        engine = backend._get_engine()
        for model in (engine.text_det, engine.text_cls, engine.text_rec):
            assert model.session.session.get_session_options().enable_cpu_mem_arena is arena
