"""Pinhole camera of the synthetic set-up (the paper's DAVIS: 640x480, 60 deg horizontal FoV).

Camera frame: X right, Y down, Z forward (optical axis), metres. Pixel (i, j) has its centre
at image coordinates (u, v) = (i, j), so the mean of event coordinates is directly comparable
with a projected centre:

    u = cx + f X / Z,   v = cy + f Y / Z,   f = (W / 2) / tan(hfov / 2),
    cx = (W - 1) / 2,   cy = (H - 1) / 2.

Image-plane velocity of a point with 3-D velocity (VX, VY, VZ):

    du/dt = f (VX Z - X VZ) / Z^2,   dv/dt = f (VY Z - Y VZ) / Z^2.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class PinholeCamera:
    """Ideal pinhole, square pixels, principal point at the image centre (see module doc)."""

    width: int = 640
    height: int = 480
    hfov_deg: float = 60.0

    @property
    def sensor_size(self) -> tuple[int, int]:
        return (int(self.width), int(self.height))

    @property
    def f(self) -> float:
        """Focal length in pixels: (W / 2) / tan(hfov / 2) (554.3 px for 640 px at 60 deg)."""
        return (self.width / 2.0) / math.tan(math.radians(self.hfov_deg) / 2.0)

    @property
    def cx(self) -> float:
        return (self.width - 1) / 2.0

    @property
    def cy(self) -> float:
        return (self.height - 1) / 2.0

    def project(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(u, v) pixels of points p (..., 3) in the camera frame."""
        z = p[..., 2]
        return self.cx + self.f * p[..., 0] / z, self.cy + self.f * p[..., 1] / z

    def project_velocity(self, p: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(du/dt, dv/dt) in px/s of points p (..., 3) moving at v (..., 3) m/s."""
        z = p[..., 2]
        du = self.f * (v[..., 0] * z - p[..., 0] * v[..., 2]) / (z * z)
        dv = self.f * (v[..., 1] * z - p[..., 1] * v[..., 2]) / (z * z)
        return du, dv

    def half_extent_m(self, depth_m: float) -> tuple[float, float]:
        """Half width and half height (metres) of the field of view at a depth."""
        return depth_m * (self.width / 2.0) / self.f, depth_m * (self.height / 2.0) / self.f
