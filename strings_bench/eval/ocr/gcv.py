"""Google Cloud Vision TEXT_DETECTION over REST: the OCR the paper uses.

`POST {endpoint}` with an API key sent in the `X-Goog-Api-Key` header (not in the URL, so it cannot
leak through URLs in error messages or proxies' logs). The key comes from the `api_key` argument, the
environment (STRINGS_BENCH_GCV_KEY, then GOOGLE_API_KEY) or a key file (STRINGS_BENCH_GCV_KEY_FILE,
default ~/.config/strings-bench/gcv_key). It is held in a `_Secret` that never prints, is not a
setting (settings are stored with results), and is scrubbed from every error message.

Answers 429 and 5xx, time-outs (also a body that trickles in past the time-out), dropped connections
(also mid-body), answers that are not JSON or hold no response for the image, and per-image errors
Google marks as transient are retried with exponential backoff (honouring Retry-After, capped);
401/403 stop at once with a clear error. After the last attempt the image fails (an OCRError: the
runner counts it under the CER's `ignored.failed`). One image takes at most about
(max_retries + 1) x 2 x timeout + max_retries x max_backoff seconds.

Settings from the environment, for runs started from the command line (`strings-bench run --ocr gcv`):
STRINGS_BENCH_GCV_ENDPOINT (the `endpoint` setting, e.g. a proxy or a test server), and the runtime
options STRINGS_BENCH_GCV_TIMEOUT, STRINGS_BENCH_GCV_RETRIES, STRINGS_BENCH_GCV_BACKOFF and
STRINGS_BENCH_GCV_MAX_BACKOFF (seconds). Arguments win over the environment.
"""

from __future__ import annotations

import base64
import http.client
import io
import json
import logging
import os
import time
import urllib.error
import urllib.parse
import urllib.request
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from strings_bench.core.errors import OCRError
from strings_bench.eval.ocr.base import BackendStatus, OCRBackend, Word, BackendSettings

log = logging.getLogger(__name__)

DEFAULT_ENDPOINT = "https://vision.googleapis.com/v1/images:annotate"
KEY_ENV_VARS = ("STRINGS_BENCH_GCV_KEY", "GOOGLE_API_KEY")
KEY_FILE_ENV = "STRINGS_BENCH_GCV_KEY_FILE"
MAX_REQUEST_BYTES = 10 * 1024 * 1024  # the API's JSON request size limit
RETRY_STATUS = {429, 500, 502, 503, 504}
# Per-image error codes (google.rpc.Code) worth another try: DEADLINE_EXCEEDED, RESOURCE_EXHAUSTED, INTERNAL, UNAVAILABLE.
RETRY_RPC_CODES = {4, 8, 13, 14}
ENDPOINT_ENV = "STRINGS_BENCH_GCV_ENDPOINT"
RUNTIME_ENV = {"timeout": "STRINGS_BENCH_GCV_TIMEOUT", "max_retries": "STRINGS_BENCH_GCV_RETRIES",
               "backoff": "STRINGS_BENCH_GCV_BACKOFF", "max_backoff": "STRINGS_BENCH_GCV_MAX_BACKOFF"}
READ_CHUNK = 1 << 16


class _Retry(Exception):
    """One attempt failed in a way worth another try; the message says how (never holds the key)."""


def _env_number(name: str, default: float) -> float:
    value = os.environ.get(name, "").strip()
    if not value:
        return default
    try:
        number = float(value)
    except ValueError:
        raise OCRError(f"{name}={value!r} is not a number", hint="give seconds (or a count of retries)") from None
    if not number >= 0:
        raise OCRError(f"{name}={value!r} must be >= 0", hint="give seconds (or a count of retries)")
    return number

DEFAULTS: dict[str, Any] = {
    "endpoint": DEFAULT_ENDPOINT,
    "feature": "TEXT_DETECTION",
    "language_hints": [],
    "model": None,  # e.g. "builtin/latest"; None lets the API choose (what the paper did)
    "image_format": "png",  # "png" (lossless) or "jpeg" (quality 95) for very large images
}


def default_key_file() -> Path:
    base = os.environ.get("XDG_CONFIG_HOME") or str(Path.home() / ".config")
    return Path(base) / "strings-bench" / "gcv_key"


class GCVImageError(OCRError):
    """Cloud Vision answered, but with an error for this image (an OCR failure, not bad input)."""


class _Secret:
    """A string that never shows itself in reprs, logs or tracebacks' locals."""

    __slots__ = ("_value",)

    def __init__(self, value: str):
        self._value = value

    def reveal(self) -> str:
        return self._value

    def __repr__(self) -> str:
        return "<secret>"

    __str__ = __repr__


def find_api_key(api_key: str | None = None, key_file: str | os.PathLike | None = None) -> tuple[_Secret, str] | None:
    """The key and where it came from ("argument", "env:NAME", "file:PATH"), or None."""
    if api_key:
        return _Secret(api_key.strip()), "argument"
    for var in KEY_ENV_VARS:
        if os.environ.get(var, "").strip():
            return _Secret(os.environ[var].strip()), f"env:{var}"
    path = Path(key_file) if key_file else Path(os.environ.get(KEY_FILE_ENV) or default_key_file())
    if path.is_file():
        value = path.read_text(encoding="utf-8").strip()
        if value:
            return _Secret(value), f"file:{path}"
    return None


def _vertex_xy(v: Mapping[str, Any]) -> tuple[float, float]:
    # The API omits a coordinate that is 0 (proto3 JSON), so a missing x or y means 0.
    try:
        return float(v.get("x", 0) or 0), float(v.get("y", 0) or 0)
    except (AttributeError, ValueError, TypeError):
        raise OCRError(f"Google Vision answer holds a vertex that is not {{x, y}} numbers: {json.dumps(v)[:80]}",
                       hint="pass the annotate response as saved") from None


def parse_gcv_response(obj: Mapping[str, Any]) -> list[Word]:
    """Words of one image from an images:annotate answer ({"responses": [one]}) or one response.

    Element 0 of textAnnotations is the whole text of the image and is skipped. A response with an
    "error" raises OCRError. Google Vision gives no per-word confidence: it is NaN.
    """
    if not isinstance(obj, Mapping):
        raise OCRError(f"Google Vision answer is a {type(obj).__name__}, expected a JSON object", hint="pass the annotate response as saved")
    resp: Any = obj
    if "responses" in obj:
        responses = obj["responses"]
        if not isinstance(responses, list) or len(responses) != 1:
            raise OCRError(
                f"Google Vision answer holds {len(responses) if isinstance(responses, list) else 'no'} responses, expected 1",
                hint="store one annotate response per image",
            )
        resp = responses[0]
    if not isinstance(resp, Mapping):
        raise OCRError("Google Vision response is not a JSON object", hint="pass the annotate response as saved")
    err = resp.get("error")
    if err:
        raise GCVImageError(
            f"Google Vision could not read the image: {err.get('code', '?')} {err.get('message', '')}".strip(),
            hint="the image is excluded and counted as an OCR failure",
        )
    words = []
    for ann in (resp.get("textAnnotations") or [])[1:]:
        verts = (ann.get("boundingPoly") or {}).get("vertices") or []
        poly = np.array([_vertex_xy(v) for v in verts], dtype=np.float64).reshape(-1, 2)
        conf = ann.get("confidence", ann.get("score"))
        words.append(Word(ann.get("description", ""), poly, float("nan") if conf in (None, 0, 0.0) else conf))
    return words


class GoogleVisionBackend(OCRBackend):
    name = "gcv"

    def __init__(
        self,
        cache: Any = None,
        api_key: str | None = None,
        key_file: str | os.PathLike | None = None,
        timeout: float | None = None,
        max_retries: int | None = None,
        backoff: float | None = None,
        max_backoff: float | None = None,
        **settings: Any,
    ):
        if "endpoint" not in settings and os.environ.get(ENDPOINT_ENV, "").strip():
            settings["endpoint"] = os.environ[ENDPOINT_ENV].strip()
        merged = BackendSettings(DEFAULTS, settings).merged(self.name)
        if merged["image_format"] not in ("png", "jpeg"):
            raise OCRError(f"gcv setting image_format={merged['image_format']!r} is not 'png' or 'jpeg'", hint="use png (default) or jpeg")
        if urllib.parse.urlparse(str(merged["endpoint"])).scheme not in ("http", "https"):
            raise OCRError(f"gcv endpoint {merged['endpoint']!r} is not an http(s) URL", hint=f"default: {DEFAULT_ENDPOINT}")
        merged["language_hints"] = list(merged["language_hints"] or [])
        super().__init__(merged, cache)
        found = find_api_key(api_key, key_file)
        self._key: _Secret | None = found[0] if found else None
        self.key_source: str | None = found[1] if found else None
        given = {"timeout": timeout, "max_retries": max_retries, "backoff": backoff, "max_backoff": max_backoff}
        fallback = {"timeout": 60.0, "max_retries": 5, "backoff": 1.0, "max_backoff": 32.0}
        runtime = {k: (float(v) if v is not None else _env_number(RUNTIME_ENV[k], fallback[k])) for k, v in given.items()}
        if not runtime["timeout"] > 0:
            raise OCRError(f"gcv timeout {runtime['timeout']} must be > 0", hint="seconds, e.g. 60")
        self.timeout = runtime["timeout"]
        self.max_retries = int(runtime["max_retries"])
        self.backoff = runtime["backoff"]
        self.max_backoff = runtime["max_backoff"]

    @classmethod
    def status(cls) -> BackendStatus:
        found = find_api_key()
        if found is None:
            return BackendStatus(
                cls.name, False,
                f"no API key (set {KEY_ENV_VARS[0]} or put the key in {default_key_file()})",
            )
        return BackendStatus(cls.name, True, f"Cloud Vision v1 REST, key from {found[1]}")

    @property
    def version(self) -> str:
        # The service is versioned by its API only; Google updates the model behind it.
        return "vision v1 images:annotate"

    def _redact(self, text: str) -> str:
        if self._key is not None and self._key.reveal():
            text = text.replace(self._key.reveal(), "***")
        return text

    def _encode(self, rgb: np.ndarray) -> bytes:
        from PIL import Image

        buf = io.BytesIO()
        if self.settings["image_format"] == "jpeg":
            Image.fromarray(rgb).save(buf, format="JPEG", quality=95)
        else:
            Image.fromarray(rgb).save(buf, format="PNG")
        return buf.getvalue()

    def request_body(self, rgb: np.ndarray) -> dict[str, Any]:
        feature: dict[str, Any] = {"type": self.settings["feature"]}
        if self.settings["model"]:
            feature["model"] = self.settings["model"]
        req: dict[str, Any] = {
            "image": {"content": base64.b64encode(self._encode(rgb)).decode("ascii")},
            "features": [feature],
        }
        if self.settings["language_hints"]:
            req["imageContext"] = {"languageHints": list(self.settings["language_hints"])}
        return {"requests": [req]}

    def _opener(self) -> urllib.request.OpenerDirector:
        host = urllib.parse.urlparse(self.settings["endpoint"]).hostname or ""
        if host in ("127.0.0.1", "localhost", "::1"):
            return urllib.request.build_opener(urllib.request.ProxyHandler({}))  # local test servers: no proxy
        return urllib.request.build_opener()

    def _recognize(self, rgb: np.ndarray) -> list[Word]:
        if self._key is None:
            raise OCRError(
                "no Google Cloud Vision API key",
                hint=f"set {KEY_ENV_VARS[0]} (or {KEY_ENV_VARS[1]}), or write the key to {default_key_file()}",
            )
        data = json.dumps(self.request_body(rgb)).encode("utf-8")
        if len(data) > MAX_REQUEST_BYTES:
            raise OCRError(
                f"the Google Vision request would be {len(data) / 2**20:.1f} MiB, over the API's 10 MiB limit",
                hint="use the setting image_format='jpeg' or downscale the image",
            )
        endpoint = self.settings["endpoint"]
        opener = self._opener()
        attempts = self.max_retries + 1
        last_problem = ""
        for attempt in range(attempts):
            retry_after: float | None = None
            try:
                return self._attempt(opener, endpoint, data)
            except _Retry as exc:
                last_problem = str(exc)
                retry_after = getattr(exc, "retry_after", None)
            if attempt + 1 < attempts:
                wait = min(self.max_backoff, self.backoff * (2**attempt))
                if retry_after is not None:
                    wait = min(self.max_backoff, max(wait, retry_after))
                log.info("Google Vision: %s; retry %d/%d in %.1f s", last_problem, attempt + 1, self.max_retries, wait)
                time.sleep(wait)
        raise OCRError(
            f"Google Vision at {endpoint} failed after {attempts} attempt(s): {last_problem}",
            hint="try again later, or raise timeout/max_retries",
        )

    def _read_body(self, resp) -> bytes:
        """The answer's body, read in chunks against a deadline: a server that trickles bytes would
        otherwise hold the socket time-out off for ever."""
        deadline = time.monotonic() + self.timeout
        chunks = []
        while block := resp.read(READ_CHUNK):
            chunks.append(block)
            if time.monotonic() > deadline:
                raise TimeoutError("the answer's body took longer than the time-out")
        return b"".join(chunks)

    def _attempt(self, opener, endpoint: str, data: bytes) -> list[Word]:
        """One request: the words, an OCRError that retrying cannot fix, or _Retry."""
        req = urllib.request.Request(
            endpoint,
            data=data,
            method="POST",
            headers={"Content-Type": "application/json", "X-Goog-Api-Key": self._key.reveal()},
        )
        try:
            with opener.open(req, timeout=self.timeout) as resp:
                body = self._read_body(resp)
        except urllib.error.HTTPError as exc:
            status = exc.code
            message = self._error_message(exc)
            if status in (401, 403):
                raise OCRError(
                    f"Google Vision refused the request (HTTP {status}): {message}",
                    hint="check the API key (source: "
                    f"{self.key_source}), that the Cloud Vision API is enabled for its project, and billing",
                ) from None
            if status not in RETRY_STATUS:
                raise OCRError(f"Google Vision answered HTTP {status}: {message}", hint="check the request settings") from None
            retry = _Retry(f"HTTP {status}: {message}")
            retry.retry_after = _retry_after_seconds(exc.headers.get("Retry-After") if exc.headers else None)
            raise retry from None
        except (TimeoutError, urllib.error.URLError, http.client.HTTPException, OSError) as exc:
            reason = getattr(exc, "reason", exc)
            if isinstance(reason, TimeoutError) or isinstance(exc, TimeoutError):
                raise _Retry(f"no answer within {self.timeout:g} s (timed out)") from None
            if isinstance(exc, http.client.IncompleteRead):
                raise _Retry(f"the connection closed mid-answer ({len(exc.partial)} bytes read)") from None
            raise _Retry(f"connection failed: {self._redact(f'{type(reason).__name__}: {reason}')}") from None
        try:
            answer = json.loads(body)
        except ValueError:
            raise _Retry(f"the answer is not JSON: {self._redact(body[:120].decode('utf-8', 'replace'))!r}") from None
        responses = answer.get("responses") if isinstance(answer, dict) else None
        if not isinstance(responses, list) or len(responses) != 1:
            count = len(responses) if isinstance(responses, list) else "no"
            raise _Retry(f"the answer holds {count} responses for 1 image")
        err = responses[0].get("error") if isinstance(responses[0], dict) else None
        if isinstance(err, dict) and err.get("code") in RETRY_RPC_CODES:
            raise _Retry(f"the image's response is error {err.get('code')} {self._redact(str(err.get('message', '')))}")
        try:
            return parse_gcv_response(answer)
        except OCRError as exc:
            raise type(exc)(self._redact(exc.message), hint=exc.hint) from None

    def _error_message(self, exc: urllib.error.HTTPError) -> str:
        try:
            raw = exc.read()[:2000].decode("utf-8", "replace")
        except Exception:
            raw = ""
        try:
            msg = json.loads(raw)["error"]["message"]
        except Exception:
            msg = raw.strip() or str(exc.reason)
        return self._redact(str(msg))[:300]


def _retry_after_seconds(value: str | None) -> float | None:
    if not value:
        return None
    try:
        return max(0.0, float(value))
    except ValueError:
        return None  # an HTTP date: fall back to our own backoff
