"""The generator: its ground truth against the events it emits, determinism, exactness of
rendering only boxes, and the split protocol (speeds inside the target bins)."""
from __future__ import annotations

import numpy as np
import pytest

from toffe_deploy.camera import PinholeCamera
from toffe_deploy.dataset.dvs import DVSEmulator, DVSParams
from toffe_deploy.dataset.groundtruth import window_truth
from toffe_deploy.dataset.splits import PROGRAMMED_SPEEDS, split_specs
from toffe_deploy.dataset.synth import (ObjectSpec, SequenceSpec, _background, _render, object_tracks,
                                        generate_sequence)
from toffe_deploy.dataset.trajectories import Trajectory
from toffe_deploy.events.binning import window_slice
from toffe_deploy.events.core import EVENT_DTYPE


def _spec(shape="circle", lap=2.0, duration=0.05, depth_amp=0.3, curve="ellipse", **kw):
    traj = Trajectory(curve, lap, depth_amp_m=depth_amp, phase0=0.3)
    return SequenceSpec("t", (ObjectSpec(shape, traj),), duration_s=duration, **kw)


@pytest.fixture(scope="module")
def slow_circle():
    return generate_sequence(_spec(), seed=3)


def test_reported_centre_is_centre_of_events(slow_circle):
    """A symmetric shape at ~5 m/s: events of each 5 ms window centre on the truth within 1 px."""
    ev, gt, size = slow_circle
    assert size == (640, 480) and ev.dtype == EVENT_DTYPE
    errs = []
    for t0 in range(0, 45001, 5000):
        w = window_slice(ev, t0, 5000)
        (tr,) = window_truth(gt, t0, 5000)
        assert w.shape[0] > 200
        errs.append(np.hypot(w["x"].mean() - tr.x, w["y"].mean() - tr.y))
    assert max(errs) < 1.0


def test_direction_and_speed_agree_with_finite_differences(slow_circle):
    ev, gt, _ = slow_circle
    cam = PinholeCamera()
    t = gt["t"] * 1e-6
    dx, dy, dt = np.diff(gt["x"]), np.diff(gt["y"]), np.diff(t)
    mid_dir = np.angle(np.exp(1j * gt["direction"][1:]) + np.exp(1j * gt["direction"][:-1]))
    assert np.abs(np.angle(np.exp(1j * (np.arctan2(dy, dx) - mid_dir)))).max() < 1e-3
    # 3-D speed against finite differences of the analytic 3-D centre
    traj = _spec().objects[0].trajectory
    p = traj.position(t)
    fd_speed = np.linalg.norm(np.diff(p, axis=0), axis=1) / dt
    np.testing.assert_allclose(fd_speed, (gt["speed"][1:] + gt["speed"][:-1]) / 2, rtol=1e-3)
    # centre of the emitted events, 10 ms apart: direction within 10 deg, image speed within 10%
    cents = []
    for t0 in (0, 10000, 20000, 30000, 40000):
        w = window_slice(ev, t0, 5000)
        cents.append((w["x"].mean(), w["y"].mean(), *[(o.direction) for o in window_truth(gt, t0, 5000)]))
    c = np.array(cents)
    d = np.diff(c[:, :2], axis=0)
    truth_dir = np.angle(np.exp(1j * c[1:, 2]) + np.exp(1j * c[:-1, 2]))
    assert np.degrees(np.abs(np.angle(np.exp(1j * (np.arctan2(d[:, 1], d[:, 0]) - truth_dir))))).max() < 10
    i = np.searchsorted(gt["t"], [12500, 22500, 32500, 42500])  # mid-points between window centres
    img_speed = np.hypot(np.gradient(gt["x"]), np.gradient(gt["y"])) / 50e-6
    est = np.hypot(d[:, 0], d[:, 1]) / 0.01  # ~5.4 px per 10 ms: centroid noise matters per pair
    np.testing.assert_allclose(est, img_speed[i], rtol=0.2)
    assert est.mean() == pytest.approx(img_speed[i].mean(), rel=0.05)


def test_fronto_parallel_image_speed_is_f_over_z_times_speed():
    """With no depth swing, image speed (px/s) = f / Z * speed (m/s): the camera model holds."""
    spec = _spec(lap=0.2, duration=0.002, depth_amp=0.0)
    _, gt = object_tracks(spec, np.arange(spec.n_samples) * 50e-6)
    img = np.hypot(np.diff(gt["x"]), np.diff(gt["y"])) / 50e-6
    np.testing.assert_allclose(img, PinholeCamera().f / 5.0 * (gt["speed"][1:] + gt["speed"][:-1]) / 2, rtol=1e-3)


def test_deterministic_for_a_seed():
    spec = _spec(shape="star", lap=0.15, duration=0.01)
    a, ga, _ = generate_sequence(spec, seed=7)
    b, gb, _ = generate_sequence(spec, seed=7)
    c, gc, _ = generate_sequence(spec, seed=8)
    assert np.array_equal(a, b) and all(np.array_equal(ga[k], gb[k]) for k in ga)
    assert not np.array_equal(a, c)  # other thresholds
    assert all(np.array_equal(ga[k], gc[k]) for k in ga)  # same motion
    assert a.shape[0] > 1000 and np.all(np.diff(a["t"]) >= 0)
    assert 0.4 < a["p"].mean() < 0.6  # both polarities


@pytest.mark.parametrize("refractory_us", [0.0, 400.0])
def test_rendering_boxes_equals_rendering_whole_frames(refractory_us):
    """Two objects (overlapping boxes merge) on a small sensor: rendering only the edge bands
    of boxes (and the pixels a refractory period holds pending) loses nothing."""
    cam = PinholeCamera(96, 72)
    objs = (ObjectSpec("square", Trajectory("lemniscate", 0.05, scale_m=1.2, phase0=1.0), size_m=1.0),
            ObjectSpec("star", Trajectory("limacon", 0.08, scale_m=1.2, clockwise=False), size_m=1.2,
                       intensity=0.2))
    spec = SequenceSpec("two", objs, duration_s=0.01, camera=cam, texture=0.2,
                        dvs=DVSParams(refractory_us=refractory_us))
    ev, gt, size = generate_sequence(spec, seed=11)
    # reference: whole frames, sample by sample, same seed order (texture, thresholds)
    rng = np.random.default_rng(11)
    n = spec.n_samples
    tracks, _ = object_tracks(spec, np.arange(n) * 50e-6)
    bg = _background(spec, rng)
    full = (0, 0, 96, 72)
    frames = spec.dvs.log(_render(bg, full, tracks, np.arange(n)))
    dvs = DVSEmulator(frames[0], spec.dvs, rng)
    ref = np.concatenate([dvs.process(0, 0, frames[k:k + 1], np.array([50 * k])) for k in range(1, n)])
    key = lambda e: np.sort(e, order=["t", "y", "x", "p"])
    assert ev.shape[0] > 500
    assert np.array_equal(key(ev), key(ref))


def test_split_protocol_and_speeds_in_target_bins():
    train, test = split_specs("train", seed=0), split_specs("test", seed=0)
    assert len(train) == 384 and len(test) == 64
    assert {o.trajectory.curve for s in train for o in s.objects}.isdisjoint(
        {o.trajectory.curve for s in test for o in s.objects})
    assert {s.objects[0].trajectory.orientation_deg for s in test} == {0.0}
    assert split_specs("train", seed=0) == train and split_specs("train", seed=1) != train
    inside = []
    for s in train[::7] + test[::3]:
        o = s.objects[0]
        lap = o.trajectory.lap_time_s
        sp = np.linalg.norm(o.trajectory.velocity(np.linspace(0, lap, 400, endpoint=False)), axis=1)
        lo, hi = PROGRAMMED_SPEEDS[o.target_bin]
        inside.append(np.mean((sp >= lo) & (sp < hi)))
        assert sp.max() <= 150.0
    assert np.mean(inside) > 0.95 and min(inside) > 0.7


def test_multi_object_sequences_keep_objects_apart_and_in_view():
    multi = split_specs("multi", seed=0, duration_s=0.02, multi_count=6)
    for s in multi:
        bins = [o.target_bin for o in s.objects]
        assert 2 <= len(bins) <= 4 and len(set(bins)) == len(bins)
        _, gt = object_tracks(s, np.arange(0, 1.0, 1e-3))  # a full second of motion
        assert gt["visible"].all()
        xy = np.stack([gt["x"], gt["y"]], 1).reshape(-1, len(bins), 2)
        for i in range(len(bins)):
            for j in range(i + 1, len(bins)):
                assert np.hypot(*(xy[:, i] - xy[:, j]).T).min() > 60  # > one object width apart


def test_contrast_modes_set_object_intensity():
    from toffe_deploy.dataset.synth import BRIGHT, DARK
    bright = {o.intensity for s in split_specs("test", seed=0) for o in s.objects}
    mixed = {o.intensity for s in split_specs("test", seed=0, contrast="mixed") for o in s.objects}
    dark = {o.intensity for s in split_specs("multi", seed=0, multi_count=3, contrast="dark") for o in s.objects}
    assert bright == {BRIGHT} and mixed == {BRIGHT, DARK} and dark == {DARK}
    with pytest.raises(ValueError):
        split_specs("test", contrast="grey")
