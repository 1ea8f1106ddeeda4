"""How many cores this process may use."""

from __future__ import annotations

import os


def usable_cores() -> int:
    """Cores this process may run on (its CPU affinity, e.g. a container's or Slurm's share)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not Linux
        return max(1, os.cpu_count() or 1)


# --- The instruction set of the CPU kernels -------------------------------------------------------------
# torch, MKL and oneDNN each choose their CPU kernels by the host's instruction set (torch: DEFAULT, AVX2 or
# AVX512), and kernels of different vector widths add in different orders: the same training gave other
# bits on an AVX-512 CPU than on an AVX2 one, and densification's thresholds turned those bits into
# other models. torch and oneDNN are pinned to their AVX2 kernels, which run on every x86-64 CPU that has AVX2
# (Intel since 2013, AMD since 2015). MKL (torch's CPU exp, log and sqrt, and its BLAS) is pinned to its COMPATIBLE
# code branch: MKL's other branches exist on Intel CPUs only, and elsewhere MKL picks its own (oneMKL developer
# guide, "Specifying Code Branches": settings other than AUTO or COMPATIBLE are available only for Intel
# processors), so an AVX2 pin gave an Intel and an AMD CPU different square roots (docs/reproducibility.md). Each
# library reads its variable at its first kernel call, so setting them at the package's import is early enough even
# after `import torch`. The numba kernels need no pin: none of them leaves an operation's order to the
# compiler (no fastmath reassociation or contraction; vector sums kept in fixed lanes), so they give the
# same bits at any vector width (tests/integration/test_reproducible.py runs a training under lower targets).
PORTABLE_ISA = {"ATEN_CPU_CAPABILITY": "avx2", "MKL_CBWR": "COMPATIBLE", "ONEDNN_MAX_CPU_ISA": "AVX2"}
# Set to 1 to let torch, MKL and oneDNN use the host's widest kernels (e.g. AVX-512): faster there, but a
# run's figures then differ in the last digits from those of other machines.
NATIVE_ISA_ENV = "STRINGS_BENCH_NATIVE_ISA"


def host_has_avx2() -> bool:
    """True on an x86-64 CPU with AVX2 and FMA (read from /proc/cpuinfo, else from LLVM's host features)."""
    import platform

    if platform.machine().lower() not in ("x86_64", "amd64"):
        return False
    try:
        with open("/proc/cpuinfo") as fh:
            for line in fh:
                if line.startswith("flags"):
                    flags = set(line.split(":", 1)[1].split())
                    return {"avx2", "fma"} <= flags
    except OSError:
        pass
    features = host_cpu_features().split(",")  # '' when LLVM cannot tell: leave the libraries to choose
    return "+avx2" in features and "+fma" in features


def isa_mode(environ=None) -> str:
    """'portable' (torch, MKL and oneDNN on AVX2 kernels: the same figures on every AVX2 CPU), 'native'
    (STRINGS_BENCH_NATIVE_ISA=1) or 'host' (not an x86-64 CPU with AVX2: the libraries choose)."""
    environ = os.environ if environ is None else environ
    if environ.get(NATIVE_ISA_ENV, "0") not in ("", "0"):
        return "native"
    return "portable" if host_has_avx2() else "host"


def pin_portable_isa(environ=None) -> dict:
    """In the portable mode, set PORTABLE_ISA's variables that the user has not set; returns those set.
    A variable the user set wins (and `isa_record` shows it)."""
    environ = os.environ if environ is None else environ
    if isa_mode(environ) != "portable":
        return {}
    done = {}
    for key, value in PORTABLE_ISA.items():
        if key not in environ:
            environ[key] = value
            done[key] = value
    return done


# --- The vector width of the numba kernels ----------------------------------------------------------------
# LLVM tunes code for Intel's AVX-512 CPUs (skylake-avx512 and later) to prefer 256-bit vectors (its subtarget
# feature `prefer-256-bit`), so numba's float32 kernels ran 8 lanes per instruction on 16-lane hardware: the
# blends' pixel loops, whose blocks are 16 lanes, took two passes of every instruction. Without that preference
# they run in one, with the same bits (no kernel leaves an operation's order to the compiler, see above): on a
# 2-core Intel Xeon with AVX-512 the forward blend at 336k Gaussians took 37 instead of 67 ms and the
# backward 68 instead of 110 (docs/results/engine-speed.md, "512-bit vectors on AVX-512 CPUs").
WIDE_VECTORS = "-prefer-256-bit"


def passive_omp_waits(environ=None) -> bool:
    """OMP_WAIT_POLICY=passive unless the user has set it or GOMP_SPINCOUNT: OpenMP threads sleep as soon as their
    work ends rather than spin for cores another process needs. libgomp reads the variable once, when it loads, and
    torch loads its own copy (torch/lib/libgomp.so.1) at import, numba's OpenMP pool another one later: the package
    sets it before anything of it imports torch. Measured on a 2-core Xeon, two test processes at once (a 350-step
    training of tests/engine/test_engine.py beside tests/bench/test_budget.py): 26.1 s with the variable set after
    torch's import, 1.1 s with it set before, 0.65 s alone. Returns True when it was set here."""
    environ = os.environ if environ is None else environ
    if "OMP_WAIT_POLICY" in environ or "GOMP_SPINCOUNT" in environ:
        return False
    environ["OMP_WAIT_POLICY"] = "passive"
    return True


def host_cpu_features() -> str:
    """LLVM's feature string of this CPU ('+avx2,+avx512f,...'), or '' when LLVM cannot tell."""
    try:
        from llvmlite import binding as llvm

        return llvm.get_host_cpu_features().flatten()
    except Exception:  # noqa: BLE001 - no features: leave numba to its own choice
        return ""


def widen_numba_vectors(environ=None, host_features: str | None = None) -> str | None:
    """On a CPU with AVX-512, compile numba's kernels for 512-bit vectors: NUMBA_CPU_FEATURES becomes the host's
    features plus WIDE_VECTORS. Nothing is set when the CPU has no AVX-512 or when the user (or a test emulating
    another CPU) has set NUMBA_CPU_NAME or NUMBA_CPU_FEATURES. Returns the features set, else None. Numba reads
    the variable when it builds its CPU target (at the first kernel it compiles or loads), so a process that has
    imported numba but compiled nothing yet gets the setting too."""
    environ = os.environ if environ is None else environ
    if "NUMBA_CPU_NAME" in environ or "NUMBA_CPU_FEATURES" in environ:
        return None
    features = host_cpu_features() if host_features is None else host_features
    if "+avx512f" not in features.split(","):
        return None
    value = features + "," + WIDE_VECTORS
    environ["NUMBA_CPU_FEATURES"] = value
    if environ is os.environ:
        import sys

        config = sys.modules.get("numba.core.config")
        if config is not None and getattr(config, "CPU_FEATURES", None) is None:
            config.CPU_FEATURES = value
    return value


_VECTOR_REGISTERS = (("zmm", 512), ("ymm", 256))  # x86-64's 512- and 256-bit register names in assembly


def numba_vector_width() -> int:
    """Bits per vector of the numba kernels: the widest vector register in the machine code numba compiles for a
    float32 loop in this process (zmm 512, ymm 256, else 128), so the record is what was compiled, whatever
    the features, the CPU's tuning or a setting that came too late. Compiled once per process (~0.1 s)."""
    global _vector_bits
    if _vector_bits is None:
        import numpy as np
        from numba import njit

        @njit(nogil=True)
        def _axpy(a, x, y):  # the shape of the blends' pixel loops: a float32 multiply-add over an array
            for i in range(x.shape[0]):
                y[i] = a * x[i] + y[i]

        x = np.ones(64, np.float32)
        _axpy(np.float32(2.0), x, x.copy())
        asm = "".join(_axpy.inspect_asm().values())
        _vector_bits = next((bits for name, bits in _VECTOR_REGISTERS if name in asm), 128)
    return _vector_bits


_vector_bits: int | None = None


def isa_record() -> dict:
    """What a run records of the CPU kernels: the mode, torch's kernel set in use, the variables of
    PORTABLE_ISA as the process has them, the CPU's model name and the numba kernels' vector width."""
    import platform

    import torch

    out = {"isa_mode": isa_mode(), "torch_cpu_capability": torch.backends.cpu.get_cpu_capability()}
    out.update({key.lower(): os.environ.get(key) for key in PORTABLE_ISA})
    model = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as fh:
            model = next((ln.split(":", 1)[1].strip() for ln in fh if ln.startswith("model name")), model)
    except OSError:
        pass
    out["cpu_model"] = model
    out["numba_vector_bits"] = numba_vector_width()
    return out


def portable_isa_in_effect() -> bool:
    """False when the portable mode is asked for but torch already runs other kernels (torch computed on
    the CPU before strings_bench was imported, so its variable came too late)."""
    if isa_mode() != "portable":
        return True
    import torch

    return torch.backends.cpu.get_cpu_capability() == "AVX2"
