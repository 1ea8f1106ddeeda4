"""strings-bench: text readability benchmark for 3D Gaussian Splatting (reproduces STRinGS, WACV 2026)."""

__version__ = "0.1.0"

import os as _os

# onnxruntime (RapidOCR) writes a device-id file under ~/.cache at import unless telemetry is off;
# set it before anything can import onnxruntime. The user's own setting wins.
_os.environ.setdefault("ORT_DISABLE_TELEMETRY", "1")
