"""OFPD input from a window's speed-separated frames kept as coordinates (the cpu fast path).

Building four dense 640x480 frames per window costs more than the whole cascade, so the runtime
keeps a window as its ones (``SpikeVolume``) plus one boolean mask per stage frame, and hands
their pixel coordinates to ``toffe_deploy.ofpd_io``'s coordinate core, the one definition of
what OFPD sees (the dense ``report_objects`` / ``merge_frames`` / ``prepare`` used by training,
evaluation and export are thin wrappers over the same functions):

    pixels_k  = unique (x, y) of frame k's ones (any order: the core's means are exact integer
                sums, its density seed is computed on a grid)
    objects   = ofpd_io.group_objects_xy(pixels_1..N)                 (stage, centre, claims)
    merged_j  = the ones of every frame at object j's claimed pixels (ofpd_io.object_masks_xy)
    input     = ofpd_io.prepare_xy(ones of merged_j, crop_origin_xy(pixels of merged_j))

This module only converts between SpikeVolume and coordinates, with O(n) de-duplication through
an all -1 ``scratch`` array (``compiled.new_scratch``; no sort) when the caller has one.
``batch`` (the pipeline's per-window call) runs these steps as compiled passes over the
window's ones (compiled.frame_pixels, blob_objects, claimed_by, then object_input: object_crops,
fill_input and fill_motion in one call; the same definitions, tested bit for bit against the
per-object Python form in tests/test_objects_compiled.py).
"""
from __future__ import annotations

from typing import Sequence

import numpy as np

from ..compiled import dedupe, frame_pixels, object_input, window_objects
from ..config import ToffeConfig
from ..ofpd_io import (COORD_SCALE, blob_settings, crop_origin_xy, group_objects_flat, group_objects_xy, input_shape,
                       object_masks_xy, ofpd_settings, prepare_xy, recent_args, uses_polarity)
from .spikes import SpikeVolume


def unique_xy(pix: np.ndarray, width: int, scratch: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(xs, ys) of the unique linear pixel ids y * W + x in ``pix``.

    Sorted (row-major) without ``scratch``; with an all -1 ``scratch`` of >= H * W entries, in
    O(n) and in order of first appearance (the ofpd_io core does not depend on the order).
    """
    u = np.unique(pix) if scratch is None else dedupe(pix, scratch)[0]
    ys, xs = np.divmod(u, width)
    return xs, ys


def merge_objects(volume: SpikeVolume, frames: Sequence[np.ndarray], config: ToffeConfig,
                  scratch: np.ndarray | None = None, recent=None) -> tuple[np.ndarray, list[SpikeVolume]]:
    """``ofpd_io.merge_frames`` on coordinates: (stage_k (G,) 1-based, merged frames), fastest first.

    volume: the window's ones; frames[k-1]: bool mask over volume.idx of stage k's frame.
    scratch: optional all -1 array (>= H * W entries, ``compiled.new_scratch``) that makes the pixel sets O(n).
    recent: the front end's SupportHistory after this window (ofpd.recent_events; group_objects_xy).
    """
    _b, _c, h, w = volume.shape
    pix = volume.pix
    stage_px = [unique_xy(pix[m], w, scratch) for m in frames]
    every = np.flatnonzero(np.logical_or.reduce(list(frames)))     # the ones of every frame
    if uses_polarity(ofpd_settings(config)):                       # ofpd_io.pixel_polarity on the ones
        pol = np.zeros(h * w, np.int8)
        np.bitwise_or.at(pol, pix[every], (1 << volume.c[every]).astype(np.int8))
        stage_px = [(xs, ys, pol[ys * w + xs]) for xs, ys in stage_px]
    objs, claims = group_objects_xy(stage_px, (w, h), config, recent)
    if not objs:
        return np.zeros(0, dtype=np.int64), []
    fy, fx = np.divmod(pix[every], w)
    merged = [volume.subset(every[m]) for m in object_masks_xy(fx, fy, objs, claims)]
    return np.array([i + 1 for i, _, _ in objs], dtype=np.int64), merged


def _crop_args(s: dict, g: int) -> tuple[int, int, int, int]:
    """(fixed crop side or 0 for "scaled", grid g, pool_min, pool_max) as compiled.object_input and
    window_objects take them, from ofpd_settings ``s``."""
    return int(s["crop_px"]) if s["crop"] == "fixed" else 0, g, int(s["pool_min"]), int(s["pool_max"])


def batch_settings(config: ToffeConfig) -> tuple:
    """What ``batch`` reads from a config: (ofpd_settings, C, g of input_shape, blob_settings,
    _crop_args), for a caller that runs every window of one config (the Pipeline) to work out
    once: the dict copies and look-ups cost ~6 us a window."""
    s = ofpd_settings(config)
    c, g, _ = input_shape(config)
    return s, c, g, blob_settings(s), _crop_args(s, g)


def batch(volume: SpikeVolume, frames: Sequence[np.ndarray], config: ToffeConfig,
          scratch: np.ndarray | None = None, recent=None,
          settings: tuple | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray, tuple]:
    """``prepare(*merge_objects(...))`` in one pass: (stage_k (G,), OFPD input (G, C, g, g)
    float32, n_events (G,) = the number of ones of each merged frame, ones = (object, x, y,
    channel) flat arrays of every object's merged ones: plane_fit.object_planes_flow's input,
    the same sets as plane_fit.dense_flow of the merged frames).

    The same core calls on the same coordinate sets, with the window's pixels de-duplicated
    once (``volume.pixel_index``, shared with the OFS window) instead of once per stage frame
    and once per object: a frame's (or an object's) unique pixels are the unique pixel ids
    its ones point to, marked on a (U,) array over the window's U unique pixels. An object's
    merged frame is the ones of every frame whose pixel it claims, so its unique pixels are
    the window pixels of those ones it claims. The stage pixels go to the grouping as flat
    arrays (ofpd_io.group_objects_flat); each object's crop and ones, and the OFPD input, come
    from one compiled call (compiled.object_input: object_crops, then ofpd_io.prepare_flat's kernels).
    For grouping "blobs" with a ``scratch`` (the pipeline) every step is one compiled call
    (compiled.window_objects: the same kernels back to back, fewer crossings into compiled code).
    recent: merge_objects'. settings: ``batch_settings(config)`` when the caller keeps it.
    """
    _b, nc, h, w = volume.shape
    upix, pinv = volume.pixel_index(scratch)
    stacked = (frames if isinstance(frames, np.ndarray) else       # the cpu cascade's (N, n) array as it is
               np.stack(frames) if len(frames) else np.zeros((0, len(pinv)), bool))
    s, c, g, blobs, crop = batch_settings(config) if settings is None else settings
    if s["grouping"] == "blobs" and scratch is not None:     # the cpu pipeline: every step in one compiled call
        stage, x, n_ev, *ones = window_objects(stacked, pinv, upix, w, volume.bc, nc, *blobs, scratch,
                                               *crop, h, c, int(config.n_bins), COORD_SCALE,
                                               *recent_args(s, recent))
        return stage + 1, x, n_ev, tuple(ones)
    with_pol = uses_polarity(s)
    sx, sy, starts, ev_u, fx, fy, ch, spol = frame_pixels(stacked, pinv, upix, w, volume.bc, nc, with_pol)
    objs, claims = group_objects_flat(sx, sy, starts, (w, h), config, recent, spol if with_pol else None)
    if not objs:
        none = np.zeros(0, dtype=np.int64)
        return none, np.zeros((0, c, g, g), np.float32), none, (none, none, none, none)
    x, n_ev, *ones = object_input(claims.matrix(fx, fy, len(objs), scratch), fx, fy, ch, ev_u, upix.shape[0],
                                  *crop, w, h, c, int(config.n_bins), COORD_SCALE)
    return np.array([i + 1 for i, _, _ in objs], dtype=np.int64), x, n_ev, tuple(ones)


def prepare(frames: Sequence[SpikeVolume], config: ToffeConfig, scratch: np.ndarray | None = None) -> np.ndarray:
    """(N, C, g, g) float32 (ofpd_io.input_shape), equal to ``ofpd_io.prepare`` of the dense frames."""
    b = config.n_bins
    ones, origins = [], []
    for f in frames:
        nb, nc, h, w = f.shape
        if nc != 2 or nb != b or f.shape != frames[0].shape:
            raise ValueError(f"frames must all be ({b}, 2, H, W), got {f.shape}")
        origins.append(crop_origin_xy(*unique_xy(f.pix, w, scratch), (w, h), config))
        ys, xs = np.divmod(f.pix, w)
        ones.append((xs, ys, f.b * 2 + f.c))
    return prepare_xy(ones, np.asarray(origins, dtype=np.int64).reshape(-1, 3), config)
