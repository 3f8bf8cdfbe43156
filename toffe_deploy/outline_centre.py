"""A slow object's position from its outline over the windows before (``config.ofpd.outline_centre``).

Why: in one 500 us window a slow object (bin 1, under 2 px/ms) fires a few scattered pixels of
its outline, often one edge. The OFPD regresses the centre from that crop, and where the crop is
one edge it can put the centre outside the object: on held-out ``appearance`` 6 of the 13 misses
of a running stream were reported 20-39 px from objects of 22-75 px (detect_diagnose.py,
"mislocated"). Over the K windows the object takes to move D px, its pixels fill in the whole
outline, and the outline's centre is the object's centre less the motion over those windows.

For each object whose decoded speed s (px/ms) asks for K >= k_min windows, where the ring holds
all K of them (a stream's start keeps the OFPD's position), and whose own pixels of this window
are not closed (below):

    K = min(K_ring, ceil(D / (s dt_ms)))          (outline_centre = [D, k_min, reach, closed_frac])
    P = the distinct pixels the front end kept in the last K windows (OnesHistory, any bin or
        polarity) within c0 +- 2 r
    c0 = centroid of the object's distinct pixels of this window; r = max(6, reach * extent)
         (extent: the larger side of their bounding box, + 1)
    c <- mean of the pixels of P within c +- r that are no nearer to another object's path
         than to c, 5 times (mean shift; stops where none is left); an object's path: the
         segment from its decoded position back along its decoded velocity over the K windows
    position = c + s dt_ms (K - 1) / 2 (cos a, sin a)         (a: the decoded direction)

The last term undoes the lag of the outline's centroid: it spans the K windows, so it lies
half of them behind the object. Closed: each quadrant around c0 holds at least closed_frac of
the object's own pixels. Such an object is an outline the OFPD saw whole, or two objects in one
detection as their paths cross; for the second, the outline holds both and the decoded velocity
is neither's, which moved positions up to 27 px off and cost tracking through crossings 0.02
MOTA and 0.06 IDF1 before this test (ckpt/README.md, "Position from the outline").

Every target runs the same compiled kernel on the same front-end ones (the ring the plane fit
reads, ``plane_fit_history``), so positions are the same bits on cpu, cuda, the Lava targets
and in eval. D = 10 px is the plane fit's; k_min 4 (bins 1-3 at dt 500 us), reach 1.0 and
closed_frac 0.1 from eval on ``appearance`` and ``pairs`` and tracking on ``crossing`` seed 0;
the shipped ``ckpt/`` runs [10, 4, 1.0, 0.1] since 2026-11-24 (on whole streams it finds more
slow objects, and tracking through crossings no longer loses with it: ckpt/README.md).
"""
from __future__ import annotations

import math

import numpy as np
from .jit import njit

from .config import ToffeConfig
from .time_surface import OnesHistory, history_rows

MIN_REACH_PX = 6.0      # r's floor: a blob of a few pixels still reaches its outline
SHIFTS = 5              # mean-shift steps (converged well before on every split measured)


def outline_settings(config: ToffeConfig) -> tuple[float, int, float, float] | None:
    """(D px, k_min windows, reach, closed_frac) of config.ofpd.outline_centre ([D, k_min,
    reach] means closed_frac 0), or None (absent: the OFPD's position stands). Needs
    ofpd.plane_fit_history (its ring holds the windows before)."""
    v = (config.ofpd or {}).get("outline_centre")
    if v is None:
        return None
    bad = ValueError("ofpd.outline_centre must be [distance px > 0, min windows >= 1, reach > 0(, closed "
                     f"fraction 0-0.25)], got {v!r}")
    if not isinstance(v, (list, tuple)) or len(v) not in (3, 4) or any(isinstance(a, bool) for a in v):
        raise bad
    try:
        d, k, reach = float(v[0]), v[1], float(v[2])
        closed = float(v[3]) if len(v) == 4 else 0.0
    except (TypeError, ValueError):
        raise bad from None
    if not (isinstance(k, int) and k >= 1 and math.isfinite(d) and d > 0 and math.isfinite(reach) and reach > 0
            and 0.0 <= closed <= 0.25):
        raise bad
    if (config.ofpd or {}).get("plane_fit_history") is None:
        raise ValueError("ofpd.outline_centre needs ofpd.plane_fit_history (the windows before)")
    return d, k, reach, closed


@njit(cache=True, nogil=True)
def outline_centres(obj, xs, ys, n_obj, x_px, y_px, speed_px_ms, direction_rad, ring_ptr, ring_xs, slot_win, now,
                    available, width, height, distance_px, k_min, reach, dt_ms, closed_frac):
    """The module doc's positions: (x, y) float64 arrays of n_obj, the decoded (x_px, y_px)
    where an object does not qualify. obj, xs, ys: the objects' ones of this window (any
    order, repeats allowed); ring_*: an OnesHistory's arrays with this window pushed."""
    out_x = x_px.copy()
    out_y = y_px.copy()
    k_ring = ring_ptr.shape[0]
    ks = history_rows(speed_px_ms, False, distance_px, k_ring, dt_ms)     # the plane fit's K rule
    first = np.zeros(n_obj + 1, np.int64)       # the ones by object (a counting sort, one pass)
    for m in range(obj.shape[0]):
        if 0 <= obj[m] < n_obj:
            first[obj[m] + 1] += 1
    for i in range(n_obj):
        first[i + 1] += first[i]
    order = np.empty(first[n_obj], np.int64)
    fill = first[:n_obj].copy()
    for m in range(obj.shape[0]):
        if 0 <= obj[m] < n_obj:
            order[fill[obj[m]]] = m
            fill[obj[m]] += 1
    for i in range(n_obj):
        step = speed_px_ms[i] * dt_ms
        if not (step > 0.0 and math.isfinite(step)):
            continue
        k = ks[i]
        if k < k_min or k > available:
            continue
        sel = order[first[i]:first[i + 1]]
        if sel.size == 0:
            continue
        ox, oy = _distinct_pixels(xs, ys, sel)
        cx = ox.sum() / ox.size                      # integer sums: exact in any order
        cy = oy.sum() / oy.size
        extent = max(ox.max() - ox.min(), oy.max() - oy.min()) + 1
        if closed_frac > 0.0:                        # its own pixels all round their centroid: an
            q = np.zeros(4)                          # outline the OFPD saw whole, or two objects
            for m in range(ox.size):
                q[(1 if ox[m] >= cx else 0) + (2 if oy[m] >= cy else 0)] += 1.0
            if q.min() >= closed_frac * ox.size:
                continue
        r = max(MIN_REACH_PX, reach * extent)
        # candidates: the ring's pixels of the last k windows within c0 +- 2 r, once each (a
        # bitmap of the box marks the pixels seen)
        x0, x1 = max(0, int(math.floor(cx - 2 * r))), min(width - 1, int(math.ceil(cx + 2 * r)))
        y0, y1 = max(0, int(math.floor(cy - 2 * r))), min(height - 1, int(math.ceil(cy + 2 * r)))
        bw = x1 - x0 + 1
        seen = np.zeros((y1 - y0 + 1) * bw, np.bool_)
        px = np.empty(seen.size, np.float64)
        py = np.empty(seen.size, np.float64)
        nc = 0
        for s in range(k_ring):
            win = slot_win[s]
            if win < 0 or win <= now - k:
                continue
            for p in range(2):
                for y in range(y0, y1 + 1):
                    row = p * height + y
                    base = (y - y0) * bw - x0
                    for j in range(ring_ptr[s, row], ring_ptr[s, row + 1]):
                        x = int(ring_xs[s, j])
                        if x0 <= x <= x1 and not seen[base + x]:
                            seen[base + x] = True
                            px[nc] = x
                            py[nc] = y
                            nc += 1
        if nc == 0:
            continue
        px = px[:nc]
        py = py[:nc]
        # each candidate's squared distance to the nearest other object's path (from its decoded
        # position back along its decoded velocity over the k windows): fixed while c moves
        others = np.full(nc, np.inf)
        for j in range(n_obj):
            if j == i:
                continue
            back = speed_px_ms[j] * dt_ms * (k - 1)
            if not math.isfinite(back):
                back = 0.0
            dx = -back * math.cos(direction_rad[j])
            dy = -back * math.sin(direction_rad[j])
            for m in range(nc):
                others[m] = min(others[m], _to_path(px[m], py[m], x_px[j], y_px[j], dx, dy))
        for _step in range(SHIFTS):
            sx = 0.0
            sy = 0.0
            n = 0
            for m in range(nc):
                if abs(px[m] - cx) > r or abs(py[m] - cy) > r:
                    continue
                if (px[m] - cx) ** 2 + (py[m] - cy) ** 2 <= others[m]:   # a pixel nearer to another path is its
                    sx += px[m]
                    sy += py[m]
                    n += 1
            if n == 0:
                break
            cx = sx / n
            cy = sy / n
        lag = step * (k - 1) / 2.0
        out_x[i] = cx + lag * math.cos(direction_rad[i])
        out_y[i] = cy + lag * math.sin(direction_rad[i])
    return out_x, out_y


@njit(cache=True, nogil=True)
def _distinct_pixels(xs, ys, sel):
    """(x, y) int64 of the distinct pixels among xs[sel], ys[sel] (a bitmap of their box, no sort)."""
    x0 = x1 = xs[sel[0]]
    y0 = y1 = ys[sel[0]]
    for m in sel:
        x0, x1 = min(x0, xs[m]), max(x1, xs[m])
        y0, y1 = min(y0, ys[m]), max(y1, ys[m])
    bw = x1 - x0 + 1
    seen = np.zeros((y1 - y0 + 1) * bw, np.bool_)
    ox = np.empty(sel.size, np.int64)
    oy = np.empty(sel.size, np.int64)
    n = 0
    for m in sel:
        b = (ys[m] - y0) * bw + xs[m] - x0
        if not seen[b]:
            seen[b] = True
            ox[n] = xs[m]
            oy[n] = ys[m]
            n += 1
    return ox[:n], oy[:n]


@njit(cache=True, nogil=True)
def _to_path(x, y, ax, ay, dx, dy):
    """Squared distance from (x, y) to the segment from (ax, ay) to (ax + dx, ay + dy)."""
    n2 = dx * dx + dy * dy
    t = 0.0
    if n2 > 0.0:
        t = min(1.0, max(0.0, ((x - ax) * dx + (y - ay) * dy) / n2))
    ex = x - ax - t * dx
    ey = y - ay - t * dy
    return ex * ex + ey * ey


def outline_positions(settings: tuple[float, int, float, float], history: OnesHistory, ones, x_px, y_px, speed_px_ms, direction_rad,
                      dt_us: int) -> tuple[np.ndarray, np.ndarray]:
    """outline_centres for ``settings`` (outline_settings), an OnesHistory with this window
    pushed and the objects' ones (object, x, y, ...) of this window: (x, y) float64 arrays."""
    d_px, k_min, reach, closed_frac = settings
    x = np.asarray(x_px, np.float64).reshape(-1)
    return outline_centres(np.asarray(ones[0], np.int64), np.asarray(ones[1], np.int64),
                           np.asarray(ones[2], np.int64), x.size, x, np.asarray(y_px, np.float64).reshape(-1),
                           np.asarray(speed_px_ms, np.float64).reshape(-1),
                           np.asarray(direction_rad, np.float64).reshape(-1), history._ptr, history._xs,
                           history._slot_win, history.now, history.available, history.width, history.height,
                           float(d_px), int(k_min), float(reach), dt_us / 1000.0, float(closed_frac))


def warm_up() -> None:
    """Compile (or load from numba's cache) the kernel before the first window is timed."""
    h = OnesHistory(2, (4, 4), 1, 500)
    h.push(0, np.array([0, 5], np.int64))
    h.push(500, np.array([1, 6], np.int64))
    z = np.zeros(2, np.int64)
    outline_positions((10.0, 1, 1.0, 0.1), h, (z, np.array([0, 1]), np.array([0, 1])), [0.0], [0.0], [1.0], [0.0], 500)
