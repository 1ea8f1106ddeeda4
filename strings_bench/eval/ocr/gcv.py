"""Google Cloud Vision TEXT_DETECTION over REST: the OCR the paper uses.

`POST {endpoint}` with an API key sent in the `X-Goog-Api-Key` header (not in the URL, so it cannot
leak through URLs in error messages or proxies' logs). The key comes from the `api_key` argument, the
environment (STRINGS_BENCH_GCV_KEY, then GOOGLE_API_KEY) or a key file (STRINGS_BENCH_GCV_KEY_FILE,
default ~/.config/strings-bench/gcv_key). It is held in a `_Secret` that never prints, is not a
setting (settings are stored with results), and is scrubbed from every error message.

Answers 429 and 5xx, time-outs and dropped connections are retried with exponential backoff
(honouring Retry-After); 401/403 stop at once with a clear error.
"""

from __future__ import annotations

import base64
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
from strings_bench.eval.ocr.base import BackendStatus, OCRBackend, Word, _Settings

log = logging.getLogger(__name__)

DEFAULT_ENDPOINT = "https://vision.googleapis.com/v1/images:annotate"
KEY_ENV_VARS = ("STRINGS_BENCH_GCV_KEY", "GOOGLE_API_KEY")
KEY_FILE_ENV = "STRINGS_BENCH_GCV_KEY_FILE"
MAX_REQUEST_BYTES = 10 * 1024 * 1024  # the API's JSON request size limit
RETRY_STATUS = {429, 500, 502, 503, 504}

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
        timeout: float = 60.0,
        max_retries: int = 5,
        backoff: float = 1.0,
        max_backoff: float = 32.0,
        **settings: Any,
    ):
        merged = _Settings(DEFAULTS, settings).merged(self.name)
        if merged["image_format"] not in ("png", "jpeg"):
            raise OCRError(f"gcv setting image_format={merged['image_format']!r} is not 'png' or 'jpeg'", hint="use png (default) or jpeg")
        if urllib.parse.urlparse(str(merged["endpoint"])).scheme not in ("http", "https"):
            raise OCRError(f"gcv endpoint {merged['endpoint']!r} is not an http(s) URL", hint=f"default: {DEFAULT_ENDPOINT}")
        merged["language_hints"] = list(merged["language_hints"] or [])
        super().__init__(merged, cache)
        found = find_api_key(api_key, key_file)
        self._key: _Secret | None = found[0] if found else None
        self.key_source: str | None = found[1] if found else None
        self.timeout = float(timeout)
        self.max_retries = int(max_retries)
        self.backoff = float(backoff)
        self.max_backoff = float(max_backoff)

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
            req = urllib.request.Request(
                endpoint,
                data=data,
                method="POST",
                headers={"Content-Type": "application/json", "X-Goog-Api-Key": self._key.reveal()},
            )
            retry_after: float | None = None
            try:
                with opener.open(req, timeout=self.timeout) as resp:
                    body = resp.read()
                try:
                    answer = json.loads(body)
                except ValueError as exc:
                    raise OCRError(
                        f"Google Vision at {endpoint} answered with something that is not JSON: {self._redact(body[:200].decode('utf-8', 'replace'))!r}",
                        hint="check the endpoint setting",
                    ) from None
                return parse_gcv_response(answer)
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
                last_problem = f"HTTP {status}: {message}"
                retry_after = _retry_after_seconds(exc.headers.get("Retry-After") if exc.headers else None)
            except (TimeoutError, urllib.error.URLError, ConnectionError, OSError) as exc:
                reason = getattr(exc, "reason", exc)
                if isinstance(reason, TimeoutError) or isinstance(exc, TimeoutError):
                    last_problem = f"no answer within {self.timeout:g} s (timed out)"
                else:
                    last_problem = f"connection failed: {self._redact(str(reason))}"
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
