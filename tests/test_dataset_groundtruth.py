"""window_truth: interpolation at the window midpoint, visibility, several objects."""
from __future__ import annotations

import numpy as np
import pytest

from toffe_deploy.dataset.groundtruth import ObjectTruth, window_truth


def _gt():
    # two objects, samples every 50 us, rows sample-major as the generator writes them
    t = np.repeat(np.arange(0, 250, 50, dtype=np.int64), 2)
    oid = np.tile(np.array([0, 1], np.int32), 5)
    x = np.where(oid == 0, t * 0.1, 100.0 - t * 0.2).astype(np.float32)
    y = np.where(oid == 0, 10.0, 20.0 + t * 0.04).astype(np.float32)
    # object 1's direction crosses +-pi between samples at t = 100 and 150
    d1 = np.array([3.0, 3.1, np.pi - 0.02, -np.pi + 0.02, -3.1])
    direction = np.where(oid == 0, 0.5, np.repeat(d1, 2)).astype(np.float32)
    speed = np.where(oid == 0, 5.0 + t * 0.01, 100.0).astype(np.float32)
    speed_bin = np.where(oid == 0, np.where(t < 100, 1, 2), 4).astype(np.int8)
    visible = ~((oid == 0) & (t == 200))
    return dict(t=t, object_id=oid, x=x, y=y, direction=direction, speed=speed, speed_bin=speed_bin,
                visible=visible)


def test_interpolates_at_window_midpoint():
    out = window_truth(_gt(), 0, 50)  # midpoint 25 us
    assert [o.object_id for o in out] == [0, 1]
    o0, o1 = out
    assert isinstance(o0, ObjectTruth)
    assert o0.x == pytest.approx(2.5) and o0.y == pytest.approx(10.0)
    assert o0.speed == pytest.approx(5.25) and o0.direction == pytest.approx(0.5)
    assert o1.x == pytest.approx(95.0) and o1.y == pytest.approx(21.0)
    assert o0.speed_bin == 1 and o1.speed_bin == 4


def test_direction_interpolates_through_the_short_way_across_pi():
    (_, o1) = window_truth(_gt(), 100, 50)  # midpoint 125, between pi - 0.02 and -pi + 0.02
    assert abs(abs(o1.direction) - np.pi) < 1e-3


def test_speed_bin_from_nearer_sample_and_exact_sample_times():
    o0 = window_truth(_gt(), 40, 40)[0]  # midpoint 60: nearer the sample at 50 (bin 1)
    assert o0.speed_bin == 1 and o0.x == pytest.approx(6.0)
    o0 = window_truth(_gt(), 80, 60)[0]  # midpoint 110: nearer 100 (bin 2)
    assert o0.speed_bin == 2
    o0 = window_truth(_gt(), 0, 200)[0]  # midpoint exactly on the sample at 100
    assert o0.x == pytest.approx(10.0) and o0.speed == pytest.approx(6.0)


def test_invisible_and_out_of_span_objects_are_left_out():
    ids = [o.object_id for o in window_truth(_gt(), 150, 50)]  # 175: object 0 invisible at 200
    assert ids == [1]
    assert window_truth(_gt(), 1000, 50) == []
    assert window_truth(_gt(), -200, 50) == []


def test_missing_columns_are_reported():
    gt = _gt()
    del gt["visible"]
    with pytest.raises(ValueError, match="visible"):
        window_truth(gt, 0, 50)
