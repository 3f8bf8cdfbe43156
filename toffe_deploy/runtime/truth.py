"""Ground truth per window for long recordings: ``dataset.groundtruth.window_truth`` on a slice.

window_truth scans every ground-truth row (one per object per 50 us sample) for each window,
which grows with the recording (a 10 s file holds ~10^6 rows). Here rows are sorted by time
once, and each window hands window_truth only the rows within (largest sampling gap + dt) of
the window's midpoint: the two samples around the midpoint that it interpolates are always
inside that slice, so the truth is the same as on the whole table.
"""
from __future__ import annotations

import numpy as np

from ..dataset.groundtruth import window_truth


class TruthIndex:
    """``window(t0, dt_us)`` = window_truth(gt, t0, dt_us), in O(log n + rows near the window)."""

    def __init__(self, gt: dict[str, np.ndarray]):
        t = np.asarray(gt["t"])
        order = np.argsort(t, kind="stable")
        self.gt = {k: np.asarray(v)[order] for k, v in gt.items()}
        self.t = self.gt["t"]
        ut = np.unique(self.t)
        self.gap = int(np.diff(ut).max()) if ut.size > 1 else 0

    def window(self, t0: int, dt_us: int):
        tm = t0 + dt_us / 2.0
        margin = self.gap + dt_us
        i0, i1 = np.searchsorted(self.t, [tm - margin, tm + margin], side="left")
        return window_truth({k: v[i0:i1] for k, v in self.gt.items()}, t0, dt_us)


def sequence_focal_px(attrs: dict) -> float | None:
    """The focal length (px) of the camera that recorded a sequence, from its file attrs: a
    top-level ``focal_px``, else the generator spec's camera (width, hfov_deg); None if neither
    (eval then compares speeds in m/s, metrics module doc)."""
    from ..camera import focal_px_from_hfov

    def num(v):
        return isinstance(v, (int, float)) and not isinstance(v, bool) and v > 0

    if num(attrs.get("focal_px")):
        return float(attrs["focal_px"])
    gen = attrs.get("generator")
    spec = gen.get("spec") if isinstance(gen, dict) else None
    cam = spec.get("camera") if isinstance(spec, dict) else None
    if isinstance(cam, dict) and num(cam.get("width")) and num(cam.get("hfov_deg")):
        return focal_px_from_hfov(cam["width"], cam["hfov_deg"])
    return None
