#!/usr/bin/env bash
# Set up (idempotent) and run the default test suite (heavy tests are opt-in: pass -m slow).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/bootstrap.sh --test
bash scripts/system_deps.sh
exec .venv/bin/python -m pytest -q "$@"
