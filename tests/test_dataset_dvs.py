"""DVS emulator and shape rasterisation: against slow obvious references."""
from __future__ import annotations

import numpy as np
import pytest

from toffe_deploy.dataset.dvs import DVSEmulator, DVSParams, noise_events
from toffe_deploy.dataset.shapes import SHAPES, STAR_INNER, coverage


def _reference_dvs(log_frames, l0, c, t_us):
    """Per pixel, per sample: fire while |L - ref| >= C, moving ref by C each event."""
    out = []
    k, h, w = log_frames.shape
    ref = l0.copy()
    for i in range(k):
        for y in range(h):
            for x in range(w):
                while log_frames[i, y, x] - ref[y, x] >= c[y, x]:
                    ref[y, x] += c[y, x]
                    out.append((t_us[i], x, y, 1))
                while log_frames[i, y, x] - ref[y, x] <= -c[y, x]:
                    ref[y, x] -= c[y, x]
                    out.append((t_us[i], x, y, 0))
    return sorted(out)


def test_dvs_matches_per_event_reference(rng):
    h, w, k = 6, 7, 40
    l0 = rng.normal(0.0, 0.3, (h, w))
    walk = l0 + np.cumsum(rng.normal(0.0, 0.2, (k, h, w)), axis=0)
    t_us = np.arange(1, k + 1) * 50
    dvs = DVSEmulator(l0, DVSParams(threshold=0.25, threshold_sigma=0.05), np.random.default_rng(5))
    c = 1.0 / dvs.inv_c
    # two calls over overlapping rectangles: the state carries over between calls
    ev1 = dvs.process(0, 0, walk[:25], t_us[:25])
    ev2 = dvs.process(0, 0, walk[25:], t_us[25:])
    got = sorted((int(e["t"]), int(e["x"]), int(e["y"]), int(e["p"])) for e in np.concatenate([ev1, ev2]))
    assert got == _reference_dvs(walk, l0, c, t_us)
    assert len(got) > 100


def test_dvs_step_fires_floor_of_contrast_over_threshold():
    l0 = np.zeros((1, 1))
    dvs = DVSEmulator(l0, DVSParams(threshold=0.25, threshold_sigma=0.0), np.random.default_rng(0))
    ev = dvs.process(0, 0, np.array([[[0.8]], [[0.8]], [[0.0]]]), np.array([50, 100, 150]))
    assert [(int(e["t"]), int(e["p"])) for e in ev] == [(50, 1)] * 3 + [(150, 0)] * 3


def test_noise_events_rate_and_range(rng):
    ev = noise_events(10.0, 2001, 50, (64, 48), rng)  # 0.1 s, 10 Hz per pixel -> ~3072 events
    assert abs(ev.shape[0] - 3072) < 5 * np.sqrt(3072)
    assert ev["x"].max() < 64 and ev["y"].max() < 48 and ev["t"].min() >= 50
    assert np.all(np.diff(ev["t"]) >= 0)
    assert 0.4 < ev["p"].mean() < 0.6
    assert noise_events(0.0, 2001, 50, (64, 48), rng).shape[0] == 0


@pytest.mark.parametrize("shape", SHAPES)
def test_shape_area_and_symmetry(shape):
    r = 20.0
    g = np.arange(-30, 31, dtype=np.float64)
    cov = coverage(shape, g[None, :] + 0.3, g[:, None] - 0.2, r)  # sub-pixel offset centre
    a = STAR_INNER
    # star area: 10 triangles between an outer (r) and an inner (a r) vertex, 36 deg apart
    exact = {"circle": np.pi * r * r, "square": 4 * r * r, "diamond": 2 * r * r,
             "star": 10 * 0.5 * r * (a * r) * np.sin(np.radians(36))}[shape]
    assert cov.sum() == pytest.approx(exact, rel=0.01)
    assert cov.min() == 0.0 and cov.max() == 1.0
    ys, xs = np.mgrid[-30:31, -30:31]
    cx, cy = (cov * xs).sum() / cov.sum(), (cov * ys).sum() / cov.sum()
    assert abs(cx + 0.3) < 0.05 and abs(cy - 0.2) < 0.05  # centroid is the centre


def test_unknown_shape_is_an_error():
    with pytest.raises(ValueError, match="unknown shape"):
        coverage("hexagon", np.zeros(1), np.zeros(1), 1.0)
