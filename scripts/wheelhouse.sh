#!/usr/bin/env bash
# Wheels for an offline GPU node: every wheel strings-bench[cuda] needs beyond an installed torch.
#   bash scripts/wheelhouse.sh DIR [--python 3.12] [--platform manylinux_2_28_x86_64 ...] [--extras cuda]
# Then on the node: pip install --no-index --find-links DIR -e .[cuda]   (docs/guide/gpu.md, "Installing on an
# offline GPU node"). Needs Python >= 3.11 and pip here, and access to the package index.
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3}
if ! "$PY" -c 'import sys; sys.exit(sys.version_info < (3, 11))'; then
  echo "wheelhouse: needs Python >= 3.11 here (set PYTHON=...); the target's version is --python" >&2; exit 2
fi
if ! "$PY" -c 'import packaging.requirements' 2>/dev/null; then "$PY" -m pip install --quiet packaging; fi
exec "$PY" scripts/wheelhouse.py "$@"
