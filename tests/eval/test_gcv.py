"""Google Cloud Vision backend against a local fake images:annotate server on 127.0.0.1."""

from __future__ import annotations

import base64
import io
import json
import logging
import time
from http.server import BaseHTTPRequestHandler

import numpy as np
import pytest
from _local_http import LocalVisionServer

from strings_bench.core.errors import OCRError
from strings_bench.eval.ocr import OCRCache, get_backend
from strings_bench.eval.ocr.gcv import DEFAULT_ENDPOINT, GoogleVisionBackend, parse_gcv_response

KEY = "AIzaFAKE-test-key-0123456789abcdef"

# A response of the real shape: element 0 is the whole text; vertex coordinates that are 0 are
# omitted (and a vertex at the origin is {}).
REAL_SHAPE = {
    "responses": [
        {
            "textAnnotations": [
                {
                    "locale": "en",
                    "description": "FIRE EXIT\nPULL\n",
                    "boundingPoly": {"vertices": [{}, {"x": 210}, {"x": 210, "y": 95}, {"y": 95}]},
                },
                {"description": "FIRE", "boundingPoly": {"vertices": [{}, {"x": 90}, {"x": 90, "y": 40}, {"y": 40}]}},
                {
                    "description": "EXIT",
                    "boundingPoly": {"vertices": [{"x": 110}, {"x": 210}, {"x": 210, "y": 40}, {"x": 110, "y": 40}]},
                },
                {
                    "description": "PULL",
                    "boundingPoly": {"vertices": [{"x": 5, "y": 55}, {"x": 80, "y": 55}, {"x": 80, "y": 95}, {"x": 5, "y": 95}]},
                },
            ],
            "fullTextAnnotation": {"text": "FIRE EXIT\nPULL\n", "pages": []},
        }
    ]
}


class FakeVision(LocalVisionServer):
    """Serves scripted answers: a list of (status, json body or bytes, delay seconds, headers)."""

    def __init__(self):
        self.script: list[tuple[int, object, float, dict]] = []
        self.requests: list[dict] = []
        fake = self

        class Handler(BaseHTTPRequestHandler):
            def do_POST(self):
                length = int(self.headers.get("Content-Length", 0))
                body = self.rfile.read(length)
                fake.requests.append({"path": self.path, "headers": dict(self.headers), "body": json.loads(body)})
                status, payload, delay, headers = fake.script.pop(0) if fake.script else (500, {"error": {"message": "no script"}}, 0, {})
                if delay:
                    time.sleep(delay)
                data = payload if isinstance(payload, bytes) else json.dumps(payload).encode()
                try:
                    self.send_response(status)
                    self.send_header("Content-Type", "application/json")
                    self.send_header("Content-Length", str(len(data)))
                    for k, v in headers.items():
                        self.send_header(k, v)
                    self.end_headers()
                    self.wfile.write(data)
                except (BrokenPipeError, ConnectionResetError):
                    pass  # the client gave up (time-out test)

            def log_message(self, *args):
                pass

        self._serve(Handler)


@pytest.fixture
def fake():
    f = FakeVision()
    yield f
    f.close()


@pytest.fixture(autouse=True)
def no_ambient_key(monkeypatch, tmp_path):
    for var in ("STRINGS_BENCH_GCV_KEY", "GOOGLE_API_KEY"):
        monkeypatch.delenv(var, raising=False)
    monkeypatch.setenv("STRINGS_BENCH_GCV_KEY_FILE", str(tmp_path / "no_key_here"))
    monkeypatch.setenv("STRINGS_BENCH_CACHE", str(tmp_path / "cache"))


def backend(fake, **kw):
    kw.setdefault("api_key", KEY)
    kw.setdefault("backoff", 0.01)
    kw.setdefault("timeout", 5.0)
    return GoogleVisionBackend(cache=kw.pop("cache", None), endpoint=fake.url, **kw)


IMG = np.zeros((100, 220, 3), np.uint8)
IMG[10:30, 10:200] = 255


def assert_no_key(*texts):
    for t in texts:
        assert KEY not in t


def test_real_shape_and_omitted_zero_coordinates(fake):
    fake.script.append((200, REAL_SHAPE, 0, {}))
    b = backend(fake, language_hints=["en"])
    mask = np.zeros(IMG.shape[:2], bool)
    mask[:50] = True
    words = b.read(IMG, mask=mask)
    assert [w.text for w in words] == ["FIRE", "EXIT", "PULL"]  # element 0 (whole text) skipped
    np.testing.assert_array_equal(words[0].polygon, [[0, 0], [90, 0], [90, 40], [0, 40]])
    np.testing.assert_array_equal(words[1].polygon, [[110, 0], [210, 0], [210, 40], [110, 40]])
    assert np.isnan(words[0].confidence)
    # The request: key in a header (not the URL), TEXT_DETECTION, the masked image as PNG.
    req = fake.requests[0]
    assert req["path"] == "/v1/images:annotate" and KEY not in req["path"]
    assert req["headers"]["X-Goog-Api-Key"] == KEY
    r0 = req["body"]["requests"][0]
    assert r0["features"] == [{"type": "TEXT_DETECTION"}]
    assert r0["imageContext"] == {"languageHints": ["en"]}
    from PIL import Image

    sent = np.asarray(Image.open(io.BytesIO(base64.b64decode(r0["image"]["content"]))))
    np.testing.assert_array_equal(sent, IMG * mask[:, :, None])


def test_empty_answer_and_per_image_error(fake):
    fake.script.append((200, {"responses": [{}]}, 0, {}))
    assert backend(fake).read(IMG) == []
    fake.script.append((200, {"responses": [{"error": {"code": 3, "message": "Bad image data."}}]}, 0, {}))
    with pytest.raises(OCRError, match="Bad image data"):
        backend(fake).read(IMG)
    fake.script.append((200, b"<html>proxy page</html>", 0, {}))
    with pytest.raises(OCRError, match="not JSON"):  # retried like a dropped answer (test_gcv_faults.py); here no retry
        backend(fake, max_retries=0).read(IMG)


@pytest.mark.parametrize("status", [429, 500, 503])
def test_retries_then_success(fake, status, caplog):
    fake.script += [(status, {"error": {"code": status, "message": "try later"}}, 0, {"Retry-After": "0"}), (200, REAL_SHAPE, 0, {})]
    with caplog.at_level(logging.DEBUG):
        words = backend(fake).read(IMG)
    assert [w.text for w in words] == ["FIRE", "EXIT", "PULL"]
    assert len(fake.requests) == 2
    assert f"HTTP {status}" in caplog.text
    assert_no_key(caplog.text)


def test_backoff_is_exponential(fake, monkeypatch):
    import strings_bench.eval.ocr.gcv as gcv

    sleeps = []
    monkeypatch.setattr(gcv.time, "sleep", lambda s: sleeps.append(s))
    fake.script += [(500, {}, 0, {})] * 4
    with pytest.raises(OCRError, match=r"failed after 4 attempt\(s\): HTTP 500"):
        backend(fake, max_retries=3, backoff=0.5, max_backoff=1.5).read(IMG)
    assert sleeps == [0.5, 1.0, 1.5]  # doubling, capped
    assert len(fake.requests) == 4


@pytest.mark.parametrize("status", [401, 403])
def test_auth_errors_are_clear_and_keyless(fake, status):
    # Even a server that echoes the key back must not get it into our message.
    body = {"error": {"code": status, "message": f"API key not valid: {KEY}", "status": "PERMISSION_DENIED"}}
    fake.script.append((status, body, 0, {}))
    b = backend(fake)
    with pytest.raises(OCRError) as info:
        b.read(IMG)
    exc = info.value
    text = str(exc)
    assert f"HTTP {status}" in text and "API key" in text and exc.hint and "enabled" in exc.hint
    assert_no_key(text, repr(exc), exc.message, exc.hint)
    assert KEY not in str(exc.__context__) and KEY not in str(exc.__cause__)
    assert len(fake.requests) == 1  # not retried


def test_timeout(fake):
    fake.script += [(200, REAL_SHAPE, 1.5, {}), (200, REAL_SHAPE, 1.5, {})]
    b = backend(fake, timeout=0.2, max_retries=1)
    t0 = time.perf_counter()
    with pytest.raises(OCRError, match="timed out") as info:
        b.read(IMG)
    assert time.perf_counter() - t0 < 1.4
    assert len(fake.requests) == 2
    assert_no_key(str(info.value))


def test_connection_refused_is_an_ocr_error():
    b = GoogleVisionBackend(cache=None, api_key=KEY, endpoint="http://127.0.0.1:9/v1/images:annotate", max_retries=0, timeout=2)
    with pytest.raises(OCRError, match="connection failed"):
        b.read(IMG)


def test_key_sources_and_secrecy(fake, monkeypatch, tmp_path):
    st = GoogleVisionBackend.status()
    assert not st.available and "no API key" in st.detail
    with pytest.raises(OCRError, match="no Google Cloud Vision API key"):
        GoogleVisionBackend(cache=None, endpoint=fake.url).read(IMG)
    assert fake.requests == []

    key_file = tmp_path / "key.txt"
    key_file.write_text(KEY + "\n")
    monkeypatch.setenv("STRINGS_BENCH_GCV_KEY_FILE", str(key_file))
    b = GoogleVisionBackend(cache=OCRCache(tmp_path / "c"), endpoint=fake.url)
    assert b.key_source == f"file:{key_file}"
    assert GoogleVisionBackend.status().available

    monkeypatch.setenv("GOOGLE_API_KEY", "other-key")
    monkeypatch.setenv("STRINGS_BENCH_GCV_KEY", KEY)
    b = GoogleVisionBackend(cache=OCRCache(tmp_path / "c"), endpoint=fake.url)
    assert b.key_source == "env:STRINGS_BENCH_GCV_KEY"
    fake.script.append((200, REAL_SHAPE, 0, {}))
    b.read(IMG)
    assert fake.requests[-1]["headers"]["X-Goog-Api-Key"] == KEY
    assert_no_key(repr(b), json.dumps(b.describe()), repr(vars(b)))
    for f in (tmp_path / "c").rglob("*.json"):
        assert_no_key(f.read_text())
    # Cached: the server is not asked again.
    n = len(fake.requests)
    b.read(IMG)
    assert len(fake.requests) == n


def test_settings_validation_and_registry(fake):
    with pytest.raises(OCRError, match="unknown setting"):
        GoogleVisionBackend(cache=None, api_key=KEY, feature_type="X")
    with pytest.raises(OCRError, match="http"):
        GoogleVisionBackend(cache=None, api_key=KEY, endpoint="ftp://example.com")
    b = get_backend("gcv", cache=False, api_key=KEY, endpoint=fake.url, backoff=0.01)
    assert b.settings["endpoint"] == fake.url and b.describe()["name"] == "gcv"
    assert GoogleVisionBackend(cache=None, api_key=KEY).settings["endpoint"] == DEFAULT_ENDPOINT
    fake.script.append((200, REAL_SHAPE, 0, {}))
    assert len(b.read(IMG)) == 3


def test_parse_response_forms():
    single = REAL_SHAPE["responses"][0]
    assert [w.text for w in parse_gcv_response(single)] == ["FIRE", "EXIT", "PULL"]
    assert parse_gcv_response({}) == []
    with pytest.raises(OCRError, match="2 responses"):
        parse_gcv_response({"responses": [single, single]})
