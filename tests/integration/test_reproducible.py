"""The same figures on every x86-64 CPU with AVX2, at any thread count.

A machine with other vector units is emulated on this one: numba compiles for a lower target when a
process sets NUMBA_CPU_NAME / NUMBA_CPU_FEATURES (here SSE4.2: 4-lane float vectors, no AVX, no FMA,
against the host's 8 or 16 lanes), and torch, MKL and oneDNN take their kernel set from environment
variables, which strings_bench pins to AVX2 (strings_bench/core/cpus.py). Short trainings of 3DGS and
STRinGS (densification on, SH degree 3, SSIM) run in fresh processes under each target and thread count,
and every bit of every parameter and loss is compared. MKL cannot be made to run another vendor's code here: it is
pinned to the one code branch it has on every vendor's CPU (COMPATIBLE), and Adam, the one MKL function a training
step called, no longer calls it (tested under MKL's other branches). A kernel that leaves an addition's order to the
compiler (fastmath `reassoc`: a vector sum with one partial sum per lane) gives other bits at another
vector width, and this test fails.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from strings_bench.core.cpus import PORTABLE_ISA, host_has_avx2  # noqa: E402

REPO = Path(__file__).resolve().parents[2]

BUILD_AND_TRAIN = textwrap.dedent("""
    import hashlib, json, sys
    import numpy as np
    import strings_bench  # first, as the command line does: it pins torch's kernel set
    import torch
    from dataclasses import replace
    from strings_bench.datasets.synthetic import build_scene, default_settings
    from strings_bench.datasets.synthetic.generate import read_meta
    from strings_bench.engine.trainer import Trainer
    from strings_bench.methods.registry import get_method
    from strings_bench.scene.scene import Scene

    def sha(data):
        return hashlib.sha256(data).hexdigest()

    room, room_settings, methods = sys.argv[1], json.loads(sys.argv[2]), json.loads(sys.argv[3])
    settings = replace(default_settings(room, "synthetic360-cpu"), **room_settings)
    folder = build_scene(room, settings, progress=False)  # a fresh cache: built here
    out = {"torch_cpu_capability": torch.backends.cpu.get_cpu_capability(),
           "scene files": {str(p.relative_to(folder)): sha(p.read_bytes()) for p in sorted(folder.rglob("*"))
                           if p.is_file() and p.name != "scene_meta.json"}}
    meta = read_meta(folder)  # its timings and the machine's core count aside
    meta["sfm_attempts"] = [{k: v for k, v in a.items() if not k.endswith("_s")} for a in meta["sfm_attempts"]]
    out["scene record"] = {k: v for k, v in meta.items() if k not in ("timings_s", "cpu_count")}
    scene = Scene.load(folder)
    for name, settings in methods.items():
        method = get_method(name).build(None, **settings)
        losses = []
        real = method.train_step
        method.train_step = lambda step: losses.append(real(step)) or losses[-1]
        for result in Trainer(method, scene, [240], device="cpu", progress=False).train():
            pass
        digest = {k: sha(v.detach().numpy().tobytes()) for k, v in method.model.params.items()}
        digest["losses"] = sha(np.asarray(losses, np.float64).tobytes())
        digest["gaussians"] = method.num_gaussians()
        out[name] = digest
    import numba
    out["threading_layer"] = numba.threading_layer()
    print("RESULT " + json.dumps(out))
""")
# The room: the default run's (synthetic360-cpu/storeroom) at 160x120 with 20 views, which SfM still triangulates
ROOM = ("storeroom", {"width": 160, "height": 120, "n_views": 20})
# 240 steps: densification from step 10, every 50 steps (the schedule's floor); STRinGS' phase 1 is 60 steps
SETTINGS = {"3dgs": dict(steps_scale=0.02, sh_degree=3),
            "strings": dict(steps_scale=0.02, sh_degree=3, mask_dilation_fraction=0.0, n_max=3)}
# The lower target: Nehalem's instruction set (SSE4.2), whatever the host has
SSE42 = {"NUMBA_CPU_NAME": "nehalem", "NUMBA_CPU_FEATURES": "+sse4.2"}
# numpy's own SIMD code paths for AVX-512 (numpy ignores those the CPU lacks)
NUMPY_AVX512 = "AVX512F AVX512CD AVX512_SKX AVX512_CLX AVX512_CNL AVX512_ICL AVX512_SPR"


def openblas_core_types() -> tuple[str, str, str]:
    """(the host's side, the other side, why) of the OpenBLAS core types the test compares: SkylakeX (AVX-512
    kernels) against Haswell (AVX2) on a CPU with AVX-512, the pair whose kernels round otherwise; elsewhere
    Haswell against Prescott (SSE3), as SkylakeX's kernels cannot run there."""
    from strings_bench.core.cpus import host_cpu_features

    if "+avx512f" in host_cpu_features().split(","):
        return "SkylakeX", "Haswell", "OpenBLAS' AVX-512 against its AVX2 kernels"
    return "Haswell", "Prescott", "no AVX-512 here: OpenBLAS' AVX2 against its SSE3 kernels, not SkylakeX against Haswell"


def _build_and_train(env: dict, tmp_path: Path, label: str, cores: set[int] | None = None) -> dict:
    dropped = ("NUMBA_THREADING_LAYER", "NPY_DISABLE_CPU_FEATURES", "MKL_ENABLE_INSTRUCTIONS")
    full = {k: v for k, v in os.environ.items() if k not in PORTABLE_ISA and k not in dropped
            and not k.startswith(("NUMBA_CPU", "OPENBLAS_"))}
    full.update(env)
    full["STRINGS_BENCH_CACHE"] = str(tmp_path / f"cache-{label}")  # fresh: the room is built in the process
    full["PYTHONPATH"] = os.pathsep.join([str(REPO), full.get("PYTHONPATH", "")])
    proc = subprocess.run([sys.executable, "-c", BUILD_AND_TRAIN, ROOM[0], json.dumps(ROOM[1]), json.dumps(SETTINGS)],
                          env=full, capture_output=True, text=True, timeout=1500, cwd=tmp_path,
                          preexec_fn=(lambda: os.sched_setaffinity(0, cores)) if cores else None)
    assert proc.returncode == 0, proc.stderr[-3000:]
    line = next(ln for ln in proc.stdout.splitlines() if ln.startswith("RESULT "))
    return json.loads(line[len("RESULT "):])


@pytest.mark.heavy
@pytest.mark.skipif(not host_has_avx2(), reason="the portable kernels are those of x86-64 CPUs with AVX2")
def test_scene_and_training_are_bit_identical_on_another_cpu(tmp_path):
    """Two fresh processes, each with a fresh cache, build the same small room and train 3DGS and STRinGS on it
    (densification on, SH degree 3, SSIM, STRinGS' two phases) as two CPUs would: numba's kernels for the host
    at 2 threads on its OpenMP layer against SSE4.2 on one core on its workqueue layer; OpenBLAS' kernels for
    AVX-512 against those for AVX2 (OPENBLAS_CORETYPE: nothing the scene build computes may reach BLAS); numpy
    with and without its AVX-512 code paths; MKL allowed AVX-512 and not (its code branch pinned, COMPATIBLE);
    torch on its pinned AVX2 kernels in both. Every byte of every scene file, the scene's record, and every bit
    of every trained parameter and loss must agree."""
    host_blas, other_blas, why = openblas_core_types()
    host = _build_and_train({"NUMBA_NUM_THREADS": "2", "OPENBLAS_CORETYPE": host_blas}, tmp_path, "host")
    other = _build_and_train({**SSE42, "NUMBA_NUM_THREADS": "1", "NUMBA_THREADING_LAYER": "workqueue",
                              "OPENBLAS_CORETYPE": other_blas, "NPY_DISABLE_CPU_FEATURES": NUMPY_AVX512,
                              "MKL_ENABLE_INSTRUCTIONS": "AVX2"}, tmp_path, "other",
                             cores={min(os.sched_getaffinity(0))})
    assert host["torch_cpu_capability"] == other["torch_cpu_capability"] == "AVX2"
    assert other["threading_layer"] == "workqueue"
    assert host["scene record"]["fallback"] is None, "SfM did not triangulate the room: the check would be weak"
    differ = sorted(k for k in set(host["scene files"]) | set(other["scene files"])
                    if host["scene files"].get(k) != other["scene files"].get(k))
    assert not differ, f"{len(differ)} scene files differ ({why}): {differ[:8]}"
    assert host["scene record"] == other["scene record"]
    for name in SETTINGS:
        assert host[name]["gaussians"] > 400, "densification did not run: the check would be weak"
        differ = [k for k in host[name] if host[name][k] != other[name][k]]
        assert not differ, f"{name}: {differ} differ between the two CPUs ({why})"


def test_portable_mode_pins_torch_mkl_and_onednn_to_avx2(tmp_path):
    """On any host: importing strings_bench sets the three libraries' variables (unless the user did), and
    torch then runs its AVX2 kernels even where the CPU has AVX-512; STRINGS_BENCH_NATIVE_ISA=1 leaves
    them alone."""
    probe = ("import os, json, strings_bench, torch; print(json.dumps({'cap': torch.backends.cpu.get_cpu_capability(),"
             " 'env': {k: os.environ.get(k) for k in " + repr(sorted(PORTABLE_ISA)) + "}}))")
    base = {k: v for k, v in os.environ.items() if k not in PORTABLE_ISA}
    base["PYTHONPATH"] = os.pathsep.join([str(REPO), base.get("PYTHONPATH", "")])

    def run(extra):
        proc = subprocess.run([sys.executable, "-c", probe], env={**base, **extra}, capture_output=True, text=True,
                              timeout=300, cwd=tmp_path)
        assert proc.returncode == 0, proc.stderr[-2000:]
        return json.loads(proc.stdout.strip().splitlines()[-1])

    portable = run({"STRINGS_BENCH_NATIVE_ISA": "0"})
    native = run({"STRINGS_BENCH_NATIVE_ISA": "1"})
    if not host_has_avx2():
        pytest.skip("not an x86-64 CPU with AVX2: the libraries choose their own kernels")
    assert portable["env"] == PORTABLE_ISA
    assert portable["cap"] == "AVX2"
    assert native["env"] == {k: None for k in PORTABLE_ISA}
    # a variable the user set wins
    assert run({"MKL_CBWR": "AVX2"})["env"]["MKL_CBWR"] == "AVX2"


ADAM = textwrap.dedent("""
    import hashlib, strings_bench, torch
    from strings_bench.engine.optim import GaussianAdam
    g = torch.Generator().manual_seed(0)
    p = torch.nn.Parameter(torch.randn(20000, 3, generator=g))
    opt = GaussianAdam({"means": p}, {"means": 1e-2})
    for it in range(5):
        p.grad = torch.randn(20000, 3, generator=g) * 10.0 ** (-it)
        opt.step()
    print("RESULT " + hashlib.sha256(p.detach().numpy().tobytes()).hexdigest())
""")


def test_adam_does_not_depend_on_mkls_code_branch(tmp_path):
    """Adam's square root is the correctly rounded one, not torch's CPU sqrt (MKL's vsSqrt, whose rounding follows
    MKL's code branch: on an Intel Xeon the AVX2 branch rounds correctly and COMPATIBLE does not, and an AMD CPU has
    a branch of its own): the same steps under three of MKL's branches give the same parameters."""
    base = {k: v for k, v in os.environ.items() if k not in PORTABLE_ISA}
    base["PYTHONPATH"] = os.pathsep.join([str(REPO), base.get("PYTHONPATH", "")])
    got = set()
    for branch in ("COMPATIBLE", "AVX2", "AUTO"):
        proc = subprocess.run([sys.executable, "-c", ADAM], env={**base, "MKL_CBWR": branch}, capture_output=True,
                              text=True, timeout=300, cwd=tmp_path)
        assert proc.returncode == 0, proc.stderr[-2000:]
        got.add(next(ln for ln in proc.stdout.splitlines() if ln.startswith("RESULT ")))
    assert len(got) == 1, got


def test_no_cpu_kernel_leaves_the_order_of_additions_to_the_compiler():
    """The numba kernels on the training path compile without fastmath reassociation or contraction (the
    flags that let LLVM reorder or fuse float operations per target)."""
    import strings_bench.raster.cpu_kernels_f32 as K32

    assert not ({"reassoc", "contract", "fast"} & set(K32.FASTMATH))
    for fn in (K32.forward, K32.backward, K32.pack):
        flags = fn.targetoptions.get("fastmath")
        flags = set(flags) if isinstance(flags, (set, frozenset, dict, list, tuple)) else ({"fast"} if flags else set())
        assert not ({"reassoc", "contract", "fast"} & flags), (fn.__name__, flags)


def test_wide_vectors_only_on_avx512_and_never_over_a_users_target():
    """widen_numba_vectors: on a CPU with AVX-512 the host's features plus `-prefer-256-bit`; nothing on a CPU
    without it, and nothing where NUMBA_CPU_NAME or NUMBA_CPU_FEATURES is set (a user's target, or a test
    emulating another CPU, wins)."""
    from strings_bench.core.cpus import WIDE_VECTORS, widen_numba_vectors

    env = {}
    assert widen_numba_vectors(env, "+avx2,+avx512f,-amx-tile") == "+avx2,+avx512f,-amx-tile," + WIDE_VECTORS
    assert env == {"NUMBA_CPU_FEATURES": "+avx2,+avx512f,-amx-tile,-prefer-256-bit"}
    for features in ("+avx2,+fma,-avx512f", "+avx2,+avx512fp16", ""):
        env = {}
        assert widen_numba_vectors(env, features) is None and env == {}
    for key in ("NUMBA_CPU_NAME", "NUMBA_CPU_FEATURES"):
        env = {key: "haswell"}
        assert widen_numba_vectors(env, "+avx2,+avx512f") is None and env == {key: "haswell"}


WIDE_PROBE = textwrap.dedent("""
    import strings_bench  # first, as the command line does: it turns LLVM's 256-bit preference off
    import numpy as np
    from numba import njit
    from strings_bench.core.cpus import isa_record

    @njit
    def scale_add(a, x, y):  # a loop of the test's own, not the one the record compiles
        for i in range(x.shape[0]):
            y[i] = y[i] * a + x[i]

    x = np.ones(4096, np.float32)
    scale_add(np.float32(2.0), x, x.copy())
    asm = "".join(scale_add.inspect_asm().values())
    widest = 512 if "zmm" in asm else 256 if "ymm" in asm else 128
    print("RESULT", widest, isa_record()["numba_vector_bits"])
""")


def test_the_recorded_numba_vector_width_is_the_width_compiled(tmp_path):
    """A run records the vector width its numba kernels were compiled to (`numba_vector_bits`), read from
    what numba compiled in that process: it equals the widest register in a loop the test compiles itself,
    whatever the CPU's tuning. On a CPU with AVX-512, importing strings_bench first compiles for 512-bit
    (zmm) registers; a target without AVX-512 (NUMBA_CPU_NAME and NUMBA_CPU_FEATURES) compiles for 256 bits, SSE4.2
    for 128. The bits are the same at any width: the training test above compares targets."""
    from strings_bench.core.cpus import host_cpu_features

    if "+avx2" not in host_cpu_features().split(","):
        pytest.skip("not an x86-64 CPU with AVX2")
    base = {k: v for k, v in os.environ.items() if not k.startswith("NUMBA_CPU")}
    base["PYTHONPATH"] = os.pathsep.join([str(REPO), base.get("PYTHONPATH", "")])

    def probe(extra):
        proc = subprocess.run([sys.executable, "-c", WIDE_PROBE], env={**base, **extra}, capture_output=True,
                              text=True, timeout=300, cwd=tmp_path)
        assert proc.returncode == 0, proc.stderr[-2000:]
        compiled, recorded = next(ln for ln in proc.stdout.splitlines() if ln.startswith("RESULT ")).split()[1:]
        return int(compiled), int(recorded)

    avx512 = "+avx512f" in host_cpu_features().split(",")
    assert probe({}) == ((512, 512) if avx512 else (256, 256))
    # the host's own features set by hand: LLVM's tuning for this CPU decides, and the record follows it
    host = ",".join(f for f in host_cpu_features().split(",") if f != "-prefer-256-bit")
    compiled, recorded = probe({"NUMBA_CPU_FEATURES": host})
    assert compiled == recorded and compiled in ((256, 512) if avx512 else (256,))
    assert probe({"NUMBA_CPU_NAME": "haswell", "NUMBA_CPU_FEATURES": "+avx2,+fma"}) == (256, 256)
    assert probe(SSE42) == (128, 128)


def test_numba_runs_on_its_openmp_threads_unless_the_user_chooses():
    """strings_bench.raster selects numba's OpenMP layer where its pool loads (the workqueue layer launched a
    kernel 30-100x slower on a 2-core Xeon), its threads passive (spinning ones made a step 2.8x slower beside
    another training); a user's NUMBA_THREADING_LAYER, OMP_WAIT_POLICY or GOMP_SPINCOUNT wins."""
    code = ("import strings_bench.raster, numba, numpy as np\n"
            "from strings_bench.engine.optim_kernels import _total_f32\n"
            "_total_f32(np.ones(10, np.float32))\n"
            "import os\n"
            "print(os.environ.get('OMP_WAIT_POLICY'), numba.threading_layer())")
    base = {k: v for k, v in os.environ.items() if k not in ("NUMBA_THREADING_LAYER", "OMP_WAIT_POLICY", "GOMP_SPINCOUNT")}
    base["PYTHONPATH"] = os.pathsep.join([str(REPO), base.get("PYTHONPATH", "")])

    def layer(extra):
        proc = subprocess.run([sys.executable, "-c", code], env={**base, **extra}, capture_output=True, text=True,
                              timeout=300)
        assert proc.returncode == 0, proc.stderr[-2000:]
        return " ".join(proc.stdout.split()[-2:])

    try:
        import numba.np.ufunc.omppool  # noqa: F401
    except (ImportError, OSError):
        pytest.skip("numba's OpenMP pool cannot load here (no libgomp)")
    assert layer({}) == "passive omp"
    assert layer({"GOMP_SPINCOUNT": "300000"}) == "None omp"  # the user's libgomp setting: nothing added
    # the user's layer for numba: OpenMP threads (torch's) still wait passively
    assert layer({"NUMBA_THREADING_LAYER": "workqueue"}) == "passive workqueue"


def test_openmp_waits_are_passive_before_torch_loads_its_libgomp():
    """libgomp reads OMP_WAIT_POLICY once, when it loads, and torch loads its own at import: the package sets the
    variable before anything of it imports torch (spinning torch threads made a training beside another test process
    24x slower on a 2-core Xeon: strings_bench/core/cpus.py, passive_omp_waits)."""
    code = ("import sys, os\n"
            "import strings_bench\n"
            "print('torch' in sys.modules, os.environ.get('OMP_WAIT_POLICY'))\n"
            "import strings_bench.cli, strings_bench.bench.runner, strings_bench.raster\n"
            "print('torch' in sys.modules, os.environ.get('OMP_WAIT_POLICY'))")
    base = {k: v for k, v in os.environ.items() if k not in ("OMP_WAIT_POLICY", "GOMP_SPINCOUNT")}
    base["PYTHONPATH"] = os.pathsep.join([str(REPO), base.get("PYTHONPATH", "")])

    def run(extra):
        proc = subprocess.run([sys.executable, "-c", code], env={**base, **extra}, capture_output=True, text=True,
                              timeout=300)
        assert proc.returncode == 0, proc.stderr[-2000:]
        return proc.stdout.split()

    assert run({}) == ["False", "passive", "True", "passive"]  # set by the package's import, torch not loaded yet
    assert run({"OMP_WAIT_POLICY": "active"}) == ["False", "active", "True", "active"]  # the user's choice wins


@pytest.mark.slow
@pytest.mark.skipif(not host_has_avx2(), reason="the portable kernels are those of x86-64 CPUs with AVX2")
def test_prepare_gives_the_same_scene_under_another_openblas_core_type(tmp_path):
    """`strings-bench prepare` on real photographs (bundler_et: 9 photos, SfM from scratch, OCR masks) at one thread,
    in fresh processes under two OpenBLAS core types (pycolmap links its own OpenBLAS, which the variable steers
    too): the same content hash, part by part. About a minute each on 2 idle cores."""
    from strings_bench.datasets.captures import DEFAULT_DATA_ROOT
    from strings_bench.scene.content_hash import scene_content_hash

    photos = DEFAULT_DATA_ROOT / "bundler_et"
    if not photos.is_dir():
        pytest.skip(f"no photographs at {photos}")
    host_blas, other_blas, why = openblas_core_types()
    hashes = {}
    for core_type in (host_blas, other_blas):
        env = {k: v for k, v in os.environ.items() if not k.startswith("OPENBLAS_")}
        env.update(OPENBLAS_CORETYPE=core_type, STRINGS_BENCH_CACHE=str(tmp_path / f"cache-{core_type}"),
                   PYTHONPATH=os.pathsep.join([str(REPO), env.get("PYTHONPATH", "")]))
        out = tmp_path / core_type / "scene"
        proc = subprocess.run([sys.executable, "-m", "strings_bench", "prepare", str(photos), "--name", f"et-{core_type}",
                               "--out", str(out), "--threads", "1"], env=env, capture_output=True, text=True,
                              timeout=1800, cwd=tmp_path)
        assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
        hashes[core_type] = scene_content_hash(out)
    assert hashes[host_blas] == hashes[other_blas], f"{why}: {hashes}"


def test_passive_omp_waits_leaves_the_users_settings():
    from strings_bench.core.cpus import passive_omp_waits

    env = {}
    assert passive_omp_waits(env) and env == {"OMP_WAIT_POLICY": "passive"}
    for users in ({"OMP_WAIT_POLICY": "active"}, {"GOMP_SPINCOUNT": "300000"}):
        env = dict(users)
        assert not passive_omp_waits(env) and env == users
