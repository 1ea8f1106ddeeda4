#!/usr/bin/env bash
# Set up (idempotent) and run the main job: STRinGS vs 3DGS on an embedded synthetic room (the default schedule, cpu).
# Prints how long the set-up and the run took, apart (the set-up is mostly pip's downloads the first time).
set -euo pipefail
cd "$(dirname "$0")/.."
start=$SECONDS
bash scripts/bootstrap.sh
setup=$((SECONDS - start))
echo "demo: set-up took ${setup} s"
.venv/bin/strings-bench run --methods strings,3dgs "$@"
run=$((SECONDS - start - setup))
echo "demo: set-up ${setup} s, run ${run} s, $((setup + run)) s in all (each method's training time: train_seconds in the run's results.csv)"
