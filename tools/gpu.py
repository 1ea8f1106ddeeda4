"""Training speed, peak memory and the evaluation share of wall time, for every trainable method, on the
device under test next to the CPU backend on the same machine (docs/guide/gpu.md).

    python tools/gpu.py                      # CUDA: 320x240 and 1280x960, 200 steps (CPU rows: 20 steps)
    python tools/gpu.py --methods 3dgs,strings --steps 500
    python tools/gpu.py --device cpu         # no CUDA: tiny sizes and steps, labelled "CPU-only check"

Each row trains one method on the synthetic `books` scene at one size for a short run (the trainer's
clock: synchronised on CUDA; preprocessing excluded), then evaluates one checkpoint the way the runner
does (PSNR/SSIM, LPIPS on the device, OCR-CER with the chosen OCR backend; GT-side work included, as
in a run's first cell). steps/s = steps / train seconds; peak MB = torch.cuda.max_memory_allocated on
CUDA, the process's peak RSS on the CPU (a lifetime peak: it never goes down between rows);
eval share = eval seconds / (train + eval seconds). The ratio column is the device's steps/s over the
CPU backend's at the same size, both measured in this run.
"""

from __future__ import annotations

from strings_bench.core.schedules import get_schedule

import argparse
import sys
import tempfile
import time
from pathlib import Path


def _sizes(text: str) -> list[tuple[int, int]]:
    return [tuple(int(v) for v in item.lower().split("x")) for item in text.split(",") if item.strip()]


def measure(name: str, size: tuple[int, int], steps: int, device: str, ocr: str, with_lpips: bool,
            run_dir: Path) -> dict:
    """Train method `name` for `steps` steps on books at `size` on `device`, then evaluate the checkpoint."""
    import torch

    from strings_bench.eval.protocol import Evaluator
    from strings_bench.datasets.synthetic import build_scene, settings_with
    from strings_bench.engine.trainer import Trainer, peak_memory_mb
    from strings_bench.eval.ocr import get_backend
    from strings_bench.methods.registry import get_method
    from strings_bench.scene.scene import Scene

    w, h = size
    scene = Scene.load(build_scene("books", settings_with(width=w, height=h), progress=False), name="books")
    method = get_method(name).build(steps_scale=get_schedule("paper").steps_scale)  # the paper's schedule; the run is cut at `steps`
    if device.startswith("cuda"):
        torch.cuda.reset_peak_memory_stats(device)
    (result,) = list(Trainer(method, scene, [steps], device=device, progress=False).train())
    evaluator = Evaluator.for_scene(scene, get_backend(ocr), 1.0, with_lpips=with_lpips, device=device)
    t0 = time.perf_counter()
    evaluator.evaluate(name, result.renders)
    eval_s = time.perf_counter() - t0
    return {"method": name, "size": f"{w}x{h}", "device": device, "steps": steps,
            "steps_per_s": steps / max(result.train_seconds, 1e-9), "train_s": result.train_seconds,
            "eval_s": eval_s, "eval_share": eval_s / (eval_s + result.train_seconds),
            "peak_mb": peak_memory_mb(device), "gaussians": result.gaussians}


def _write_csv(path: Path, rows: list[dict]) -> None:
    import csv
    import io

    from strings_bench.core.io import atomic_write_text

    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=list(rows[0]))
    w.writeheader()
    w.writerows(rows)
    atomic_write_text(path, buf.getvalue())


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--device", default="auto", help="device under test: auto (default), cuda, cuda:N, cpu")
    ap.add_argument("--methods", default=None, help="comma-separated (default: every trainable method)")
    ap.add_argument("--sizes", default=None, help="WxH list (default 320x240,1280x960 on CUDA; 64x48 on the CPU)")
    ap.add_argument("--steps", type=int, default=None, help="steps on the device (default 200 on CUDA, 10 on the CPU)")
    ap.add_argument("--cpu-steps", type=int, default=None, help="steps of the CPU-backend rows (default 20; 10 CPU-only)")
    ap.add_argument("--no-cpu", action="store_true", help="skip the CPU-backend rows")
    ap.add_argument("--ocr", default="rapidocr")
    ap.add_argument("--no-lpips", action="store_true")
    ap.add_argument("--csv", type=Path, default=None,
                    help="also write the rows to this CSV, rewritten (atomically) after every row: a run cut "
                         "short keeps the rows it finished (scripts/gpu_campaign.py banks them)")
    args = ap.parse_args(argv)

    from strings_bench.core.method import Method
    from strings_bench.engine.trainer import resolve_device
    from strings_bench.methods.registry import list_methods

    device = resolve_device(args.device)
    cuda = device.startswith("cuda")
    if args.methods:
        methods = [m.strip() for m in args.methods.split(",") if m.strip()]
    else:
        methods = [s.name for s in list_methods() if s.name not in ("ply", "external")
                   and isinstance(s.build(), Method)]
    sizes = _sizes(args.sizes) if args.sizes else ([(320, 240), (1280, 960)] if cuda else [(64, 48)])
    steps = args.steps or (200 if cuda else 10)
    cpu_steps = args.cpu_steps or (20 if cuda else 10)
    label = "" if cuda else "  [CPU-only check: no CUDA here; tiny sizes and steps, not a GPU measurement]"
    print(f"device under test: {device}{label}")
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for size in sizes:
            for m in methods:
                for dev, n in ([(device, steps)] + ([("cpu", cpu_steps)] if cuda and not args.no_cpu else [])):
                    r = measure(m, size, n, dev, args.ocr, not args.no_lpips, Path(tmp) / f"{m}-{size[0]}-{dev}")
                    rows.append(r)
                    if args.csv:
                        _write_csv(args.csv, rows)
                    print(f"  {r['method']:20s} {r['size']:>9s} {r['device']:7s} {r['steps_per_s']:8.2f} steps/s "
                          f"peak {r['peak_mb']:8.0f} MB  eval {r['eval_s']:6.1f} s", file=sys.stderr, flush=True)
    print("\n| method | size | device | steps | steps/s | peak MB | Gaussians | eval s | eval share | x CPU |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    cpu_rate = {(r["method"], r["size"]): r["steps_per_s"] for r in rows if r["device"] == "cpu"}
    for r in rows:
        ratio = cpu_rate.get((r["method"], r["size"]))
        ratio_s = f"{r['steps_per_s'] / ratio:.1f}" if ratio and r["device"] != "cpu" else "-"
        print(f"| {r['method']} | {r['size']} | {r['device']} | {r['steps']} | {r['steps_per_s']:.2f} | "
              f"{r['peak_mb']:.0f} | {r['gaussians']} | {r['eval_s']:.1f} | {r['eval_share']:.0%} | {ratio_s} |")
    if not cuda:
        print("\nCPU-only check: the table shows the script works; GPU figures need a CUDA machine.")
    return 0


if __name__ == "__main__":
    sys.exit(main())
