"""The camera model shared by the generator, the bundle and ``run``: a pinhole (the paper's
DAVIS: 640x480, 60 deg horizontal FoV) and the conversion between image-plane and metric speed.

An event camera sees image-plane motion only. The OFS speed bins are therefore image-plane
speeds (px/ms); they are *stated* in m/s for an object at a reference depth seen with a
reference focal length (the paper's set-up: 5 m, 554.3 px), by

    v_px_per_ms = v_mps * focal_px / depth_m / 1000,

and ``run --depth-m`` / ``--focal-px`` re-express a detected px/ms speed in m/s for another
camera or distance (``SpeedScale``).

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

#: The paper's set-up, the reference for speeds stated in m/s: 640 px at 60 deg, objects at 5 m.
REFERENCE_WIDTH_PX, REFERENCE_HFOV_DEG, REFERENCE_DEPTH_M = 640, 60.0, 5.0


def focal_px_from_hfov(width_px: int, hfov_deg: float) -> float:
    """Focal length in pixels of a sensor ``width_px`` wide with horizontal field of view ``hfov_deg``:
    f = (W / 2) / tan(hfov / 2)."""
    return (float(width_px) / 2.0) / math.tan(math.radians(float(hfov_deg)) / 2.0)


def hfov_deg_from_focal(width_px: int, focal_px: float) -> float:
    """Horizontal field of view (deg) of a sensor ``width_px`` wide with focal length ``focal_px``
    (the inverse of ``focal_px_from_hfov``): hfov = 2 atan(W / (2 f))."""
    return math.degrees(2.0 * math.atan((float(width_px) / 2.0) / float(focal_px)))


REFERENCE_FOCAL_PX = focal_px_from_hfov(REFERENCE_WIDTH_PX, REFERENCE_HFOV_DEG)   # 554.26 px
#: the horizontal fields of view (deg) an option may state: over 8 .. 4096 px they give focal
#: lengths of 0.035 .. 2.3e6 px, inside --focal-px's range (runtime.run_camera.OPTION_RANGE);
#: (0, 180) took 1e-300 deg (a focal length of 3.7e304 px) and 179.99999999 deg (3e-8 px)
HFOV_RANGE_DEG = (0.1, 179.0)
#: the object depths (m) and focal lengths (px) a camera option may state, `run`'s and `dataset
#: synth`'s alike: any camera's, with room (a depth of 1e308 m made every m/s factor 0 and a
#: division by it fail; 1e-9 m gave the generator objects of 0 px/ms)
DEPTH_RANGE_M = (1e-3, 1e6)
FOCAL_RANGE_PX = (1e-2, 1e7)


@dataclass(frozen=True)
class SpeedScale:
    """Metric <-> image-plane speed for an object at ``depth_m`` seen with ``focal_px``:

        v_px_per_ms = v_mps * focal_px / (1000 * depth_m)

    (motion parallel to the image plane; a component along the optical axis is invisible)."""

    focal_px: float = REFERENCE_FOCAL_PX
    depth_m: float = REFERENCE_DEPTH_M

    def __post_init__(self):
        if not (self.focal_px > 0 and math.isfinite(self.focal_px)):
            raise ValueError(f"focal length must be a positive number of pixels, got {self.focal_px}")
        if not (self.depth_m > 0 and math.isfinite(self.depth_m)):
            raise ValueError(f"depth must be a positive number of metres, got {self.depth_m}")

    @property
    def px_ms_per_mps(self) -> float:
        return self.focal_px / (1000.0 * self.depth_m)

    def to_px_ms(self, v_mps):
        return np.asarray(v_mps, dtype=np.float64) * self.px_ms_per_mps if np.ndim(v_mps) else float(v_mps) * self.px_ms_per_mps

    def to_mps(self, v_px_ms):
        return np.asarray(v_px_ms, dtype=np.float64) / self.px_ms_per_mps if np.ndim(v_px_ms) else float(v_px_ms) / self.px_ms_per_mps


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
        return focal_px_from_hfov(self.width, self.hfov_deg)

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


def speed_text(v: float) -> str:
    """A speed for a summary line: 3 significant digits, without an exponent from 1e-4 to below
    1e6 (0.337, 6.06, 84, 5000; ``:g`` wrote 5e+03 and ``:.6g`` 0.336729), with one beyond
    (3.3e-05, 2.7e+09), never "0.0000001" or "2700000000": one rule at both ends (an extreme
    --depth-m or --focal-px reaches either)."""
    r = float(f"{v:.3g}")
    if r != 0.0 and not 1e-4 <= abs(r) < 1e6:
        return f"{r:.3g}"
    return f"{r:.0f}" if abs(r) >= 100 else f"{r:g}"
