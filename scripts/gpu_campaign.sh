#!/usr/bin/env bash
# The GPU verification in stages of at most ~8 minutes each (docs/guide/gpu.md, "Verifying a GPU machine in stages"):
#   bash scripts/gpu_campaign.sh [--dry-run] [--force] [--budget S] OUT_DIR STAGE     (STAGE: list)
# On a CUDA machine with the suite importable (pip install -e .[cuda], or PYTHONPATH=the checkout).
# --dry-run runs every step on the CPU at a tiny size (tests/integration/test_gpu_campaign.py, in CI).
set -euo pipefail
cd "$(dirname "$0")/.."
exec "${PYTHON:-python3}" scripts/gpu_campaign.py "$@"
