#!/usr/bin/env bash
# Set up (idempotent) and run the default test suite (heavy tests are opt-in: pass -m slow).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/bootstrap.sh --test
bash scripts/system_deps.sh
# Two worker processes (pytest-xdist), each test file on one worker so that its module fixtures are built once:
# most of the suite is single-threaded Python, OCR and subprocess start-up, so on 2 cores this takes about 0.6x the
# time of one process. STRINGS_BENCH_TEST_WORKERS=0 runs everything in this process (-n 0).
exec .venv/bin/python -m pytest -q -n "${STRINGS_BENCH_TEST_WORKERS:-2}" --dist loadfile "$@"
