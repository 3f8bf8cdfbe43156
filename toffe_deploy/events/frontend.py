"""The input front end: which binary spikes of a window the OFS cascade and the OFPD see.

A window's events become a binary volume s[b, p, y, x] (bin b = (t - t0) * B // dt, p the
polarity): a spike wherever at least one event fell. ``input_norm`` (ToffeConfig) then picks:

- ``none``:  s as it is (what the paper's OFS sees);
- ``first``: each (p, y, x)'s first spike of the window only,

      s'[b, p, y, x] = s[b, p, y, x] AND NOT OR_{b' < b} s[b', p, y, x].

Why ``first``: a passing edge makes a pixel fire about |log contrast| / C events, so the number
of spikes per pixel scales with the object's contrast and the sensor's threshold, while the
number of *pixels* the edge sweeps in a window scales with its speed. An OFS integrating all
spikes reads speed from event density (measured: with 3x the events per edge every object of
bins 1-3 came out one bin too fast). Keeping one spike per pixel and polarity leaves the swept
area and the order in which pixels were reached (the speed and the direction), and drops the
multiplicity (the appearance). It is a per-pixel refractory period of one window, applied on
the host before the spikes go to Loihi, so the chip side is unchanged.

Then ``input_min_cluster`` (ToffeConfig, n >= 1; 1 keeps everything) drops the spikes of every
pixel whose 8-connected cluster of the window's event pixels (any bin, any polarity) has fewer
than n pixels: an area opening of the window's event image, a background-activity filter. A
moving edge sweeps a connected band of pixels in a window, while sensor noise fires isolated
pixels: at 20 Hz per pixel 1 % of the pixels fire in a 500 us window, and a cluster of 4 of
them needs three noise neighbours next to each other. Before it, the first-spike front end kept
every noise pixel's spike while thinning the object's (measured: recall 0.93 -> 0.44 at 50 Hz).
Cluster sizes do not change when other clusters are dropped, so the filter is idempotent, like
``first``.
"""
from __future__ import annotations

import threading

import numpy as np

INPUT_NORMS = ("none", "first")
_LOCAL = threading.local()            # .slots: the front end's scratch per H * W, one per thread


def slots_for(n_pixels: int) -> np.ndarray:
    """The front end's all -1 scratch for a sensor of n_pixels (compiled.new_scratch; the kernels
    leave it all -1, so it is reused: no page faults per window). One per thread: the kernels
    release the GIL, and two pipelines running in two threads must not share it."""
    d = getattr(_LOCAL, "slots", None)
    if d is None:
        d = _LOCAL.slots = {}
    slots = d.get(n_pixels)
    if slots is None:
        from ..compiled import new_scratch

        slots = d[n_pixels] = new_scratch(n_pixels)
    return slots


def check_norm(norm: str) -> str:
    if norm not in INPUT_NORMS:
        raise ValueError(f"unknown input_norm {norm!r} (expected one of {', '.join(INPUT_NORMS)})")
    return norm


def first_spikes_dense(volume: np.ndarray) -> np.ndarray:
    """(..., B, C, H, W) spikes -> the first spike of each (C, H, W) along B (bool, same shape)."""
    s = np.asarray(volume) > 0
    seen = np.logical_or.accumulate(s, axis=-4)
    out = s.copy()
    out[..., 1:, :, :, :] &= ~seen[..., :-1, :, :, :]
    return out


def first_spikes_index(idx: np.ndarray, shape: tuple[int, ...]) -> np.ndarray:
    """The same on a sorted, unique linear index into a (B, C, H, W) volume: keeps, for each
    (c, y, x), its smallest b. Since b is the slowest axis, the sorted index already lists every
    (c, y, x) in order of b, so its first occurrence is the one to keep: one compiled pass
    (front_end_index; ~10x faster than np.unique on a window). Returns a sorted index."""
    return front_end_index(idx, shape, True, 1)


def front_end_index(idx: np.ndarray, shape: tuple[int, ...], first: bool, min_cluster: int) -> np.ndarray:
    """The ones of a sorted unique linear index into a (B, C, H, W) volume that ``first`` (if
    set) and the cluster filter of ``min_cluster`` keep, in one compiled pass
    (compiled.front_end_keep). Returns a sorted index."""
    from ..compiled import front_end_keep

    idx = np.asarray(idx, dtype=np.int64)
    if idx.size == 0 or (not first and min_cluster <= 1):
        return idx
    w = int(shape[3])
    n_pixels = int(shape[2]) * w
    slots = slots_for(n_pixels)
    # compress: idx[mask]'s result at two thirds of its cost
    return idx.compress(front_end_keep(idx, int(shape[1]), n_pixels, w, bool(first), int(min_cluster), slots))


def check_support(value) -> tuple[int, int, int, int]:
    """``input_support`` (ToffeConfig) as (K, r, m, c): integers, 1 <= K <= 255 (the count image
    is uint8), 0 <= r <= 16, m >= 1, c >= 0 (events/support.py's rule)."""
    ok = isinstance(value, (list, tuple)) and len(value) == 4 and all(
        isinstance(v, (int, np.integer)) and not isinstance(v, bool) for v in value)
    if ok:
        k, r, m, c = (int(v) for v in value)
        ok = 1 <= k <= 255 and 0 <= r <= 16 and m >= 1 and c >= 0
    if not ok:
        raise ValueError(f"input_support must be [K, r, m, c]: integers with 1 <= K <= 255, 0 <= r <= 16, m >= 1, "
                         f"c >= 0 (windows before, box radius, min count, noise factor), got {value!r}")
    return (k, r, m, c)


def check_min_cluster(n: int) -> int:
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
        raise ValueError(f"input_min_cluster must be an integer >= 1, got {n!r}")
    return int(n)


def min_cluster_dense(volume: np.ndarray, n: int) -> np.ndarray:
    """(..., B, C, H, W) bool: the spikes of the pixels whose 8-connected cluster of event
    pixels (any b, c) has >= n pixels."""
    import cv2

    v = np.asarray(volume) > 0
    if n <= 1:
        return v
    lead = v.shape[:-4]
    flat = v.reshape((-1,) + v.shape[-4:])
    out = np.zeros_like(flat)
    for i in range(flat.shape[0]):
        pix = flat[i].any(axis=(0, 1))
        _n, labels, stats, _c = cv2.connectedComponentsWithStats(pix.view(np.uint8), connectivity=8)
        keep = (stats[:, cv2.CC_STAT_AREA] >= n)[labels] & pix
        out[i] = flat[i] & keep
    return out.reshape(lead + v.shape[-4:])


def min_cluster_index(idx: np.ndarray, shape: tuple[int, ...], n: int) -> np.ndarray:
    """The same on a sorted unique linear index of ones into a (B, C, H, W) volume, in one
    compiled pass (front_end_index: union-find over the window's event pixels). Returns a
    sorted index."""
    return front_end_index(idx, shape, False, n)


def apply_dense(volume: np.ndarray, norm: str, min_cluster: int = 1) -> np.ndarray:
    """The front end on a dense (..., B, C, H, W) volume; returns a bool volume."""
    out = first_spikes_dense(volume) if check_norm(norm) == "first" else np.asarray(volume) > 0
    return min_cluster_dense(out, check_min_cluster(min_cluster))


def apply_index(idx: np.ndarray, shape: tuple[int, ...], norm: str, min_cluster: int = 1) -> np.ndarray:
    """The front end on a sorted unique linear index of ones into a (B, C, H, W) volume."""
    return front_end_index(idx, shape, check_norm(norm) == "first", check_min_cluster(min_cluster))
