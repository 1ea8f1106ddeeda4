"""Keep ONNX Runtime from writing a telemetry id under the home folder.

onnxruntime (1.31 here) creates ~/.cache/Microsoft/DeveloperTools/.onnxruntime/{deviceid,
onnxruntime.db} (or under $XDG_CACHE_HOME) as soon as it is imported, and may try to upload
telemetry events; the environment variable ORT_DISABLE_TELEMETRY=1, set before that import, stops
both (checked: see docs/ocr.md). Calling onnxruntime.disable_telemetry_events() does not: the files
are already written at import. An explicit user setting of the variable is respected.
"""

from __future__ import annotations

import os
import sys

ORT_TELEMETRY_ENV = "ORT_DISABLE_TELEMETRY"

# True when something imported onnxruntime before us without the variable: too late to prevent it.
imported_unguarded = "onnxruntime" in sys.modules and ORT_TELEMETRY_ENV not in os.environ

os.environ.setdefault(ORT_TELEMETRY_ENV, "1")
