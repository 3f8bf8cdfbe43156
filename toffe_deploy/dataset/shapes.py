"""The four object shapes of the TOFFE data set, as signed distance functions in pixels.

Each shape is centred at the origin with half-size R (pixels): the circle has radius R, the
square half-side R, the diamond half-diagonal R and the star outer radius R (inner radius
STAR_INNER * R, five points, one pointing up the image). Anti-aliased coverage of a pixel is
the area-coverage approximation of a one-pixel-wide edge ramp:

    coverage = clip(0.5 - sdf, 0, 1)

Every function is vectorized: dx, dy, R broadcast (e.g. (T, h, w) offsets, (T, 1, 1) radii),
so a whole chunk of samples is rasterised in a few numpy calls.
"""
from __future__ import annotations

import numpy as np

SHAPES = ("square", "circle", "diamond", "star")
STAR_INNER = 0.5

_K1 = np.array([0.809016994375, -0.587785252292])  # (cos 36, -sin 36): star fold axes


def sdf_circle(dx, dy, r):
    return np.hypot(dx, dy) - r


def sdf_square(dx, dy, r):
    qx = np.abs(dx) - r
    qy = np.abs(dy) - r
    outside = np.hypot(np.maximum(qx, 0.0), np.maximum(qy, 0.0))
    return outside + np.minimum(np.maximum(qx, qy), 0.0)


def sdf_diamond(dx, dy, r):
    """A square of half-diagonal r turned 45 degrees (exact distance)."""
    s = np.sqrt(0.5)
    return sdf_square((dx + dy) * s, (dy - dx) * s, r * s)


def sdf_star(dx, dy, r, inner: float = STAR_INNER):
    """Five-pointed star (exact distance, after I. Quilez's sdStar5), one point up the image."""
    k1x, k1y = _K1
    k2x, k2y = -k1x, k1y
    px = np.abs(dx)
    py = -dy  # the construction has y up; image y points down
    d = np.maximum(k1x * px + k1y * py, 0.0) * 2.0
    px, py = px - d * k1x, py - d * k1y
    d = np.maximum(k2x * px + k2y * py, 0.0) * 2.0
    px, py = px - d * k2x, py - d * k2y
    px = np.abs(px)
    py = py - r
    bax, bay = -inner * k1y, inner * k1x - 1.0  # ba = inner * (-k1.y, k1.x) - (0, 1), per unit r
    h = np.clip((px * bax + py * bay) / (bax * bax + bay * bay), 0.0, r)
    ex, ey = px - bax * h, py - bay * h
    return np.hypot(ex, ey) * np.sign(py * bax - px * bay)


_SDF = {"square": sdf_square, "circle": sdf_circle, "diamond": sdf_diamond, "star": sdf_star}


def sdf(shape: str, dx, dy, r):
    """Signed distance (px, negative inside) of offsets (dx, dy) to ``shape`` of half-size r."""
    try:
        return _SDF[shape](dx, dy, r)
    except KeyError:
        raise ValueError(f"unknown shape {shape!r} (expected one of {', '.join(SHAPES)})") from None


def coverage(shape: str, dx, dy, r) -> np.ndarray:
    """Anti-aliased fraction in [0, 1] of each pixel covered by the shape (see module doc)."""
    return np.clip(0.5 - sdf(shape, dx, dy, r), 0.0, 1.0)
