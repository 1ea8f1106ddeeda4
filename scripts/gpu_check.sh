#!/usr/bin/env bash
# The GPU verification of docs/guide/gpu.md in one command, on a CUDA machine with the suite installed
# (`pip install -e .[cuda]`), writing every log into OUT_DIR:
#
#   bash scripts/gpu_check.sh [OUT_DIR] [--quick]
#
#  1. gsplat's first-use CUDA compilation, timed (TORCH_CUDA_ARCH_LIST defaults to this GPU's
#     capability, MAX_JOBS to the cores);
#  2. pytest -m gpu (backend parity, every method 100 steps through `run --device cuda`, flat memory);
#  3. tools/gpu.py (steps/s, peak memory, evaluation share, next to the CPU backend);
#  4. the paper regime as a command: strings and 3dgs on synthetic/books at 1280x960, preset paper,
#     checkpoints 3K and 7K, on CUDA (--quick: x0.1 of the schedule, for a smoke check).
# Each step's exit status is printed at the end; the script exits non-zero if any failed.
set -uo pipefail

out=${1:-runs/gpu_check}
quick=0
[[ "${2:-}" == "--quick" || "${1:-}" == "--quick" ]] && quick=1
[[ "$out" == "--quick" ]] && out=runs/gpu_check
mkdir -p "$out"
py=${PYTHON:-python}
export PYTHONUNBUFFERED=1

if ! $py -c "import torch, sys; sys.exit(0 if torch.cuda.is_available() else 1)"; then
    echo "gpu_check: torch sees no CUDA device; nothing to verify here (docs/guide/gpu.md)" >&2
    exit 2
fi
export TORCH_CUDA_ARCH_LIST=${TORCH_CUDA_ARCH_LIST:-$($py -c 'import torch; M, m = torch.cuda.get_device_capability(); print(f"{M}.{m}")')}
export MAX_JOBS=${MAX_JOBS:-$(nproc)}
$py - <<'EOF' | tee "$out/versions.txt"
import platform, torch
print("python", platform.python_version(), "| torch", torch.__version__, "| CUDA", torch.version.cuda,
      "|", torch.cuda.get_device_name(0))
try:
    from importlib.metadata import version
    print("gsplat", version("gsplat"))
except Exception as exc:
    print("gsplat not installed:", exc)
EOF

declare -A status
step() {  # step NAME LOGFILE COMMAND...
    local name=$1 log=$2; shift 2
    echo "== $name" | tee -a "$out/summary.txt"
    local t0=$SECONDS
    "$@" 2>&1 | tee "$out/$log"
    status[$name]=${PIPESTATUS[0]}
    echo "== $name: exit ${status[$name]} in $((SECONDS - t0)) s" | tee -a "$out/summary.txt"
}

step compile compile.log $py -c "
import time, torch
t0 = time.perf_counter()
from strings_bench.raster.gsplat_backend import gsplat_available
assert gsplat_available(), 'gsplat does not import'
import gsplat
means = torch.zeros(1, 3, device='cuda'); means[0, 2] = 3
quats = torch.tensor([[1.0, 0, 0, 0]], device='cuda'); scales = torch.full((1, 3), 0.1, device='cuda')
K = torch.tensor([[[50.0, 0, 32], [0, 50.0, 24], [0, 0, 1]]], device='cuda')
gsplat.rasterization(means, quats, scales, torch.ones(1, device='cuda'), torch.ones(1, 3, device='cuda'),
                     torch.eye(4, device='cuda')[None], K, 64, 48)
torch.cuda.synchronize()
print(f'gsplat first use (compilation included): {time.perf_counter() - t0:.0f} s')
"
step pytest_gpu pytest_gpu.log $py -m pytest -m gpu -q -p no:cacheprovider
step benchmark gpu_benchmark.log $py tools/gpu.py

scale_args=()
[[ $quick == 1 ]] && scale_args=(--steps-scale 0.1)
scene=$($py -c "
from strings_bench.datasets.synthetic import build_scene, settings_with
print(build_scene('books', settings_with(width=1280, height=960), progress=False))")
step paper_run paper_run.log $py -m strings_bench run --device cuda --methods strings,3dgs --datasets "$scene" \
    --schedule paper --checkpoints 3000,7000 "${scale_args[@]}" --out "$out/paper_run"
if [[ -f "$out/paper_run/results.csv" ]]; then cp "$out/paper_run/results.csv" "$out/paper_results.csv"; fi

failed=0
for name in compile pytest_gpu benchmark paper_run; do
    echo "$name: exit ${status[$name]:-not run}" | tee -a "$out/summary.txt"
    [[ "${status[$name]:-1}" == 0 ]] || failed=1
done
exit $failed
