"""Temporal support of the front end (events/support.py): what it keeps back, dense = index."""
from __future__ import annotations

import numpy as np
import pytest

from toffe_deploy.events.frontend import apply_dense
from toffe_deploy.compiled import dedupe, new_scratch
from toffe_deploy.config import ToffeConfig
from toffe_deploy.events.support import SupportHistory, event_pixels, front_end, history_counts, support_dense, support_index
from toffe_deploy.runtime.spikes import SpikeVolume


def _window(pixels, shape=(5, 2, 12, 16)):
    vol = np.zeros(shape, bool)
    for b, c, y, x in pixels:
        vol[b, c, y, x] = True
    return vol


def test_scattered_slow_edge_is_kept_when_it_fired_before_and_noise_is_not():
    """A slow edge: isolated pixels every 3 px along a column, firing again on the same column in
    the windows before; a lone pixel elsewhere with no history is noise."""
    edge = [(b % 5, 1, y, 5) for b, y in enumerate(range(0, 12, 3))]
    noise = [(2, 0, 6, 13)]
    vol = _window(edge + noise)
    assert not apply_dense(vol, "first", 4).any()                      # the cluster filter drops all
    before = np.zeros((4, 12, 16), bool)
    before[:, :, 5] = True                                               # the same column
    counts = history_counts(before)
    got = support_dense(vol, "first", 4, counts, 1, 6)
    assert {tuple(p) for p in np.argwhere(got)} == set(edge)
    assert not support_dense(vol, "first", 4, np.zeros_like(counts), 1, 6).any()   # no history: dropped
    assert not support_dense(vol, "first", 4, counts, 1, 99).any()


def test_support_only_adds_to_the_cluster_filter(rng):
    vol = rng.random((5, 2, 20, 24)) < 0.02
    counts = history_counts(rng.random((4, 20, 24)) < 0.05)
    base = apply_dense(vol, "first", 3)
    got = support_dense(vol, "first", 3, counts, 1, 4)
    assert not (base & ~got).any()                                       # every base spike stays
    assert got.sum() > base.sum()
    assert not (got & ~apply_dense(vol, "first", 1)).any()               # only first spikes of event pixels
    assert np.array_equal(event_pixels(got) & ~event_pixels(base),
                          event_pixels(got) & ~event_pixels(base) & event_pixels(vol))


@pytest.mark.parametrize("shape", [(5, 2, 17, 23), (3, 2, 1, 30), (2, 1, 25, 2), (4, 3, 9, 9)])
def test_support_dense_and_index_agree(rng, shape):
    """The compiled box sums (border pixels included) against the dense definition (cv2 box
    filter), for both front-end norms, cluster sizes, radii and thresholds."""
    vol = rng.random(shape) < 0.06
    counts = history_counts(rng.random((4,) + shape[2:]) < 0.1)
    for norm in ("none", "first"):
        for n in (1, 2, 4):
            for r, m, c in ((1, 3, 0), (1, 6, 0), (2, 8, 0), (1, 2, 2), (1, 3, 5)):
                dense = support_dense(vol, norm, n, counts, r, m, c)
                got = support_index(np.flatnonzero(vol), vol.shape, norm, n, counts, r, m, c)
                assert np.array_equal(got, np.flatnonzero(dense)), (norm, n, r, m, c)
                total = int(counts.sum())
                assert np.array_equal(support_index(np.flatnonzero(vol), vol.shape, norm, n, counts, r, m, c, total), got)
    assert support_index(np.zeros(0, np.int64), shape, "first", 4, counts, 1, 6).size == 0


def test_noise_factor_raises_the_threshold_with_the_event_density():
    """T = m + floor(c (2r+1)^2 E / (H W)): the same window and history keep fewer pixels back
    when the sensor fires more (E larger), none more."""
    edge = [(b % 5, 1, y, 5) for b, y in enumerate(range(1, 11, 2))]
    vol = _window(edge)
    before = np.zeros((4, 12, 16), bool)
    before[:, :, 5] = True
    quiet = history_counts(before)
    assert support_dense(vol, "first", 4, quiet, 1, 6, 2).sum() == len(edge)    # S = 13 >= T = 6 + 18 * 53 // 192 = 10
    noisy = quiet.copy()
    noisy[:, 10:] += 4                                                          # far from the edge: E up, S the same
    assert not support_dense(vol, "first", 4, noisy, 1, 6, 2).any()
    assert support_dense(vol, "first", 4, noisy, 1, 6, 0).sum() == len(edge)


def test_streamed_front_end_gives_the_kept_pixel_index_and_the_history_counts(rng):
    """front_end on a SpikeVolume: the same ones as the dense form, the pixel_index it leaves on
    the volume is compiled.dedupe's of the kept ones, and the history's counts (compiled
    update) are the sum of the last K windows' event pixels."""
    shape = (5, 2, 18, 22)
    cfg = ToffeConfig(sensor_size=(22, 18), input_min_cluster=3, input_support=(3, 1, 3, 1))
    hist = SupportHistory(3, (22, 18), cfg.dt_us)
    dense_hist = SupportHistory(3, (22, 18), cfg.dt_us)
    seen = []
    for i in range(8):
        t0 = i * cfg.dt_us
        vol = rng.random(shape) < 0.05
        want = front_end(vol, cfg, dense_hist, t0)
        got = front_end(SpikeVolume.from_dense(vol), cfg, hist, t0)
        assert np.array_equal(got.to_dense(), want)
        upix, inv = got.__dict__["_pixel_index"]
        ref_u, ref_inv = dedupe(got.idx % (18 * 22), new_scratch(18 * 22))
        assert np.array_equal(upix, ref_u) and np.array_equal(inv, ref_inv)
        seen.append(event_pixels(vol))
        assert np.array_equal(hist.counts, history_counts(seen[-3:]).reshape(-1))
        assert hist.total == int(history_counts(seen[-3:]).sum())


@pytest.mark.parametrize("dense", [True, False])
def test_a_skipped_window_is_shifted_in_once(dense):
    """A stream that skips an empty window: the history holds the windows before as they were,
    [w0, w1, (empty), w3] for K = 4, not the gap twice (front_end advances, then push does)."""
    cfg = ToffeConfig(sensor_size=(8, 6), dt_us=10, input_support=(4, 1, 5, 0))
    hist = SupportHistory(4, (8, 6), 10)
    for t0, px in ((0, 1), (10, 2), (30, 3)):
        vol = np.zeros((cfg.n_bins, 2, 6, 8), np.uint8)
        vol[0, 0, px // 8, px % 8] = 1
        front_end(vol if dense else SpikeVolume.from_dense(vol), cfg, hist, t0)
    assert [r.tolist() for r in hist._ring] == [[1], [2], [], [3]]
    assert hist.counts[[1, 2, 3]].tolist() == [1, 1, 1] and hist.total == 3
