"""The GPU verification in rounds of at most ~8 minutes each (docs/guide/gpu.md, "Verifying a GPU machine in stages").

    bash scripts/gpu_campaign.sh [--dry-run] [--force] [--budget S] OUT_DIR STAGE

Stages (in order of value; `list` prints them):
  captures-7k    the real captures whose GT clears the OCR floor (bundler_et, saharov32) at the size they are
                 built, the paper's schedule to 7K (checkpoints 3K, 7K): 3DGS, STRinGS and STRinGS without the
                 lock (strings-pos-lr), seed 0, each cell its own step; the scenes built on a CPU beforehand
                 and carried in STRINGS_BENCH_CACHE (`strings-bench datasets prepare captures/NAME`);
  verify         versions, gsplat's first-use compilation (timed), pytest -m gpu, tools/gpu.py
                 (3dgs, strings) at 320x240 with the CPU backend's rows, strings then 3dgs on synthetic/books
                 at 1280x960 to 7K (paper schedule, checkpoints 3K and 7K) with the peak GPU memory of each
                 cell, and the benchmark at 1280x960 (CUDA rows only); it takes two rounds on an H200;
  cal7k-rs1.5    3DGS on synthetic360/storeroom built at 1280x960 with 100 views, room_scale 1.5, the
  cal7k-rs2      card's photometric settings, to 7K (room_scale 2 for the second point);
  cal30k         3DGS to 30K on the banked 7K point closest to the paper's 3DGS OCR-CER (0.736);
  strings-frozen STRinGS to 7K and 30K on that setting;
  x1-rooms       the paper's schedule (x1) on the three synthetic360 rooms built at 1280x960 in the
                 synthetic360-cpu configuration (48 views, room_scale 0.6) with the text heights scaled
                 with the width (10-16 px at 320 -> 40-64 px at 1280: the same rooms, four times the
                 pixels): 3DGS, STRinGS, STRinGS without the lock and EDC-AbsGS, seed 0, each cell its
                 own step; every cell to 7K first (checkpoints 3K, 7K), then each to 30K (3K, 7K, 30K)
                 in a run folder of its own (a run folder keeps its checkpoints). The full-size
                 counterparts of the CPU reference cells at x1;
  x1-rooms-320   the same cells on the rooms as synthetic360-cpu registers them (320x240): the CPU
                 reference cells themselves, through the CUDA backend.

Each stage writes `<date>_<stage>_<gpu>.csv` into OUT_DIR (meant for docs/results/data/gpu/; a later
round of the same stage on the same day writes `<date>.2_...`, and so on, keeping the earlier files): one row
per step with its status (ok, failed, partial = cut at the stage's time budget), seconds, and the
versions and GPU name; a run's results.csv is copied beside it with the same columns added. A stage
whose CSV in OUT_DIR has every step ok is banked and skipped (--force runs it again); in a stage cut
short, the steps already banked ok are skipped at the next round (gsplat's compilation and scene
builds excepted: a round starts on a fresh machine), and so is a run or benchmark step whose every
result row an earlier round banked, though that round cut the step after them. Runs train under RUNS/<stage> (--runs, default
OUT_DIR/runs) and resume there while the machine is the same; each step's log is RUNS/logs/<stage>_<step>.log.

STAGE may be a comma-separated list (verify,x1-rooms): the stages run in that order within the one
--budget, each on the time the ones before it left.

--prepare: only gsplat's compilation and the stages' scene builds, which need neither OCR nor a
result folder (their rows go to RUNS/logs, not OUT_DIR): on a machine that takes its wheels in two
loads, run it in the background after the first load while the second travels.

--dry-run: the same steps on the CPU at a tiny size (64x48, the tiny schedule, a few benchmark steps),
the GPU column "cpu (dry run)"; tests/integration/test_gpu_campaign.py runs it in CI.
"""

from __future__ import annotations

import argparse
import csv
import datetime as dt
import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PAPER_3DGS_CER_7K = 0.736  # the paper's 3DGS row (Table 1, STRinGS-360, 7K)
# x1-rooms: the rooms and methods of the CPU reference cells at the paper's schedule
X1_ROOMS = ("storeroom", "pantry", "office")
X1_METHODS = ("3dgs", "strings", "strings-pos-lr", "edc-absgs")
X1_TEXT_PX_320 = (10.0, 16.0)  # synthetic360-cpu's word heights at 320 px; scaled with the build's width
STEP_COLUMNS = ["date", "stage", "step", "status", "seconds", "detail", "gpu", "torch", "cuda", "gsplat", "python",
                "dry_run"]


def versions(dry_run: bool) -> dict:
    import platform

    import torch

    try:
        from importlib.metadata import version
        gs = version("gsplat")
    except Exception:  # noqa: BLE001 - not installed
        gs = "none"
    gpu = torch.cuda.get_device_name(0) if torch.cuda.is_available() else "none"
    if dry_run:
        gpu = "cpu (dry run)"
    return {"gpu": gpu, "torch": torch.__version__, "cuda": str(torch.version.cuda), "gsplat": gs,
            "python": platform.python_version(), "dry_run": str(dry_run).lower()}


def slug(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9]+", "-", text).strip("-").lower() or "none"


# Steps that a later round does again even when an earlier one banked them: each round starts on a
# fresh machine, where gsplat compiles and scenes build anew.
ALWAYS = ("versions", "compile")


def banked_steps(out: Path, stage: str, dry_run: bool) -> dict[str, str]:
    """{step: file} of the steps of `stage` that a CSV in `out` records as ok (same dry-run flag)."""
    done = {}
    for path in sorted(out.glob(f"*_{stage}_*.csv")):
        with open(path, newline="") as fh:
            for row in csv.DictReader(fh):
                if row.get("status") == "ok" and row.get("dry_run") == str(dry_run).lower() and "step" in row:
                    done[row["step"]] = path.name
    return done


def result_rows(out: Path, stage: str, pattern: str, dry_run: bool) -> list[tuple[dict, str]]:
    """(row, file name) of every result row in OUT_DIR's `<date>_<stage>_<pattern>_<gpu>.csv` files (same
    dry-run flag), the rows of a step cut short included; steps CSVs (a `step` column) are not results."""
    found = []
    for path in sorted(out.glob(f"*_{stage}_{pattern}_*.csv")):
        with open(path, newline="") as fh:
            found += [(r, path.name) for r in csv.DictReader(fh)
                      if r.get("dry_run") == str(dry_run).lower() and "step" not in r]
    return found


def banked_run(out: Path, stage: str, pattern: str, methods: list[str], label: str, dry_run: bool) -> str | None:
    """The CSV(s) holding every method's row at checkpoint `label`, or None when one is missing."""
    rows = result_rows(out, stage, pattern, dry_run)
    files = [next((f for r, f in rows if r.get("method") == m and r.get("label") == label), None) for m in methods]
    return ", ".join(sorted(set(files))) if all(files) else None


def banked_benchmark(out: Path, stage: str, name: str, want: set[tuple[str, str]], dry_run: bool) -> str | None:
    """The CSV(s) holding a (method, device) row for each of `want`, or None when one is missing."""
    rows = result_rows(out, stage, name, dry_run)
    have = {(r.get("method"), r.get("device")) for r, _ in rows}
    return ", ".join(sorted({f for r, f in rows if (r.get("method"), r.get("device")) in want})) if want <= have else None


def round_stem(where: Path, date: str, stage: str, gpu: str) -> str:
    """The file-name prefix of a new round: its date, or `<date>.<n>` for the n-th round of that stage and GPU on
    one day, so that a second round on a warm machine keeps the first one's files."""
    stem, n = date, 1
    while (where / f"{stem}_{stage}_{gpu}.csv").exists():
        n += 1
        stem = f"{date}.{n}"
    return stem


class Round:
    def __init__(self, out: Path, stage: str, dry_run: bool, budget_s: float, runs: Path | None = None,
                 prepare: bool = False, date: str | None = None):
        self.out, self.stage, self.dry_run, self.prepare = out, stage, dry_run, prepare
        self.runs = runs or out / "runs"
        self.done = banked_steps(out, stage, dry_run)
        self.t0, self.budget_s = time.monotonic(), budget_s
        self.v = versions(dry_run)
        self.date = date or dt.date.today().isoformat()
        # --prepare's rows (compilation, builds) must not bank anything: they go beside the logs
        where = self.runs / "logs" if prepare else out
        self.stem = round_stem(where, self.date, stage, slug(self.v["gpu"]))
        self.csv = where / f"{self.stem}_{stage}_{slug(self.v['gpu'])}.csv"
        self.rows: list[dict] = []
        self.py = sys.executable
        self.device = "cpu" if dry_run else "cuda"
        (self.runs / "logs").mkdir(parents=True, exist_ok=True)

    def left(self) -> float:
        return self.budget_s - (time.monotonic() - self.t0)

    def step(self, name: str, argv: list[str], limit_s: float, env: dict | None = None,
             banked_in: str | None = None) -> str:
        """Run one step (its own process group), at most `limit_s` and never past the stage's budget.
        A step an earlier round banked as ok is not run again (except ALWAYS and scene builds), nor one
        whose results an earlier round banked whole (`banked_in`: the CSV that holds them), even where
        that round's step was cut after them."""
        if self.prepare and name != "compile" and not name.startswith("build_"):
            return "skipped"  # --prepare: compilation and scene builds only
        where = banked_in or (self.done.get(name) if name not in ALWAYS and not name.startswith("build_") else None)
        if where:
            self.record(name, "ok", 0.0, f"banked in {where}")
            print(f"== {self.stage}/{name}: banked in {where}; skipped", flush=True)
            return "ok"
        limit = max(0.1, min(limit_s, self.left()))
        log = self.runs / "logs" / f"{self.stage}_{name}.log"
        t = time.monotonic()
        print(f"== {self.stage}/{name} (at most {limit:.0f} s): {' '.join(argv)}", flush=True)
        with open(log, "w") as fh:
            proc = subprocess.Popen(argv, cwd=ROOT, stdout=fh, stderr=subprocess.STDOUT, start_new_session=True,
                                    env={**os.environ, "PYTHONUNBUFFERED": "1", **(env or {})})
            try:
                rc = proc.wait(timeout=limit)
                status = "ok" if rc == 0 else f"failed rc={rc}"
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, signal.SIGTERM)
                try:
                    proc.wait(timeout=20)
                except subprocess.TimeoutExpired:
                    os.killpg(proc.pid, signal.SIGKILL)
                    proc.wait()
                status = "partial"
        seconds = time.monotonic() - t
        tail = log.read_text(errors="replace").strip().splitlines()[-1:] or [""]
        self.record(name, status, seconds, tail[0][:200])
        print(f"== {self.stage}/{name}: {status} in {seconds:.0f} s (log {log})", flush=True)
        return status

    def record(self, name: str, status: str, seconds: float, detail: str = "") -> None:
        self.rows.append({"date": self.date, "stage": self.stage, "step": name, "status": status,
                          "seconds": f"{seconds:.1f}", "detail": detail, **self.v})
        self.write(self.csv, STEP_COLUMNS, self.rows)

    def results_csv(self, name: str) -> Path:
        return self.out / f"{self.stem}_{self.stage}_{name}_{slug(self.v['gpu'])}.csv"

    def bank_results(self, src: Path, name: str) -> None:
        """Copy a step's results CSV (a run's results.csv, the benchmark's rows) next to the steps CSV,
        versions added (partial rows as they are)."""
        if self.prepare or not src.exists():
            return
        with open(src, newline="") as fh:
            rows = list(csv.DictReader(fh))
        if not rows:
            return
        cols = list(rows[0]) + [c for c in ("gpu", "torch", "cuda", "gsplat", "python", "dry_run") if c not in rows[0]]
        for r in rows:
            r.update({k: self.v[k] for k in ("gpu", "torch", "cuda", "gsplat", "python", "dry_run")})
        self.write(self.results_csv(name), cols, rows)

    @staticmethod
    def write(path: Path, cols: list[str], rows: list[dict]) -> None:
        tmp = path.with_suffix(".csv.tmp")
        with open(tmp, "w", newline="") as fh:
            w = csv.DictWriter(fh, fieldnames=cols, extrasaction="ignore")
            w.writeheader()
            w.writerows(rows)
        os.replace(tmp, path)  # atomic: a round cut anywhere leaves a whole file

    # ---- shared pieces ----------------------------------------------------------------------------
    def compile(self) -> str:
        """gsplat's first CUDA use as a step, timed (its kernels compile then; later processes load them)."""
        if self.dry_run:
            compile_code = "import gsplat, strings_bench.raster.gsplat_backend; print('import only (dry run)')"
        else:
            compile_code = (
                "import time, torch\nt0 = time.perf_counter()\nimport gsplat\n"
                "d = 'cuda'\nmeans = torch.tensor([[0.0, 0.0, 3.0]], device=d)\n"
                "K = torch.tensor([[[50.0, 0, 32], [0, 50.0, 24], [0, 0, 1]]], device=d)\n"
                "gsplat.rasterization(means, torch.tensor([[1.0, 0, 0, 0]], device=d), torch.full((1, 3), 0.1, device=d),"
                " torch.ones(1, device=d), torch.ones(1, 3, device=d), torch.eye(4, device=d)[None], K, 64, 48)\n"
                "torch.cuda.synchronize()\nprint(f'gsplat first use (compilation included): {time.perf_counter() - t0:.0f} s')\n")
        env = {} if self.dry_run else {"TORCH_CUDA_ARCH_LIST": os.environ.get("TORCH_CUDA_ARCH_LIST", "9.0"),
                                       "MAX_JOBS": os.environ.get("MAX_JOBS", str(os.cpu_count() or 16))}
        # One first import at a time across campaigns sharing RUNS: gsplat's loader deletes its build folder's lock
        # file at import, so two processes importing it at once both run the build (seen: 132 s instead of 1 s).
        import fcntl

        with open(self.runs / "gsplat-compile.lock", "w") as lock:
            fcntl.flock(lock, fcntl.LOCK_EX)
            return self.step("compile", [self.py, "-c", compile_code], 180, env)

    def size(self) -> tuple[int, int]:
        return (64, 48) if self.dry_run else (1280, 960)

    def build(self, scene: str, dataset: str | None = None, **settings) -> str | None:
        """Build (or find in the cache) a synthetic scene as a step, with the settings of `dataset` (a
        configuration such as synthetic360-cpu; default: the scene's own card) and `settings` over them;
        returns its path."""
        w, h = self.size()
        settings = {"width": w, "height": h, **settings}
        if self.dry_run and "n_views" in settings:
            settings["n_views"] = 8
        code = ("import json, sys\nfrom strings_bench.datasets.synthetic import build_scene, default_settings\n"
                "from dataclasses import replace\n"
                f"s = replace(default_settings({scene!r}, {dataset!r}), **json.loads(sys.argv[1]))\n"
                f"p = build_scene({scene!r}, s, progress=False)\n"
                "open(sys.argv[2], 'w').write(str(p))\n")
        where = self.runs / "logs" / f"{self.stage}_scene_{scene}.path"
        status = self.step(f"build_{scene}", [self.py, "-c", code, json.dumps(settings), str(where)], 300)
        return where.read_text().strip() if status == "ok" and where.exists() else None

    def run(self, name: str, methods: str, scene: str, checkpoints: str, limit_s: float, extra=(),
            banked_as: str | None = None) -> None:
        """Train and evaluate `methods` on `scene`; banked when every method's last checkpoint has a row in
        a results CSV of a step named `banked_as` (a glob; default `name`), an earlier round's cut after
        that cell included."""
        from strings_bench.core.schedules import iteration_label  # the label results.csv gives the last checkpoint

        label = iteration_label(max(int(c) for c in checkpoints.split(",")))
        banked_in = banked_run(self.out, self.stage, banked_as or name, methods.split(","), label, self.dry_run)
        if self.prepare:
            return
        run_dir = self.runs / self.stage / name
        schedule = ["--schedule", "tiny"] if self.dry_run else ["--schedule", "paper"]
        argv = [self.py, "-m", "strings_bench", "run", "--device", self.device, "--methods", methods,
                "--datasets", scene, *schedule, "--checkpoints", checkpoints, "--out", str(run_dir),
                "--no-progress", "--save-every", "2", *extra]
        if self.dry_run:
            argv.append("--no-lpips")
        self.step(name, argv, limit_s, banked_in=banked_in)
        if not banked_in:
            self.bank_results(run_dir / "results.csv", name)

    def benchmark(self, size: str, limit_s: float, with_cpu: bool) -> None:
        """tools/gpu.py for 3dgs and strings at one size (the CPU backend's rows beside it when
        `with_cpu`); banked when every (method, device) row of an earlier round is in a CSV."""
        if self.prepare:
            return
        name, methods = f"benchmark_{size}", ("3dgs",) if self.dry_run else ("3dgs", "strings")
        want = {(m, d) for m in methods for d in (self.device,) + (("cpu",) if with_cpu and not self.dry_run else ())}
        banked_in = banked_benchmark(self.out, self.stage, name, want, self.dry_run)
        rows_csv = self.runs / "logs" / f"{self.stage}_{name}.rows.csv"
        rows_csv.unlink(missing_ok=True)
        argv = [self.py, "tools/gpu.py", "--methods", ",".join(methods), "--csv", str(rows_csv)]
        argv += (["--device", "cpu", "--sizes", "64x48", "--steps", "2", "--no-lpips"] if self.dry_run
                 else ["--sizes", size, "--steps", "200", "--cpu-steps", "3"] + ([] if with_cpu else ["--no-cpu"]))
        self.step(name, argv, limit_s, banked_in=banked_in)
        if not banked_in:
            self.bank_results(rows_csv, name)


# ---- stages ----------------------------------------------------------------------------------------

def stage_verify(s: Round) -> None:
    s.record("versions", "ok", 0.0, json.dumps(s.v))
    if s.compile() != "ok":
        return  # nothing else can run without gsplat
    # Measured on an H200 (docs/results/gpu.md): pytest -m gpu needs more than 150 s (14 tests, each a
    # run with its OCR); the CPU rows of the benchmark at 1280x960 cost minutes, so its CPU ratio is the
    # 320x240 one. Order: correctness, the 320x240 ratio, the paper runs, then the large benchmark.
    # pytest: every test file with a test marked gpu (not all of tests/, whose other modules may need
    # packages a GPU node lacks), on four workers where pytest-xdist is installed (each test is a short
    # run whose OCR takes the CPU, so they overlap on one GPU; CUDA memory figures are per process).
    import importlib.util

    files = sorted(str(f.relative_to(ROOT)) for f in (ROOT / "tests").rglob("test_*.py") if "mark.gpu" in f.read_text())
    workers = ["-n", "4"] if not s.dry_run and importlib.util.find_spec("xdist") else []
    s.step("pytest_gpu", [s.py, "-m", "pytest", "-m", "gpu", "-q", "-p", "no:cacheprovider", *workers, *files], 300)
    s.benchmark("320x240", 120, with_cpu=True)
    scene = s.build("books")
    if scene:
        for method in ("strings", "3dgs"):
            # banked_as: the first round's `paper_run` step (both methods in one) banked STRinGS' cells
            s.run(f"paper_run_{method}", method, scene, "7000" if s.dry_run else "3000,7000", s.left(),
                  banked_as="paper_run*")
    s.benchmark("1280x960", 150, with_cpu=False)


def _cal7k(room_scale: float):
    def stage(s: Round) -> None:
        s.record("versions", "ok", 0.0, json.dumps(s.v))
        if s.compile() != "ok":  # here, not inside the run's first step and its training time
            return
        scene = s.build("storeroom", n_views=100, room_scale=room_scale)
        if scene:
            s.run("run", "3dgs", scene, "7000", s.left())
    return stage


def _banked_7k(out: Path) -> list[tuple[float, float]]:
    """(|CER - 0.736|, room_scale) of each banked 7K calibration point with an OCR-CER."""
    points = []
    for path in out.glob("*_cal7k-rs*_run_*.csv"):
        rs = float(re.search(r"cal7k-rs([0-9.]+?)_run", path.name).group(1))
        with open(path, newline="") as fh:
            for row in csv.DictReader(fh):
                cer = row.get("ocr_cer") or row.get("cer")
                if cer not in (None, "", "nan"):
                    points.append((abs(float(cer) - PAPER_3DGS_CER_7K), rs))
    return sorted(points)


def _frozen(s: Round) -> float | None:
    points = _banked_7k(s.out)
    if not points:
        s.record("choose_setting", "failed", 0.0, "no banked 7K calibration point with an OCR-CER: run cal7k-* first")
        return None
    s.record("choose_setting", "ok", 0.0, f"room_scale {points[0][1]} (|CER - {PAPER_3DGS_CER_7K}| = {points[0][0]:.3f})")
    return points[0][1]


def stage_cal30k(s: Round) -> None:
    rs = _frozen(s)
    scene = s.build("storeroom", n_views=100, room_scale=rs) if rs else None
    if scene:
        s.run("run", "3dgs", scene, "7000,30000", s.left())


def stage_strings_frozen(s: Round) -> None:
    rs = _frozen(s)
    scene = s.build("storeroom", n_views=100, room_scale=rs) if rs else None
    if scene:
        s.run("run", "strings", scene, "7000,30000", s.left())


def _x1_rooms(width: int, height: int):
    def stage(s: Round) -> None:
        """Every cell to 7K first, room by room (storeroom first: the CPU reference's first room), then
        each to 30K. A room is built just before its first cell that is not banked: a build at 1280x960
        costs two to three minutes of a 16-core machine (docs/results/gpu.md), too much to spend on rooms
        a round does not reach."""
        s.record("versions", "ok", 0.0, json.dumps(s.v))
        if s.compile() != "ok":
            return
        w, h = (width, height) if not s.dry_run else s.size()
        text_px = [v * w / 320 for v in X1_TEXT_PX_320]
        scenes: dict[str, str | None] = {}
        for label, checkpoints in (("7k", "3000,7000"), ("30k", "3000,7000,30000")):  # label: the last checkpoint's
            for room in X1_ROOMS:
                for method in X1_METHODS:
                    if s.left() <= 0:
                        return
                    cell = f"x1_{room}_{method}"
                    if not banked_run(s.out, s.stage, f"{cell}_*", [method], label.upper(), s.dry_run):
                        if room not in scenes:
                            scenes[room] = s.build(room, "synthetic360-cpu", width=w, height=h, text_px=text_px)
                        if scenes[room] is None:
                            break  # its build failed or was cut: the next room
                    # banked_as: a 30K run's 3K and 7K rows bank the 7K cell too (a banked cell is skipped
                    # without its scene)
                    s.run(f"{cell}_{label}", method, scenes.get(room) or "", checkpoints, s.left(),
                          banked_as=f"{cell}_*")
    return stage


# captures-7k: the real captures whose held-out GT clears the OCR floor (docs/results/captures.md), and the methods
CAPTURES_7K = ("bundler_et", "saharov32")
CAPTURES_7K_METHODS = ("3dgs", "strings", "strings-pos-lr")


def stage_captures_7k(s: Round) -> None:
    """The captures at the size they are built, the paper's schedule to 7K (checkpoints 3K, 7K), seed 0, each
    (capture, method) cell its own step with its time and peak memory. The scenes are found in the cache
    (STRINGS_BENCH_CACHE): built on a CPU beforehand (`strings-bench datasets prepare captures/NAME`) and carried,
    so that the GPU's time goes to training; a capture not found there is built as a step. The dry run takes
    bundler_et alone (9 photos) at the tiny schedule."""
    s.record("versions", "ok", 0.0, json.dumps(s.v))
    if s.compile() != "ok":
        return
    captures = CAPTURES_7K[:1] if s.dry_run else CAPTURES_7K
    methods = CAPTURES_7K_METHODS[:1] if s.dry_run else CAPTURES_7K_METHODS
    for capture in captures:
        todo = [m for m in methods if not banked_run(s.out, s.stage, f"{capture}_{m}_7k", [m], "7K", s.dry_run)]
        if todo:  # the scene is needed: found in the cache, or built here
            code = ("from strings_bench.datasets.captures import build_capture\n"
                    f"print(build_capture({capture!r}, progress=False))\n")
            if s.step(f"build_{capture}", [s.py, "-c", code], 900) != "ok":
                continue
        for method in methods:
            if s.left() <= 0:
                return
            s.run(f"{capture}_{method}_7k", method, f"captures/{capture}", "7000" if s.dry_run else "3000,7000",
                  s.left())


STAGES = {"captures-7k": stage_captures_7k, "verify": stage_verify, "cal7k-rs1.5": _cal7k(1.5), "cal7k-rs2": _cal7k(2.0), "cal30k": stage_cal30k,
          "strings-frozen": stage_strings_frozen, "x1-rooms": _x1_rooms(1280, 960),
          # the CPU reference cells' own scenes (synthetic360-cpu as registered, 320x240): the same cells
          # as the CPU's x1 reference, through the CUDA backend, in about a minute each
          "x1-rooms-320": _x1_rooms(320, 240)}


def banked(out: Path, stage: str, dry_run: bool) -> Path | None:
    for path in sorted(out.glob(f"*_{stage}_*.csv")):
        with open(path, newline="") as fh:
            rows = list(csv.DictReader(fh))
        if rows and "status" in rows[0] and rows[0].get("dry_run") == str(dry_run).lower() \
                and all(r["status"] == "ok" for r in rows):
            return path
    return None


def _iso_date(text: str) -> str:
    try:
        return dt.date.fromisoformat(text).isoformat()
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a date of the form YYYY-MM-DD") from None


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("out", metavar="OUT_DIR")
    ap.add_argument("stage", metavar="STAGE", help=f"one of {', '.join(STAGES)} or several, comma-separated; list")
    ap.add_argument("--dry-run", action="store_true", help="on the CPU at a tiny size (CI)")
    ap.add_argument("--force", action="store_true", help="run a banked stage again")
    ap.add_argument("--prepare", action="store_true",
                    help="only gsplat's compilation and the stages' scene builds (no OCR needed; nothing banked)")
    ap.add_argument("--date", type=_iso_date, default=None,
                    help="the round's date in its file names and rows, YYYY-MM-DD (default: today's)")
    ap.add_argument("--budget", type=float, default=480.0, help="seconds for the whole stage (default 480)")
    ap.add_argument("--runs", type=Path, default=None,
                    help="where runs train and resume (default OUT_DIR/runs; outside the repo when OUT_DIR is "
                         "docs/results/data/gpu)")
    args = ap.parse_args(argv)
    if args.stage == "list":
        print("\n".join(STAGES))
        return 0
    stages = [x for x in args.stage.split(",") if x]
    unknown = [x for x in stages if x not in STAGES]
    if unknown or not stages:
        ap.error(f"unknown stage {', '.join(unknown) or '(none)'}: choose from {', '.join(STAGES)} (or list)")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    if not args.dry_run:
        import torch

        if not torch.cuda.is_available():
            print("gpu_campaign: torch sees no CUDA device (use --dry-run to check the script on the CPU)",
                  file=sys.stderr)
            return 2
    t0, failed = time.monotonic(), False
    for stage in stages:
        done = banked(out, stage, args.dry_run)
        if done and not args.force and not args.prepare:
            print(f"{stage}: banked in {done}; skipped (--force to run it again)")
            continue
        left = args.budget - (time.monotonic() - t0)
        if left <= 0:
            print(f"{stage}: no time left in the budget; not started")
            failed = True
            continue
        s = Round(out, stage, args.dry_run, left, args.runs, prepare=args.prepare, date=args.date)
        STAGES[stage](s)
        bad = [r for r in s.rows if r["status"] != "ok"]
        failed |= bool(bad)
        print(f"{stage}: {len(s.rows) - len(bad)}/{len(s.rows)} steps ok in {time.monotonic() - s.t0:.0f} s; "
              f"{s.csv}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
