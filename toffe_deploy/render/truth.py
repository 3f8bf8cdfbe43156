"""Ground truth as drawable marks, with each object's outline when the recording says its shape.

Recordings from our generator list their objects in the file attrs (``objects``: shape, size_m,
trajectory.depth_m; index = ground-truth ``object_id``) and give the camera's focal length
(runtime.truth.sequence_focal_px). An object's half-size on the image is then

    radius_px = focal_px * (size_m / 2) / depth_m

with depth_m the ground-truth column at the window (else the trajectory's mean depth), as the
generator renders it (dataset/synth.py). Without these attrs the outline is a nominal circle.
"""
from __future__ import annotations

from typing import Iterable

from .draw import TruthMark


class TruthShapes:
    """object_id -> (shape, size_m, mean depth_m) from a recording's attrs, and its focal length."""

    def __init__(self, attrs: dict | None):
        from ..runtime.truth import sequence_focal_px

        attrs = attrs or {}
        self.focal_px = sequence_focal_px(attrs)
        self.objects: dict[int, tuple[str, float, float | None]] = {}
        objs = attrs.get("objects")
        if not isinstance(objs, list):
            return
        for i, o in enumerate(objs):
            if not isinstance(o, dict) or not isinstance(o.get("shape"), str):
                continue
            size = o.get("size_m")
            traj = o.get("trajectory")
            depth = traj.get("depth_m") if isinstance(traj, dict) else None
            if isinstance(size, (int, float)) and size > 0:
                self.objects[i] = (o["shape"], float(size), float(depth) if isinstance(depth, (int, float)) else None)

    def marks(self, truths: Iterable) -> list[TruthMark]:
        """TruthMarks of dataset.groundtruth.ObjectTruth rows, with outlines where known."""
        out = []
        for t in truths:
            shape = radius = None
            info = self.objects.get(int(t.object_id))
            if info is not None and self.focal_px:
                shape, size_m, depth = info
                z = t.depth_m if t.depth_m else depth
                radius = self.focal_px * size_m / 2.0 / z if z and z > 0 else None
                if radius is None:
                    shape = None
            out.append(TruthMark(t.x, t.y, t.direction, int(t.speed_bin), float(t.speed), int(t.object_id),
                                 shape, radius))
        return out
