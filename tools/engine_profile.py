"""Where a 3DGS training step's milliseconds go at the default run's sizes, stage by stage, each beside
a lower bound measured in the same run.

    python tools/engine_profile.py [--scene synthetic/extinguisher] [--schedule early]
                                        [--at 450,1050] [--steps 8] [--big-at 450] [--json]
    python tools/engine_profile.py --table BEFORE.json,... AFTER.json,...   (stage medians side by side)

Models: the 3DGS of the former default run (schedule `early`, synthetic/extinguisher, 320x240) trained with the
suite's own loop to the 3K and 7K checkpoints (steps 450 and 1 050 by default; about 40 000 and
300 000 Gaussians), then one more case: the 3K model trained at 640x480 (the scene's images upsampled
x2 and its cameras resized, `downscale=0.5`). The trained states are cached under
`--state-dir` (default `cache_root()/engine_profile`; training to 1 050 steps takes minutes); results
are bit-identical before and after the engine's speed work, so one cache serves both.

At each size the benchmark runs `--steps` ordinary training steps (`train_step` + `refine`, as the
Trainer does) and splits each step's wall time into the stages that the trainer and the rasterizer mark
(strings_bench/core/instrument.py: this tool installs a recorder; nothing of the package is replaced):

| stage | marked stage |
|---|---|
| projection + SH | `raster.cpu.Preprocess.forward` |
| binning + sort | `raster.cpu.RasterizeTiles.forward` minus its blend kernel (depth sort, packing, tile lists) |
| forward blend | the blend kernel `forward` (`raster.cpu_kernels_f32`, the default, or `cpu_kernels` with `--backend cpu-f64`) |
| backward blend | `RasterizeTiles.backward` (blend backward, per-Gaussian reduction, scatter) |
| backward projection | `Preprocess.backward` |
| loss + SSIM | the method's `loss` (forward) and the backward from its start until the render's gradient arrives (a hook on `out.color`) |
| Adam | `GaussianAdam.step` |
| densification | `refine` (the per-step statistics) + one densification round (timed after the steps) / the refinement interval |
| other | the rest of `train_step`: finite checks, view order, the SH concatenation, the output composition and their backward, gradient accumulation |

Lower bounds, measured in this run on this machine:
- copy bandwidth: a parallel numba copy of 256 MiB with the kernels' thread count, counted as bytes
  read + written per second;
- peak arithmetic: float32 matrix products (torch.mm 2048^2) at the same thread count, for SSIM;
- float32 vector peak, for the two blends: a numba kernel of independent float32
  multiply-add chains over arrays that LLVM vectorises (`vector_peak`), at the kernels' thread count:
  what vectorised float32 code on this CPU can reach, without a matmul's cache blocking.
Each stage's bound is max(bytes it must move / bandwidth, flops it must do / peak), with bytes
counted at float32 for what the stage must read and write at least (listed in `stage_bounds`), and
flops per blended (pixel, Gaussian) pair (20 forward, 40 backward, exp counted as one) for the
blends, over the vector peak; the pairs are counted by a separate numba kernel that walks the same
lists. `fraction` is bound / measured.

`--backend cpu-f64` profiles the float64 blend kernels (the setting `backend=cpu-f64`) instead of
the default float32 ones.
"""

from __future__ import annotations

from strings_bench.core.schedules import get_schedule

import argparse
import io
import json
import math
import statistics
import sys
import time
from pathlib import Path

import numpy as np
import torch

DEFAULT_SCENE = "synthetic/extinguisher"  # the former default run's room (320x240)
DEFAULT_SCHEDULE = "early"
STAGES = ("projection+SH", "binning+sort", "forward blend", "backward blend", "backward projection",
          "loss+SSIM", "Adam", "densification", "other")
FWD_FLOPS_PER_PAIR = 20
BWD_FLOPS_PER_PAIR = 40


# ---- the trained models ------------------------------------------------------------------------------
def load_scene(spec: str):
    from strings_bench.datasets.registry import resolve_scenes
    from strings_bench.scene.scene import Scene

    ref = resolve_scenes([spec])[0]
    return Scene.load(ref.path, settings=ref.settings)


def build_method(schedule: str):
    from strings_bench.core.errors import StringsBenchError
    from strings_bench.methods.registry import get_method

    spec = get_method("3dgs")
    try:
        return spec.build(steps_scale=get_schedule(schedule).steps_scale)
    except StringsBenchError:  # an older commit's arm (engine_ab.py): build(schedule=...) before the redesign
        return spec.build(schedule=schedule)


def trained_states(scene, schedule: str, at: list[int], state_dir: Path) -> dict[int, Path]:
    """Train 3DGS with the loop's own calls and save the method's state after `refine(step)` for each
    step in `at` (cached)."""
    paths = {s: state_dir / f"3dgs-{scene.name}-{schedule}-{s}.pt" for s in at}
    if all(p.is_file() for p in paths.values()):
        return paths
    state_dir.mkdir(parents=True, exist_ok=True)
    from strings_bench.engine.trainer import seed_everything

    method = build_method(schedule)
    seed_everything(method.config.seed)
    method.setup(scene, device="cpu")
    t0 = time.perf_counter()
    counts = [(0, method.num_gaussians())]
    for step in range(1, max(at) + 1):
        method.train_step(step)
        method.refine(step)
        if step in paths and not paths[step].is_file():
            buf = io.BytesIO()
            torch.save(method.state_dict(), buf)
            paths[step].write_bytes(buf.getvalue())
        if step % 50 == 0:
            counts.append((step, method.num_gaussians()))
            print(f"  training the profile's model: step {step}, {method.num_gaussians()} Gaussians, "
                  f"{time.perf_counter() - t0:.0f} s", file=sys.stderr, flush=True)
    (state_dir / "counts.json").write_text(json.dumps(counts))  # the Gaussian count every 50 steps (engine_ab)
    return paths


def restore(scene, schedule: str, path: Path, downscale: float = 1.0):
    method = build_method(schedule)
    method.setup(scene, device="cpu", downscale=downscale)
    method.load_state_dict(torch.load(path, map_location="cpu", weights_only=False))
    return method


def params_hash(method) -> str:
    """sha256 over the model's parameters (names and bytes, in name order): equal hashes, identical parameters."""
    import hashlib

    h = hashlib.sha256()
    for k, v in sorted(method.model.params.items()):
        h.update(k.encode())
        h.update(v.detach().contiguous().numpy().tobytes())
    return h.hexdigest()


# ---- stage times ----------------------------------------------------------------------------------------
class StepClock:
    """A recorder of strings_bench.core.instrument: each stage's wall seconds, and the part of the backward that
    is the loss's (from its start until the gradient of the rendered image arrives)."""

    def __init__(self):
        self.t: dict[str, float] = {}
        self.color_grad_at: float | None = None

    def add(self, stage: str, start: float, seconds: float, cpu_seconds: float) -> None:
        self.t[stage] = self.t.get(stage, 0.0) + seconds
        if stage == "backward" and self.color_grad_at is not None:
            self.t["loss.backward"] = self.t.get("loss.backward", 0.0) + self.color_grad_at - start
            self.color_grad_at = None

    def note(self, name: str, values: dict) -> None:
        color = values.get("color") if name == "render" else None
        if color is not None and color.requires_grad:
            color.register_hook(self._color_grad)

    def _color_grad(self, grad):
        self.color_grad_at = time.perf_counter()


def profile_steps(method, first_step: int, steps: int) -> dict:
    """Run `steps` training steps from `first_step`; per-stage ms per step (the stages the trainer and the
    rasterizer mark, strings_bench/core/instrument.py)."""
    from strings_bench.core.instrument import recording

    clock = StepClock()
    total = refine = 0.0
    with recording(clock):
        for step in range(first_step, first_step + steps):
            t0 = time.perf_counter()
            method.train_step(step)
            t1 = time.perf_counter()
            method.refine(step)
            t2 = time.perf_counter()
            total += t2 - t0
            refine += t2 - t1
    t = {k: v / steps * 1e3 for k, v in clock.t.items()}
    st = {
        "projection+SH": t.get("preprocess.forward", 0.0),
        "binning+sort": t.get("tiles.forward", 0.0) - t.get("blend.forward", 0.0),
        "forward blend": t.get("blend.forward", 0.0),
        "backward blend": t.get("tiles.backward", 0.0),
        "backward projection": t.get("preprocess.backward", 0.0),
        "loss+SSIM": t.get("loss", 0.0) + t.get("loss.backward", 0.0),
        "Adam": t.get("adam", 0.0),
        "densification": refine / steps * 1e3,
    }
    st["other"] = total / steps * 1e3 - sum(st.values())
    return {"stages": st, "step_ms": total / steps * 1e3}


def refine_interval(method) -> int:
    """The strategy's densification interval in steps (this version: `every(nominal)`; older commits'
    arms, engine_ab.py: `every(state, nominal)`)."""
    strat = method.strategy
    try:
        return strat.every(strat.refine_every)
    except TypeError:
        return strat.every(method.strategy_state, strat.refine_every)


def densify_round_ms(method) -> float:
    """One densification round of the strategy on the current statistics (changes the model)."""
    strat, state = method.strategy, method.strategy_state
    t0 = time.perf_counter()
    strat.densify(method.model, method.optimizer, state, method.step)
    return (time.perf_counter() - t0) * 1e3


# ---- lower bounds ---------------------------------------------------------------------------------------
def copy_bandwidth(mib: int = 256, reps: int = 5) -> float:
    """Bytes read + written per second by a parallel numba copy (the kernels' thread count)."""
    from numba import njit, prange

    @njit(parallel=True)
    def pcopy(dst, src):
        n = src.shape[0]
        chunk = 1 << 16
        for c in prange((n + chunk - 1) // chunk):
            for i in range(c * chunk, min(n, (c + 1) * chunk)):
                dst[i] = src[i]

    src = np.ones(mib * 2 ** 20 // 8)
    dst = np.empty_like(src)
    pcopy(dst, src)
    best = min(_timed(lambda: pcopy(dst, src)) for _ in range(reps))
    return 2 * src.nbytes / best


def peak_flops(n: int = 2048, reps: int = 3) -> float:
    """float32 matrix-product flops per second (torch.mm) at the current torch thread count."""
    a, b = torch.randn(n, n), torch.randn(n, n)
    torch.mm(a, b)
    best = min(_timed(lambda: torch.mm(a, b)) for _ in range(reps))
    return 2 * n ** 3 / best


def vector_peak(reps: int = 5) -> float:
    """float32 flops per second of vectorised multiply-adds (numba, the kernels' thread count): per
    array element CHAINS independent chains of LINKS multiply-adds, written out; elements are
    independent, so LLVM vectorises over them (as the blends do over a tile row) and the chains hide
    the latency. Arrays in cache (no memory bound). 2 flops per multiply-add; best of `reps`."""
    import numba
    from numba import njit, prange

    ind = " " * 12
    lines = [f"{ind}v{k} = x[j] + np.float32({k})" for k in range(CHAINS)]
    for _ in range(LINKS):
        lines += [f"{ind}v{k} = v{k} * m + c" for k in range(CHAINS)]
    lines.append(f"{ind}y[j] = " + " + ".join(f"v{k}" for k in range(CHAINS)))
    src = ("def chains(x, y, m, c, n_threads):\n"
           "    per = x.shape[0] // n_threads\n"
           "    for t in prange(n_threads):\n"
           "        for r in range(ROUNDS):\n"
           "          for j in range(t * per, (t + 1) * per):\n" + "\n".join(lines) + "\n")
    ns = {"prange": prange, "ROUNDS": 400, "np": np}
    exec(src, ns)  # noqa: S102 (our own source, generated above)
    chains = njit(parallel=True, fastmath={"contract"})(ns["chains"])
    n_threads = numba.get_num_threads()
    x = np.random.default_rng(0).random(n_threads * 2048).astype(np.float32)
    y = np.empty_like(x)
    m, c = np.float32(0.999), np.float32(0.001)
    chains(x, y, m, c, n_threads)
    best = min(_timed(lambda: chains(x, y, m, c, n_threads)) for _ in range(reps))
    return x.shape[0] * 400 * CHAINS * LINKS * 2 / best


CHAINS, LINKS = 4, 16


def _timed(fn) -> float:
    t0 = time.perf_counter()
    fn()
    return time.perf_counter() - t0


def count_pairs(method, view: int) -> tuple[int, int, int, int]:
    """(visible Gaussians, tile intersections, blended pixel-Gaussian pairs forward, pairs backward)
    of one render of `view` at the current model: the work the blends cannot avoid (from the blend's inputs,
    which the rasterizer hands to an installed recorder: strings_bench/core/instrument.py)."""
    from strings_bench.core.instrument import StageTimes, recording

    times = StageTimes()
    with recording(times), torch.no_grad():
        method.render_raster(view, sh_degree=method.sh_degree_for_step(method.step))
    b = times.notes["blend.forward"]
    pairs = _blended_pairs(b["tile_start"], b["lst"], b["P"], b["BB"], b["W"], b["H"], b["tiles_x"], b["out_last"])
    # P holds one row per intersection (list order) in this version, one per visible Gaussian in older ones
    return b.get("visible", b["P"].shape[0]), b["lst"].shape[0], pairs[0], pairs[1]


def _blended_pairs(tile_start, lst, P, BB, W, H, tiles_x, out_last):
    from numba import njit

    @njit(cache=False)
    def count(tile_start, lst, P, BB, W, H, tiles_x, out_last, tile):
        fwd = 0
        bwd = 0
        for t in range(tile_start.shape[0] - 1):
            ty = t // tiles_x
            tx = t - ty * tiles_x
            px0, py0 = tx * tile, ty * tile
            for k in range(tile_start[t], tile_start[t + 1]):
                i = lst[k]
                for py in range(max(BB[i, 2], py0), min(BB[i, 3], py0 + tile - 1, H - 1) + 1):
                    for px in range(max(BB[i, 0], px0), min(BB[i, 1], px0 + tile - 1, W - 1) + 1):
                        dx = P[i, 0] - (px + 0.5)
                        dy = P[i, 1] - (py + 0.5)
                        power = -0.5 * (P[i, 2] * dx * dx + P[i, 4] * dy * dy) - P[i, 3] * dx * dy
                        if power > 0.0:
                            continue
                        if min(P[i, 5] * math.exp(power), 0.99) < 1.0 / 255.0:
                            continue
                        if k < out_last[py, px]:
                            fwd += 1
                            bwd += 1
        return fwd, bwd
    import strings_bench.raster.cpu_kernels as K

    return count(tile_start, lst, P, BB, W, H, tiles_x, out_last, K.TILE)


def stage_bounds(n: int, v: int, m: int, pairs_f: int, pairs_b: int, k_sh: int, hw: int, bw: float,
                 flops: float, refine_every: int, vflops: float | None = None) -> dict[str, tuple[float, str]]:
    """ms lower bound per stage and what it counts. n Gaussians, v visible, m tile intersections,
    k_sh SH coefficients per channel in use, hw pixels; vflops the float32 vector peak (the blends'
    arithmetic bound; the matmul peak `flops` where not given)."""
    vflops = flops if vflops is None else vflops
    f4 = 4.0
    params = (3 + 4 + 3 + 1 + 3 * k_sh) * f4  # what projection+SH reads per Gaussian
    proj_out = (2 + 3 + 1 + 4) * f4 + 4 + 16  # means2d, conic, opacity, feats, radius, box
    all_params = (3 + 4 + 3 + 1 + 3 * 16) * f4  # every parameter of a degree-3 model (Adam touches all)
    ssim_flops = 3 * 5 * 2 * 2 * 11 * hw * 3  # 15 filtered planes, 2 passes of 11 taps; backward ~2x
    rows = {
        "projection+SH": (n * (params + proj_out) / bw, f"N x ({params:.0f} B read + {proj_out:.0f} B written)"),
        "binning+sort": ((v * 20 + m * 8) / bw, "V x 20 B (depth, box) + M x 8 B (key and list entry)"),
        "forward blend": (max((m * 10 * f4 + hw * 24) / bw, pairs_f * FWD_FLOPS_PER_PAIR / vflops),
                          f"max(M x 40 B + image, {FWD_FLOPS_PER_PAIR} flops x blended pairs)"),
        "backward blend": (max((m * 10 * f4 + hw * 40 + v * 12 * f4) / bw, pairs_b * BWD_FLOPS_PER_PAIR / vflops),
                           f"max(M x 40 B + image grads + V x 48 B, {BWD_FLOPS_PER_PAIR} flops x pairs)"),
        "backward projection": (n * (2 * params) / bw + v * 10 * f4 / bw, "N x params read and grads written + V x 40 B"),
        "loss+SSIM": (max(hw * 3 * f4 * 4 / bw, ssim_flops / flops), "max(2 images read, grad written; SSIM filter flops)"),
        "Adam": (n * all_params * 7 / bw, "N x all parameters x 7 streams (p, g, m, v read; p, m, v written)"),
        "densification": (n * 36 / bw, "N x 36 B per step (means2d grad, radii, 3 statistics read+written)"),
    }
    return {k: (sec * 1e3, what) for k, (sec, what) in rows.items()}


def profile_case(name: str, method, first_step: int, steps: int, bw: float, flops: float,
                 vflops: float | None = None) -> dict:
    """Warm one step, profile `steps`, count the pairs, time one densification round."""
    method.train_step(first_step)
    method.refine(first_step)
    n = method.num_gaussians()
    prof = profile_steps(method, first_step + 1, steps)
    view = method.views_for_step(first_step + steps + 1)
    cam = method.camera(view)
    v, m, pf, pb = count_pairs(method, view)
    every = refine_interval(method)
    dens = densify_round_ms(method)
    prof["stages"]["densification"] += dens / every
    prof["step_ms"] += dens / every
    deg = method.sh_degree_for_step(method.step)
    bounds = stage_bounds(n, v, m, pf, pb, (deg + 1) ** 2, cam.width * cam.height, bw, flops, every, vflops)
    return {"case": name, "gaussians": n, "visible": v, "intersections": m, "pairs": pf,
            "width": cam.width, "height": cam.height, "sh_degree": deg, "step_ms": prof["step_ms"],
            "densify_round_ms": dens, "refine_every": every,
            "stages": {s: {"ms": prof["stages"][s], "bound_ms": bounds.get(s, (None, ""))[0],
                           "bound": bounds.get(s, (None, ""))[1]} for s in STAGES}}


def threads_ab(method, rounds: int, steps: int) -> dict:
    """ms/step (and its loss+SSIM part) with torch at 1 and at 2 intra-op threads, alternating rounds
    of `steps` steps on the same (continuing) model; medians."""
    from strings_bench.engine.trainer import cpu_threads

    got = {1: [], 2: []}
    for r in range(rounds):
        for n in ((1, 2) if r % 2 == 0 else (2, 1)):
            with cpu_threads(n):
                p = profile_steps(method, method.step + 1, steps)
            got[n].append((p["step_ms"], p["stages"]["loss+SSIM"]))
    return {f"threads_{n}": {"step_ms": statistics.median(x[0] for x in v), "loss_ms": statistics.median(x[1] for x in v)}
            for n, v in got.items()}


def print_case(r: dict) -> None:
    print(f"\n{r['case']}: {r['gaussians']} Gaussians ({r['visible']} visible, {r['intersections']} tile "
          f"intersections, {r['pairs']} blended pairs), {r['width']}x{r['height']}, SH degree {r['sh_degree']}: "
          f"{r['step_ms']:.1f} ms per step (densification round {r['densify_round_ms']:.0f} ms every {r['refine_every']} steps)")
    print(f"| stage | ms/step | share | lower bound ms | bound / measured |\n|---|---|---|---|---|")
    for s in STAGES:
        x = r["stages"][s]
        b = x["bound_ms"]
        frac = f"{b / x['ms']:.2f}" if b is not None and x["ms"] > 0 else "-"
        bs = f"{b:.2f}" if b is not None else "-"
        print(f"| {s} | {x['ms']:.1f} | {x['ms'] / r['step_ms'] * 100:.0f} % | {bs} | {frac} |")
    if "threads_ab" in r:
        print("torch intra-op threads: " + ", ".join(f"{k[-1]}: {v['step_ms']:.0f} ms/step (loss+SSIM {v['loss_ms']:.0f})"
                                                      for k, v in r["threads_ab"].items()))


def read_json_output(path: str) -> dict:
    """A `--json` run's output file (its first line is the printed bandwidth summary)."""
    text = Path(path).read_text()
    return json.loads(text[text.index("{"):])


def stage_table(before: list[str], after: list[str]) -> str:
    """CSV of the stage medians of two sets of `--json` outputs (e.g. two runs of an older checkout and two of this
    one): ms per step before and after, their ratio, and the after runs' bound with the share of it reached."""
    def medians(files):
        runs = [read_json_output(f) for f in files]
        out = {}
        for ci, case in enumerate(runs[0]["cases"]):
            for stage in list(case["stages"]) + ["step"]:
                ms = [r["cases"][ci]["step_ms"] if stage == "step" else r["cases"][ci]["stages"][stage]["ms"]
                      for r in runs]
                bound = [r["cases"][ci]["stages"][stage].get("bound_ms") for r in runs] if stage != "step" else []
                out[(case["gaussians"], stage)] = (statistics.median(ms),
                                                   statistics.median(bound) if bound and None not in bound else None)
        return out

    b, a = medians(before), medians(after)
    lines = ["Gaussians,stage,before ms,after ms,before / after,bound ms,bound / after"]
    for key, (b_ms, _) in b.items():
        a_ms, bound = a[key]
        bound_txt = "" if bound is None else (f"{bound:.2f}" if bound < 1 else f"{bound:.1f}")
        share = "" if bound is None else f"{bound / a_ms:.2f}"
        lines.append(f"{key[0]},{key[1]},{b_ms:.1f},{a_ms:.1f},{b_ms / a_ms:.2f},{bound_txt},{share}")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--table", nargs=2, metavar=("BEFORE", "AFTER"),
                    help="print the stage table of two comma-separated lists of --json outputs and stop")
    ap.add_argument("--scene", default=DEFAULT_SCENE)
    ap.add_argument("--schedule", default=DEFAULT_SCHEDULE)
    ap.add_argument("--at", default="450,1050", help="steps of the trained models profiled (3K, 7K of early)")
    ap.add_argument("--big-at", type=int, default=450, help="the model profiled at 640x480 (0: skip)")
    ap.add_argument("--steps", type=int, default=8, help="profiled steps per case")
    ap.add_argument("--state-dir", default=None)
    ap.add_argument("--torch-threads", default="trainer",
                    help="torch intra-op threads during the steps: 'trainer' (the Trainer's CPU setting), N, or 'none'")
    ap.add_argument("--threads-ab", type=int, default=0, metavar="ROUNDS",
                    help="also time ROUNDS alternating rounds with torch at 1 and 2 threads per case")
    ap.add_argument("--backend", default="cpu", choices=("cpu", "cpu-f64"),
                    help="the CPU rasterizer: float32 blends (default) or the float64 reference kernels")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    if args.table:
        print(stage_table(args.table[0].split(","), args.table[1].split(",")), end="")
        return 0
    import strings_bench.raster  # noqa: F401  (selects numba's threading layer before any kernel runs)
    from strings_bench.core.io import cache_root
    from strings_bench.engine.trainer import CPU_TORCH_THREADS, cpu_threads, keep_freed_memory

    keep_freed_memory()  # as the Trainer does on the CPU

    threads = {"trainer": CPU_TORCH_THREADS, "none": None}.get(args.torch_threads)
    if args.torch_threads not in ("trainer", "none"):
        threads = int(args.torch_threads)

    at = [int(x) for x in args.at.split(",") if x]
    state_dir = Path(args.state_dir) if args.state_dir else cache_root() / "engine_profile"
    scene = load_scene(args.scene)
    paths = trained_states(scene, args.schedule, sorted(set(at + ([args.big_at] if args.big_at else []))), state_dir)
    import numba

    results = []
    with cpu_threads(threads):
        bw, flops, vflops = copy_bandwidth(), peak_flops(), vector_peak()
        if threads is not None:  # numba's parallel launches above can reset the shared OpenMP thread count
            torch.set_num_threads(threads)
        info = {"numba_threads": numba.get_num_threads(), "torch_threads": torch.get_num_threads(),
                "copy_GBps": bw / 1e9, "peak_GFLOPs": flops / 1e9, "vector_peak_GFLOPs": vflops / 1e9,
                "backend": args.backend}
        print(f"copy bandwidth {bw / 1e9:.1f} GB/s (read + write), float32 matmul peak {flops / 1e9:.0f} GFLOP/s, "
              f"float32 vector peak {vflops / 1e9:.0f} GFLOP/s (the blends' bound); backend {args.backend}; "
              f"numba threads {info['numba_threads']}, torch threads {info['torch_threads']}", flush=True)
        cases = [(f"{s} steps, 320x240", s, 1.0) for s in at]
        if args.big_at:
            cases.append((f"{args.big_at} steps, 640x480", args.big_at, 0.5))
        for name, s, ds in cases:
            method = restore(scene, args.schedule, paths[s], downscale=ds)
            method.config.backend = args.backend
            r = profile_case(name, method, s + 1, args.steps, bw, flops, vflops)
            if args.threads_ab:
                r["threads_ab"] = threads_ab(method, args.threads_ab, args.steps)
            results.append(r)
            if not args.json:
                print_case(r)
    if args.json:
        print(json.dumps({"info": info, "cases": results}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
