#!/usr/bin/env bash
# Set up (idempotent) and run the main job: STRinGS vs 3DGS on an embedded synthetic room (the default schedule, cpu).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/bootstrap.sh
exec .venv/bin/strings-bench run --methods strings,3dgs "$@"
