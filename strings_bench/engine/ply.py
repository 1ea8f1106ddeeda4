"""Gaussian models as PLY files in the standard 3DGS layout, so splat viewers open our models and
models trained elsewhere can be evaluated.

Binary little-endian, one `vertex` element, float32 properties in this order:
x y z nx ny nz f_dc_0..2 f_rest_0..(3K-1) opacity scale_0..2 rot_0..3
with opacity as a logit, scales as logs, rotations as wxyz quaternions (unnormalised allowed), and
f_rest channel-major as 3DGS writes it: f_rest index = c * K + k for channel c, coefficient k
(K = 15 for degree 3). nx..nz are written as zeros (3DGS does the same).

Reading accepts float or double properties in any order and ignores unknown ones (some tools add
extra fields); `extras=True` writes/reads model.extras as additional float properties named
`extra_<name>_<j>`, which standard viewers ignore.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import torch

from strings_bench.core.errors import StringsBenchError
from strings_bench.engine.gaussians import GaussianModel, num_sh_rest
from strings_bench.core.io import atomic_write

_PLY_TYPES = {"char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "i2", "int16": "i2",
              "ushort": "u2", "uint16": "u2", "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
              "float": "f4", "float32": "f4", "double": "f8", "float64": "f8"}


def _columns(model: GaussianModel, extras: bool) -> tuple[list[str], np.ndarray]:
    p = {k: v.detach().cpu().to(torch.float32).numpy() for k, v in model.params.items()}
    n = len(model)
    k_rest = p["shN"].shape[1]
    rest = p["shN"].transpose(0, 2, 1).reshape(n, 3 * k_rest)  # channel-major: c * K + k
    names = ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
    names += [f"f_rest_{i}" for i in range(3 * k_rest)]
    names += ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
    cols = [p["means"], np.zeros((n, 3), np.float32), p["sh0"].reshape(n, 3), rest,
            p["opacity_logits"].reshape(n, 1), p["log_scales"], p["quats"]]
    if extras:
        for name, v in sorted(model.extras.items()):
            if not re.fullmatch(r"[A-Za-z0-9_]+", name):
                raise StringsBenchError(f"extra {name!r} cannot be a PLY property name")
            a = v.detach().cpu().numpy().reshape(n, -1).astype(np.float32)
            names += [f"extra_{name}_{j}" for j in range(a.shape[1])]
            cols.append(a)
    return names, np.concatenate(cols, axis=1).astype("<f4")


def write_ply(path: str | Path, model: GaussianModel, extras: bool = False) -> Path:
    """Write `model` atomically."""
    names, data = _columns(model, extras)
    header = ["ply", "format binary_little_endian 1.0", f"element vertex {len(model)}"]
    header += [f"property float {n}" for n in names]
    header.append("end_header")
    blob = ("\n".join(header) + "\n").encode("ascii") + np.ascontiguousarray(data).tobytes()
    return atomic_write(path, lambda p: p.write_bytes(blob))


def _parse_header(path: Path, raw: bytes) -> tuple[int, int, np.dtype]:
    end = raw.find(b"end_header")
    if not raw.startswith(b"ply") or end < 0:
        raise StringsBenchError(f"{path} is not a PLY file (no 'ply' magic or end_header)",
                                hint="pass a Gaussian-splat PLY as written by 3DGS or `strings-bench`")
    nl = raw.find(b"\n", end)
    body_start = nl + 1
    lines = raw[:end].decode("ascii", errors="replace").splitlines()
    fmt = None
    elements: list[tuple[str, int, list[tuple[str, str]]]] = []
    for line in lines:
        tok = line.split()
        if not tok:
            continue
        if tok[0] == "format":
            fmt = tok[1] if len(tok) > 1 else None
        elif tok[0] == "element":
            if len(tok) != 3 or not tok[2].isdigit():
                raise StringsBenchError(f"{path}: PLY header line {line!r} is not 'element NAME COUNT' with a count >= 0",
                                        hint="the header is damaged; re-export the model")
            elements.append((tok[1], int(tok[2]), []))
        elif tok[0] == "property":
            if not elements:
                raise StringsBenchError(f"{path}: property before any element in the PLY header")
            if len(tok) < 3:
                raise StringsBenchError(f"{path}: PLY header line {line!r} is not 'property TYPE NAME'",
                                        hint="the header is damaged; re-export the model")
            if tok[1] == "list":
                raise StringsBenchError(f"{path}: list property {tok[-1]} in element {elements[-1][0]}",
                                        hint="Gaussian-splat PLYs have only scalar vertex properties")
            if tok[1] not in _PLY_TYPES:
                raise StringsBenchError(f"{path}: unknown PLY property type {tok[1]}")
            elements[-1][2].append((tok[2], _PLY_TYPES[tok[1]]))
    if fmt != "binary_little_endian":
        raise StringsBenchError(f"{path} is PLY format {fmt!r}; only binary_little_endian is read",
                                hint="convert it, e.g. with plyfile or meshlab, to binary little-endian")
    if not elements or elements[0][0] != "vertex":
        raise StringsBenchError(f"{path} has no vertex element first in its header")
    _, count, props = elements[0]
    names = [n for n, _ in props]
    if len(set(names)) != len(names):
        raise StringsBenchError(f"{path}: the PLY header repeats a vertex property name")
    return body_start, count, np.dtype([(n, "<" + t) for n, t in props])


def read_ply(path: str | Path, device: str = "cpu", extras: bool = True) -> GaussianModel:
    """Read a 3DGS-layout PLY. Properties `extra_<name>_<j>` become model.extras[name] (float32)."""
    path = Path(path)
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise StringsBenchError(f"cannot read {path}: {exc}", hint="check the path") from exc
    start, n, dtype = _parse_header(path, raw)
    if len(raw) - start < n * dtype.itemsize:
        raise StringsBenchError(f"{path} is truncated: header says {n} vertices of {dtype.itemsize} bytes, "
                                f"file has {len(raw) - start} bytes of data", hint="the file is incomplete; re-export it")
    arr = np.frombuffer(raw, dtype=dtype, count=n, offset=start)
    fields = set(dtype.names)
    need = ["x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "opacity", "scale_0", "scale_1", "scale_2",
            "rot_0", "rot_1", "rot_2", "rot_3"]
    missing = [f for f in need if f not in fields]
    if missing:
        raise StringsBenchError(f"{path} lacks Gaussian-splat properties {missing}",
                                hint="this looks like a plain point cloud, not a 3DGS model PLY")
    n_rest = sum(1 for f in fields if re.fullmatch(r"f_rest_\d+", f))
    k_rest = n_rest // 3
    degree = int(round(np.sqrt(k_rest + 1))) - 1
    if n_rest % 3 or num_sh_rest(degree) != k_rest:
        raise StringsBenchError(f"{path} has {n_rest} f_rest properties; expected 3 x ((d+1)^2 - 1) (0, 9, 24 or 45)")

    def cols(names):
        return np.stack([arr[c].astype(np.float32) for c in names], axis=1) if names else np.zeros((n, 0), np.float32)

    for label, names in (("positions", ["x", "y", "z"]), ("colours", ["f_dc_0", "f_dc_1", "f_dc_2"]),
                         ("opacities", ["opacity"]), ("scales", ["scale_0", "scale_1", "scale_2"]),
                         ("rotations", ["rot_0", "rot_1", "rot_2", "rot_3"]),
                         ("SH coefficients", [f"f_rest_{i}" for i in range(n_rest)])):
        values = cols(names)
        bad = ~np.all(np.isfinite(values), axis=1)
        if bad.any():
            raise StringsBenchError(f"{path}: {int(bad.sum())} of {n} Gaussians have NaN or Inf {label} "
                                    f"(first: vertex {int(np.argmax(bad))})",
                                    hint="the model diverged or the file is damaged; re-export or retrain it")
    zero_rot = np.linalg.norm(cols(["rot_0", "rot_1", "rot_2", "rot_3"]), axis=1) == 0
    if zero_rot.any():
        raise StringsBenchError(f"{path}: {int(zero_rot.sum())} Gaussians have a zero rotation quaternion "
                                f"(first: vertex {int(np.argmax(zero_rot))})", hint="the file is damaged; re-export it")

    t = lambda a: torch.from_numpy(np.ascontiguousarray(a)).to(device)  # noqa: E731
    rest = cols([f"f_rest_{i}" for i in range(n_rest)]).reshape(n, 3, k_rest).transpose(0, 2, 1)
    params = {
        "means": t(cols(["x", "y", "z"])),
        "quats": t(cols(["rot_0", "rot_1", "rot_2", "rot_3"])),
        "log_scales": t(cols(["scale_0", "scale_1", "scale_2"])),
        "opacity_logits": t(arr["opacity"].astype(np.float32)),
        "sh0": t(cols(["f_dc_0", "f_dc_1", "f_dc_2"]).reshape(n, 1, 3)),
        "shN": t(rest),
    }
    ex = {}
    if extras:
        groups: dict[str, list[tuple[int, str]]] = {}
        for f in dtype.names:
            m = re.fullmatch(r"extra_(\w+)_(\d+)", f)
            if m:
                groups.setdefault(m.group(1), []).append((int(m.group(2)), f))
        for name, items in groups.items():
            a = cols([f for _, f in sorted(items)])
            ex[name] = t(a[:, 0] if a.shape[1] == 1 else a)
    return GaussianModel(params, extras=ex, sh_degree=degree)
