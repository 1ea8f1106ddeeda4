"""OCR backends behind one interface, with an on-disk result cache.

    from strings_bench.eval.ocr import get_backend
    ocr = get_backend("rapidocr")            # local default; also "tesseract", "gcv"
    words = ocr.read(image, mask=text_mask)  # list[Word]; raises OCRError on failure
    ocr.describe()                           # name, version, settings: store with results
"""

from __future__ import annotations

import json
import threading
from typing import Any

# First: ONNX Runtime writes a telemetry id under ~/.cache/Microsoft when imported unless told not to.
from strings_bench.eval.ocr import _ort_guard  # noqa: F401  isort: skip

from strings_bench.core.errors import OCRError  # noqa: E402
from strings_bench.eval.ocr.base import (  # noqa: E402
    BackendStatus, OCRBackend, Word, apply_mask, load_image, load_mask, read_many,
)
from strings_bench.eval.ocr.cache import OCRCache  # noqa: E402

__all__ = [
    "BackendStatus",
    "OCRBackend",
    "OCRCache",
    "OCRError",
    "Word",
    "apply_mask",
    "available_backends",
    "backend_class",
    "get_backend",
    "get_engine",
    "engine_settings",
    "parse_engines",
    "scene_engines",
    "load_image",
    "load_mask",
    "read_many",
    "BACKENDS",
]

# name -> "module:Class"; modules are imported on first use so that listing backends stays cheap.
BACKENDS: dict[str, str] = {
    "rapidocr": "strings_bench.eval.ocr.rapid:RapidOCRBackend",
    "tesseract": "strings_bench.eval.ocr.tesseract:TesseractBackend",
    "gcv": "strings_bench.eval.ocr.gcv:GoogleVisionBackend",
}
ALIASES = {"rapid": "rapidocr", "google": "gcv", "google-vision": "gcv", "tess": "tesseract"}

_instances: dict[str, OCRBackend] = {}
_lock = threading.Lock()


def backend_class(name: str) -> type[OCRBackend]:
    import importlib

    key = ALIASES.get(name.lower(), name.lower())
    if key not in BACKENDS:
        raise OCRError(f"unknown OCR backend {name!r}", hint=f"choose one of: {', '.join(BACKENDS)}")
    module, cls = BACKENDS[key].split(":")
    return getattr(importlib.import_module(module), cls)


def parse_engines(spec: str | list[str] | tuple[str, ...], strict: bool = True) -> list[str]:
    """`run --ocr`: one engine or a comma-separated list ("rapidocr,tesseract"), as canonical backend
    names (aliases resolved); the first is the primary engine. Repeated names, and with `strict` unknown
    ones, raise OCRError (strict=False keeps an unknown name as given: a backend object passed in code
    may carry any name)."""
    items = [x.strip() for x in (spec.split(",") if isinstance(spec, str) else spec) if str(x).strip()]
    if not items:
        raise OCRError(f"no OCR engine in {spec!r}", hint=f"e.g. --ocr rapidocr or --ocr rapidocr,tesseract; engines: {', '.join(BACKENDS)}")
    names = []
    for item in items:
        name, _, rest = item.partition(":")
        key = ALIASES.get(name.lower(), name.lower())
        if key not in BACKENDS:
            if strict:
                raise OCRError(f"unknown OCR backend {name!r}",
                               hint=f"choose from: {', '.join(BACKENDS)} (comma-separated for several)")
            key = name
        if key in [n.partition(":")[0] for n in names]:
            raise OCRError(f"OCR engine {key!r} is named twice in {spec!r}", hint="name each engine once")
        settings = engine_settings(item)
        names.append(key + "".join(f":{k}={v}" for k, v in settings.items()))
    return names


def scene_engines(run_spec: str, scene_settings: dict | None) -> tuple[str, str | None]:
    """The OCR engines that score one scene: the run's (`--ocr`, canonical names), with the scene's own GT engine
    first where its settings name one (`gt_ocr`: a capture whose text only that engine reads, e.g. Cyrillic by
    Tesseract, and whose floor on GT characters was measured with it). A run engine of the same kind is replaced
    by the scene's; the run's other engines are kept as further engines. Returns the engines and a sentence saying
    what changed (None: the run's engines as they are)."""
    run = parse_engines(run_spec, strict=False)
    own = (scene_settings or {}).get("gt_ocr") if isinstance(scene_settings, dict) else None
    if not own:
        return ",".join(run), None
    own_name = parse_engines(own)[0]
    if run[0] == own_name:
        return ",".join(run), None
    kind = own_name.partition(":")[0]
    kept = [n for n in run if n.partition(":")[0] != kind]
    engines = ",".join([own_name] + kept)
    return engines, (f"read by {own_name}, the engine its GT text and floor were measured with"
                     + (f"; {', '.join(kept)} scored beside it" if kept else "") + f" (run's --ocr: {','.join(run)})")


def engine_settings(item: str) -> dict[str, Any]:
    """The settings of one `--ocr` entry: "tesseract:lang=rus+eng:psm=6" -> {"lang": "rus+eng", "psm": 6}
    (values parsed as JSON when they can be, else kept as strings)."""
    out: dict[str, Any] = {}
    for part in item.split(":")[1:]:
        key, eq, value = part.partition("=")
        if not eq or not key.strip():
            raise OCRError(f"OCR engine setting {part!r} in {item!r} is not KEY=VALUE",
                           hint="e.g. --ocr tesseract:lang=rus or tesseract:lang=rus+eng:psm=6")
        try:
            out[key.strip()] = json.loads(value)
        except ValueError:
            out[key.strip()] = value.strip()
    return out


def get_engine(spec: str) -> OCRBackend:
    """The backend of one `--ocr` entry with its settings ("tesseract:lang=rus")."""
    return get_backend(spec.partition(":")[0], **engine_settings(spec))


def get_engines(names_or_backend) -> list:
    """The OCR engines of a run or an evaluation: from `--ocr` ("rapidocr" or "rapidocr,tesseract"), a backend
    object (tests), or a list of either; the first is the primary."""
    if isinstance(names_or_backend, str):
        return [get_engine(n) for n in parse_engines(names_or_backend)]
    if isinstance(names_or_backend, (list, tuple)):
        return [x for item in names_or_backend for x in get_engines(item)]
    return [names_or_backend]


def get_backend(name: str = "rapidocr", cache: bool | OCRCache = True, **settings: Any) -> OCRBackend:
    """A backend by name, reused within the process for the same arguments.

    cache=True stores results under cache_root()/ocr; pass an OCRCache to use another folder, or
    False for none. Other keyword arguments are the backend's settings or runtime options (e.g.
    threads, timeout, api_key); unknown names raise OCRError.
    """
    cls = backend_class(name)
    cache_obj = OCRCache() if cache is True else (cache or None)
    # The memo key holds no secret in clear: api_key is hashed.
    memo_settings = dict(settings)
    if "api_key" in memo_settings and memo_settings["api_key"]:
        import hashlib

        memo_settings["api_key"] = hashlib.sha256(str(memo_settings["api_key"]).encode()).hexdigest()
    memo = json.dumps(
        [cls.name, str(cache_obj.root) if cache_obj is not None else None, memo_settings], sort_keys=True, default=str
    )
    with _lock:
        backend = _instances.get(memo)
        if backend is None:
            backend = cls(cache=cache_obj, **settings)
            _instances[memo] = backend
        return backend


def available_backends() -> dict[str, BackendStatus]:
    """name -> BackendStatus(available, detail): the version when usable, otherwise why not."""
    out = {}
    for name in BACKENDS:
        try:
            out[name] = backend_class(name).status()
        except Exception as exc:  # a broken install is "not available", not a crash
            out[name] = BackendStatus(name, False, f"{type(exc).__name__}: {exc}")
    return out
