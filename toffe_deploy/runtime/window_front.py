"""The cpu pipeline's steps before the OFPD, for one window, in one compiled call.

Per window the cpu and cuda targets run, on the window's binned ones ``idx``:

    front end      events.support.support_keep (first spike, clusters, temporal support) and the
                   support history's counts moved on (events.support._shift_counts)
    OFS cascade    compiled.pooled_cascade (pool p x p, the N stages, closings, masks, Up_p)
    grouping       compiled.window_objects (objects, claims, crops, the OFPD input), reading the
                   history's counts after this window (ofpd.recent_events)

``window_front`` runs these kernels back to back on the same arrays, so that a window crosses
from Python into compiled code once for the three instead of four times, with no Python between
them (``Pipeline.front``, ``events.support.front_end``, ``Pipeline.batch``, ``ofpd_input.batch``:
their argument building, checks and look-ups). Measured on the shipped sample, one pinned core of
this project's 2-core VM, in-process A/B: ~3 % of a window's CPU time less, 30-40 us (docs/speed-log.md,
"2026-11-29 (late)"); a first step of the one-core redesign, not the whole of it.

Why a second path at all: the step-by-step path (``Pipeline.front`` then ``Pipeline.batch``)
stays, for every configuration this one does not cover (no temporal support, an unpooled OFS
grid, the other groupings, ``keep_stages``), for the per-part benchmark, and as the reference:
both call the same kernels with the same arguments in the same order, so their results are the
same bits (tests/test_window_front.py checks them window by window, gaps and resets included).
"""
from __future__ import annotations

import numpy as np

from ..compiled import pooled_cascade, window_objects
from ..events.frontend import check_min_cluster, check_norm, slots_for
from ..events.support import _shift_counts, support_keep
from ..jit import njit
from ..ofpd_io import COORD_SCALE
from .spikes import SpikeVolume


@njit(cache=True, nogil=True)
def window_front(idx, slot_of, counts, old, counts_total, n_channels, n_pixels, width, height, first, min_size, radius,
                 m, noise_factor, p, hp, wp, kernel, ofs_slot_of, weights, dv, vth_mant, reset_zero, n_bins,
                 mask_kernel, union, link, frac_closed, frac_open, need, min_count, split_frac, split_waist,
                 split_polarity, closed_apart, fixed_size, g, pool_min, pool_max, n_input, coord_scale, rule):
    """support_keep, _shift_counts(counts, pixels, old), pooled_cascade and window_objects of one
    window (module doc). idx: its sorted unique ones; slot_of: the front end's all -1 (H * W,)
    scratch (events.frontend.slots_for, left so); counts, counts_total: the support history's
    (H * W,) uint8 counts (moved on in place) and their sum before this window; old: the event
    pixels of the window leaving it (empty while it holds fewer than K). ``rule``:
    ofpd.recent_events' (r, m, c, total), its total set here to the history's sum after this
    window (ofpd_io.recent_args'), or None when the grouping reads no recent events. Returns
    (kept ones, the window's event pixels, the kept ones' bc, pix, their unique pixels and
    inverse, then window_objects' stage (0-based), OFPD input, n_ones, object, x, y, channel)."""
    kept, pixels, upix, inverse = support_keep(idx, n_channels, n_pixels, width, height, first, min_size, slot_of,
                                               counts, radius, m, noise_factor, counts_total)
    _shift_counts(counts, pixels, old)
    bc, pix, frames = pooled_cascade(kept, n_pixels, width, p, hp, wp, n_channels, kernel, ofs_slot_of, weights, dv,
                                     vth_mant, reset_zero, n_bins, mask_kernel)
    if rule is None:
        stage, x, n_ones, obj, ox, oy, och = window_objects(
            frames, inverse, upix, width, bc, n_channels, union, link, frac_closed, frac_open, need, min_count,
            split_frac, split_waist, split_polarity, closed_apart, slot_of, fixed_size, g, pool_min, pool_max, height,
            n_input, n_bins, coord_scale, None, None)
    else:
        rule[3] = counts_total + pixels.shape[0] - old.shape[0]       # the history's sum after this window
        stage, x, n_ones, obj, ox, oy, och = window_objects(
            frames, inverse, upix, width, bc, n_channels, union, link, frac_closed, frac_open, need, min_count,
            split_frac, split_waist, split_polarity, closed_apart, slot_of, fixed_size, g, pool_min, pool_max, height,
            n_input, n_bins, coord_scale, counts, rule)
    return kept, pixels, bc, pix, upix, inverse, stage, x, n_ones, obj, ox, oy, och


class WindowFront:
    """``WindowFront(pipeline)(t0, volume, history)``: a raw window's (volume after the front end,
    batch = (stage_k, OFPD input, n_events, ones), its event pixels before the front end) through
    window_front, with the Pipeline's settings worked out once; ``history``, the Pipeline's
    support history, is moved on as events.support.front_end does. Taken at each call, as the
    front end's scratch is: a caller may hand the Pipeline another history (deploy/parity.py's
    windows each get their own), and the scratch is the calling thread's. Only for a Pipeline
    that ``applies`` says it fits."""

    def __init__(self, pipe):
        cfg, cascade = pipe.config, pipe.cascade
        s, n_input, g, blobs, crop = pipe._batch
        w, h = pipe.sensor_size
        wp, hp = cascade.sensor_size
        _k, radius, m, noise_factor = cfg.input_support
        self.n_pixels = w * h
        self.shape = (int(cfg.n_bins), 2, h, w)
        rule = s["recent_events"]
        self.recent = rule is not None       # which form of window_front it calls (warm_up's)
        #: every argument after (idx, slot_of, counts, old, counts_total), in window_front's order; the
        #: arrays in it (the cascade's scratch and weights, the rule) are this Pipeline's, updated in place
        self._args = (2, w * h, w, h, check_norm(cfg.input_norm) == "first", check_min_cluster(cfg.input_min_cluster),
                      int(radius), int(m), int(noise_factor), int(cfg.ofs_pool), hp,
                      wp, cascade.kernel_size, cascade._scratch, cascade._weights, cascade._dv, cascade._vth,
                      cascade._reset_zero, cascade.n_bins, cascade.mask_kernel, *blobs, *crop, n_input, COORD_SCALE,
                      None if rule is None else np.array([*rule, 0], np.int64))   # total: window_front's

    @staticmethod
    def applies(pipe) -> bool:
        """Whether ``pipe`` runs its windows this way: its fast path (Pipeline.fast_path) with
        temporal support."""
        return pipe.fast_path and pipe.support is not None

    def __call__(self, t0: int, volume: SpikeVolume, hist) -> tuple:
        hist.advance(t0)
        old = hist.leaving()
        (kept, pixels, bc, pix, upix, inverse, stage, x, n_ones, *ones) = window_front(
            volume.idx, slots_for(self.n_pixels), hist.counts, old, hist.total, *self._args)
        hist.add_counted(t0, pixels, old)
        out = SpikeVolume(kept, self.shape)
        out.__dict__.update(bc=bc, pix=pix, _pixel_index=(upix, inverse))
        return out, (stage + 1, x, n_ones, tuple(ones)), pixels


def warm_up(recent: bool) -> None:
    """Compile (or load from numba's cache) window_front for the argument types a Pipeline passes
    (``recent``: with ofpd.recent_events' rule, else None), before the first window is timed."""
    i64 = np.zeros(1, np.int64)
    scratch = slots_for(4)
    counts = np.zeros(4, np.uint8)
    window_front(i64, scratch, counts, i64[:0], 0, 2, 4, 2, 2, True, 2, 1, 1, 0, 2, 1, 1, 1, slots_for(1),
                 np.ones((1, 1, 1), np.int64), i64, i64, np.zeros(1, np.bool_), 1, 1, True, 1, 0.2, 1.5, 1, 1, 0.0,
                 0.65, 0.0, False, 0, 1, 1, 1, 5, 1000.0, np.zeros(4, np.int64) if recent else None)
