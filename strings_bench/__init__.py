"""strings-bench: text readability benchmark for 3D Gaussian Splatting (reproduces STRinGS, WACV 2026)."""

__version__ = "0.1.0"

import os as _os

# onnxruntime (RapidOCR) writes a device-id file under ~/.cache at import unless telemetry is off;
# set it before anything can import onnxruntime. The user's own setting wins.
_os.environ.setdefault("ORT_DISABLE_TELEMETRY", "1")

# torch, MKL and oneDNN on the AVX2 kernels on every x86-64 CPU with AVX2, so that a run gives the same
# figures on any such machine (strings_bench/core/cpus.py; STRINGS_BENCH_NATIVE_ISA=1 opts out).
from strings_bench.core.cpus import passive_omp_waits as _passive_omp_waits  # noqa: E402
from strings_bench.core.cpus import pin_portable_isa as _pin_portable_isa  # noqa: E402
from strings_bench.core.cpus import widen_numba_vectors as _widen_numba_vectors  # noqa: E402

# OpenMP threads (torch's and numba's) sleep when their work ends instead of spinning for another process's cores;
# libgomp reads this when it loads, so before torch is imported. The user's own setting wins.
_passive_omp_waits()
_pin_portable_isa()
# numba's kernels on 512-bit vectors where the CPU has them (the same bits, about 1.7x faster blends).
_widen_numba_vectors()
