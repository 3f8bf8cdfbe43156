"""OFPD input from a window's speed-separated frames kept as coordinates (the cpu fast path).

``toffe_deploy.ofpd_io`` defines what OFPD sees, on dense (N, B, 2, H, W) frames:
``report_objects`` / ``merge_frames`` (which stages report an object, and each object's frame)
and ``prepare`` (object-centric crop, pooled). Building four dense 640x480 frames per window
costs more than the whole cascade, so this module runs the same steps on the window's ones
(``SpikeVolume`` plus one boolean mask per stage frame), reusing ofpd_io's own
``centroid_of_pixels`` and settings; tests/test_run_pipeline.py checks equality with ofpd_io
bit for bit (objects, stages, prepared arrays):

    pixels_k  = unique (y, x) of frame k's ones (any order: the centroid's integer sums are exact)
    objects   = fastest stage first: pixels of frame k outside every box |x - cx|, |y - cy| < R
                of the objects found so far; >= min_events of them make an object at their
                centroid_of_pixels, speed bin k                              (report_objects)
    merged_j  = frame k_j's ones plus every frame's ones inside object j's box   (merge_frames)
    origin    = floor(c - (S - 1) / 2 + 0.5) of the merged frame's centroid     (crop_origins)
    x[2b+p, i, j] = #ones of (b, p) in crop cell (i, j) / P^2   (the mean of P x P binary pixels)
    x[2B], x[2B+1] = ofpd_io's coordinate planes
"""
from __future__ import annotations

from typing import Sequence

import numpy as np

from ..config import ToffeConfig
from ..ofpd_io import COORD_SCALE, centroid_of_pixels, ofpd_settings
from .ofs_sparse import dedupe
from .spikes import SpikeVolume


def event_pixels(frame: SpikeVolume, lookup: np.ndarray | None = None) -> np.ndarray:
    """Unique linear pixel ids y * W + x holding any one of the frame.

    Sorted (row-major) without ``lookup``; with a scratch ``lookup`` of >= H * W entries, in
    O(n) and in no particular order. Either is fine for the centroid: its sums of integer
    coordinates are exact in float64 in any order, so the means come out bit identical.
    """
    if lookup is None:
        return np.unique(frame.pix)
    return dedupe(frame.pix, lookup)[0]


def _in_box(xs: np.ndarray, ys: np.ndarray, cx: float, cy: float, r: float) -> np.ndarray:
    """ofpd_io._box evaluated at given coordinates: |x - cx| < r and |y - cy| < r."""
    return (np.abs(xs - cx) < r) & (np.abs(ys - cy) < r)


def merge_objects(volume: SpikeVolume, frames: Sequence[np.ndarray], config: ToffeConfig,
                  lookup: np.ndarray | None = None) -> tuple[np.ndarray, list[SpikeVolume]]:
    """``ofpd_io.merge_frames`` on coordinates: (stage_k (G,) 1-based, merged frames), fastest first.

    volume: the window's ones; frames[k-1]: bool mask over volume.idx of stage k's frame.
    lookup: optional scratch memory (>= H * W int64) that makes the pixel sets O(n).
    """
    s = ofpd_settings(config)
    r, need, half = s["dedupe_px"], s["min_events"], s["crop_px"] // 2
    _b, _c, h, w = volume.shape
    boxes: list[tuple[float, float]] = []
    ks: list[int] = []
    merged: list[SpikeVolume] = []
    fy = fx = every = None
    for i in range(len(frames) - 1, -1, -1):              # fastest stage first; N is tiny
        ys, xs = np.divmod(event_pixels(volume.subset(frames[i]), lookup), w)
        if boxes:
            free = np.ones(xs.shape, dtype=bool)
            for cx, cy in boxes:
                free &= ~_in_box(xs, ys, cx, cy, r)
            xs, ys = xs[free], ys[free]
        if xs.size < need:
            continue
        cx, cy = centroid_of_pixels(xs, ys, half, w, h)
        boxes.append((cx, cy))
        ks.append(i + 1)
        if fy is None:                     # the ones of every frame, once per window
            every = np.flatnonzero(np.logical_or.reduce(list(frames)))
            fy, fx = np.divmod(volume.pix[every], w)
        keep = frames[i].copy()
        keep[every[_in_box(fx, fy, cx, cy, r)]] = True
        merged.append(volume.subset(keep))
    return np.asarray(ks, dtype=np.int64), merged


def prepare(frames: Sequence[SpikeVolume], config: ToffeConfig, lookup: np.ndarray | None = None) -> np.ndarray:
    """(N, 2B+2, S/P, S/P) float32, equal to ``ofpd_io.prepare`` of the dense frames.

    One crop origin per frame (N is a handful of objects), then the ones of all N frames are
    binned to crop cells in one pass; the pooled planes are written only at the cells that hold
    ones (count / P^2, the mean of P x P binary pixels), the rest of the input stays zero.
    """
    s = ofpd_settings(config)
    size, pool = s["crop_px"], s["pool"]
    g = size // pool
    b = config.n_bins
    n = len(frames)
    out = np.zeros((n, 2 * b + 2, g, g), dtype=np.float32)
    if n == 0:
        return out
    centres = (np.arange(g) + 0.5) * pool - 0.5
    origins = np.empty((n, 2), dtype=np.int64)
    for i, f in enumerate(frames):
        nb, nc, h, w = f.shape
        if nc != 2 or nb != b or f.shape != frames[0].shape:
            raise ValueError(f"frames must all be ({b}, 2, H, W), got {f.shape}")
        ys, xs = np.divmod(event_pixels(f, lookup), w)
        cx, cy = centroid_of_pixels(xs, ys, size // 2, w, h)
        origins[i] = int(np.floor(cx - (size - 1) / 2 + 0.5)), int(np.floor(cy - (size - 1) / 2 + 0.5))
        out[i, 2 * b] = ((origins[i, 0] + centres) / COORD_SCALE)[None, :]
        out[i, 2 * b + 1] = ((origins[i, 1] + centres) / COORD_SCALE)[:, None]
    w = frames[0].shape[3]
    counts = [len(f) for f in frames]
    obj = np.repeat(np.arange(n), counts)
    fy, fx = np.divmod(np.concatenate([f.pix for f in frames]), w)
    fx -= np.repeat(origins[:, 0], counts)
    fy -= np.repeat(origins[:, 1], counts)
    inside = (fx >= 0) & (fx < size) & (fy >= 0) & (fy < size)
    ch = np.concatenate([f.b * 2 + f.c for f in frames])
    keys = ((obj * (2 * b + 2) + ch) * g + fy // pool) * g + fx // pool
    keys = keys[inside]
    if keys.size:
        if lookup is not None and lookup.shape[0] >= out.size:
            cells, inv = dedupe(keys, lookup)
            hits = np.bincount(inv, minlength=cells.shape[0])
        else:
            cells, hits = np.unique(keys, return_counts=True)
        out.reshape(-1)[cells] = hits.astype(np.float32) / np.float32(pool * pool)
    return out
