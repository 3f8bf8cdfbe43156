"""Each object's image-plane velocity from the time surface of its ones (local plane fits), and
its fusion with the OFPD's regressed speed and direction (``config.ofpd`` keys
``plane_fit_weight``, ``plane_fit_min_px_ms``, ``plane_fit_dir_weight``).

Why: the OFPD reads speed off pooled cells (P = 2-16 px) and two motion planes that say which
way time runs inside each cell, not how fast; a fast object (bins 3-4) moves 2-8 px per window
and its speed head errs by 1.4 px/ms there (held-out appearance). The time at which an edge
reaches each pixel measures it directly (Benosman et al., "Event-based visual flow", IEEE TNNLS
2014: a plane fitted to the time surface has gradient 1 / normal speed).

For each polarity p of an object's ones (channel ch = 2 b + p), its time surface is
T_p(x, y) = the first time bin b at which pixel (x, y) fired. At every pixel i of it with at
least 4 of its 3 x 3 neighbours (itself included) on the surface, a least-squares plane

    T_p(x, y) = a_i (x - x_i) + b_i (y - y_i) + c_i           (a_i, b_i: bins per px)

is kept when its neighbourhood is not a line (det of the position covariance > 0.05 px^4). A
translating object with velocity v (px per bin) satisfies g_i . v = 1 at every edge pixel
(g_i = (a_i, b_i); the aperture problem: each pixel sees the normal component only), so

    v = argmin sum_i w_i (g_i . v - 1)^2,

solved with 4 passes of iteratively reweighted least squares (w_i = 1 / max(1, |r_i| / s),
r_i = g_i . v - 1, s = 1.5 median |r| + 1e-6, the median of every k-th residual, k = ceil(m /
64): of all m it cost half the fit and changed the fused error by 0.002 px/ms on the training
split), needs >= 3 planes (NaN otherwise). Velocity in px/ms = v * B * 1000 / dt_us.

Every plane is exact integer arithmetic but one division per coefficient (the position moments
of each of the 512 possible 3 x 3 neighbourhoods come from a table), and the pixels are visited
in the order of the ones, which every path hands over sorted (bin, polarity, y, x): the result
is the same bits on every target and in eval (cpu and loihi-sim share this code; a test
checks the runtime's against eval's).

Fusion (``fuse_speed``, on ln px/ms before ofpd_io.decode): where the OFPD's speed exceeds
``plane_fit_min_px_ms`` and the plane fit has a velocity,
ln s = w ln |v_plane| + (1 - w) ln s_OFPD, w = ``plane_fit_weight`` (0: off, the default, every
checkpoint written before these keys). Below the threshold the OFPD alone: slow objects (bins
1-2) move under 2 px per window, their time surface is a step or two of 100 us and the plane
fit over-reads. Direction (``PlaneFusion.direction``): the unit vectors of the plane fit's
velocity and of the OFPD's (cos, sin) averaged with weight ``plane_fit_dir_weight`` (0: off),
for every object the plane fit answers for; the OFPD is unsure where the time surface is
clear (fast objects) and the other way round. The constants are fitted on the training split
(benchmarks/fit_plane_fit.py), never on held-out data.

With ``plane_fit_history`` ([D, K_max, margin]; toffe_deploy/time_surface.py) the surface is
each object's over its last K windows instead of its ones of this one (the same planes and
IRLS, at most time_surface.MAX_PLANES planes); the shipped checkpoint then takes the fit alone
(both weights 1, threshold 0: fitted so on ``train``). ``plane_fit_refits`` (refit_history):
K again from the fit's own speed, which is closer than the OFPD's.
"""
from __future__ import annotations

import math

import numpy as np
from .jit import njit

from .config import ToffeConfig

MIN_DET = 0.05          # a plane needs a neighbourhood with det(position covariance) > 0.05 px^4
MIN_NEIGHBOURS = 4      # of the 3 x 3 (itself included) on the surface
MIN_PLANES = 3
IRLS_PASSES = 4
MEDIAN_OF = 64          # the IRLS scale: the median of every k-th residual, at most 64 of them


def _neighbourhood_table() -> np.ndarray:
    """(512, 7) int64: for each set of present 3 x 3 neighbours (bit k = (dy + 1) * 3 + dx + 1),
    n, sum dx, sum dy, then n^2 times the position covariances cxx, cyy, cxy and their
    determinant, or det 0 where the plane is not kept (n < MIN_NEIGHBOURS or a line)."""
    out = np.zeros((512, 7), np.int64)
    for mask in range(512):
        d = [((k // 3) - 1, (k % 3) - 1) for k in range(9) if mask >> k & 1]
        n = len(d)
        sx, sy = sum(x for _y, x in d), sum(y for y, _x in d)
        cxx = n * sum(x * x for _y, x in d) - sx * sx
        cyy = n * sum(y * y for y, _x in d) - sy * sy
        cxy = n * sum(x * y for y, x in d) - sx * sy
        det = cxx * cyy - cxy * cxy
        keep = n >= MIN_NEIGHBOURS and det > MIN_DET * n ** 4
        out[mask] = (n, sx, sy, cxx, cyy, cxy, det if keep else 0)
    return out


NEIGHBOURHOODS = _neighbourhood_table()


@njit(cache=True, nogil=True)
def _object_planes(xs, ys, ch, grid, planes, table):
    """Fills planes[:m] = (a, b) of every accepted plane of one object's ones (xs, ys, channel
    ch = 2 b + p; grid: scratch of -1 at least (2, h + 2, w + 2) over the bounding box with a
    one-pixel border, left all -1 again; table: NEIGHBOURHOODS); returns m. Visits the pixels in
    the order of the ones (both paths hand them over sorted by bin, polarity, y, x)."""
    x0 = xs.min() - 1
    y0 = ys.min() - 1
    for i in range(xs.shape[0]):
        p, b = ch[i] & 1, ch[i] >> 1
        t = grid[p, ys[i] - y0, xs[i] - x0]
        if t < 0 or b < t:
            grid[p, ys[i] - y0, xs[i] - x0] = b
    vx, vy, vp = np.empty(xs.shape[0], np.int64), np.empty(xs.shape[0], np.int64), np.empty(xs.shape[0], np.int64)
    n = 0
    for i in range(xs.shape[0]):
        p, y, x = ch[i] & 1, ys[i] - y0, xs[i] - x0
        if grid[p, y, x] == ch[i] >> 1:           # not a later one of a pixel that fired before
            vx[n], vy[n], vp[n] = x, y, p
            n += 1
    m = _grid_planes(vx, vy, vp, n, 1, grid, planes, table)
    for i in range(xs.shape[0]):
        grid[ch[i] & 1, ys[i] - y0, xs[i] - x0] = -1
    return m


@njit(cache=True, nogil=True)
def _grid_planes(vx, vy, vp, n, step, grid, planes, table):
    """The plane at every ``step``-th of the n pixels (vx, vy, polarity vp; grid coordinates,
    one-pixel border) of the time surface ``grid`` (-1: none), in that order, into planes[:m];
    returns m."""
    m = 0
    for i in range(0, n, step):
        p, y, x = vp[i], vy[i], vx[i]
        mask = k = st = sxt = syt = 0
        for dy in range(-1, 2):
            for dx in range(-1, 2):
                t = grid[p, y + dy, x + dx]
                if t >= 0:
                    mask |= 1 << k
                    st += t
                    sxt += t * dx
                    syt += t * dy
                k += 1
        det = table[mask, 6]
        if det == 0:
            continue
        n_, sx, sy, cxx, cyy, cxy = table[mask, 0], table[mask, 1], table[mask, 2], table[mask, 3], \
            table[mask, 4], table[mask, 5]
        cxt = n_ * sxt - sx * st                  # n^2 times the covariances: integers
        cyt = n_ * syt - sy * st
        planes[m, 0] = (cyy * cxt - cxy * cyt) / det
        planes[m, 1] = (cxx * cyt - cxy * cxt) / det
        m += 1
    return m


@njit(cache=True, nogil=True)
def _median(a, n):
    """np.median of a[:n] (n >= 1) by selection; reorders a."""
    k = n // 2
    lo, hi = 0, n - 1
    while lo < hi:                               # Hoare selection of the k-th smallest
        pivot = a[(lo + hi) // 2]
        i, j = lo, hi
        while i <= j:
            while a[i] < pivot:
                i += 1
            while a[j] > pivot:
                j -= 1
            if i <= j:
                a[i], a[j] = a[j], a[i]
                i += 1
                j -= 1
        if k <= j:
            hi = j
        elif k >= i:
            lo = i
        else:
            break
    kth = a[k]
    if n % 2:
        return kth
    below = a[0]
    for i in range(1, k):
        below = max(below, a[i])
    return (below + kth) / 2


@njit(cache=True, nogil=True)
def _solve(planes, m):
    """IRLS velocity (px per bin) from planes[:m]; NaN when fewer than MIN_PLANES or singular.
    Pass 1 weighs every plane 1; each further pass weighs plane i by 1 / max(1, r_i / s) of the
    pass before (its weights computed where they are summed)."""
    if m < MIN_PLANES:
        return np.nan, np.nan
    res = np.empty(m)
    step = (m + MEDIAN_OF - 1) // MEDIAN_OF
    work = np.empty((m + step - 1) // step)
    vx = vy = s = 0.0
    for it in range(IRLS_PASSES):
        a11 = a12 = a22 = b1 = b2 = 0.0
        for i in range(m):
            ga, gb = planes[i, 0], planes[i, 1]
            wi = 1.0 if it == 0 else 1.0 / max(1.0, res[i] / s)
            a11 += wi * ga * ga
            a12 += wi * ga * gb
            a22 += wi * gb * gb
            b1 += wi * ga
            b2 += wi * gb
        a11 += 1e-9
        a22 += 1e-9
        det = a11 * a22 - a12 * a12
        if not det > 0.0:
            return np.nan, np.nan
        vx = (a22 * b1 - a12 * b2) / det
        vy = (a11 * b2 - a12 * b1) / det
        if it == IRLS_PASSES - 1:
            break
        for i in range(m):
            res[i] = abs(planes[i, 0] * vx + planes[i, 1] * vy - 1.0)
        k = 0
        for i in range(0, m, step):              # the scale from at most MEDIAN_OF residuals
            work[k] = res[i]
            k += 1
        s = 1.5 * _median(work, k) + 1e-6
    return vx, vy


@njit(cache=True, nogil=True)
def object_planes_flow(obj, xs, ys, ch, n_obj, want):
    """(n_obj, 2) float64 velocity (px per time bin, y down) of each object j with want[j] from
    its ones given as flat arrays (object obj, pixel xs, ys, channel ch = 2 b + p); NaN where the
    plane fit has no answer (module doc) or was not wanted. Each object's result depends on its
    own ones and their order only (the runtime asks for the fast objects alone). Both paths hand
    the ones over object by object (obj non-decreasing: each object's ones a slice); any other
    order is grouped first (a counting sort, each object's ones kept in their order)."""
    out = np.full((n_obj, 2), np.nan)
    n = obj.shape[0]
    count = np.zeros(n_obj + 1, np.int64)
    grouped = True
    for i in range(n):
        count[obj[i] + 1] += 1
        if i and obj[i] < obj[i - 1]:
            grouped = False
    for j in range(n_obj):
        count[j + 1] += count[j]
    if not grouped:
        fill = count[:-1].copy()
        order = np.empty(n, np.int64)
        for i in range(n):
            order[fill[obj[i]]] = i
            fill[obj[i]] += 1
        xs, ys, ch = xs[order], ys[order], ch[order]
    size = 0
    w = h = 0
    for j in range(n_obj):
        lo, hi = count[j], count[j + 1]
        if hi - lo >= MIN_NEIGHBOURS and want[j]:
            size = max(size, hi - lo)
            w = max(w, xs[lo:hi].max() - xs[lo:hi].min() + 3)
            h = max(h, ys[lo:hi].max() - ys[lo:hi].min() + 3)
    if size == 0:
        return out
    grid = np.full((2, h, w), -1, np.int16)       # one scratch for all: each object leaves it all -1
    planes = np.empty((size, 2))
    for j in range(n_obj):
        lo, hi = count[j], count[j + 1]
        if hi - lo < MIN_NEIGHBOURS or not want[j]:
            continue
        m = _object_planes(xs[lo:hi], ys[lo:hi], ch[lo:hi], grid, planes, NEIGHBOURHOODS)
        out[j, 0], out[j, 1] = _solve(planes, m)
    return out


def fit_settings(config: ToffeConfig) -> tuple[float, float, float]:
    """(plane_fit_weight, plane_fit_min_px_ms, plane_fit_dir_weight) of config.ofpd; the weights
    0 (off) when absent. Checks ``plane_fit_history`` too (history_settings)."""
    s = config.ofpd or {}
    try:
        w = float(s.get("plane_fit_weight", 0.0))
        lo = float(s.get("plane_fit_min_px_ms", 4.0))
        wd = float(s.get("plane_fit_dir_weight", 0.0))
    except (TypeError, ValueError):
        raise ValueError("ofpd.plane_fit_weight, plane_fit_min_px_ms and plane_fit_dir_weight must be numbers") from None
    for name, v in (("plane_fit_weight", w), ("plane_fit_dir_weight", wd)):
        if not 0.0 <= v <= 1.0:
            raise ValueError(f"ofpd.{name} must be in [0, 1], got {v}")
    if not lo >= 0.0:
        raise ValueError(f"ofpd.plane_fit_min_px_ms must be >= 0, got {lo}")
    history_settings(config)
    refit_settings(config)
    return w, lo, wd


def refit_settings(config: ToffeConfig) -> int:
    """config.ofpd.plane_fit_refits: how many times K is worked out again from the plane fit's
    own speed and the surface fitted again (refit_history); 0 (off) when absent. Needs
    plane_fit_history."""
    v = (config.ofpd or {}).get("plane_fit_refits", 0)
    if isinstance(v, bool) or not isinstance(v, int) or not 0 <= v <= 4:
        raise ValueError(f"ofpd.plane_fit_refits must be an integer 0-4, got {v!r}")
    if v and history_settings(config) is None:
        raise ValueError("ofpd.plane_fit_refits needs ofpd.plane_fit_history")
    return v


def refit_history(flow, k_windows: list[int], want, flow_of, distance_px: float, k_max: int, dt_us: int,
                  per_bin: float, refits: int) -> tuple[np.ndarray, list[int]]:
    """(flow, K) after ``refits`` rounds of: K again from each wanted object's fitted speed
    (time_surface.history_windows of |v| per_bin px/ms), then ``flow_of(redo, K)`` for the objects whose K
    changed; an object keeps its earlier flow and K where the new fit gives no answer.

    Why: K comes first from the OFPD's speed, and where that errs the surface spans the wrong
    time (too short: a noisy ramp; too long: a turning path). The fit's own speed is closer
    (train: 0.38 against 1.0 px/ms), so K from it spans nearer the D px the fit wants
    (benchmarks/fit_plane_fit.py --refits; ckpt/README.md, "Refitting K")."""
    from .time_surface import history_windows

    flow = np.array(flow, dtype=np.float64).reshape(-1, 2)
    k = list(k_windows)
    wanted = np.asarray(want, dtype=bool).reshape(-1).tolist()
    for _ in range(int(refits)):
        speeds = flow_speed_rows(flow, per_bin).tolist()       # px/ms
        k_new = history_windows(speeds, distance_px, k_max, dt_us)
        redo = [w and s > 0.0 and math.isfinite(s) and a != b for w, s, a, b in zip(wanted, speeds, k, k_new)]
        if not any(redo):
            break
        again = np.asarray(flow_of(np.array(redo, np.bool_), [b if r else 0 for r, b in zip(redo, k_new)]),
                           dtype=np.float64).reshape(-1, 2)
        for i, (r, (fx, fy)) in enumerate(zip(redo, again.tolist())):
            v = math.hypot(fx, fy)
            if r and v > 0.0 and math.isfinite(v):
                flow[i] = fx, fy
                k[i] = k_new[i]
    return flow, k


def history_settings(config: ToffeConfig) -> tuple[float, int, int] | None:
    """(D px, K_max windows, margin px) of config.ofpd.plane_fit_history, or None (absent: the
    plane fit reads each object's ones of its window; toffe_deploy/time_surface.py)."""
    v = (config.ofpd or {}).get("plane_fit_history")
    if v is None:
        return None
    bad = ValueError(f"ofpd.plane_fit_history must be [distance px > 0, max windows 1-1000, margin px 0-64], got {v!r}")
    if not isinstance(v, (list, tuple)) or len(v) != 3 or isinstance(v[1], bool) or isinstance(v[2], bool):
        raise bad
    try:
        d, k, g = float(v[0]), v[1], v[2]
    except (TypeError, ValueError):
        raise bad from None
    if not (isinstance(k, int) and isinstance(g, int) and math.isfinite(d) and d > 0 and 1 <= k <= 1000
            and 0 <= g <= 64):
        raise bad
    return d, k, g


def px_ms_per_px_bin(config: ToffeConfig) -> float:
    """px per time bin -> px/ms: B bins in dt_us."""
    return config.n_bins * 1000.0 / config.dt_us


def flow_px_ms(flow_px_bin: np.ndarray, config: ToffeConfig) -> np.ndarray:
    """Plane-fit speeds |v| in px/ms of object_planes_flow's (N, 2) px per bin."""
    return flow_speed_rows(_rows2(flow_px_bin), px_ms_per_px_bin(config))


class PlaneFusion:
    """The plane fit blended into the OFPD's outputs, with the config's settings worked out once
    (the cpu runtime fuses every window):

    - ``speed(speed_ln, flow)``: ln s = w ln |v| + (1 - w) ln s_OFPD where s_OFPD >
      plane_fit_min_px_ms (w = plane_fit_weight);
    - ``direction(direction, flow)``: the unit vectors blended, u = wd v / |v| + (1 - wd)
      d / |d| (wd = plane_fit_dir_weight, d the OFPD's (cos, sin)), for every object with a
      plane fit; decode takes its angle;
    - ``wanted(speed_ln)``: the objects whose plane fit either would use (the runtime fits those
      only): every object when wd > 0, else those over the speed threshold.

    Rows without a plane fit (NaN) keep the OFPD's values. The row arithmetic is compiled
    (fuse_speed_rows, fuse_direction_rows, time_surface.history_rows) and shared by every path:
    eval runs ``apply``; the runtime, with plane_fit_history, runs the same steps on the same
    pieces in one compiled call (time_surface.fuse_history); they agree to the bit (tests)."""

    def __init__(self, config: ToffeConfig, weight: float | None = None, min_px_ms: float | None = None,
                 dir_weight: float | None = None):
        w, lo, wd = fit_settings(config)
        self.weight = w if weight is None else float(weight)
        self.min_px_ms = lo if min_px_ms is None else float(min_px_ms)
        self.dir_weight = wd if dir_weight is None else float(dir_weight)
        self.log_min = math.log(self.min_px_ms) if self.min_px_ms > 0 else -math.inf
        self.per_bin = px_ms_per_px_bin(config)
        self.history = history_settings(config)      # (D, K_max, margin) or None
        self.refits = refit_settings(config)
        self.dt_us = int(config.dt_us)

    @property
    def on(self) -> bool:
        return self.weight > 0.0 or self.dir_weight > 0.0

    def wanted(self, speed_ln) -> np.ndarray:
        s = np.asarray(speed_ln, dtype=np.float64).reshape(-1)
        if self.dir_weight > 0.0:
            return np.ones(s.shape[0], np.bool_)
        if self.weight > 0.0:
            return s > self.log_min
        return np.zeros(s.shape[0], np.bool_)

    def windows(self, speed_ln) -> list[int] | None:
        """K of each object with plane_fit_history (time_surface.history_windows of the OFPD's
        speed), else None."""
        if self.history is None:
            return None
        from .time_surface import history_windows

        s = np.asarray(speed_ln, dtype=np.float64).reshape(-1).tolist()
        return history_windows(s, self.history[0], self.history[1], self.dt_us, log=True)

    def apply(self, speed_ln, direction, flow_of, available: int | None = None):
        """(speed, direction) with the plane fit blended in, or as given when it is off or no
        object wants it; ``flow_of(want, k_windows)`` gives the (N, 2) plane-fit flow of the
        objects ``want`` marks (the runtime fits those only, eval every object: the unwanted rows
        are not read), k_windows: ``windows(speed_ln)`` (None: each object's ones of this window),
        then again from the fit's speed with plane_fit_refits (refit_history).
        available: the windows the history holds (plane_fit_history): an object that wants more
        gets the fit's direction but keeps the OFPD's speed (its surface is too short in time:
        a slow object's reads too fast), as at a stream's start."""
        if not self.on:
            return speed_ln, direction
        want = self.wanted(speed_ln)
        if not want.any():
            return speed_ln, direction
        k = self.windows(speed_ln)
        flow = flow_of(want, k)
        if k is not None and self.refits:        # short: by the OFPD's K or the refitted one
            flow, k_fit = refit_history(flow, k, want, flow_of, self.history[0], self.history[1], self.dt_us,
                                        self.per_bin, self.refits)
            k = [max(a, b) for a, b in zip(k, k_fit)]
        if k is not None and available is not None and any(v > available for v in k):
            short = np.array([v > available for v in k])
            speed_flow = np.where(short[:, None], np.nan, np.asarray(flow, dtype=np.float64).reshape(-1, 2))
            return self.speed(speed_ln, speed_flow), self.direction(direction, flow)
        return self.speed(speed_ln, flow), self.direction(direction, flow)

    def speed(self, speed_ln, flow_px_bin) -> list[float]:
        s = np.array(speed_ln, dtype=np.float64).reshape(-1)
        if self.weight > 0.0:
            fuse_speed_rows(s, _rows2(flow_px_bin), self.weight, self.log_min, self.per_bin)
        return s.tolist()

    def direction(self, direction, flow_px_bin) -> np.ndarray:
        d = np.array(direction, dtype=np.float64).reshape(-1, 2)
        if self.dir_weight > 0.0:
            fuse_direction_rows(d, _rows2(flow_px_bin), self.dir_weight)
        return d


def _rows2(flow) -> np.ndarray:
    """(N, 2) C-contiguous float64 rows of a flow (the compiled row kernels' input)."""
    return np.ascontiguousarray(np.asarray(flow, dtype=np.float64).reshape(-1, 2))


@njit(cache=True, nogil=True)
def fuse_speed_rows(s, flow, w, log_min, per_bin):
    """PlaneFusion.speed in place on s (N,) ln px/ms: ln s = w ln |v| + (1 - w) ln s where
    s > log_min and |v| = hypot(flow) * per_bin (px/ms) is finite and > 0. Compiled, and the
    one implementation every path calls: numba's hypot and CPython's math.hypot differ in the
    last bit for ~0.2 % of inputs, so the runtime and eval must share it to agree to the bit."""
    for i in range(s.shape[0]):
        v = math.hypot(flow[i, 0], flow[i, 1]) * per_bin
        if s[i] > log_min and v > 0.0 and math.isfinite(v):
            s[i] = w * math.log(v) + (1.0 - w) * s[i]


@njit(cache=True, nogil=True)
def fuse_direction_rows(d, flow, wd):
    """PlaneFusion.direction in place on d (N, 2) (cos, sin): u = wd v / |v| + (1 - wd) d / |d|
    for the rows whose flow v is finite and > 0 (and |d| > 0)."""
    for i in range(d.shape[0]):
        fx, fy = flow[i, 0], flow[i, 1]
        v = math.hypot(fx, fy)
        c, sn = d[i, 0], d[i, 1]
        n = math.hypot(c, sn)
        if v > 0.0 and math.isfinite(v) and n > 0.0:
            d[i, 0] = wd * (fx / v) + (1.0 - wd) * (c / n)
            d[i, 1] = wd * (fy / v) + (1.0 - wd) * (sn / n)


@njit(cache=True, nogil=True)
def flow_speed_rows(flow, per_bin):
    """(N,) |v| px/ms = hypot(flow) * per_bin of (N, 2) px-per-bin rows (the compiled hypot:
    fuse_speed_rows)."""
    out = np.empty(flow.shape[0])
    for i in range(flow.shape[0]):
        out[i] = math.hypot(flow[i, 0], flow[i, 1]) * per_bin
    return out


def fuse_speed(speed_ln: np.ndarray, flow_px_bin: np.ndarray, config: ToffeConfig, weight: float | None = None,
               min_px_ms: float | None = None) -> np.ndarray:
    """The OFPD's ln px/ms (N,) with the plane fit blended in (PlaneFusion.speed), a new float64
    array. ``weight`` / ``min_px_ms`` override the config's (the fitting script)."""
    return np.asarray(PlaneFusion(config, weight, min_px_ms).speed(speed_ln, flow_px_bin), dtype=np.float64)


def fuse_direction(direction: np.ndarray, flow_px_bin: np.ndarray, config: ToffeConfig,
                   dir_weight: float | None = None) -> np.ndarray:
    """The OFPD's (N, 2) (cos, sin) with the plane fit's direction blended in
    (PlaneFusion.direction), a new float64 array; ``dir_weight`` overrides the config's."""
    return PlaneFusion(config, dir_weight=dir_weight).direction(direction, flow_px_bin)


def dense_flow(frames: np.ndarray) -> np.ndarray:
    """object_planes_flow of (N, B, 2, H, W) frames (eval, training's reference path)."""
    frames = np.asarray(frames)
    if frames.ndim == 4:
        frames = frames[None]
    n = frames.shape[0]
    nz = np.nonzero(frames > 0)
    obj, bb, cc, ys, xs = (a.astype(np.int64) for a in nz)
    return object_planes_flow(obj, xs, ys, bb * 2 + cc, n, np.ones(n, np.bool_))


def warm_up() -> None:
    """Load (or compile) the one-window plane fit's kernels as the Pipeline calls them
    (object_planes_flow on window_objects' int64 ones, the fusion rows), before the first window."""
    z = np.zeros(1, np.int64)
    object_planes_flow(z, z, z, z, 1, np.ones(1, np.bool_))
    flow = np.full((1, 2), np.nan)
    fuse_speed_rows(np.zeros(1), flow, 0.5, 0.0, 1.0)
    fuse_direction_rows(np.ones((1, 2)), flow, 0.5)
    flow_speed_rows(flow, 1.0)
