"""Ground truth of one window, from the per-sample ground-truth columns of a sequence file.

The truth of a window [t0, t0 + dt) is taken at its midpoint tm = t0 + dt / 2, linearly
interpolated between the two samples around tm (for the direction: the interpolated unit vector
(cos, sin), then atan2, so it never wraps through +-pi the long way). An object counts when both
samples around tm are visible; tm outside an object's sampled span gives no truth for it.
The speed bin is the bin of the nearer sample (bins are stored, not recomputed, so the file's
own bin edges are used). speed_px_ms and depth_m are interpolated like speed when the ground
truth has them (files from before those columns give None).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..events.fmt_toffe import GT_OPTIONAL as OPTIONAL, GT_REQUIRED as REQUIRED


@dataclass(frozen=True)
class ObjectTruth:
    """One object at a window's midpoint: centre (px), direction (rad, y down), speed (m/s, 3-D),
    image-plane speed (px/ms) and depth (m) when known."""

    object_id: int
    x: float
    y: float
    direction: float
    speed: float
    speed_bin: int
    speed_px_ms: float | None = None
    depth_m: float | None = None


def _check(gt: dict) -> None:
    missing = [k for k in REQUIRED if k not in gt]
    if missing:
        raise ValueError(f"ground truth lacks columns {missing}")


def window_truth(gt: dict[str, np.ndarray], t0: int, dt_us: int) -> list[ObjectTruth]:
    """Visible objects at the midpoint of [t0, t0 + dt_us), sorted by object_id (module doc)."""
    _check(gt)
    tm = float(t0) + float(dt_us) / 2.0
    ids = np.asarray(gt["object_id"])
    out = []
    for oid in np.unique(ids):
        sel = np.flatnonzero(ids == oid)
        t = np.asarray(gt["t"])[sel]
        if t.shape[0] == 0 or tm < t[0] or tm > t[-1]:
            continue
        j = int(np.searchsorted(t, tm, side="right"))
        i0, i1 = max(j - 1, 0), min(j, t.shape[0] - 1)
        a, b = sel[i0], sel[i1]
        if not (gt["visible"][a] and gt["visible"][b]):
            continue
        w = 0.0 if t[i1] == t[i0] else (tm - t[i0]) / float(t[i1] - t[i0])

        def lerp(col):
            return float((1.0 - w) * gt[col][a] + w * gt[col][b])

        da, db = float(gt["direction"][a]), float(gt["direction"][b])
        c = (1.0 - w) * np.cos(da) + w * np.cos(db)
        s = (1.0 - w) * np.sin(da) + w * np.sin(db)
        near = a if w < 0.5 else b
        out.append(ObjectTruth(int(oid), lerp("x"), lerp("y"), float(np.arctan2(s, c)), lerp("speed"),
                               int(gt["speed_bin"][near]),
                               *(lerp(k) if k in gt else None for k in OPTIONAL)))
    return out
