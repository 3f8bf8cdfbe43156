"""Temporal support for the input front end (issue 11): a pixel the cluster filter drops is kept
when the window and the K windows before it fired enough pixels around it.

With e_j(q) = 1 when pixel q had an event in the j-th window before this one (e_0: this window),
the event pixels p of the window that the front end (events/frontend.py, ``input_min_cluster``)
drops are kept when

    S(p) = sum over q with max(|q_y - p_y|, |q_x - p_x|) <= r of  sum_{j=0..K} e_j(q)  >= T,
    T    = m + floor(c * (2r + 1)^2 * E / (H * W)),   E = sum over all q, j of e_j(q),

(T: m plus c times the S a pixel would get from the recording's event-pixel density alone,
which is the sensor noise's unless an object fills the sensor; c = 0: T = m).

Why: an object slower than ~0.5 px per 500 us window fires scattered pixels of its edge, not
a connected band, so the cluster filter drops all of them (measured: a median 22 pixels in, 0
kept, for the bin-1 misses); but the edge stays on the same pixels for several windows, so they
fire again, while sensor noise does not: at 50 Hz per pixel and 500 us, e_j(q) = 1 for 2.5 % of
the pixels, so S(p) of a noise pixel is 1 + Poisson(44 * 0.025) for K = 4, r = 1, and S >= 6
for 0.5 % of them (20 Hz: 0.01 %; 100 Hz: 7 %); T grows with the noise (c = 2: T = m at 20 Hz,
m + 2 at 50 Hz, m + 4 at 100 Hz) so that fewer of them pass. Lowering the cluster size instead
(n = 2) keeps the slow edges and every pair of neighbouring noise pixels (50 Hz: 1.73 false
positives per window).

``counts`` is the (H, W) sum of the K previous windows' event-pixel images (``history_counts``);
a caller that streams windows in order keeps it up to date, one that samples a window reads the
events of [t0 - K dt, t0). Dense (``support_dense``) and index (``support_index``) forms agree bit
for bit.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from ..jit import njit

from ..compiled import _root, cluster_sizes, front_end_pass
from .frontend import apply_dense, check_min_cluster, check_norm, slots_for


def event_pixels(volume: np.ndarray) -> np.ndarray:
    """(B, C, H, W) spikes -> (H, W) bool: the pixels with an event (any bin, any polarity)."""
    return (np.asarray(volume) > 0).any(axis=(0, 1))


def history_counts(pixel_images) -> np.ndarray:
    """(K, H, W) event-pixel images of the previous windows -> (H, W) uint8 counts (K <= 255)."""
    imgs = np.asarray(pixel_images, dtype=bool)
    return imgs.sum(axis=0, dtype=np.uint8)


def support_threshold(m: int, noise_factor: int, radius: int, total: int, n_pixels: int) -> int:
    """T of the module doc, in integers (``total`` = E)."""
    return int(m) + (int(noise_factor) * (2 * int(radius) + 1) ** 2 * int(total)) // int(n_pixels)


def support_mask_dense(pix: np.ndarray, counts: np.ndarray, radius: int, m: int, noise_factor: int = 0) -> np.ndarray:
    """(H, W) bool: pixels of ``pix`` with S >= T (module doc), S from ``counts`` + ``pix``."""
    import cv2

    acc = counts.astype(np.float32) + pix
    k = 2 * int(radius) + 1
    box = cv2.boxFilter(acc, -1, (k, k), normalize=False, borderType=cv2.BORDER_CONSTANT)
    t = support_threshold(m, noise_factor, radius, int(counts.sum(dtype=np.int64)) + int(pix.sum()), pix.size)
    return pix & (np.rint(box) >= t)


def support_dense(volume: np.ndarray, norm: str, min_cluster: int, counts: np.ndarray, radius: int,
                  m: int, noise_factor: int = 0) -> np.ndarray:
    """The front end with temporal support on a dense (B, C, H, W) window; bool volume."""
    base = apply_dense(volume, norm, min_cluster)
    every = apply_dense(volume, norm, 1)
    keep = event_pixels(base) | support_mask_dense(event_pixels(volume), counts, radius, m, noise_factor)
    return every & keep[None, None]


@njit(cache=True, nogil=True)
def support_keep(idx, n_channels, n_pixels, width, height, first, min_size, slot_of, counts, radius, m, noise_factor,
                 counts_total):
    """The front end with temporal support over a sorted linear index of ones, in one pass
    (compiled.front_end_pass, as front_end_keep): a one that ``first`` keeps stays when its
    pixel's cluster has >= min_size pixels or S >= T (module doc). While the pass's slots are
    set, slot_of[q] >= 0 marks the window's event pixels, so S = box sum of counts + marks;
    S is read once per dropped pixel. Returns (the kept ones: idx[keep], written as they pass,
    which spares the caller a compress (~3 us a window); the window's event pixels, first seen
    first: what SupportHistory.push takes; and the kept ones' SpikeVolume.pixel_index: their
    unique pixels, first seen first, and inverse, as compiled.dedupe gives them); leaves
    slot_of all -1."""
    keep, slot, parent, pix, u = front_end_pass(idx, n_channels, n_pixels, width, first, min_size > 1, slot_of)
    t = m + (noise_factor * (2 * radius + 1) ** 2 * (counts_total + u)) // n_pixels
    size = cluster_sizes(parent, u) if min_size > 1 else np.zeros(0, np.int64)
    passed = np.zeros(u, np.int8)               # per slot: 0 not read yet, 1 S >= T, -1 S < T
    new_of = np.full(u, -1, np.int64)           # slot -> index among the kept ones' pixels
    upix = np.empty(u, np.int64)
    inverse = np.empty(idx.shape[0], np.int64)
    kept = np.empty(idx.shape[0], idx.dtype)
    nu = 0
    e = 0
    for i in range(idx.shape[0]):
        if not keep[i]:
            continue
        q = slot[i]
        if min_size > 1 and size[_root(parent, q)] < min_size:
            if passed[q] == 0:
                p = pix[q]
                y = p // width
                x = p - y * width
                s = 0
                for yy in range(max(0, y - radius), min(height, y + radius + 1)):
                    row = yy * width
                    for xx in range(max(0, x - radius), min(width, x + radius + 1)):
                        s += np.int64(counts[row + xx]) + (slot_of[row + xx] >= 0)
                passed[q] = 1 if s >= t else -1
            if passed[q] < 0:
                continue
        if new_of[q] < 0:
            new_of[q] = nu
            upix[nu] = pix[q]
            nu += 1
        inverse[e] = new_of[q]
        kept[e] = idx[i]
        e += 1
    for q in range(u):
        slot_of[pix[q]] = -1
    return kept[:e], pix[:u], upix[:nu], inverse[:e]


def support_index(idx: np.ndarray, shape: tuple[int, ...], norm: str, min_cluster: int, counts: np.ndarray,
                  radius: int, m: int, noise_factor: int = 0, counts_total: int | None = None,
                  return_pixels: bool = False):
    """The same on a sorted unique linear index of ones into a (B, C, H, W) volume; ``counts`` an
    (H, W) or (H * W,) uint8 count image, ``counts_total`` its sum (a streaming caller keeps it;
    None: summed here, only when noise_factor > 0). One compiled pass (support_keep).
    Returns a sorted index; with ``return_pixels`` also the window's event pixels (unique linear
    y * W + x, unsorted: what SupportHistory.push takes)."""
    kept, pixels, _pixel_index = _support_run(idx, shape, norm, min_cluster, counts, radius, m, noise_factor,
                                              counts_total)
    return (kept, pixels) if return_pixels else kept


def _support_run(idx, shape, norm, min_cluster, counts, radius, m, noise_factor=0, counts_total=None):
    """support_index's (kept index, the window's event pixels, (unique pixels, inverse) of the
    kept ones or None when there are none)."""
    idx = np.asarray(idx, dtype=np.int64)
    if idx.size == 0:
        return idx, idx, None
    c, h, w = int(shape[1]), int(shape[2]), int(shape[3])
    n_pixels = h * w
    first = check_norm(norm) == "first"
    slots = slots_for(n_pixels)
    cnt = np.ascontiguousarray(counts, np.uint8).reshape(-1)
    total = int(cnt.sum(dtype=np.int64)) if counts_total is None and noise_factor else int(counts_total or 0)
    kept, pixels, upix, inverse = support_keep(idx, c, n_pixels, w, h, first, check_min_cluster(min_cluster), slots,
                                               cnt, int(radius), int(m), int(noise_factor), total)
    return kept, pixels, (upix, inverse)


_NONE = np.zeros(0, np.int64)


@njit(cache=True, nogil=True)
def _shift_counts(counts, add, sub):
    """counts[sub] -= 1, counts[add] += 1 (unique indices each): numpy's two fancy-index
    updates in one compiled pass, ~10x cheaper on a window's ~1,000 pixels."""
    for i in range(sub.shape[0]):
        counts[sub[i]] -= 1
    for i in range(add.shape[0]):
        counts[add[i]] += 1


def skipped_windows(last_t0: int | None, t0: int, dt_us: int, cap: int) -> int | None:
    """How many empty windows a history that holds windows up to ``last_t0`` shifts in before the
    window at t0 (at most ``cap``; 0 for the next window or a fresh history), or None when t0 is
    no later window on its grid (a jump back, a gap that is no multiple of dt): start afresh."""
    if last_t0 is None:
        return 0
    gap = int(t0) - int(last_t0)
    if gap <= 0 or gap % int(dt_us):
        return None
    return min(gap // int(dt_us) - 1, int(cap))


@dataclass(frozen=True)
class Latest:
    """SupportHistory.latest: counts (H * W,) uint8 = sum over the latest K windows of their
    event-pixel images, total = their sum."""

    counts: np.ndarray
    total: int


class SupportHistory:
    """The event pixels of the last K windows (a ring of their linear pixel indices) and their
    (H * W,) uint8 count image ``counts`` with sum ``total``: what ``front_end`` reads as the
    windows before. ``advance(t0)`` moves it to the window starting at t0: the next window
    (t0 = last + dt) keeps it, a gap of whole windows shifts in empty ones (a skipped window had
    no events), anything else (a jump back, a gap that is no multiple of dt) forgets it
    (``reset``); a fresh history is K empty windows, as before a recording's start. Advancing
    twice to the same t0 (``front_end`` advances, then ``push`` does) shifts the gap in once."""

    def __init__(self, k: int, sensor_size: tuple[int, int], dt_us: int):
        self.k = int(k)
        self.width, self.height = int(sensor_size[0]), int(sensor_size[1])
        self.dt_us = int(dt_us)
        self.counts = np.zeros(self.width * self.height, np.uint8)
        self.reset()

    def reset(self) -> None:
        self.counts[:] = 0
        self.total = 0
        self._ring: list[np.ndarray] = []
        self.last_t0: int | None = None

    def advance(self, t0: int) -> None:
        skipped = skipped_windows(self.last_t0, t0, self.dt_us, self.k)
        if skipped is None:
            self.reset()
            return
        for _ in range(skipped):
            self._push(_NONE)
        if self.last_t0 is not None:
            self.last_t0 = int(t0) - self.dt_us      # the skipped windows are in: advancing again to t0 adds none

    @property
    def latest_pixels(self) -> np.ndarray:
        """The event pixels of the latest window pushed (unique y * W + x; empty when none)."""
        return self._ring[-1] if self._ring else _NONE

    def latest(self) -> "Latest":
        """A copy of what it holds now (counts, total): what ofpd.recent_events reads for this
        window, kept while later windows move the history on (the Lava targets' pipelining)."""
        return Latest(self.counts.copy(), self.total)

    def push(self, t0: int, pixels: np.ndarray) -> None:
        """Add the window at t0 (``advance`` to it first): ``pixels`` its unique linear pixel
        indices (y * W + x) with an event."""
        self.advance(t0)
        self._add(t0, pixels)

    def _add(self, t0: int, pixels: np.ndarray) -> None:
        """push after ``advance(t0)`` (front_end advances before it reads the counts: a second
        advance to the same t0 shifts in nothing, but cost ~1.3 us a window)."""
        self._push(np.asarray(pixels, np.int64))
        self.last_t0 = int(t0)

    def _push(self, pixels: np.ndarray) -> None:
        old = self.leaving()
        _shift_counts(self.counts, pixels, old)
        self._keep(pixels, old)

    def leaving(self) -> np.ndarray:
        """The event pixels of the window the next push drops (empty while it holds fewer than K)."""
        return self._ring[0] if len(self._ring) == self.k else _NONE

    def add_counted(self, t0: int, pixels: np.ndarray, old: np.ndarray) -> None:
        """push after ``advance(t0)``, for a caller whose compiled pass already moved ``counts``
        on (counts[old] -= 1, counts[pixels] += 1 with old = ``leaving()``:
        runtime.window_front): the ring, the total and the window's start."""
        self._keep(pixels, old)
        self.last_t0 = int(t0)

    def _keep(self, pixels: np.ndarray, old: np.ndarray) -> None:
        if len(self._ring) == self.k:
            self._ring.pop(0)
        self.total += pixels.size - old.size
        self._ring.append(pixels)

    @classmethod
    def before(cls, read, t0: int, dt_us: int, k: int, sensor_size: tuple[int, int]) -> "SupportHistory":
        """The history a stream would hold at window t0, from the K windows [t0 - K dt, t0):
        ``read(t_lo, t_hi)`` gives their events (none before a recording's start)."""
        hist = cls(k, sensor_size, dt_us)
        for j in range(k, 0, -1):
            s = int(t0) - j * int(dt_us)
            hist.push(s, window_pixels(read(s, s + int(dt_us)), s, dt_us, sensor_size))
        return hist


def window_pixels(events: np.ndarray, t0: int, dt_us: int, sensor_size: tuple[int, int]) -> np.ndarray:
    """Sorted unique linear pixel indices (y * W + x) with an event in [t0, t0 + dt_us), the
    pixels of bin_window's volume (events outside the sensor are dropped there too)."""
    from .binning import event_bin_index

    w, h = int(sensor_size[0]), int(sensor_size[1])
    idx = event_bin_index(events, t0, dt_us, 1, sensor_size)
    return np.unique(idx % (w * h))


def front_end(volume, config, history: "SupportHistory | None" = None, t0: int | None = None):
    """The input front end of ``config`` (input_norm, input_min_cluster, input_support) on one
    raw window: a dense (B, C, H, W) array (-> bool volume) or a SpikeVolume (-> SpikeVolume).
    With input_support, ``history`` holds the windows before (``SupportHistory``; streaming: the
    same object for every window, ``t0`` the window's start; sampled: ``SupportHistory.before``)
    and gets this window's event pixels. Not idempotent with support: pass raw windows."""
    norm, min_cluster = config.input_norm, config.input_min_cluster
    dense = isinstance(volume, np.ndarray)
    if config.input_support is None:
        return apply_dense(volume, norm, min_cluster) if dense else volume.front_end(norm, min_cluster)
    if history is None:
        raise ValueError("input_support needs the windows before: pass a SupportHistory")
    if t0 is None:
        raise ValueError("input_support needs the window's start t0")
    _k, r, m, c = config.input_support
    history.advance(t0)
    if dense:
        pix = event_pixels(volume)
        out = support_dense(volume, norm, min_cluster, history.counts.reshape(pix.shape), r, m, c)
        history._add(t0, np.flatnonzero(pix))
        return out
    idx, pixels, pixel_index = _support_run(volume.idx, volume.shape, norm, min_cluster, history.counts, r, m, c,
                                            history.total)
    history._add(t0, pixels)                             # advanced above
    out = type(volume)(idx, volume.shape)
    if pixel_index is not None:
        out.__dict__["_pixel_index"] = pixel_index      # = out.pixel_index(scratch), made in the same pass
    return out


def sampled_window(read, t0: int, dt_us: int, config, sensor_size: tuple[int, int]) -> np.ndarray:
    """The front end's (B, 2, H, W) bool volume of the window [t0, t0 + dt_us) of a recording read
    at chosen starts (eval, held-out and training windows): ``read(t_lo, t_hi)`` gives events
    (a superset is fine); with input_support the K windows before are read too (SupportHistory.before)."""
    return sampled_window_recent(read, t0, dt_us, config, sensor_size)[0]


def sampled_window_recent(read, t0: int, dt_us: int, config, sensor_size: tuple[int, int]
                          ) -> tuple[np.ndarray, "SupportHistory | None"]:
    """(sampled_window, its SupportHistory after the window: the latest K windows' event pixels,
    this one included, what a streaming Pipeline holds there and ofpd.recent_events reads;
    None without input_support)."""
    from .binning import bin_window

    t0, dt_us = int(t0), int(dt_us)
    binned = bin_window(read(t0, t0 + dt_us), t0, dt_us, config.n_bins, sensor_size, dtype=np.uint8)
    hist = (SupportHistory.before(read, t0, dt_us, config.input_support[0], sensor_size)
            if config.input_support is not None else None)
    return front_end(binned, config, hist, t0), hist


def history_before(read, t0: int, dt_us: int, config, sensor_size: tuple[int, int], t_start: int | None = None):
    """(SupportHistory or None, time_surface.OnesHistory) a stream started at ``t_start`` (the
    recording's first window; None: long before) holds just before window t0 with
    ofpd.plane_fit_history: the front end's ones of the K_max - 1 windows before, each window's
    front end run with its own windows before (the SupportHistory moved along)."""
    from ..plane_fit import history_settings
    from ..runtime.spikes import SpikeVolume
    from ..time_surface import OnesHistory

    t0, dt_us, k = int(t0), int(dt_us), int(history_settings(config)[1])
    first = t0 - (k - 1) * dt_us
    if t_start is not None and first < int(t_start):
        first = t0 - ((t0 - int(t_start)) // dt_us) * dt_us       # the stream's first window on t0's grid
    hist = (SupportHistory.before(read, first, dt_us, config.input_support[0], sensor_size)
            if config.input_support is not None else None)
    ring = OnesHistory(k, sensor_size, config.n_bins, dt_us)
    for s in range(first, t0, dt_us):
        vol = SpikeVolume.from_events(read(s, s + dt_us), s, dt_us, config.n_bins, sensor_size)
        ring.push(s, front_end(vol, config, hist, s).idx)
    return hist, ring


def sampled_window_history(read, t0: int, dt_us: int, config, sensor_size: tuple[int, int],
                           t_start: int | None = None):
    """(sampled_window, its SupportHistory or None, its plane-fit history or None): with
    ofpd.plane_fit_history, ``history_before``'s with this window's ones pushed (what a stream
    holds after it); else sampled_window_recent's and None."""
    return WindowHistories(read, dt_us, config, sensor_size, t_start)(t0)


class WindowHistories:
    """``sampled_window_history`` for windows asked for in time order (eval's samples): a window
    right after the one asked for before continues that stream (its SupportHistory and ring moved
    on by this window, what a streaming Pipeline does), any other is built anew from the events
    before it. Same arrays as sampled_window_history either way; eval over every window of a
    recording then costs one front end per window, not one per window of the plane fit's
    history (K_max = 20: 20x)."""

    def __init__(self, read, dt_us: int, config, sensor_size: tuple[int, int], t_start: int | None = None):
        from ..plane_fit import history_settings

        self.read, self.dt_us, self.config, self.sensor = read, int(dt_us), config, sensor_size
        self.t_start = t_start
        self.streams = history_settings(config) is not None
        self._next = None            # the window that continues the stream, its history and ring
        self._hist = self._ring = None

    def __call__(self, t0: int):
        from .binning import bin_window

        t0 = int(t0)
        if not self.streams:
            return (*sampled_window_recent(self.read, t0, self.dt_us, self.config, self.sensor), None)
        if t0 != self._next:
            self._hist, self._ring = history_before(self.read, t0, self.dt_us, self.config, self.sensor,
                                                    self.t_start)
        binned = front_end(bin_window(self.read(t0, t0 + self.dt_us), t0, self.dt_us, self.config.n_bins,
                                      self.sensor, dtype=np.uint8), self.config, self._hist, t0)
        self._ring.push(t0, np.flatnonzero(binned))
        self._next = t0 + self.dt_us
        return binned, self._hist, self._ring


def sampled_index(read, t0: int, dt_us: int, config, sensor_size: tuple[int, int]) -> np.ndarray:
    """``sampled_window``'s ones as a sorted linear index into the (B, 2, H, W) volume, by the
    compiled index forms (training reads many windows of the whole sensor)."""
    from .binning import event_ones
    from .frontend import apply_index

    t0, dt_us = int(t0), int(dt_us)
    w, h = int(sensor_size[0]), int(sensor_size[1])
    shape = (int(config.n_bins), 2, h, w)
    idx = event_ones(read(t0, t0 + dt_us), t0, dt_us, config.n_bins, sensor_size)
    if config.input_support is None:
        return apply_index(idx, shape, config.input_norm, config.input_min_cluster)
    k, r, m, c = config.input_support
    hist = SupportHistory.before(read, t0, dt_us, k, sensor_size)
    return support_index(idx, shape, config.input_norm, config.input_min_cluster, hist.counts, r, m, c, hist.total)


def warm_up() -> None:
    """Compile (or load from numba's cache) the support kernels before the first window is timed."""
    _idx, pixels = support_index(np.zeros(1, np.int64), (1, 2, 1, 1), "first", 2, np.zeros(1, np.uint8), 1, 1, 1, 0,
                                 return_pixels=True)
    _shift_counts(np.zeros(1, np.uint8), pixels, pixels)
