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


def _one_window(pixels, shape=(5, 2, 10, 12)):
    vol = np.zeros(shape, bool)
    for b, c, y, x in pixels:
        vol[b, c, y, x] = True
    return vol


def test_min_cluster_drops_isolated_pixels_and_keeps_edges():
    edge = [(b, 1, 2 + b, 3) for b in range(4)]                     # 4 pixels, diagonal-free column
    diag = [(0, 0, 6, 6), (1, 1, 7, 7), (2, 0, 8, 8)]                # 3 pixels linked by corners
    noise = [(3, 0, 0, 11), (0, 1, 9, 0)]                            # isolated
    vol = _one_window(edge + diag + noise)
    kept = apply_dense(vol, "none", 3)
    assert {tuple(p) for p in np.argwhere(kept)} == set(edge + diag)
    assert {tuple(p) for p in np.argwhere(apply_dense(vol, "none", 4))} == set(edge)
    assert np.array_equal(apply_dense(vol, "none", 1), vol)


def test_min_cluster_counts_pixels_not_spikes():
    """Two spikes (both polarities) of one pixel are one pixel of its cluster."""
    vol = _one_window([(0, 0, 4, 4), (2, 1, 4, 4), (1, 0, 4, 5)])
    assert not apply_dense(vol, "none", 3).any()
    assert apply_dense(vol, "none", 2).sum() == 3


@pytest.mark.parametrize("n", [2, 3, 5])
def test_min_cluster_dense_and_index_agree_and_are_idempotent(rng, n):
    vol = rng.random((5, 2, 17, 23)) < 0.03
    for norm in ("none", "first"):
        dense = apply_dense(vol, norm, n)
        idx = apply_index(np.flatnonzero(vol), vol.shape, norm, n)
        assert np.array_equal(idx, np.flatnonzero(dense))
        assert np.array_equal(apply_dense(dense, norm, n), dense)
        sv = SpikeVolume.from_dense(vol)
        assert np.array_equal(sv.front_end(norm, n).front_end(norm, n).idx, idx)
    assert 0 < apply_dense(vol, "none", n).sum() < vol.sum()
    batch = np.stack([vol, vol[:, :, ::-1]])
    assert np.array_equal(apply_dense(batch, "first", n)[1], apply_dense(vol[:, :, ::-1], "first", n))


def test_bad_min_cluster_is_refused():
    with pytest.raises(ValueError, match="input_min_cluster"):
        apply_dense(np.zeros((5, 2, 4, 4), bool), "first", 0)


@pytest.mark.parametrize("shape", [(4, 1, 13, 9), (3, 3, 7, 20), (6, 2, 1, 30), (2, 2, 25, 1)])
def test_index_front_end_equals_dense_for_any_channel_count_and_sensor(rng, shape):
    """compiled.front_end_keep (one pass, both filters, no divisions) against the dense definitions,
    also for C != 2 channels and one-row or one-column sensors."""
    vol = rng.random(shape) < 0.15
    for norm in ("none", "first"):
        for n in (1, 2, 4):
            got = apply_index(np.flatnonzero(vol), vol.shape, norm, n)
            assert np.array_equal(got, np.flatnonzero(apply_dense(vol, norm, n))), (norm, n)


def test_front_end_scratch_is_one_per_thread():
    """The front end's kernels release the GIL: two pipelines in two threads must not share the
    all -1 scratch they write into (one per thread and sensor size, reused within a thread)."""
    import threading

    from toffe_deploy.events.frontend import slots_for

    mine = slots_for(12 * 10)
    assert slots_for(12 * 10) is mine and (mine == -1).all()
    theirs = []
    t = threading.Thread(target=lambda: theirs.append(slots_for(12 * 10)))
    t.start()
    t.join()
    assert theirs[0] is not mine and theirs[0].shape == mine.shape and (theirs[0] == -1).all()
