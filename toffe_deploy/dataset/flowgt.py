"""Per-pixel optical-flow targets of a window, computed on the fly from the stored ground truth.

The generator's objects are rigid planar shapes translating in the image plane (no rotation;
depth changes by at most a few percent per window), so every pixel an object covers moves with
the object's projected centre. The flow of a window is taken at its midpoint truth
(``window_truth``): for object i, (u_i, v_i) = speed_px_ms_i * (cos dir_i, sin dir_i) px/ms.

The target is defined on the window's *event pixels* only (the pixels an event-based network
sees; a pixel without events has no flow to measure). An event pixel at distance d_i from
object i's centre belongs to the object when

    d_i <= r_i + |v_i| * dt / 2 + margin_px        (r_i: the object's radius at the midpoint)

(its disc at the midpoint, grown by the half-window motion and a margin for the edge's
anti-aliasing and the emulator's half-sample lag); of several, the one whose edge is closest,
d_i - reach_i. Every other event pixel (background noise, hot pixels) gets flow 0 and owner -1.
r_i = size_px / 2 * (depth_mean / depth_m(t)) from the file's ``appearance`` attrs (the drawn
apparent diameter at the trajectory's mean depth); the shapes (star, diamond) lie inside that
disc, so the disc is a superset of the covered pixels: the approximation is that event pixels of
another object or of noise inside the disc would take this object's flow (objects never overlap
in the data set's scenes; noise inside a disc is rare).
"""
from __future__ import annotations

import numpy as np

from .groundtruth import ObjectTruth

MARGIN_PX = 3.0


def object_radii_px(attrs: dict) -> dict[int, tuple[float, float]]:
    """{object_id: (radius_px at the mean depth, mean depth m)} from a sequence file's attrs
    (``appearance.objects``, in object order); empty when the file does not record them."""
    app = attrs.get("appearance") if isinstance(attrs, dict) else None
    objs = app.get("objects") if isinstance(app, dict) else None
    out = {}
    for i, o in enumerate(objs or []):
        if isinstance(o, dict) and o.get("size_px"):
            out[i] = (float(o["size_px"]) / 2.0, float(o.get("depth_m") or 0.0))
    return out


def object_velocity_px_ms(t: ObjectTruth) -> tuple[float, float]:
    """(u, v) image velocity of an object's centre, px/ms (y down)."""
    s = float(t.speed_px_ms) if t.speed_px_ms is not None else float("nan")
    return s * float(np.cos(t.direction)), s * float(np.sin(t.direction))


def pixel_flow(xs: np.ndarray, ys: np.ndarray, truths: list[ObjectTruth], radii: dict[int, tuple[float, float]],
               dt_us: int, margin_px: float = MARGIN_PX) -> tuple[np.ndarray, np.ndarray]:
    """Flow targets of event pixels (module doc): (flow (n, 2) float32 px/ms, owner (n,) int64,
    the object_id or -1). Objects without a recorded radius or speed are skipped (owner -1)."""
    xs = np.asarray(xs, np.float64)
    ys = np.asarray(ys, np.float64)
    n = xs.shape[0]
    flow = np.zeros((n, 2), np.float32)
    owner = np.full(n, -1, np.int64)
    best = np.full(n, np.inf)
    for t in truths:
        if t.object_id not in radii or t.speed_px_ms is None:
            continue
        r0, z0 = radii[t.object_id]
        r = r0 * (z0 / t.depth_m) if (t.depth_m and z0) else r0
        u, v = object_velocity_px_ms(t)
        reach = r + float(t.speed_px_ms) * dt_us * 1e-3 / 2.0 + margin_px
        slack = np.hypot(xs - t.x, ys - t.y) - reach
        take = (slack <= 0) & (slack < best)
        best[take] = slack[take]
        owner[take] = t.object_id
        flow[take] = (u, v)
    return flow, owner


def dense_flow(event_mask: np.ndarray, truths: list[ObjectTruth], radii: dict[int, tuple[float, float]],
               dt_us: int, margin_px: float = MARGIN_PX) -> tuple[np.ndarray, np.ndarray]:
    """``pixel_flow`` on an (H, W) event mask: (flow (2, H, W) float32 px/ms, owner (H, W) int64,
    -2 where the pixel has no event)."""
    h, w = event_mask.shape
    ys, xs = np.nonzero(event_mask)
    f, o = pixel_flow(xs, ys, truths, radii, dt_us, margin_px)
    flow = np.zeros((2, h, w), np.float32)
    owner = np.full((h, w), -2, np.int64)
    flow[:, ys, xs] = f.T
    owner[ys, xs] = o
    return flow, owner
