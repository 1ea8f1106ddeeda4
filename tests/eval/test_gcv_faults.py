"""A faulty Google Cloud Vision server (issue 19, item 3).

A local HTTP server on 127.0.0.1 speaks the `images:annotate` REST shape and misbehaves on cue: 429
with and without Retry-After, 500 and 503, stalls past the client's time-out, connections closed
mid-body, answers that are not JSON, answers with no response for the image, a transient per-image
error, words without a box. The `gcv` backend, pointed at it through STRINGS_BENCH_GCV_ENDPOINT, must
retry with a bounded backoff and then fail the image, a `strings-bench run` must complete with those
images under the CER's `ignored.failed`, and the API key must appear in no file of the run folder or
the cache, no log record and no captured output.
"""

from __future__ import annotations

import json
import logging
import sys
import time
from http.server import BaseHTTPRequestHandler

import numpy as np
import pytest
from _local_http import LocalVisionServer

import runner_fakes as rf  # noqa: E402
from strings_bench.core.errors import OCRError  # noqa: E402
from strings_bench.eval.ocr.gcv import GoogleVisionBackend  # noqa: E402

KEY = "AIzaFAULTY-key-5f1e0c9d8b7a6f5e4d3c2b1a"
X0, Y0, X1, Y1 = rf.TEXT_BOX
WORDS = {"responses": [{"textAnnotations": [
    {"description": "hello"},
    {"description": "hello", "boundingPoly": {"vertices": [{"x": X0, "y": Y0}, {"x": X1, "y": Y0}, {"x": X1, "y": Y1},
                                                           {"x": X0, "y": Y1}]}}]}]}
# Partial: one word has no box (Google leaves boundingPoly out now and then).
PARTIAL_WORDS = {"responses": [{"textAnnotations": WORDS["responses"][0]["textAnnotations"] + [{"description": "extra"}]}]}

# Faults: what the server does instead of answering WORDS.
RETRIED = ["429", "429-retry-after", "500", "503", "stall", "mid-body", "not-json", "no-response", "unavailable"]


class FaultyVision(LocalVisionServer):
    """Answers each request with the next action of `plan` (then "ok"); counts requests and closes."""

    def __init__(self, stall_seconds: float = 1.0):
        self.plan: list[str] = []
        self.requests = 0
        self.keys_seen: set[str] = set()
        self.stall_seconds = stall_seconds
        fake = self

        class Handler(BaseHTTPRequestHandler):
            protocol_version = "HTTP/1.1"

            def log_message(self, *args):
                pass

            def _send(self, status: int, body: bytes, headers: dict | None = None, length: int | None = None):
                self.send_response(status)
                self.send_header("Content-Type", "application/json")
                self.send_header("Content-Length", str(len(body) if length is None else length))
                for k, v in (headers or {}).items():
                    self.send_header(k, v)
                self.end_headers()
                self.wfile.write(body)
                self.wfile.flush()

            def do_POST(self):
                self.rfile.read(int(self.headers.get("Content-Length", 0)))
                fake.requests += 1
                fake.keys_seen.add(self.headers.get("X-Goog-Api-Key", ""))
                action = fake.plan.pop(0) if fake.plan else "ok"
                self.close_connection = True
                err = lambda code, msg: json.dumps({"error": {"code": code, "message": msg}}).encode()  # noqa: E731
                try:
                    if action == "ok":
                        self._send(200, json.dumps(WORDS).encode())
                    elif action == "partial-words":
                        self._send(200, json.dumps(PARTIAL_WORDS).encode())
                    elif action == "429":
                        self._send(429, err(429, "Quota exceeded"))
                    elif action == "429-retry-after":
                        self._send(429, err(429, "Quota exceeded"), {"Retry-After": "0.3"})
                    elif action == "429-retry-after-huge":
                        self._send(429, err(429, "Quota exceeded"), {"Retry-After": "3600"})
                    elif action in ("500", "503"):
                        self._send(int(action), err(int(action), "backend error"))
                    elif action == "stall":
                        time.sleep(fake.stall_seconds)
                        self._send(200, json.dumps(WORDS).encode())
                    elif action == "mid-body":
                        body = json.dumps(WORDS).encode()
                        self._send(200, body[: len(body) // 3], length=len(body))  # then the connection closes
                    elif action == "not-json":
                        self._send(200, b"<html><body>502 Bad Gateway</body></html>")
                    elif action == "no-response":
                        self._send(200, b'{"responses": []}')
                    elif action == "unavailable":
                        self._send(200, json.dumps({"responses": [{"error": {"code": 14, "message": "try again"}}]}).encode())
                    elif action == "bad-image":
                        self._send(200, json.dumps({"responses": [{"error": {"code": 3, "message": "Bad image data."}}]}).encode())
                    elif action == "echo-key":
                        self._send(500, err(500, f"internal error for key {self.headers.get('X-Goog-Api-Key')}"))
                    else:
                        raise AssertionError(action)
                except (BrokenPipeError, ConnectionResetError):
                    pass  # the client gave up (time-out)

        self._serve(Handler)


@pytest.fixture
def server():
    s = FaultyVision()
    yield s
    s.close()


@pytest.fixture(autouse=True)
def _env(monkeypatch, tmp_path):
    for var in ("STRINGS_BENCH_GCV_KEY", "GOOGLE_API_KEY", "STRINGS_BENCH_GCV_ENDPOINT", "STRINGS_BENCH_GCV_TIMEOUT",
                "STRINGS_BENCH_GCV_RETRIES", "STRINGS_BENCH_GCV_BACKOFF", "STRINGS_BENCH_GCV_MAX_BACKOFF"):
        monkeypatch.delenv(var, raising=False)
    monkeypatch.setenv("STRINGS_BENCH_GCV_KEY_FILE", str(tmp_path / "no-key-file"))
    monkeypatch.setenv("STRINGS_BENCH_CACHE", str(tmp_path / "cache"))


IMG = np.full((rf.H, rf.W, 3), 200, np.uint8)


def backend(server, **kw):
    kw = {"api_key": KEY, "timeout": 0.3, "max_retries": 1, "backoff": 0.01, "max_backoff": 0.5, **kw}
    return GoogleVisionBackend(cache=None, endpoint=server.url, **kw)


@pytest.mark.parametrize("fault", RETRIED)
def test_a_fault_is_retried_then_the_answer_is_used(server, fault, caplog):
    server.plan = [fault, "ok"]
    with caplog.at_level(logging.INFO, logger="strings_bench"):
        words = backend(server).read(IMG)
    assert [w.text for w in words] == ["hello"] and server.requests == 2
    assert "retry 1/1" in caplog.text and KEY not in caplog.text


@pytest.mark.parametrize("fault", RETRIED)
def test_a_lasting_fault_fails_the_image_within_bounded_time(server, fault, caplog):
    server.plan = [fault] * 3
    b = backend(server, max_retries=2)
    t0 = time.perf_counter()
    with caplog.at_level(logging.INFO, logger="strings_bench"), pytest.raises(OCRError) as info:
        b.read(IMG)
    elapsed = time.perf_counter() - t0
    assert server.requests == 3 and "failed after 3 attempt(s)" in str(info.value)
    # Bounded: 3 attempts x 2 x time-out + 2 waits (<= max_backoff), with slack for a loaded machine.
    assert elapsed < 3 * 2 * 0.3 + 2 * 0.5 + 2.0
    for text in (str(info.value), repr(info.value), caplog.text, str(info.value.__context__), str(info.value.__cause__)):
        assert KEY not in text


def test_retry_after_is_honoured_and_capped(server):
    server.plan = ["429-retry-after", "ok"]
    t0 = time.perf_counter()
    backend(server).read(IMG)
    assert time.perf_counter() - t0 >= 0.3  # the server's Retry-After, over our 0.01 s backoff
    server.plan = ["429-retry-after-huge", "ok"]
    t0 = time.perf_counter()
    backend(server, max_backoff=0.2).read(IMG)
    assert time.perf_counter() - t0 < 3.0  # an hour asked for, max_backoff given


def test_a_per_image_error_fails_at_once_and_partial_words_are_kept(server):
    server.plan = ["bad-image"]
    with pytest.raises(OCRError, match="Bad image data"):
        backend(server).read(IMG)
    assert server.requests == 1  # code 3 (INVALID_ARGUMENT) is not retried
    server.plan = ["partial-words"]
    words = backend(server).read(IMG)
    assert [w.text for w in words] == ["hello", "extra"] and words[1].polygon.shape == (0, 2)


def test_an_echoed_key_is_scrubbed(server, caplog):
    server.plan = ["echo-key"] * 2
    with caplog.at_level(logging.INFO, logger="strings_bench"), pytest.raises(OCRError) as info:
        backend(server).read(IMG)
    assert "***" in str(info.value) and KEY not in str(info.value) and KEY not in caplog.text


def test_environment_settings_reach_the_backend(server, monkeypatch):
    monkeypatch.setenv("STRINGS_BENCH_GCV_ENDPOINT", server.url)
    monkeypatch.setenv("STRINGS_BENCH_GCV_TIMEOUT", "0.25")
    monkeypatch.setenv("STRINGS_BENCH_GCV_RETRIES", "3")
    monkeypatch.setenv("STRINGS_BENCH_GCV_BACKOFF", "0.02")
    monkeypatch.setenv("STRINGS_BENCH_GCV_MAX_BACKOFF", "0.1")
    b = GoogleVisionBackend(cache=None, api_key=KEY)
    assert (b.settings["endpoint"], b.timeout, b.max_retries, b.backoff, b.max_backoff) == (server.url, 0.25, 3, 0.02, 0.1)
    assert GoogleVisionBackend(cache=None, api_key=KEY, endpoint="http://127.0.0.1:1/x", timeout=5).timeout == 5
    monkeypatch.setenv("STRINGS_BENCH_GCV_RETRIES", "many")
    with pytest.raises(OCRError, match="STRINGS_BENCH_GCV_RETRIES"):
        GoogleVisionBackend(cache=None, api_key=KEY)


def test_a_run_against_the_faulty_server_completes_and_counts_failed_images(server, tmp_path, monkeypatch, capsys, caplog):
    """`strings-bench run --ocr gcv` (in-process) through every fault: the images whose attempts all
    fail are left out of CER and named in `ignored.failed`; the run finishes; the key is nowhere."""
    import strings_bench.eval.ocr as ocr
    from strings_bench.cli import main

    rf.register_fakes()
    scene = rf.make_scene(tmp_path, "scene")
    monkeypatch.setattr(ocr, "_instances", {})
    monkeypatch.setenv("STRINGS_BENCH_GCV_KEY", KEY)
    monkeypatch.setenv("STRINGS_BENCH_GCV_ENDPOINT", server.url)
    monkeypatch.setenv("STRINGS_BENCH_GCV_TIMEOUT", "0.3")
    monkeypatch.setenv("STRINGS_BENCH_GCV_RETRIES", "1")
    monkeypatch.setenv("STRINGS_BENCH_GCV_BACKOFF", "0.01")
    monkeypatch.setenv("STRINGS_BENCH_GCV_MAX_BACKOFF", "0.5")
    # Reads in order (test views view_00, view_08; checkpoints 15, 35, 150 of the tiny preset):
    # GT 00, render 00 @15, GT 08, render 08 @15, render 00 @35, render 08 @35. Two attempts each. At 150
    # fake-a renders the GT exactly: its reads come from the OCR cache.
    server.plan = ["429", "ok",                  # GT view_00: recovered
                   "stall", "ok",                # render view_00 @15: recovered
                   "500", "ok",                  # GT view_08: recovered
                   "mid-body", "not-json",       # render view_08 @15: fails
                   "503", "429-retry-after",     # render view_00 @35: fails
                   "no-response", "partial-words"]  # render view_08 @35: recovered, one word without a box
    run_dir = tmp_path / "run"
    argv = ["run", "--methods", "fake-a", "--datasets", str(scene), "--schedule", "tiny",
            "--ocr", "gcv", "--no-lpips", "--no-progress", "--out", str(run_dir)]
    with caplog.at_level(logging.INFO):
        assert main(argv) == 0
    assert server.plan == [] and server.requests == 12 and server.keys_seen == {KEY}
    cells = {int(p.parent.name): json.loads(p.read_text()) for p in run_dir.glob("cells/**/result.json")}
    assert sorted(cells) == [15, 35, 150]
    assert cells[15]["cer"]["ignored"]["failed"] == ["view_08.png"]
    assert cells[35]["cer"]["ignored"]["failed"] == ["view_00.png"]
    assert cells[150]["cer"]["ignored"]["failed"] == [] and cells[150]["cer"]["cer"] == 0
    assert "failed after 2 attempt(s)" in cells[15]["ocr"]["views"]["view_08.png"]["render_error"]
    for it, name in ((15, "view_00.png"), (35, "view_08.png")):
        assert cells[it]["ocr"]["views"][name]["render_error"] is None and name in cells[it]["cer"]["images"]
    csv_rows = (run_dir / "results.csv").read_text().splitlines()
    assert len(csv_rows) == 4 and (run_dir / "report" / "report.md").is_file()
    # The key: in no file of the run folder or the cache (bytes, so PNGs and CSVs count), no output, no log.
    files = [p for root in (run_dir, tmp_path / "cache") for p in root.rglob("*") if p.is_file()]
    assert len(files) > 10
    leaked = [str(p) for p in files if KEY.encode() in p.read_bytes()]
    assert not leaked
    out = capsys.readouterr()
    assert KEY not in out.out and KEY not in out.err and KEY not in caplog.text
    assert all(KEY not in str(r.args) for r in caplog.records)
