"""The time surface of each object over its last K windows (``config.ofpd.plane_fit_history``):
what the plane fit (toffe_deploy/plane_fit.py) reads instead of the object's ones of one window.

Why: one 500 us window is 5 bins of 100 us. A bin-1 object (under 2 px/ms) moves under a pixel
in it, so its one-window time surface is flat and its direction is a guess (held-out
``appearance``: 67 deg mean error on bin 1, 11 deg on bin 2). Over the K windows an object takes
to move about D px the surface is a clean ramp again. A fast object wants few windows (it
leaves its box, and curved paths stop being one velocity), a slow one many, so K follows the
OFPD's own speed s (px/ms):

    K = min(K_max, max(1, ceil(D / (s * dt_ms))))          (plane_fit_history = [D, K_max, margin])

and with ``plane_fit_refits`` n, K is worked out n times again from the fit's own speed s
(plane_fit.refit_history), the surface fitted again where K changed.

Surface: for each polarity p, T_p(x, y) = the first time bin, counted from the oldest of the K
windows (t = j * B + b for window j = 0..K-1 and bin b), at which pixel (x, y) fired, over the
object's bounding box (its merged ones of this window) grown by ``margin`` px. Only the front
end's ones count (every target computes the same front end on the host), so the surface is the
same bits on cpu, cuda, the Lava targets and in eval. D and the fusion weights come from
benchmarks/fit_plane_fit.py --history on ``train`` (ckpt/README.md, "Plane fit over the windows
before": D = 10 px; the OFPD's speed error 0.996 -> 0.378 px/ms and direction error 16.9 -> 4.6
deg over 2,186 matched training objects); K_max = 20 and the 3 px margin from a sweep on
``train`` too (K 1-20 per speed bin: bin-1 objects still gained at 20; margin 0 or 3 px).

``OnesHistory`` keeps the front end's ones of the last K_max windows, each window's indexed by
row (2 H rows: p * H + y), in a ring; ``OnesHistory.flow`` fills each object's surface from K
windows x (2 x box rows) row slices (no pass over the sensor) and fits it as plane_fit does its
one-window surface (the same plane and IRLS code; at most MAX_PLANES planes per object).
The cpu runtime runs the whole fusion with the history (K, boxes, surfaces, refits, blending) in
one compiled call (``fuse_history``: ~60 us a window less than the Python steps of
plane_fit.PlaneFusion.apply, which eval runs on the same compiled pieces; a test checks that
they agree to the bit).

Window starts follow SupportHistory's rule: the next window (t0 = last + dt) keeps the ring, a
gap of whole windows leaves empty windows between, anything else (a jump back, a gap that is no
multiple of dt) forgets it.
"""
from __future__ import annotations

import copy
import math

import numpy as np
from .compiled import _div_small
from .jit import njit

from .plane_fit import (NEIGHBOURHOODS, _grid_planes, _solve, flow_speed_rows, fuse_direction_rows,
                        fuse_speed_rows)

MAX_PLANES = 256        # planes per object: every ceil(n / 256)-th surface pixel (a slow object's reach thousands)


@njit(cache=True, nogil=True)
def _window_rows(bc, pix, width, height, ptr, xs, bs):
    """The ones (plane bc = 2 b + p, pixel pix = y W + x; in idx order, sorted) by row p * H + y:
    ptr (2 H + 1) offsets into xs, bs (capacity >= the ones). Each row keeps the ones' order, so
    a pixel's ones come bin by bin. A one's row from one float product (compiled._div_small), not
    an integer division."""
    rows = 2 * height
    n = bc.shape[0]
    row = np.empty(n, np.int64)
    inv_w = 1.0 / width
    for r in range(rows + 1):
        ptr[r] = 0
    for i in range(n):
        row[i] = (bc[i] & 1) * height + _div_small(pix[i], width, inv_w)
        ptr[row[i] + 1] += 1
    for r in range(rows):
        ptr[r + 1] += ptr[r]
    for i in range(n):                          # ptr[r] walks to the end of row r, then is shifted back
        r = row[i]
        xs[ptr[r]] = pix[i] - (r - (bc[i] & 1) * height) * width
        bs[ptr[r]] = bc[i] >> 1
        ptr[r] += 1
    for r in range(rows, 0, -1):
        ptr[r] = ptr[r - 1]
    ptr[0] = 0


@njit(cache=True, nogil=True)
def _surface_flow(ring_ptr, ring_xs, ring_bs, slot_win, now, n_bins, height, boxes, k_win, table):
    """(n, 2) px-per-bin flow of each object j with k_win[j] > 0: its time surface (first time
    per pixel and polarity, t counted from the oldest of its K windows) over its box, filled
    oldest window first, then polarity, row and the row's order, the planes visited in that
    order, every ceil(n / MAX_PLANES)-th of its n pixels (plane_fit._grid_planes, _solve). NaN
    elsewhere."""
    n_obj = boxes.shape[0]
    out = np.full((n_obj, 2), np.nan)
    n_slots = slot_win.shape[0]
    bw = bh = cap = 0
    for j in range(n_obj):
        if boxes[j, 0] < 0:
            k_win[j] = 0                        # no ones: no box
        if k_win[j] > 0:
            bw = max(bw, boxes[j, 2] - boxes[j, 0] + 3)
            bh = max(bh, boxes[j, 3] - boxes[j, 1] + 3)
            cap = max(cap, 2 * (boxes[j, 2] - boxes[j, 0] + 1) * (boxes[j, 3] - boxes[j, 1] + 1))
    if cap == 0:
        return out
    grid = np.full((2, bh, bw), -1, np.int32)     # one scratch for all: each object leaves it all -1
    vx, vy, vp = np.empty(cap, np.int64), np.empty(cap, np.int64), np.empty(cap, np.int64)
    planes = np.empty((cap, 2))
    for j in range(n_obj):
        k = k_win[j]
        if k <= 0:
            continue
        x0, y0, x1, y1 = boxes[j, 0], boxes[j, 1], boxes[j, 2], boxes[j, 3]
        n = 0
        for w in range(now - k + 1, now + 1):
            s = w % n_slots
            if slot_win[s] != w:
                continue                        # before the stream, or a skipped window: no events
            t_rel = (w - (now - k + 1)) * n_bins
            for p in range(2):
                for y in range(y0, y1 + 1):
                    r = p * height + y
                    for e in range(ring_ptr[s, r], ring_ptr[s, r + 1]):
                        x = ring_xs[s, e]
                        if x < x0 or x > x1 or grid[p, y - y0 + 1, x - x0 + 1] >= 0:
                            continue
                        grid[p, y - y0 + 1, x - x0 + 1] = t_rel + ring_bs[s, e]
                        vx[n], vy[n], vp[n] = x - x0 + 1, y - y0 + 1, p
                        n += 1
        if n == 0:
            continue                            # no ones in its box over the K windows (a history without
                                                # this window): no surface, NaN (the step below would be 0)
        m = _grid_planes(vx, vy, vp, n, (n + MAX_PLANES - 1) // MAX_PLANES, grid, planes, table)
        out[j, 0], out[j, 1] = _solve(planes, m)
        for i in range(n):
            grid[vp[i], vy[i], vx[i]] = -1
    return out


@njit(cache=True, nogil=True)
def object_boxes(obj, xs, ys, n_obj, margin, width, height):
    """(n_obj, 4) int64 x0, y0, x1, y1 (inclusive) of each object's ones grown by ``margin`` and
    clipped to the sensor; x0 = -1 for an object without ones."""
    out = np.full((n_obj, 4), -1, np.int64)
    for i in range(obj.shape[0]):
        j = obj[i]
        if out[j, 0] < 0:
            out[j, 0], out[j, 1], out[j, 2], out[j, 3] = xs[i], ys[i], xs[i], ys[i]
        else:
            out[j, 0] = min(out[j, 0], xs[i])
            out[j, 1] = min(out[j, 1], ys[i])
            out[j, 2] = max(out[j, 2], xs[i])
            out[j, 3] = max(out[j, 3], ys[i])
    for j in range(n_obj):
        if out[j, 0] < 0:
            continue
        out[j, 0] = max(0, out[j, 0] - margin)
        out[j, 1] = max(0, out[j, 1] - margin)
        out[j, 2] = min(width - 1, out[j, 2] + margin)
        out[j, 3] = min(height - 1, out[j, 3] + margin)
    return out


def history_windows(speed_px_ms, distance_px: float, k_max: int, dt_us: int, log: bool = False) -> list[int]:
    """K of each object: the windows it takes to move ``distance_px`` at its speed (px/ms; ln
    px/ms with ``log``), 1..k_max (k_max for a speed of 0 or not finite): history_rows."""
    s = np.array(speed_px_ms, dtype=np.float64).reshape(-1)
    return history_rows(s, bool(log), float(distance_px), int(k_max), dt_us / 1000.0).tolist()


@njit(cache=True, nogil=True)
def history_rows(speed, log, distance_px, k_max, dt_ms):
    """(N,) int64 K = min(k_max, max(1, ceil(distance_px / (s dt_ms)))) of speeds s px/ms
    (``log``: ln px/ms, exp'd with its argument capped at 700), k_max where s is 0 or not finite.
    Compiled: the runtime's fused_history_flow calls it too, so that eval and every target
    take the same K."""
    out = np.empty(speed.shape[0], np.int64)
    for i in range(speed.shape[0]):
        s = speed[i]
        if log:
            s = math.exp(min(s, 700.0)) if math.isfinite(s) else math.nan
        k = k_max
        if s > 0.0 and math.isfinite(s):
            q = distance_px / (s * dt_ms)
            if q < k_max:
                k = max(1, int(math.ceil(q)))
        out[i] = k
    return out


class OnesHistory:
    """The front end's ones of the last ``k`` windows, row-indexed (module doc). ``push(t0,
    idx)`` adds a window (its sorted linear indices into (B, 2, H, W)); ``flow``
    gathers objects' surfaces over their K <= k latest windows."""

    def __init__(self, k: int, sensor_size: tuple[int, int], n_bins: int, dt_us: int):
        if int(k) < 1:
            raise ValueError(f"the history needs at least 1 window, got {k}")
        self.k = int(k)
        self.width, self.height = int(sensor_size[0]), int(sensor_size[1])
        self.n_bins, self.dt_us = int(n_bins), int(dt_us)
        # narrow ring (x: int16 up to 32,767 px wide, bin: int16, row offsets: int32): a quarter
        # of int64's cache footprint; the ring is read back every window, between the other stages
        self._x_dtype = np.int16 if self.width <= np.iinfo(np.int16).max else np.int32
        self._ptr = np.zeros((self.k, 2 * self.height + 1), np.int32)
        self._cap = 256
        self._xs = np.zeros((self.k, self._cap), self._x_dtype)
        self._bs = np.zeros((self.k, self._cap), np.int16)
        self._slot_win = np.full(self.k, -1, np.int64)
        self.reset()

    def reset(self) -> None:
        """Forget every window (a new recording, or a jump in time)."""
        self._slot_win[:] = -1
        self.now = -1                 # the latest window's number (0 = the first after a reset)
        self.last_t0: int | None = None

    @property
    def available(self) -> int:
        """The windows it holds since the stream's start or last reset (at most k)."""
        return min(self.k, self.now + 1)

    def push(self, t0: int, idx: np.ndarray, bc_pix: tuple | None = None) -> None:
        """Add the window starting at t0 with the front end's ones ``idx`` (sorted, unique linear
        indices into (B, 2, H, W)); bc_pix: their (plane, pixel) = divmod(idx, H W) when the
        caller has them (runtime.spikes.SpikeVolume.bc, .pix: the pipeline needs them anyway)."""
        t0 = int(t0)
        if self.last_t0 is None:
            step = 1
        else:
            gap = t0 - self.last_t0
            step = gap // self.dt_us if gap > 0 and gap % self.dt_us == 0 else 0
            if step == 0:
                self.reset()
                step = 1
        self.now += step
        self.last_t0 = t0
        bc, pix = np.divmod(np.asarray(idx, dtype=np.int64), self.width * self.height) if bc_pix is None else bc_pix
        if bc.size > self._cap:
            cap = max(bc.size, 2 * self._cap)
            xs, bs = np.zeros((self.k, cap), self._x_dtype), np.zeros((self.k, cap), np.int16)
            xs[:, :self._cap], bs[:, :self._cap] = self._xs, self._bs
            self._xs, self._bs, self._cap = xs, bs, cap
        s = self.now % self.k
        _window_rows(np.asarray(bc, np.int64), np.asarray(pix, np.int64), self.width, self.height, self._ptr[s],
                     self._xs[s], self._bs[s])
        self._slot_win[s] = self.now

    def after(self, t0: int, window: np.ndarray) -> "OnesHistory":
        """A copy with the dense (B, 2, H, W) front-end window at t0 pushed: what a reference run
        of that window reads, leaving this history as it was (held-out and benchmark windows)."""
        ring = copy.deepcopy(self)
        ring.push(t0, np.flatnonzero(window))
        return ring

    def flow(self, boxes: np.ndarray, k_windows) -> np.ndarray:
        """(n, 2) px-per-bin plane-fit flow of each object over its time surface: its box
        (object_boxes; x0 < 0: none) over its K latest windows (k_windows; 0: none). Where K
        windows reach back before the stream's first window (or the last reset), only the
        windows held count (``available``; PlaneFusion then takes the fit's direction but not
        its speed)."""
        avail = self.available
        k_win = np.array([min(int(k), avail) for k in k_windows], np.int64)   # a handful: no numpy per row
        return _surface_flow(self._ptr, self._xs, self._bs, self._slot_win, self.now, self.n_bins, self.height,
                             np.asarray(boxes, dtype=np.int64).reshape(-1, 4), k_win, NEIGHBOURHOODS)


def warm_up() -> None:
    """Compile (or load from numba's cache) the kernels before the first window is timed."""
    h = OnesHistory(1, (2, 2), 1, 1)
    h.push(0, np.array([0], np.int64))
    boxes = object_boxes(np.zeros(1, np.int64), np.zeros(1, np.int64), np.zeros(1, np.int64), 1, 1, 2, 2)
    h.flow(boxes, [1])
    z = np.zeros(1, np.int64)
    fused_history_flow(np.zeros(1), np.ones((1, 2)), z, z, z, 1, h._ptr, h._xs, h._bs, h._slot_win, h.now,
                       h.available, h.n_bins, h.width, h.height, NEIGHBOURHOODS, 10.0, 1, 0.5, 10.0, 1.0, -np.inf,
                       1.0, 1)


def history_flow(history: OnesHistory, ones, n_obj: int, want, k_windows, margin: int) -> np.ndarray:
    """The plane fit (OnesHistory.flow) over each wanted object's time surface of its K latest
    windows (k_windows) in ``history``, its box from ``ones`` = (object, x, y, channel) of this
    window grown by ``margin``: the (n_obj, 2) px-per-bin flow (NaN: no answer or not wanted)."""
    boxes = object_boxes(np.asarray(ones[0], np.int64), np.asarray(ones[1], np.int64), np.asarray(ones[2], np.int64),
                         int(n_obj), int(margin), history.width, history.height)
    return history.flow(boxes, [k if w else 0 for k, w in zip(k_windows, np.asarray(want).tolist())])


@njit(cache=True, nogil=True)
def fused_history_flow(speed_ln, direction, obj, xs, ys, margin, ring_ptr, ring_xs, ring_bs, slot_win, now,
                       available, n_bins, width, height, table, distance_px, k_max, dt_ms, per_bin, w, log_min, wd,
                       refits):
    """plane_fit.PlaneFusion.apply with plane_fit_history, flow_of = history_flow, in one
    compiled call: the cpu runtime's form (a window crosses into compiled code once, not a
    dozen numpy and kernel calls: ~60 us a window less). The same steps on the same compiled
    pieces (history_rows, object_boxes, _surface_flow, flow_speed_rows, fuse_speed_rows,
    fuse_direction_rows) as apply and refit_history, which eval runs; a test checks the two
    agree to the bit. speed_ln (N,) float64 ln px/ms and direction (N, 2) float64 (cos, sin) of
    the OFPD, the objects' ones (obj, xs, ys) of this window, the OnesHistory's arrays; returns
    new (speed_ln, direction)."""
    s = speed_ln.copy()
    d = direction.copy()
    n = s.shape[0]
    want = np.empty(n, np.bool_)
    wanted = False
    for i in range(n):
        want[i] = wd > 0.0 or (w > 0.0 and s[i] > log_min)        # PlaneFusion.wanted
        wanted |= want[i]
    if not wanted:
        return s, d
    k = history_rows(s, True, distance_px, k_max, dt_ms)           # PlaneFusion.windows
    boxes = object_boxes(obj, xs, ys, n, margin, width, height)
    k_win = np.empty(n, np.int64)
    for i in range(n):
        k_win[i] = min(k[i], available) if want[i] else 0
    flow = _surface_flow(ring_ptr, ring_xs, ring_bs, slot_win, now, n_bins, height, boxes, k_win, table)
    k_fit = k.copy()
    for _r in range(refits):                                        # refit_history
        speeds = flow_speed_rows(flow, per_bin)
        k_new = history_rows(speeds, False, distance_px, k_max, dt_ms)
        redo = False
        for i in range(n):
            r = want[i] and speeds[i] > 0.0 and math.isfinite(speeds[i]) and k_fit[i] != k_new[i]
            k_win[i] = min(k_new[i], available) if r else 0
            redo |= r
        if not redo:
            break
        again = _surface_flow(ring_ptr, ring_xs, ring_bs, slot_win, now, n_bins, height, boxes, k_win, table)
        for i in range(n):
            v = math.hypot(again[i, 0], again[i, 1])
            if k_win[i] > 0 and v > 0.0 and math.isfinite(v):
                flow[i, 0], flow[i, 1] = again[i, 0], again[i, 1]
                k_fit[i] = k_new[i]
    if w > 0.0:
        speed_flow = flow.copy()                 # an object short of windows keeps the OFPD's speed
        for i in range(n):
            if max(k[i], k_fit[i]) > available:
                speed_flow[i, 0] = speed_flow[i, 1] = np.nan
        fuse_speed_rows(s, speed_flow, w, log_min, per_bin)
    if wd > 0.0:
        fuse_direction_rows(d, flow, wd)
    return s, d


def fuse_history(fusion, history: "OnesHistory", speed_ln, direction, ones) -> tuple[np.ndarray, np.ndarray]:
    """``fusion.apply(speed_ln, direction, flow_of, history.available)`` with flow_of the plane
    fit over ``history`` (history_flow; ``ones`` = (object, x, y, ...) of this window) through
    fused_history_flow: (ln px/ms (N,), direction (N, 2)) float64. fusion: a PlaneFusion with
    plane_fit_history."""
    d_px, k_max, margin = fusion.history
    return fused_history_flow(
        np.asarray(speed_ln, dtype=np.float64).reshape(-1), np.asarray(direction, dtype=np.float64).reshape(-1, 2),
        np.asarray(ones[0], np.int64), np.asarray(ones[1], np.int64), np.asarray(ones[2], np.int64), int(margin),
        history._ptr, history._xs, history._bs, history._slot_win, history.now, history.available, history.n_bins,
        history.width, history.height, NEIGHBOURHOODS, float(d_px), int(k_max), fusion.dt_us / 1000.0,
        fusion.per_bin, fusion.weight, fusion.log_min, fusion.dir_weight, int(fusion.refits))


def dense_history_flow(frames: np.ndarray, history: OnesHistory, want, k_windows, margin: int) -> np.ndarray:
    """history_flow with each object's box from its (N, B, 2, H, W) merged frame (eval)."""
    if history is None:
        raise ValueError("ofpd.plane_fit_history needs the windows before: pass an OnesHistory")
    frames = np.asarray(frames)
    obj, _b, _c, ys, xs = (a.astype(np.int64) for a in np.nonzero(frames > 0))
    return history_flow(history, (obj, xs, ys), frames.shape[0], want, k_windows, margin)
