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

import numpy as np
from numba import njit

from .frontend import apply_dense


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
def _support_keep(idx, n_pixels, width, height, keep_base, keep_every, counts, radius, m, noise_factor,
                  counts_total, mark):
    """keep_base | (keep_every & S >= T) over the ones of a sorted linear index (module doc):
    ``mark`` ((n_pixels,) uint8 zeros, left so) holds the window's event pixels while the box
    sums are read; S is read only for the ones the cluster filter dropped."""
    n = idx.shape[0]
    n_pix = 0
    for i in range(n):
        q = idx[i] % n_pixels
        if mark[q] == 0:
            mark[q] = 1
            n_pix += 1
    m = m + (noise_factor * (2 * radius + 1) ** 2 * (counts_total + n_pix)) // n_pixels
    keep = keep_base.copy()
    for i in range(n):
        if keep_base[i] or not keep_every[i]:
            continue
        p = idx[i] % n_pixels
        y = p // width
        x = p - y * width
        s = 0
        for yy in range(max(0, y - radius), min(height, y + radius + 1)):
            row = yy * width
            for xx in range(max(0, x - radius), min(width, x + radius + 1)):
                s += np.int64(counts[row + xx]) + np.int64(mark[row + xx])
        keep[i] = s >= m
    for i in range(n):
        mark[idx[i] % n_pixels] = 0
    return keep


_MARKS: dict[int, np.ndarray] = {}


def support_index(idx: np.ndarray, shape: tuple[int, ...], norm: str, min_cluster: int, counts: np.ndarray,
                  radius: int, m: int, noise_factor: int = 0, counts_total: int | None = None) -> np.ndarray:
    """The same on a sorted unique linear index of ones into a (B, C, H, W) volume; ``counts`` an
    (H, W) or (H * W,) uint8 count image, ``counts_total`` its sum (a streaming caller keeps it;
    None: summed here, only when noise_factor > 0). Two passes of compiled.front_end_keep (with and
    without the cluster filter) and one that reads box sums around the ones it dropped.
    Returns a sorted index."""
    from ..compiled import front_end_keep, new_scratch
    from .frontend import _SLOTS, check_min_cluster, check_norm

    idx = np.asarray(idx, dtype=np.int64)
    if idx.size == 0:
        return idx
    c, h, w = int(shape[1]), int(shape[2]), int(shape[3])
    n_pixels = h * w
    first = check_norm(norm) == "first"
    slots = _SLOTS.get(n_pixels)
    if slots is None:
        slots = _SLOTS[n_pixels] = new_scratch(n_pixels)
    every = front_end_keep(idx, c, n_pixels, w, first, 1, slots)
    base = front_end_keep(idx, c, n_pixels, w, first, check_min_cluster(min_cluster), slots)
    mark = _MARKS.get(n_pixels)
    if mark is None:
        mark = _MARKS[n_pixels] = np.zeros(n_pixels, np.uint8)
    cnt = np.ascontiguousarray(counts, np.uint8).reshape(-1)
    total = int(cnt.sum(dtype=np.int64)) if counts_total is None and noise_factor else int(counts_total or 0)
    return idx[_support_keep(idx, n_pixels, w, h, base, every, cnt, int(radius), int(m), int(noise_factor), total,
                             mark)]
