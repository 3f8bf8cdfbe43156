"""The DOTIE baseline: its LIF with the one-step-late subtractive reset, separation, clustering."""
from __future__ import annotations

import numpy as np
import pytest

from toffe_deploy.baselines.dotie import (DotieParams, boxes_from_labels, dotie_cluster, dotie_detect, dotie_frames,
                                          dotie_detect_window, dotie_input, dotie_layer, dotie_separate,
                                          dotie_separate_x)
from toffe_deploy.events.binning import bin_window


def test_layer_matches_hand_computed_sequence():
    # 6 events per step at the centre of a 3x3 image: centre current 0.2*6 = 1.2, edge 0.15*6 = 0.9
    x = np.zeros((4, 3, 3), np.uint16)
    x[:, 1, 1] = 6
    s = dotie_layer(x)
    # centre: U = 1.2 (S), 0.36+1.2-1 = 0.56, 0.168+1.2 = 1.368 (S), 0.4104+1.2-1 = 0.6104
    assert s[:, 1, 1].tolist() == [True, False, True, False]
    # edge: U = 0.9, 0.27+0.9 = 1.17 (S), 0.351+0.9-1 = 0.251, 0.0753+0.9 = 0.9753
    assert s[:, 0, 1].tolist() == [False, True, False, False]


def test_input_sums_polarities_into_one_channel():
    b = np.zeros((2, 2, 4, 4), np.uint16)
    b[0, 0, 1, 1] = 2
    b[0, 1, 1, 1] = 3
    b[1, 1, 0, 0] = 1
    x = dotie_input(b)
    assert x.shape == (2, 4, 4) and x[0, 1, 1] == 5 and x[1, 0, 0] == 1 and x.sum() == 6
    with pytest.raises(ValueError):
        dotie_input(np.zeros((2, 3, 4, 4)))


def _window(shape=(5, 2, 60, 80)):
    b = np.zeros(shape, np.uint16)
    b[:, 1, 10:50, 10:50] = 1        # dense, persistent 40x40 blob: fires (box diagonal^2 3042 >= 2300)
    b[2, 0, 45, 65] = 1              # one stray event: never fires
    return b


def test_separation_runs_per_step_and_drops_noise():
    # interior current 0.15*8 + 0.2 = 1.4: fires at steps 0, 2, 4 (U = 1.4, 0.82, 1.646, 0.894, 1.668);
    # edge current 0.95 fires at steps 1, 3 (U = 0.95, 1.235, 0.32, 1.046, 0.264); corners (0.65) never
    spikes, out = dotie_separate(_window())
    assert spikes.shape == out.shape == (5, 60, 80)
    assert spikes.reshape(5, -1).sum(axis=1).tolist() == [38 * 38, 4 * 38, 38 * 38, 4 * 38, 38 * 38]
    for t in (0, 2, 4):      # the 12x12 dilation + closing win the whole blob back
        assert out[t, 10:50, 10:50].all() and out[t].sum() == 1600
    for t in (1, 3):         # a ring of spikes recovers a 12 px band, not the blob's centre
        assert out[t, 10, 10:50].all() and not out[t, 29, 29] and 0 < out[t].sum() < 1600
    assert not out[:, 45, 65].any()          # the stray event is never separated


def test_detection_clusters_every_step_and_filters_small_boxes():
    dets = dotie_detect(_window())
    assert len(dets) == 5 and all(len(d) == 1 for d in dets)
    assert {(d[0].x0, d[0].y0, d[0].x1, d[0].y1) for d in dets} == {(10, 10, 49, 49)}
    out = dotie_separate(_window())[1]
    assert [d[0].n_points for d in dets] == out.reshape(5, -1).sum(axis=1).tolist()
    assert dets[0][0].cx == pytest.approx(29.5) and dets[0][0].cy == pytest.approx(29.5)
    # once per window: one clustering of the union of the steps
    win = dotie_detect_window(dotie_input(_window()))
    assert len(win) == 1 and win[0].n_points == 1600
    small = np.zeros((60, 80), bool)
    small[5:10, 5:10] = True          # 5x5 object: squared diagonal 32 < 2300 -> dropped
    assert dotie_cluster(small) == []
    assert dotie_cluster(small, DotieParams(min_box_diag2=0.0))[0].n_points == 25
    tiny = np.zeros((60, 80), bool)
    tiny[5, 5:14] = True              # 9 pixels < min_samples: DBSCAN is not run at all
    assert dotie_cluster(tiny, DotieParams(min_box_diag2=0.0)) == []


def test_boxes_per_label_match_a_plain_loop(rng):
    pts = rng.integers(0, 200, (500, 2)).astype(float)
    labels = rng.integers(-1, 4, 500)
    boxes = boxes_from_labels(pts, labels, DotieParams(min_box_diag2=0.0))
    for b, lab in zip(boxes, sorted(set(labels.tolist()) - {-1})):
        sel = pts[labels == lab]
        assert (b.x0, b.x1, b.y0, b.y1) == (sel[:, 0].min(), sel[:, 0].max(), sel[:, 1].min(), sel[:, 1].max())
        assert b.n_points == len(sel) and b.cx == pytest.approx(sel[:, 0].mean())


def test_frames_from_events_equal_binned_input(random_events):
    ev = random_events(n=3000, sensor_size=(32, 24), duration_us=2000)
    x = dotie_frames(ev, 500, 1000, 5, (32, 24))
    assert np.array_equal(x, dotie_input(bin_window(ev, 500, 1000, 5, (32, 24))))
    b = _window()
    s1, o1 = dotie_separate(b)
    s2, o2 = dotie_separate_x(dotie_input(b))
    assert np.array_equal(s1, s2) and np.array_equal(o1, o2)
