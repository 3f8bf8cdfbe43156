"""Faint slow objects from the event density of the last L windows (issue 11, ``ofpd.faint_objects``).

An object slow enough to move a fraction of a pixel per window, at the sensor's contrast
threshold and in background noise, fires about as many events per window near it as the noise
does (``pairs_b1_000``: 0.125 px a window, 1.4 events per passing edge, 34 Hz per pixel of
noise: 40-50 event pixels a window in a 25 px disc against 33 of noise). No per-window
detector finds it (the OFS cascade's input front end keeps 0-14 of them), but it fires at the
same place window after window while noise does not: over L = 20 windows the object's box
stands 8-12 noise standard deviations above the sensor's density. The rule:

    e_j(q)   = 1 when pixel q had an event in the j-th latest window (j = 0: this one)
    c_L(g)   = sum over the pixels q of cell g (CELL x CELL px) of min(CAP, sum_{j<L} e_j(q))
               (capped: a hot pixel, which fires every window, counts CAP, not L)
    c_K(g)   = the same over the latest K windows
    rho_L    = sum_g c_L(g) / (H W)                      (the windows' capped event-pixel density)
    S_L(b)   = sum of c_L over the BOX x BOX cells of box b, mu_L = (BOX CELL)^2 rho_L
    b is significant when  S_L(b) - mu_L >= max(z_L sqrt(mu_L), N_L)
                      and  S_K(b) - mu_K >= max(Z_K sqrt(mu_K), N_K)      (it is there now too)

where the cells of this window's reported objects' ones, and of every fast object's (speed bin
>= FAST_BIN) ones over the L windows, grown by DILATE cells, count as noise (mu per cell): a
faint object is one the window's detections did not report, and a fast object's trail is
dense over L windows without being there now. Each significant box whose excess is the
largest within BOX boxes of it is a faint object at the centroid of its region (the significant
boxes connected to it, up to REACH boxes away: an object larger than a box is one region), the
cells' counts above mu + 2 sqrt(mu) as weights (a cell's noise 2 standard deviations up), unless

- its cell is excluded (above), or it lies within 2 BOX CELL px of a faint object already taken;
- it lies within half the diagonal of a reported object's ones' bounding box + MARGIN px of that
  box's centre or of the object's position (a big slow object's own outline);
- it lies in the outer half of such a disc around the reported position of an object of one of
  the K - 1 windows before whose ones' box has a diagonal of BOX CELL px or more (from half the
  box's half diagonal to the disc's edge): such an object's edges can be regions of their own,
  whose centroids lie on an edge, and the cascade often reports it from one edge only, a thin
  box whose disc misses the other edge in the windows between (`test_trefoil_o000_ccw_square_b1`
  at 100 Hz per pixel of noise: a 44 px square reported as a second object 22 px off its centre,
  a second track). A faint region centred on such an object is kept: it fills the windows the
  cascade missed;
- the significant region of the windows' counts without exclusions (boxes within 2 of each
  other are one region) that holds it also holds a reported object's position (the rest of a
  reported object's events).

A faint object is reported in speed bin 1 (it is slow: a faster one fires enough events per
window for the cascade) with that bin's representative speed, ofs_bin 1, ``faint`` true, and
the drift of its density as direction (the centroid of the latest K windows' counts from that
of the L windows'): a rough guess, not a measurement (mean error 43 deg on `appearance`, none
better than chance at 0.1 px a window), which is why scoring leaves faint objects out of the
direction and speed errors (metrics.FlowErrors) and the tracker takes their position only
(tracking.Detections, column 7). n_events is the box's excess over the noise per window.

Why not a longer front-end history instead (events/support.py, K 8-12, measured 2026-11-25):
each pixel's 5 x 5 box is too small to lift such an object over the noise, and fast objects'
trail pixels got support too (`pairs` false positives 0.033 -> 0.065-0.092 per window).

State (``FaintDensity``) streams like the front end's SupportHistory: windows in time order,
a gap of whole windows shifts in empty ones, anything else starts afresh; a fresh density holds
no windows, and the rule waits for max(K, L / 2) of them. The per-window work is O(events) for
the counts plus one pass over the cells (4,800 at 640x480) that stops the window unless a cell
outside the exclusions holds need_K / BOX^2 over its share over the latest K windows (no box can
stand out otherwise: most windows of a quiet scene stop there); then the box sums, O(cells).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .compiled import _div_small
from .events.support import skipped_windows
from .jit import njit

K_RECENT = 5          # K: the latest windows in which the object must stand out too
CELL = 8              # px per cell side
BOX = 4               # cells per box side (32 px)
Z_RECENT = 3.0        # Z_K
N_L = 30.0            # excess floor over L windows (event pixels): low-noise scenes, where sqrt(mu) ~ 0
N_K = 8.0             # excess floor over the latest K windows
CAP = 3               # a pixel counts at most CAP windows of L
DILATE = 2            # cells an exclusion grows by
FAST_BIN = 2          # reported objects of this bin or faster leave a trail to exclude
MARGIN = 8.0          # px beyond half a reported object's diagonal
REACH = 25            # boxes (200 px) a faint object's region reaches at most from its peak


@dataclass(frozen=True)
class FaintSettings:
    """``ofpd.faint_objects`` = [L, z_L]: windows of density, significance in noise standard deviations."""

    windows: int
    z: float

    @property
    def min_windows(self) -> int:
        return max(K_RECENT, self.windows // 2)


def faint_settings(config) -> FaintSettings | None:
    """The config's faint-object rule, or None when off (absent or null)."""
    from .ofpd_io import ofpd_settings

    v = ofpd_settings(config).get("faint_objects")
    return None if v is None else FaintSettings(int(v[0]), float(v[1]))


def check_faint_objects(value, config) -> None:
    """ofpd.faint_objects must be [L, z]: L a whole number K_RECENT..255 (windows), z a number
    in (0, 100], on a front end that keeps the windows before (input_support)."""
    ok = (isinstance(value, (list, tuple)) and len(value) == 2
          and isinstance(value[0], int) and not isinstance(value[0], bool) and K_RECENT <= value[0] <= 255
          and isinstance(value[1], (int, float)) and not isinstance(value[1], bool) and 0 < value[1] <= 100)
    if not ok:
        raise ValueError(f"ofpd.faint_objects must be [L, z]: L windows {K_RECENT}..255, z in (0, 100], got {value!r}")
    if getattr(config, "input_support", None) is None:
        raise ValueError("ofpd.faint_objects needs input_support (the front end's windows' event pixels)")


@njit(cache=True, nogil=True)
def _shift(cnt, cells, tot, add, sub_l, sub_k, width, wc):
    """cnt[q, 0] (windows of L with an event at q) -= 1 for q in sub_l, cnt[q, 1] (of K) -= 1 for q
    in sub_k, both += 1 for q in add, keeping cells[r, g] = sum over g's pixels of min(CAP,
    cnt[q, r]) and tot[r] = sum of cells[r] (one pass over the new pixels for both rings). A
    pixel's row from one float product (compiled._div_small), not an integer division: ~6,000 a
    window on the sample, whose divisions took ~15 % of the step (measured)."""
    inv_w = 1.0 / width
    for r in range(2):
        sub = sub_l if r == 0 else sub_k
        for i in range(sub.shape[0]):
            q = sub[i]
            if cnt[q, r] <= CAP:
                y = _div_small(q, width, inv_w)
                cells[r, (y // CELL) * wc + (q - y * width) // CELL] -= 1
                tot[r] -= 1
            cnt[q, r] -= 1
    for i in range(add.shape[0]):
        q = add[i]
        y = _div_small(q, width, inv_w)
        g = (y // CELL) * wc + (q - y * width) // CELL
        for r in range(2):
            if cnt[q, r] < CAP:
                cells[r, g] += 1
                tot[r] += 1
            cnt[q, r] += 1


@njit(cache=True, nogil=True)
def _ones_cells(obj, ox, oy, bins, hc, wc):
    """(cells of this window's objects' ones as a mask, the cells of the fast (bin >= FAST_BIN)
    objects' ones, unique, in the order first met)."""
    cur = np.zeros(hc * wc, np.bool_)
    fast = np.zeros(hc * wc, np.bool_)
    out = np.empty(obj.shape[0], np.int64)
    n = 0
    for i in range(obj.shape[0]):
        g = (oy[i] // CELL) * wc + ox[i] // CELL
        cur[g] = True
        if bins[obj[i]] >= FAST_BIN and not fast[g]:
            fast[g] = True
            out[n] = g
            n += 1
    return cur, out[:n].copy()


@njit(cache=True, nogil=True)
def _near(mask, counts, g, hc, wc):
    """Whether a cell within DILATE of cell g is set in ``mask`` or has counts > 0."""
    cy, cx = g // wc, g % wc
    for y in range(max(0, cy - DILATE), min(hc, cy + DILATE + 1)):
        for x in range(max(0, cx - DILATE), min(wc, cx + DILATE + 1)):
            if mask[y * wc + x] or counts[y * wc + x] > 0:
                return True
    return False


@njit(cache=True, nogil=True)
def _candidates(ck, tot_k, cur, fast, hc, wc, n_pixels):
    """Whether any cell not excluded (``_near`` this window's objects' cells or a fast trail) holds
    need_K / BOX^2 over its noise share over the latest K windows: a box can stand out only then
    (the sum of its cells' excesses reaches need_K), so most windows of a quiet scene stop here."""
    mu_ck = CELL * CELL * tot_k / n_pixels
    lone = max(Z_RECENT * math.sqrt(BOX * BOX * mu_ck), N_K) / (BOX * BOX)
    for g in range(hc * wc):
        if ck[g] - mu_ck >= lone and not _near(cur, fast, g, hc, wc):
            return True
    return False


@njit(cache=True, nogil=True)
def _excluded(cur, fast, hc, wc):
    """The excluded cells: this window's objects' cells and the fast objects' over the L windows
    (fast > 0), grown by DILATE cells."""
    excl = np.zeros(hc * wc, np.bool_)
    for g in range(hc * wc):
        if cur[g] or fast[g] > 0:
            cy, cx = g // wc, g % wc
            for y in range(max(0, cy - DILATE), min(hc, cy + DILATE + 1)):
                for x in range(max(0, cx - DILATE), min(wc, cx + DILATE + 1)):
                    excl[y * wc + x] = True
    return excl


@njit(cache=True, nogil=True)
def _integral(c, excl, fill, hc, wc):
    """(hc + 1, wc + 1) summed-area table of c with the excluded cells at ``fill``."""
    s = np.zeros((hc + 1, wc + 1))
    for y in range(hc):
        row = 0.0
        for x in range(wc):
            g = y * wc + x
            row += fill if excl[g] else c[g]
            s[y + 1, x + 1] = s[y, x + 1] + row
    return s


@njit(cache=True, nogil=True)
def _box(s, y, x):
    return s[y + BOX, x + BOX] - s[y, x + BOX] - s[y + BOX, x] + s[y, x]


@njit(cache=True, nogil=True)
def _centroid(c, excl, fill, hc, wc, cover, floor):
    """Centroid (x, y) px of max(c - floor, 0) (excluded cells at ``fill``) over the cells where
    ``cover`` is set; (nan, nan) when nothing is above the floor."""
    sw = sx = sy = 0.0
    for g in range(hc * wc):
        if not cover[g]:
            continue
        w = (fill if excl[g] else c[g]) - floor
        if w > 0:
            y, x = g // wc, g % wc
            sw += w
            sx += w * (x + 0.5) * CELL
            sy += w * (y + 0.5) * CELL
    if sw <= 0:
        return np.nan, np.nan
    return sx / sw, sy / sw


@njit(cache=True, nogil=True)
def _region(ex, hb, wb, b0, used, stack, cover, hc, wc):
    """Mark in ``used`` the significant boxes (ex >= 0) connected to box b0 (8-neighbours, at most
    REACH boxes from it) and in ``cover`` (cleared first) the cells they span."""
    cover[:] = False
    y0, x0 = b0 // wb, b0 % wb
    top = 1
    stack[0] = b0
    used[b0] = True
    while top > 0:
        top -= 1
        b = stack[top]
        by, bx = b // wb, b % wb
        for y in range(by, by + BOX):
            for x in range(bx, bx + BOX):
                cover[y * wc + x] = True
        for y in range(max(0, by - 1, y0 - REACH), min(hb, by + 2, y0 + REACH + 1)):
            for x in range(max(0, bx - 1, x0 - REACH), min(wb, bx + 2, x0 + REACH + 1)):
                q = y * wb + x
                if ex[q] >= 0 and not used[q]:
                    used[q] = True
                    stack[top] = q
                    top += 1


@njit(cache=True, nogil=True)
def _push_near(ok, mark, stack, top, yc, xc, r, hb, wb):
    """Mark and push onto ``stack`` (from ``top``) the boxes within r of (yc, xc) that are ``ok``
    and not marked yet; returns the new top."""
    for y in range(max(0, yc - r), min(hb, yc + r + 1)):
        for x in range(max(0, xc - r), min(wb, xc + r + 1)):
            q = y * wb + x
            if ok[q] and not mark[q]:
                mark[q] = True
                stack[top] = q
                top += 1
    return top


@njit(cache=True, nogil=True)
def _detect(cl, ck, tot_l, tot_k, excl, hc, wc, n_pixels, n_windows, z_l, det_x, det_y, discs, rims):
    """The faint objects of the module doc: (x, y, direction, n_events) arrays. cl, ck: the
    cells' capped counts over L and K windows (totals tot_l, tot_k); excl: excluded cells;
    det_x, det_y: the reported objects' positions; discs (m, 3): x, y, radius of their extents;
    rims (r, 3): the big objects' reported positions and radii of the windows before, whose
    outer half (radius / 2 - MARGIN / 2 .. radius) a faint object may not lie in."""
    rho_l, rho_k = tot_l / n_pixels, tot_k / n_pixels
    mu_cl, mu_ck = CELL * CELL * rho_l, CELL * CELL * rho_k
    mu_l, mu_k = BOX * BOX * mu_cl, BOX * BOX * mu_ck
    need_l = max(z_l * math.sqrt(mu_l), N_L)
    need_k = max(Z_RECENT * math.sqrt(mu_k), N_K)
    empty = np.zeros(0)
    if tot_k < N_K:
        return empty, empty, empty, empty
    hb, wb = hc - BOX + 1, wc - BOX + 1
    if hb <= 0 or wb <= 0:
        return empty, empty, empty, empty
    no_excl = np.zeros(hc * wc, np.bool_)
    sl = _integral(cl, excl, mu_cl, hc, wc)
    sk = _integral(ck, excl, mu_ck, hc, wc)
    rk = _integral(ck, no_excl, 0.0, hc, wc)
    ex = np.full(hb * wb, -1.0)               # excess over L windows of the significant boxes, else -1
    n_sig = 0
    for y in range(hb):
        for x in range(wb):
            if _box(rk, y, x) - mu_k < need_k:  # neither form can be significant
                continue
            e_l = _box(sl, y, x) - mu_l
            if e_l >= need_l and _box(sk, y, x) - mu_k >= need_k:
                ex[y * wb + x] = e_l
                n_sig += 1
    if n_sig == 0:
        return empty, empty, empty, empty
    rl = _integral(cl, no_excl, 0.0, hc, wc)
    raw = np.zeros(hb * wb, np.bool_)         # significant without exclusions
    for y in range(hb):
        for x in range(wb):
            if _box(rk, y, x) - mu_k >= need_k:
                raw[y * wb + x] = _box(rl, y, x) - mu_l >= need_l
    # regions of raw-significant boxes (within 2 of each other) holding a reported object: taken
    taken = np.zeros(hb * wb, np.bool_)
    stack = np.empty(hb * wb, np.int64)
    for d in range(det_x.shape[0]):
        if not (det_x[d] >= 0 and det_y[d] >= 0):
            continue
        by, bx = int(det_y[d]) // CELL - BOX // 2, int(det_x[d]) // CELL - BOX // 2
        top = _push_near(raw, taken, stack, 0, by, bx, 1, hb, wb)
        while top > 0:
            top -= 1
            top = _push_near(raw, taken, stack, top, stack[top] // wb, stack[top] % wb, 2, hb, wb)
    # peaks, largest excess first (only the significant boxes are sorted: most windows have few)
    sig = np.flatnonzero(ex >= 0)
    order = sig[np.argsort(-ex[sig])]
    out = np.empty((min(order.shape[0], 4096), 4))   # x, y, direction, n_events of the faint objects taken
    m = 0
    used = np.zeros(hb * wb, np.bool_)        # boxes of a region already reported (or refused)
    cover = np.zeros(hc * wc, np.bool_)
    sep = 2.0 * BOX * CELL
    for i in range(order.shape[0]):
        b = order[i]
        e = ex[b]
        if e < 0:
            break
        y0, x0 = b // wb, b % wb
        peak = True
        for y in range(max(0, y0 - BOX), min(hb, y0 + BOX + 1)):
            for x in range(max(0, x0 - BOX), min(wb, x0 + BOX + 1)):
                q = y * wb + x
                if ex[q] > e or (ex[q] == e and q < b):
                    peak = False
        if not peak or taken[b] or used[b]:
            continue
        _region(ex, hb, wb, b, used, stack, cover, hc, wc)
        cx, cy = _centroid(cl, excl, mu_cl, hc, wc, cover, mu_cl + 2.0 * math.sqrt(mu_cl))
        if not (cx >= 0 and cy >= 0) or excl[int(cy) // CELL * wc + int(cx) // CELL]:
            continue
        ok = m < out.shape[0]
        for j in range(m):
            if (cx - out[j, 0]) ** 2 + (cy - out[j, 1]) ** 2 < sep * sep:
                ok = False
        for j in range(discs.shape[0]):
            if (cx - discs[j, 0]) ** 2 + (cy - discs[j, 1]) ** 2 < discs[j, 2] ** 2:
                ok = False
        for j in range(rims.shape[0]):
            d2 = (cx - rims[j, 0]) ** 2 + (cy - rims[j, 1]) ** 2
            if 0.25 * (rims[j, 2] - MARGIN) ** 2 <= d2 < rims[j, 2] ** 2:
                ok = False
        if not ok:
            continue
        qx, qy = _centroid(ck, excl, mu_ck, hc, wc, cover, mu_ck + 2.0 * math.sqrt(mu_ck))
        out[m, 0], out[m, 1] = cx, cy
        out[m, 2] = math.atan2(qy - cy, qx - cx) if qx >= 0 and qy >= 0 else 0.0
        out[m, 3] = e / n_windows
        m += 1
    return out[:m, 0].copy(), out[:m, 1].copy(), out[:m, 2].copy(), out[:m, 3].copy()


@njit(cache=True, nogil=True)
def _discs(obj, ox, oy, n_obj, pos_x, pos_y):
    """(2 n, 3): for each object with ones, its ones' bounding box centre and its position, each
    with radius half the box's diagonal + MARGIN."""
    lo_x = np.full(n_obj, 1 << 30)
    lo_y = np.full(n_obj, 1 << 30)
    hi_x = np.full(n_obj, -1)
    hi_y = np.full(n_obj, -1)
    for i in range(obj.shape[0]):
        j = obj[i]
        lo_x[j] = min(lo_x[j], ox[i])
        hi_x[j] = max(hi_x[j], ox[i])
        lo_y[j] = min(lo_y[j], oy[i])
        hi_y[j] = max(hi_y[j], oy[i])
    out = np.empty((2 * n_obj, 3))
    m = 0
    for j in range(n_obj):
        if hi_x[j] < 0:
            continue
        r = 0.5 * math.hypot(hi_x[j] - lo_x[j], hi_y[j] - lo_y[j]) + MARGIN
        out[m] = ((lo_x[j] + hi_x[j]) / 2.0, (lo_y[j] + hi_y[j]) / 2.0, r)
        out[m + 1] = (pos_x[j], pos_y[j], r)
        m += 2
    return out[:m]


@njit(cache=True, nogil=True)
def _take_window(cnt, cells, tot, fast, pixels, old_l, old_k, old_fast, obj, ox, oy, bins, pos_x, pos_y,
                 width, hc, wc):
    """A window into the density, one compiled call (as three calls and numpy's fancy-index
    updates it took about 15 % more of the step, A/B on the sample): ``_ones_cells``, ``_shift``,
    the fast cells' counts over the L windows (old_fast: those of the window leaving) -> (this
    window's objects' cells as a mask, its fast cells, its objects' discs, ``_discs``)."""
    cur, fast_cells = _ones_cells(obj, ox, oy, bins, hc, wc)
    _shift(cnt, cells, tot, pixels, old_l, old_k, width, wc)
    for i in range(old_fast.shape[0]):       # unique cells each
        fast[old_fast[i]] -= 1
    for i in range(fast_cells.shape[0]):
        fast[fast_cells[i]] += 1
    if pos_x.shape[0] == 0:                  # no objects (a window's ones without any: none to index)
        return cur, fast_cells, np.zeros((0, 3))
    return cur, fast_cells, _discs(obj, ox, oy, pos_x.shape[0], pos_x, pos_y)


_NONE = np.zeros(0, np.int64)
_NO_POS = np.zeros(0)
_NO_DISCS = np.zeros((0, 3))


class FaintDensity:
    """The capped event-pixel counts of the last L and K windows by cell, the fast objects' cells
    over the L windows, and ``step``: this window's faint objects (module doc). Windows in time
    order; ``advance`` as SupportHistory's."""

    def __init__(self, settings: FaintSettings, sensor_size: tuple[int, int], dt_us: int):
        self.settings = settings
        self.width, self.height = int(sensor_size[0]), int(sensor_size[1])
        self.dt_us = int(dt_us)
        self.hc, self.wc = -(-self.height // CELL), -(-self.width // CELL)
        self._cnt = np.zeros((self.width * self.height, 2), np.uint8)   # per pixel: windows of L, of K with an event
        self._cells = np.zeros((2, self.hc * self.wc), np.int64)       # capped sums by cell: L, K
        self._tot = np.zeros(2, np.int64)
        self._fast = np.zeros(self.hc * self.wc, np.int64)
        self.reset()

    def reset(self) -> None:
        self._cnt[:] = 0
        self._cells[:] = 0
        self._tot[:] = 0
        self._fast[:] = 0
        self._ring: list[np.ndarray] = []
        self._fast_ring: list[np.ndarray] = []
        self._disc_ring: list[np.ndarray] = []   # the reported objects' discs (_discs) of the latest K windows
        self.last_t0: int | None = None

    @property
    def tot_l(self) -> int:
        return int(self._tot[0])

    def advance(self, t0: int) -> None:
        """Move to the window at t0: a gap of whole windows shifts in empty ones, anything else resets."""
        skipped = skipped_windows(self.last_t0, t0, self.dt_us, self.settings.windows)
        if skipped is None:
            self.reset()
            return
        for _ in range(skipped):
            self._push(_NONE)

    def _push(self, pixels: np.ndarray, obj=_NONE, ox=_NONE, oy=_NONE, bins=_NONE, pos_x=_NO_POS, pos_y=_NO_POS):
        """Add one window (its event pixels, its reported objects' ones, bins and positions);
        -> the mask of its objects' cells."""
        L = self.settings.windows
        old_k = self._ring[-K_RECENT] if len(self._ring) >= K_RECENT else _NONE
        old_l = self._ring.pop(0) if len(self._ring) == L else _NONE
        old_f = self._fast_ring.pop(0) if len(self._fast_ring) == L else _NONE
        cur, fast_cells, discs = _take_window(self._cnt, self._cells, self._tot, self._fast, pixels, old_l, old_k,
                                              old_f, obj, ox, oy, bins, pos_x, pos_y, self.width, self.hc, self.wc)
        self._ring.append(pixels)
        self._fast_ring.append(fast_cells)
        if len(self._disc_ring) == K_RECENT:
            self._disc_ring.pop(0)
        self._disc_ring.append(discs)
        return cur

    def _rims(self) -> np.ndarray:
        """(x, y, radius) of the reported positions of the K - 1 windows before this one whose
        ones' box has a diagonal of a box's side or more (module doc)."""
        out = [o[1::2] for o in self._disc_ring[:-1] if o.shape[0]]     # the position's disc of each object
        if not out:
            return _NO_DISCS
        pos = np.concatenate(out) if len(out) > 1 else out[0]
        return pos[pos[:, 2] >= BOX * CELL / 2.0 + MARGIN]

    def step(self, t0: int, pixels: np.ndarray, ones: tuple, bins, pos_x, pos_y):
        """Add window t0 (``pixels``: its unique event pixels y * W + x, before the front end) and
        return its faint objects (x, y, direction_rad, n_events) arrays. ones: (object, x, y, ...)
        flat arrays of the reported objects' ones (ofpd_input.batch's), bins / pos_x / pos_y their
        speed bins and positions."""
        self.advance(t0)
        obj, ox, oy = (np.asarray(ones[0], np.int64), np.asarray(ones[1], np.int64),
                       np.asarray(ones[2], np.int64)) if len(ones) else (_NONE, _NONE, _NONE)
        pos_x, pos_y = np.asarray(pos_x, np.float64), np.asarray(pos_y, np.float64)
        cur = self._push(np.asarray(pixels, np.int64), obj, ox, oy, np.asarray(bins, np.int64), pos_x, pos_y)
        self.last_t0 = int(t0)
        if len(self._ring) < self.settings.min_windows or not _candidates(
                self._cells[1], float(self._tot[1]), cur, self._fast, self.hc, self.wc, float(self.width * self.height)):
            e = np.zeros(0)
            return e, e, e, e
        excl = _excluded(cur, self._fast, self.hc, self.wc)
        return _detect(self._cells[0], self._cells[1], float(self._tot[0]), float(self._tot[1]), excl, self.hc,
                       self.wc, float(self.width * self.height), float(len(self._ring)), self.settings.z, pos_x, pos_y,
                       self._disc_ring[-1], self._rims())


def warm_up() -> None:
    """Compile (or load from numba's cache) every kernel ``step`` may call, with the argument
    types it calls them with, before the first window is timed: the search runs in few windows,
    and its first one would pay for the compile (tests/test_run_pipeline.py checks)."""
    d = FaintDensity(FaintSettings(K_RECENT, 7.0), (40, 40), 500)
    ones = (np.zeros(2, np.int64), np.array([5, 6], np.int64), np.array([5, 6], np.int64))
    for t in range(K_RECENT):
        d.step(t * 500, np.arange(0, 1600, 3, dtype=np.int64), ones, [2], [5.0], [5.0])
    excl = _excluded(np.zeros(d.hc * d.wc, np.bool_), d._fast, d.hc, d.wc)
    pos = np.array([5.0])
    discs = np.array([[5.0, 5.0, 9.0]])
    _detect(d._cells[0], d._cells[1], float(d._tot[0]), float(d._tot[1]), excl, d.hc, d.wc, 1600.0,
            float(K_RECENT), 7.0, pos, pos, discs, discs)
