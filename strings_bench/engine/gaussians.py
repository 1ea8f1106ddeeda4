"""The Gaussian model: trainable parameters, their activations, per-Gaussian extras, rendering.

Parameters are stored raw (as 3DGS stores them) and activated on use:

    means           (N, 3)      world positions
    quats           (N, 4)      rotations, wxyz, any norm (normalised on use)
    log_scales      (N, 3)      scales = exp(log_scales)
    opacity_logits  (N,)        opacity = sigmoid(opacity_logits)
    sh0             (N, 1, 3)   degree-0 spherical-harmonic colour coefficients
    shN             (N, K, 3)   higher orders, K = (degree + 1)^2 - 1 (15 for degree 3; 0 for degree 0)

`extras` holds per-Gaussian non-trainable data (e.g. "is_text" bool) with the same first dimension;
the densification ops in `strategies/ops.py` keep it in step with the parameters.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Mapping

import numpy as np
import torch

from strings_bench.core.errors import StringsBenchError
from strings_bench.raster.projection import quat_to_rotmat  # noqa: F401  (one definition; re-exported for strategies)
from strings_bench.raster.sh import SH_C0  # one constant: sh0 decodes with the basis the renderer uses

if TYPE_CHECKING:
    from strings_bench.scene.camera import Camera

PARAM_NAMES = ("means", "quats", "log_scales", "opacity_logits", "sh0", "shN")


def num_sh_rest(degree: int) -> int:
    return (degree + 1) ** 2 - 1


def rgb_to_sh0(rgb: torch.Tensor) -> torch.Tensor:
    """Colour in [0, 1] -> degree-0 SH coefficient (the renderer adds 0.5 back)."""
    return (rgb - 0.5) / SH_C0


def sh0_to_rgb(sh0: torch.Tensor) -> torch.Tensor:
    return sh0 * SH_C0 + 0.5


def logit(p: float | torch.Tensor) -> torch.Tensor:
    # a Python number becomes a CPU tensor (never the default device: see docs/guide/gpu.md)
    p = torch.as_tensor(p, dtype=torch.float32, device=p.device if torch.is_tensor(p) else "cpu")
    return torch.log(p / (1 - p))


def knn_mean_sq_dist(xyz: np.ndarray, k: int = 3) -> np.ndarray:
    """Mean squared distance of each point to its k nearest other points (3DGS init scale)."""
    from scipy.spatial import cKDTree

    xyz = np.asarray(xyz, dtype=np.float64)
    n = len(xyz)
    if n < 2:
        return np.ones(n)
    kk = min(k, n - 1)
    dist, _ = cKDTree(xyz).query(xyz, k=kk + 1)  # the first neighbour is the point itself
    d2 = np.asarray(dist, dtype=np.float64).reshape(n, kk + 1)[:, 1:] ** 2
    return d2.mean(axis=1)


class GaussianModel:
    """A set of N 3D Gaussians: raw trainable parameters, per-Gaussian extras, rendering.

    `params` (dict of `torch.nn.Parameter`, float32, all on one device) holds the raw values, as
    3DGS stores them and as `rasterize` takes them; the properties give the activated ones:

        name            shape       meaning (activation: property)
        means           (N, 3)      centres, world units (identity: `means`)
        quats           (N, 4)      rotations, wxyz, any norm (normalised: `quats`)
        log_scales      (N, 3)      log standard deviations along the own axes, world units (exp: `scales`)
        opacity_logits  (N,)        opacity (sigmoid: `opacities`)
        sh0             (N, 1, 3)   degree-0 SH colour; colour = SH_C0 * sh0 + 0.5 (`sh0_to_rgb`)
        shN             (N, K, 3)   higher SH orders, K = (sh_degree + 1)^2 - 1 (15 for degree 3, 0 for 0)

    `sh` is sh0 and shN joined, (N, K + 1, 3). `extras` (dict of plain tensors, first dimension N,
    not optimised) carries per-Gaussian tags such as STRinGS' "is_text" (bool) or Mip-Splatting's
    "mip_filter3d"; every op of `strategies/ops.py` keeps them aligned (new rows copy their parent).

    Args:
        params: mapping with the six names above (tensors are copied into new Parameters unless
            they already are Parameters).
        extras: optional mapping name -> tensor with first dimension N.
        sh_degree: the active SH degree; None = the degree shN holds.

    Raises:
        StringsBenchError: a missing parameter, a shape that disagrees with N, shN's K not
            (d + 1)^2 - 1 for any d, or an extra with another number of rows.

    Example:
        >>> import torch
        >>> from strings_bench.engine.gaussians import GaussianModel
        >>> n = 4
        >>> model = GaussianModel({"means": torch.zeros(n, 3), "quats": torch.tensor([[2.0, 0, 0, 0]]).repeat(n, 1),
        ...                        "log_scales": torch.zeros(n, 3), "opacity_logits": torch.zeros(n),
        ...                        "sh0": torch.zeros(n, 1, 3), "shN": torch.zeros(n, 3, 3)},
        ...                       extras={"is_text": torch.tensor([True, False, False, True])})
        >>> len(model), model.sh_degree, model.quats[0].tolist(), model.opacities[0].item()
        (4, 1, [1.0, 0.0, 0.0, 0.0], 0.5)
        >>> model.subset(model.extras["is_text"]).extras["is_text"].tolist()
        [True, True]
    """

    def __init__(self, params: Mapping[str, torch.Tensor], extras: Mapping[str, torch.Tensor] | None = None,
                 sh_degree: int | None = None):
        missing = [k for k in PARAM_NAMES if k not in params]
        if missing:
            raise StringsBenchError(f"Gaussian model is missing parameters {missing}",
                                    hint=f"a model needs {', '.join(PARAM_NAMES)}")
        self.params: dict[str, torch.nn.Parameter] = {
            k: v if isinstance(v, torch.nn.Parameter) else torch.nn.Parameter(v.detach().clone())
            for k, v in params.items()
        }
        k_rest = self.params["shN"].shape[1]
        degree = int(round(np.sqrt(k_rest + 1))) - 1
        if num_sh_rest(degree) != k_rest:
            raise StringsBenchError(f"shN has {k_rest} coefficients per channel, not (d+1)^2-1 for any degree d")
        self.sh_degree = degree if sh_degree is None else int(sh_degree)
        self.extras: dict[str, torch.Tensor] = dict(extras or {})
        self.check()

    # ---- construction -------------------------------------------------------------------
    @classmethod
    def from_points(cls, xyz, rgb, sh_degree: int = 3, init_opacity: float = 0.1,
                    extras: Mapping[str, torch.Tensor] | None = None, device: str | torch.device = "cpu",
                    min_sq_dist: float = 1e-7) -> "GaussianModel":
        """3DGS initialisation from SfM points: one Gaussian per point.

        Colour from the point, opacity `init_opacity`, isotropic scale sqrt(max(mean squared
        distance to the 3 nearest neighbours, min_sq_dist)), identity rotation, higher SH orders
        zero. 3DGS clamps the squared distance at 1e-7 before the square root (so the smallest
        scale is sqrt(1e-7) ~ 3.16e-4).

        Args:
            xyz: (P, 3) array-like, point positions in world units.
            rgb: (P, 3) colours: uint8 in 0..255, or floats in [0, 1].
            sh_degree: highest SH degree (0..3); shN gets (sh_degree + 1)^2 - 1 zero coefficients.
            init_opacity: opacity of every Gaussian, in (0, 1) (stored as its logit).
            extras: optional per-point extras (first dimension P).
            device: torch device of the parameters.
            min_sq_dist: lower clamp of the squared neighbour distance (world units squared).

        Returns:
            GaussianModel with P Gaussians (float32).

        Raises:
            StringsBenchError: colours of another shape than the positions, or no points.

        Example:
            >>> import numpy as np
            >>> from strings_bench.engine.gaussians import GaussianModel
            >>> xyz = np.array([[0.0, 0, 0], [1.0, 0, 0], [0, 1.0, 0], [1.0, 1.0, 0]])
            >>> model = GaussianModel.from_points(xyz, np.full((4, 3), 255, np.uint8), sh_degree=3)
            >>> {k: tuple(v.shape) for k, v in model.params.items()}
            {'means': (4, 3), 'quats': (4, 4), 'log_scales': (4, 3), 'opacity_logits': (4,), 'sh0': (4, 1, 3), 'shN': (4, 15, 3)}
            >>> round(model.opacities[0].item(), 6)
            0.1
            >>> [round(x, 4) for x in model.scales[0].tolist()]   # sqrt((1 + 1 + 2) / 3): neighbours at 1, 1, sqrt(2)
            [1.1547, 1.1547, 1.1547]
        """
        xyz = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
        rgb = np.asarray(rgb)
        if rgb.shape != xyz.shape:
            raise StringsBenchError(f"points have {len(xyz)} positions but colours of shape {rgb.shape}")
        if len(xyz) == 0:
            raise StringsBenchError("cannot initialise Gaussians from an empty point cloud",
                                    hint="the scene's SfM model has no 3D points; re-run SfM")
        colour = rgb.astype(np.float64) / 255.0 if rgb.dtype == np.uint8 else rgb.astype(np.float64)
        n = len(xyz)
        d2 = np.maximum(knn_mean_sq_dist(xyz), min_sq_dist)
        f32 = dict(dtype=torch.float32, device=device)
        params = {
            "means": torch.tensor(xyz, **f32),
            "quats": torch.tensor([[1.0, 0.0, 0.0, 0.0]], **f32).repeat(n, 1),
            "log_scales": torch.tensor(np.log(np.sqrt(d2)), **f32)[:, None].repeat(1, 3),
            "opacity_logits": torch.full((n,), float(logit(init_opacity)), **f32),
            "sh0": rgb_to_sh0(torch.tensor(colour, **f32))[:, None, :],
            "shN": torch.zeros((n, num_sh_rest(sh_degree), 3), **f32),
        }
        return cls(params, extras=extras, sh_degree=sh_degree)

    @classmethod
    def concat(cls, models: list["GaussianModel"]) -> "GaussianModel":
        """Join models (e.g. text and non-text Gaussians) into a new one (detached copies).

        Args:
            models: non-empty list of GaussianModels on one device. Extras present in only some
                models are filled with zeros (False) for the others; the SH degree is the largest
                (all must hold the same number of shN coefficients).
        """
        if not models:
            raise StringsBenchError("nothing to concatenate")
        names = sorted({k for m in models for k in m.extras})
        params = {k: torch.cat([m.params[k].detach() for m in models]) for k in PARAM_NAMES}
        extras = {}
        for name in names:
            ref = next(m.extras[name] for m in models if name in m.extras)
            parts = [m.extras[name] if name in m.extras else
                     torch.zeros((len(m),) + tuple(ref.shape[1:]), dtype=ref.dtype, device=ref.device) for m in models]
            extras[name] = torch.cat(parts)
        return cls(params, extras=extras, sh_degree=max(m.sh_degree for m in models))

    def subset(self, mask_or_index) -> "GaussianModel":
        """A detached copy of some Gaussians, extras included.

        Args:
            mask_or_index: (N,) bool mask or an index tensor / sequence.
        """
        sel = torch.as_tensor(mask_or_index, device=self.device)
        return GaussianModel({k: v.detach()[sel].clone() for k, v in self.params.items()},
                             extras={k: v[sel].clone() for k, v in self.extras.items()}, sh_degree=self.sh_degree)

    def copy(self) -> "GaussianModel":
        """A detached copy of the whole model."""
        return self.subset(torch.arange(len(self), device=self.device))

    # ---- checks / shapes ------------------------------------------------------------------
    def check(self) -> None:
        """Raise StringsBenchError unless every parameter and extra has N rows and its layout's shape."""
        n = len(self)
        shapes = {"means": (n, 3), "quats": (n, 4), "log_scales": (n, 3), "opacity_logits": (n,), "sh0": (n, 1, 3)}
        for k, shape in shapes.items():
            if tuple(self.params[k].shape) != shape:
                raise StringsBenchError(f"parameter {k} has shape {tuple(self.params[k].shape)}, expected {shape}")
        if self.params["shN"].ndim != 3 or self.params["shN"].shape[0] != n or self.params["shN"].shape[2] != 3:
            raise StringsBenchError(f"parameter shN has shape {tuple(self.params['shN'].shape)}, expected ({n}, K, 3)")
        for k, v in self.extras.items():
            if v.shape[0] != n:
                raise StringsBenchError(f"extra {k!r} has {v.shape[0]} rows but the model has {n} Gaussians")

    def __len__(self) -> int:
        return int(self.params["means"].shape[0])

    @property
    def device(self) -> torch.device:
        """The device of the parameters."""
        return self.params["means"].device

    # ---- activations ----------------------------------------------------------------------
    @property
    def means(self) -> torch.Tensor:
        """(N, 3) centres, world units (the parameter itself)."""
        return self.params["means"]

    @property
    def quats(self) -> torch.Tensor:
        """(N, 4) unit quaternions, wxyz."""
        q = self.params["quats"]
        return q / q.norm(dim=-1, keepdim=True).clamp_min(1e-12)

    @property
    def scales(self) -> torch.Tensor:
        """(N, 3) standard deviations along the own axes, world units: exp(log_scales)."""
        return torch.exp(self.params["log_scales"])

    @property
    def opacities(self) -> torch.Tensor:
        """(N,) opacities in (0, 1): sigmoid(opacity_logits)."""
        return torch.sigmoid(self.params["opacity_logits"])

    @property
    def sh(self) -> torch.Tensor:
        """(N, K + 1, 3) all SH coefficients, sh0 then shN (what `rasterize` takes)."""
        return torch.cat([self.params["sh0"], self.params["shN"]], dim=1)

    def covariances(self) -> torch.Tensor:
        """(N, 3, 3) world covariances R S S R^T."""
        R = quat_to_rotmat(self.params["quats"])
        M = R * self.scales[:, None, :]
        return M @ M.transpose(1, 2)

    # ---- rendering ------------------------------------------------------------------------
    def render(self, camera: "Camera", background=(0.0, 0.0, 0.0), sh_degree: int | None = None, **raster_kwargs):
        """Render the model into `camera` through `strings_bench.raster.rasterize`.

        Args:
            camera: a `strings_bench.scene.camera.Camera` (image size, intrinsics, pose).
            background: (3,) RGB in [0, 1], tensor or sequence.
            sh_degree: SH degree to use, capped at the model's `sh_degree`; None = the model's.
            **raster_kwargs: passed on to `rasterize` (backend, mip_filter, compute_absgrad,
                near, far).

        Returns:
            RasterOutput (color (H, W, 3), alpha, depth, radii, means2d, absgrad, visible, backend);
            differentiable w.r.t. `params`.

        Raises:
            RasterInputError: see `rasterize`.

        Example:
            >>> import numpy as np
            >>> from strings_bench.engine.gaussians import GaussianModel
            >>> from strings_bench.scene.camera import Camera
            >>> cam = Camera(fx=40.0, fy=40.0, cx=24.0, cy=16.0, width=48, height=32, R=np.eye(3), t=np.zeros(3))
            >>> model = GaussianModel.from_points([[0.0, 0.0, 2.0], [0.2, 0.1, 2.0]], [[255, 0, 0], [0, 0, 255]])
            >>> out = model.render(cam, background=(1.0, 1.0, 1.0), backend="cpu")
            >>> out.color.shape, out.n_visible
            (torch.Size([32, 48, 3]), 2)
            >>> out.color.mean().backward()
            >>> model.params["means"].grad.shape
            torch.Size([2, 3])
        """
        from strings_bench.raster import rasterize

        degree = self.sh_degree if sh_degree is None else min(int(sh_degree), self.sh_degree)
        bg = torch.as_tensor(background, dtype=torch.float32, device=self.device)
        # sh0 and shN as they are stored (no (N, 16, 3) concatenation and gradient split each step)
        return rasterize(self.params["means"], self.params["quats"], self.params["log_scales"],
                         self.params["opacity_logits"], self.params["sh0"], camera, bg, sh_degree=degree,
                         sh_rest=self.params["shN"], **raster_kwargs)

    # ---- (de)serialisation ----------------------------------------------------------------
    def state_dict(self) -> dict:
        """{"params": {name: CPU tensor}, "extras": {name: CPU tensor}, "sh_degree": int} (detached)."""
        return {"params": {k: v.detach().cpu() for k, v in self.params.items()},
                "extras": {k: v.cpu() for k, v in self.extras.items()}, "sh_degree": self.sh_degree}

    @classmethod
    def from_state_dict(cls, state: dict, device="cpu") -> "GaussianModel":
        """Rebuild a model from `state_dict()`.

        Args:
            state: a dict made by `state_dict()`.
            device: torch device of the new parameters.
        """
        return cls({k: v.to(device) for k, v in state["params"].items()},
                   extras={k: v.to(device) for k, v in state.get("extras", {}).items()}, sh_degree=state.get("sh_degree"))
