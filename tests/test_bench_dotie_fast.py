"""The optimised DOTIE (numba, event driven, grid DBSCAN) against the reference port: identical
spikes, separated events and boxes; the grid DBSCAN against scikit-learn's labels."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from sklearn.cluster import DBSCAN

from toffe_deploy.baselines.dotie import (DotieParams, DotieState, dotie_detect_x, dotie_frames, dotie_separate_x)
from toffe_deploy.baselines.dotie_fast import FastDotie, grid_dbscan
from toffe_deploy.events import make_events

SAMPLE = Path(__file__).resolve().parents[1] / "toffe_deploy" / "samples" / "sample_multi.h5"


def _blobs(rng, size=(64, 48), n_windows=4, dt=500):
    """Dense moving blobs (they fire and get boxes) plus sparse noise, over several windows."""
    w, h = size
    xs, ys, ts, ps = [], [], [], []
    for t in range(0, n_windows * dt, 25):
        for cx, cy, v in ((10 + t * 0.01, 12, 1), (50 - t * 0.004, 34, 1)):
            n = 40
            xs += list(np.clip(rng.normal(cx, 4, n).astype(int), 0, w - 1))
            ys += list(np.clip(rng.normal(cy, 4, n).astype(int), 0, h - 1))
            ts += [t] * n
            ps += list(rng.integers(0, 2, n))
        xs += list(rng.integers(0, w, 3))
        ys += list(rng.integers(0, h, 3))
        ts += [t] * 3
        ps += [1] * 3
    return make_events(xs, ys, ts, ps)


def _compare(fast, ev, t0, dt, n_bins, size, p, state=None):
    x = dotie_frames(ev, t0, dt, n_bins, size)
    spikes, out = dotie_separate_x(x, p, state=state)
    op, optr, sp, sptr = fast.steps(ev, t0, keep_spikes=True)
    for b in range(n_bins):
        assert np.array_equal(np.flatnonzero(spikes[b]), sp[sptr[b]:sptr[b + 1]])
        assert np.array_equal(np.flatnonzero(out[b]), op[optr[b]:optr[b + 1]])
    return int(spikes.sum()), int(out.sum())


@pytest.mark.parametrize("carry", [False, True])
def test_fast_layer_and_recovery_are_bit_identical(rng, carry):
    size, dt, nb = (64, 48), 500, 5
    p = DotieParams(min_box_diag2=100.0)
    ev = _blobs(rng)
    fast = FastDotie(size, nb, dt, p, carry=carry)
    state = DotieState.zeros(size[1], size[0]) if carry else None
    fired = 0
    for t0 in range(0, 4 * dt, dt):
        w = ev[(ev["t"] >= t0) & (ev["t"] < t0 + dt)]
        s, o = _compare(fast, w, t0, dt, nb, size, p, state)
        fired += s > 0 and o > 0
        if not carry:
            assert FastDotie(size, nb, dt, p).detect(w, t0) == dotie_detect_x(dotie_frames(w, t0, dt, nb, size), p)
    assert fired >= 2                           # the check compared real spikes, not empty frames


def test_fast_detection_identical_on_the_shipped_sample():
    from toffe_deploy.events.io import open_events

    with open_events(SAMPLE) as src:
        size = tuple(src.sensor_size)
        fast = FastDotie(size, 5, 500)
        boxes = 0
        for i, (t0, ev) in enumerate(src.iter_windows(500)):
            if i >= 4:
                break
            _compare(fast, ev, t0, 500, 5, size, DotieParams())
            ref = dotie_detect_x(dotie_frames(ev, t0, 500, 5, size))
            assert fast.detect(ev, t0) == ref
            boxes += sum(len(r) for r in ref)
    assert boxes > 0


def test_host_part_from_the_layers_spikes_gives_the_references_boxes():
    """energy_latency's Loihi 2 row times DOTIE's host part at the optimised level: from the
    layer's spikes and each step's event pixels, the same boxes as the reference's recovery and
    scikit-learn DBSCAN (before 2026-11-30 the row timed that reference code, TOFFE's compiled)."""
    from toffe_deploy.baselines.dotie import dotie_cluster_steps, dotie_postprocess
    from toffe_deploy.events.io import open_events

    p = DotieParams()
    with open_events(SAMPLE) as src:
        size = tuple(src.sensor_size)
        fast = FastDotie(size, 5, 500, p)
        boxes = 0
        for i, (t0, ev) in enumerate(src.iter_windows(500)):
            if i >= 4:
                break
            x = dotie_frames(ev, t0, 500, 5, size)
            spikes, _out = dotie_separate_x(x, p)
            ref = dotie_cluster_steps(dotie_postprocess(x, spikes, p), p)
            got = fast.host_part([np.flatnonzero(s) for s in spikes], [np.flatnonzero(f) for f in x])
            assert got == ref
            boxes += sum(len(r) for r in ref)
    assert boxes > 0


def _sk(xs, ys, eps=15.0, ms=10):
    return DBSCAN(eps=eps, min_samples=ms).fit(np.column_stack([xs, ys]).astype(float)).labels_


@pytest.mark.parametrize("seed", range(6))
def test_grid_dbscan_equals_sklearn_on_random_points(seed):
    r = np.random.default_rng(seed)
    n = int(r.integers(20, 600))
    # clumps and uniform points on a small field: many cores, borders and ties at distance 15
    c = r.integers(0, 120, (4, 2))
    pts = np.concatenate([c[r.integers(0, 4, n // 2)] + r.integers(-12, 13, (n // 2, 2)),
                          r.integers(0, 160, (n - n // 2, 2))])
    pts = np.unique(pts, axis=0) if seed % 2 else pts            # duplicates too (an event image has none)
    xs, ys = pts[:, 0].astype(np.int64), pts[:, 1].astype(np.int64)
    for eps, ms in ((15.0, 10), (5.0, 4), (7.5, 3)):
        assert np.array_equal(grid_dbscan(xs, ys, eps, ms), _sk(xs, ys, eps, ms))


def test_grid_dbscan_border_point_goes_to_the_first_cluster():
    # two cores' clusters 30 px apart; the point in the middle is within eps (15) of one core
    # of each but has too few neighbours to be core: scikit-learn gives it the first cluster
    left = [(0, y) for y in range(10)]
    right = [(30, y) for y in range(10)]
    for order in (left + right + [(15, 0)], right + [(15, 0)] + left, [(15, 0)] + right + left):
        xs = np.array([q[0] for q in order], np.int64)
        ys = np.array([q[1] for q in order], np.int64)
        sk = _sk(xs, ys, 15.0, 10)
        assert np.array_equal(grid_dbscan(xs, ys, 15.0, 10), sk)
        mid = order.index((15, 0))
        assert sk[mid] == sk[0 if mid else 1]   # the border point joins the cluster met first
