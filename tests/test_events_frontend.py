"""The input front end (events/frontend.py): one definition, dense and sparse, and what it removes."""
from __future__ import annotations

import numpy as np
import pytest

from toffe_deploy.events import make_events
from toffe_deploy.events.binning import bin_window
from toffe_deploy.events.frontend import apply_dense, apply_index, first_spikes_dense, first_spikes_index
from toffe_deploy.runtime.spikes import SpikeVolume


def test_first_keeps_one_spike_per_pixel_and_polarity(rng):
    vol = rng.random((5, 2, 12, 16)) < 0.3
    out = first_spikes_dense(vol)
    assert out.sum(axis=0).max() == 1                         # at most one spike per (p, y, x)
    assert np.array_equal(out.any(axis=0), vol.any(axis=0))   # ... and every pixel that fired keeps one
    first_b = np.argmax(vol, axis=0)
    ys, xs = np.nonzero(vol.any(axis=0)[0])
    assert all(out[first_b[0, y, x], 0, y, x] for y, x in zip(ys, xs))   # the earliest one


def test_dense_and_index_agree_and_are_idempotent(rng):
    vol = rng.random((5, 2, 9, 11)) < 0.4
    idx = first_spikes_index(np.flatnonzero(vol), vol.shape)
    assert np.array_equal(idx, np.flatnonzero(first_spikes_dense(vol)))
    assert np.array_equal(first_spikes_dense(first_spikes_dense(vol)), first_spikes_dense(vol))
    sv = SpikeVolume.from_dense(vol)
    assert np.array_equal(sv.front_end("first").front_end("first").idx, idx)
    assert sv.front_end("none") is sv
    batch = np.stack([vol, ~vol])
    assert np.array_equal(apply_dense(batch, "first")[1], first_spikes_dense(~vol))   # batched (N, B, C, H, W)


def test_event_multiplicity_does_not_reach_the_network():
    """An edge sweeping 4 px firing 1 event per pixel, and the same edge firing 3 events per pixel
    spread over the window (a brighter object / lower threshold), give the same first spikes."""
    xs = np.arange(4)
    one = make_events(xs, np.zeros(4, int), xs * 100, np.ones(4, int))
    xs3 = np.repeat(xs, 3)
    t3 = np.repeat(xs * 100, 3) + np.tile([0, 150, 300], 4)
    order = np.argsort(t3, kind="stable")
    three = make_events(xs3[order], np.zeros(12, int), t3[order], np.ones(12, int))
    a = bin_window(one, 0, 500, 5, (8, 2))
    b = bin_window(three, 0, 500, 5, (8, 2))
    assert (b > 0).sum() > (a > 0).sum()                     # more spikes without the front end
    assert np.array_equal(apply_dense(a, "first"), apply_dense(b, "first"))


def test_unknown_norm_is_refused():
    with pytest.raises(ValueError, match="input_norm"):
        apply_index(np.zeros(0, np.int64), (5, 2, 4, 4), "median")
