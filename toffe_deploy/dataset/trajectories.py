"""Closed object trajectories in cylindrical coordinates about the optical axis, one lap per
lap time (the paper: "parameterized in cylindrical coordinates with same lap time", so the
speed varies along a lap).

A curve gives, for a phase phi in [0, 2 pi), a polar radius r(phi), polar angle theta(phi) in the
plane facing the camera and a depth profile zeta(phi) in [-1, 1]. The object's centre is

    phi(t) = phi0 + s 2 pi t / T_lap            (s = +1 clockwise on screen, -1 anticlockwise)
    [X, Y] = offset + R(orientation) * scale * n(r(phi) [cos theta(phi), sin theta(phi)])
    Z      = depth + depth_amp * zeta(phi)

in the camera frame (X right, Y down, Z forward), where n() centres the curve's bounding box
on the origin and scales its largest radius to 1 (so ``scale`` is the largest excursion in
metres). Because Y points down, increasing theta turns clockwise on screen. Velocity is the
derivative of this analytic position (central difference in phi, step 1e-6 rad: error ~1e-12).
"""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field

import numpy as np

TAU = 2.0 * math.pi


def _ellipse(phi):
    a, b = 1.0, 0.7
    r = a * b / np.sqrt((b * np.cos(phi)) ** 2 + (a * np.sin(phi)) ** 2)
    return r, phi


def _lemniscate(phi):
    # Lemniscate of Bernoulli, x = cos / (1 + sin^2), y = sin cos / (1 + sin^2), in polar form.
    d = 1.0 + np.sin(phi) ** 2
    x, y = np.cos(phi) / d, np.sin(phi) * np.cos(phi) / d
    return np.hypot(x, y), np.arctan2(y, x)


def _limacon(phi):
    return 1.0 + 0.2 * np.cos(phi), phi


def _trefoil(phi):
    return 1.0 + 0.2 * np.cos(3.0 * phi), phi


def _squircle(phi):
    return (np.abs(np.cos(phi)) ** 4 + np.abs(np.sin(phi)) ** 4) ** -0.25, phi


#: name -> phi -> (r, theta); the depth profile of every curve is zeta = sin(phi).
CURVES = {"ellipse": _ellipse, "lemniscate": _lemniscate, "limacon": _limacon,
          "trefoil": _trefoil, "squircle": _squircle}
TRAIN_CURVES = ("ellipse", "lemniscate", "limacon")
TEST_CURVES = ("trefoil", "squircle")


@functools.lru_cache(maxsize=None)
def _normaliser(curve: str) -> tuple[float, float, float]:
    """(centre x, centre y, 1 / max radius about that centre) of a curve, from a fine grid."""
    phi = np.linspace(0.0, TAU, 8192, endpoint=False)
    r, th = CURVES[curve](phi)
    x, y = r * np.cos(th), r * np.sin(th)
    cx, cy = (x.max() + x.min()) / 2.0, (y.max() + y.min()) / 2.0
    return cx, cy, 1.0 / float(np.hypot(x - cx, y - cy).max())


def unit_curve(curve: str, phi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Centred, unit-radius planar curve (x, y) at phases phi."""
    if curve not in CURVES:
        raise ValueError(f"unknown trajectory {curve!r} (expected one of {', '.join(CURVES)})")
    r, th = CURVES[curve](phi)
    cx, cy, k = _normaliser(curve)
    return (r * np.cos(th) - cx) * k, (r * np.sin(th) - cy) * k


@dataclass(frozen=True)
class Trajectory:
    """One object's path (see module doc for the defining equations)."""

    curve: str
    lap_time_s: float
    scale_m: float = 1.6
    depth_m: float = 5.0
    depth_amp_m: float = 0.3
    orientation_deg: float = 0.0
    clockwise: bool = True
    phase0: float = 0.0
    offset_m: tuple[float, float] = field(default=(0.0, 0.0))

    def phase(self, t_s: np.ndarray) -> np.ndarray:
        sense = 1.0 if self.clockwise else -1.0
        return self.phase0 + sense * TAU * np.asarray(t_s, dtype=np.float64) / self.lap_time_s

    def position_at_phase(self, phi: np.ndarray) -> np.ndarray:
        """(..., 3) camera-frame centre (m) at phases phi."""
        x, y = unit_curve(self.curve, phi)
        a = math.radians(self.orientation_deg)
        ca, sa = math.cos(a), math.sin(a)
        X = self.offset_m[0] + self.scale_m * (ca * x - sa * y)
        Y = self.offset_m[1] + self.scale_m * (sa * x + ca * y)
        Z = self.depth_m + self.depth_amp_m * np.sin(phi)
        return np.stack([X, Y, Z], axis=-1)

    def position(self, t_s: np.ndarray) -> np.ndarray:
        return self.position_at_phase(self.phase(t_s))

    def velocity(self, t_s: np.ndarray) -> np.ndarray:
        """(..., 3) velocity (m/s): dP/dphi * dphi/dt."""
        phi = self.phase(t_s)
        h = 1e-6
        dp = (self.position_at_phase(phi + h) - self.position_at_phase(phi - h)) / (2.0 * h)
        sense = 1.0 if self.clockwise else -1.0
        return dp * (sense * TAU / self.lap_time_s)


def speed_per_rad(curve: str, scale_m: float, depth_amp_m: float, n: int = 4096) -> tuple[float, float]:
    """(min, max) over a lap of |dP/dphi| (metres per radian of phase) for a curve's geometry."""
    probe = Trajectory(curve, lap_time_s=TAU, scale_m=scale_m, depth_amp_m=depth_amp_m)
    t = np.linspace(0.0, TAU, n, endpoint=False)  # lap time 2 pi: d phi / dt = 1
    s = np.linalg.norm(probe.velocity(t), axis=-1)
    return float(s.min()), float(s.max())


def lap_time_for_speeds(curve: str, scale_m: float, depth_amp_m: float, lo_mps: float, hi_mps: float,
                        rng: np.random.Generator, margin: float = 1.03) -> float:
    """A lap time whose speeds over the lap lie in [lo, hi] m/s where the geometry allows.

    Speed is |dP/dphi| * 2 pi / T_lap, so a lap time maps the curve's speed range [smin, smax]
    (per radian) to [smin, smax] * 2 pi / T_lap. The angular rate is drawn log-uniformly among
    those that fit inside [lo * margin, hi / margin]; when the curve's speed ratio is wider than
    the bin, the range is centred (geometric mean) on the bin, so most of the lap lies in it.
    """
    smin, smax = speed_per_rad(curve, scale_m, depth_amp_m)
    w_lo, w_hi = lo_mps * margin / smin, hi_mps / margin / smax
    if w_lo <= w_hi:
        w = math.exp(rng.uniform(math.log(w_lo), math.log(w_hi)))
    else:
        w = math.sqrt(lo_mps * hi_mps / (smin * smax))
    return TAU / w
