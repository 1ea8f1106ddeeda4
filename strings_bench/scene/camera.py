"""Pinhole camera: intrinsics, world-to-camera pose, image size.

Conventions (COLMAP / OpenCV): x right, y down, z forward; a world point X maps to camera
coordinates R @ X + t; pixel centres are at integer + 0.5 in the continuous image frame, so the
top-left pixel's centre is (0.5, 0.5) and u = fx * x / z + cx.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from strings_bench.core import vec3


@dataclass(frozen=True)
class Camera:
    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int
    R: np.ndarray  # (3, 3) world -> camera rotation
    t: np.ndarray  # (3,) world -> camera translation
    name: str = ""

    def __post_init__(self):
        object.__setattr__(self, "R", np.asarray(self.R, dtype=np.float64).reshape(3, 3))
        object.__setattr__(self, "t", np.asarray(self.t, dtype=np.float64).reshape(3))

    @property
    def K(self) -> np.ndarray:
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def viewmat(self) -> np.ndarray:
        """4x4 world-to-camera matrix."""
        m = np.eye(4)
        m[:3, :3] = self.R
        m[:3, 3] = self.t
        return m

    @property
    def center(self) -> np.ndarray:
        """Camera centre in world coordinates, -R^T t (core/vec3.py: the same bits on every CPU)."""
        return -vec3.vecmat(self.t, self.R)

    def scaled(self, factor: float) -> "Camera":
        """The same camera for an image downscaled by `factor` (2 -> half resolution)."""
        return self.resized(max(1, int(round(self.width / factor))), max(1, int(round(self.height / factor))))

    def resized(self, width: int, height: int) -> "Camera":
        """The same camera for the image resampled to width x height (each axis scaled on its own)."""
        sx, sy = width / self.width, height / self.height
        return replace(self, fx=self.fx * sx, fy=self.fy * sy, cx=self.cx * sx, cy=self.cy * sy, width=width, height=height)

    def world_to_camera(self, xyz: np.ndarray) -> np.ndarray:
        """World points (N, 3) -> camera coordinates R X + t (N, 3)."""
        return vec3.matvec(self.R, np.asarray(xyz, dtype=np.float64)) + self.t

    def project(self, xyz: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Project world points (N, 3) to pixels (N, 2) and depths (N,).

        Points with depth <= 0 get NaN pixel coordinates instead of a mirrored projection.
        """
        pc = self.world_to_camera(xyz)
        z = pc[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            u = self.fx * pc[:, 0] / z + self.cx
            v = self.fy * pc[:, 1] / z + self.cy
        uv = np.stack([u, v], axis=1)
        uv[z <= 0] = np.nan
        return uv, z
