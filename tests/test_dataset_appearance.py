"""Randomized appearance: each option changes what it says, drawn values are recorded and
reproducible, the held-out region is respected, pairs are spaced as recorded (small sensors)."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from toffe_deploy.camera import PinholeCamera
from toffe_deploy.dataset.appearance import RANDOM, AppearanceRanges, holdout_cell, is_held_out
from toffe_deploy.dataset.splits import PROGRAMMED_PX_MS, split_specs
from toffe_deploy.dataset.synth import ObjectSpec, SequenceSpec, appearance_summary, generate_sequence
from toffe_deploy.dataset.trajectories import Trajectory
from toffe_deploy.events.binning import window_slice
from toffe_deploy.events.fmt_toffe import derive_speed_px_ms

SMALL = dict(sensor_size=(96, 72), hfov_deg=(60.0, 60.0), depth_m=(5.0, 5.0), size_px=(16.0, 16.0),
             object_contrast=(1.0, 1.0), dark_fraction=0.0, background=(0.3, 0.3), threshold=(0.2, 0.2),
             threshold_sigma=(0.0, 0.0), refractory_us=(0.0, 0.0), noise_hz=(0.0, 0.0), hot_pixels=(0.0, 0.0),
             texture=(0.0, 0.0))


def _spec(name="trefoil_o000_cw_circle_b2", duration=0.02, **kw) -> SequenceSpec:
    """One test-split sequence drawn from fixed SMALL ranges with overrides."""
    specs = split_specs("test", seed=0, duration_s=duration, appearance="random",
                        ranges=AppearanceRanges(**{**SMALL, **kw}))
    return next(s for s in specs if s.name == "test_" + name)


def _run(spec, seed=1):
    ev, gt, _ = generate_sequence(spec, seed)
    return ev, gt


def test_lower_threshold_gives_proportionally_more_events():
    """Log contrast 1.05: C = 0.2 fires floor(5.25) = 5 events per pixel per edge, C = 0.1 fires 10."""
    a, _ = _run(_spec(threshold=(0.2, 0.2), object_contrast=(1.05, 1.05)))
    b, _ = _run(_spec(threshold=(0.1, 0.1), object_contrast=(1.05, 1.05)))
    assert a.shape[0] > 1000
    assert b.shape[0] / a.shape[0] == pytest.approx(2.0, rel=0.03)


def test_refractory_period_keeps_pixels_quiet():
    ev0, _ = _run(_spec(refractory_us=(0.0, 0.0)))
    ev, _ = _run(_spec(refractory_us=(300.0, 300.0)))

    def min_gap(e):
        order = np.lexsort((e["t"], e["y"].astype(np.int64) * 96 + e["x"]))
        pix = (e["y"].astype(np.int64) * 96 + e["x"])[order]
        same = pix[1:] == pix[:-1]
        return np.diff(e["t"][order])[same].min()

    assert min_gap(ev0) == 0                 # without it a pixel fires several events at a sample
    assert min_gap(ev) >= 300 and ev.shape[0] < 0.8 * ev0.shape[0]


def test_noise_rate_and_hot_pixels():
    spec = _spec(duration=0.05)
    base, _ = _run(spec)
    noisy, _ = _run(_spec(duration=0.05, noise_hz=(40.0, 40.0)))
    expect = 40.0 * 96 * 72 * (spec.n_samples - 1) * 50e-6     # 13.8 k
    assert noisy.shape[0] - base.shape[0] == pytest.approx(expect, abs=5 * np.sqrt(expect))
    hot, _ = _run(_spec(duration=0.05, hot_pixels=(1e-3, 1e-3)))
    assert hot.shape[0] > base.shape[0]
    # the extra events: round(1e-3 * 6912) = 7 pixels, ~50 events each at 1 kHz, one polarity each
    key = lambda e: set(zip(e["t"].tolist(), e["x"].tolist(), e["y"].tolist(), e["p"].tolist()))
    extra = np.array(sorted(key(hot) - key(base)))
    pix, counts = np.unique(extra[:, 1] * 1000 + extra[:, 2], return_counts=True)
    big = pix[counts >= 25]
    assert len(big) == 7
    for p in big:
        sel = extra[:, 1] * 1000 + extra[:, 2] == p
        assert len(set(extra[sel, 3])) == 1


@pytest.mark.parametrize("contrast, leading_on", [((1.0, 1.0), True), ((-1.0, -1.0), False)])
def test_dark_contrast_flips_leading_edge_polarity(contrast, leading_on):
    ev, gt = _run(_spec(object_contrast=contrast))
    from toffe_deploy.dataset.groundtruth import window_truth
    fr = []
    for t0 in range(2000, 18000, 2000):
        (tr,) = window_truth(gt, t0, 1000)
        w = window_slice(ev, t0, 1000)
        lead = (w["x"] - tr.x) * np.cos(tr.direction) + (w["y"] - tr.y) * np.sin(tr.direction) > 0
        fr.append(w["p"][lead].mean())
    assert (np.mean(fr) > 0.9) if leading_on else (np.mean(fr) < 0.1)


def test_size_px_is_the_apparent_diameter():
    """Across the motion, a circle's events span its diameter (plus the anti-aliased rim)."""
    from toffe_deploy.dataset.groundtruth import window_truth
    med = {}
    for size_px in (12.0, 24.0):
        spec = _spec(size_px=(size_px, size_px), name="trefoil_o000_cw_circle_b1")
        ev, gt = _run(spec)
        spans = []
        for t0 in range(2000, 18000, 4000):
            (tr,) = window_truth(gt, t0, 1000)
            w = window_slice(ev, t0, 1000)
            across = -(w["x"] - tr.x) * np.sin(tr.direction) + (w["y"] - tr.y) * np.cos(tr.direction)
            spans.append(across.max() - across.min() + 1)
        med[size_px] = np.median(spans)
        assert size_px <= med[size_px] <= size_px + 3.5
        assert appearance_summary(spec)["objects"][0]["size_px"] == pytest.approx(size_px, rel=0.01)
    assert med[24.0] - med[12.0] == pytest.approx(12.0, abs=1.5)


def test_focal_length_sets_the_metric_speed_not_the_image_speed():
    """Image-plane speeds are drawn per bin: a longer focal length means a slower object in m/s
    (at the same depth) for the same px/ms; focal_px replaces hfov."""
    wide = _spec(hfov_deg=(90.0, 90.0))
    tele = _spec(focal_px=(200.0, 200.0))
    assert tele.camera.f == pytest.approx(200.0) and wide.camera.f == pytest.approx(48.0)
    _, gw = _run(wide)
    _, gt_ = _run(tele)
    lo, hi = PROGRAMMED_PX_MS[2]
    for g, cam in ((gw, wide.camera), (gt_, tele.camera)):
        assert np.mean((g["speed_px_ms"] >= lo) & (g["speed_px_ms"] < hi)) > 0.9
        assert set(np.unique(g["speed_bin"])) <= {1, 2, 3}
        # metric speed ~ px/ms * 1000 * depth / f (depth swing and Z motion aside)
        ratio = g["speed"] / (g["speed_px_ms"] * 1000 * g["depth_m"] / cam.f)
        assert np.median(ratio) == pytest.approx(1.0, abs=0.1)
    # the same trajectory seen with two lenses: image speed scales with f
    traj = Trajectory("ellipse", 0.2, depth_amp_m=0.0)
    sp = []
    for cam in (PinholeCamera(96, 72, 40.0), PinholeCamera(96, 72, 80.0)):
        _, g, _ = generate_sequence(SequenceSpec("c", (ObjectSpec("circle", traj, size_m=0.2),), duration_s=0.002,
                                              camera=cam), 0)
        sp.append((g["speed_px_ms"].mean(), cam.f))
    assert sp[0][0] / sp[1][0] == pytest.approx(sp[0][1] / sp[1][1], rel=1e-6)


def test_ground_truth_speed_px_ms_and_depth():
    spec = _spec(depth_m=(3.0, 3.0))
    _, gt = _run(spec)
    t = gt["t"] * 1e-3
    fd = np.hypot(np.diff(gt["x"]), np.diff(gt["y"])) / np.diff(t)
    np.testing.assert_allclose(fd, (gt["speed_px_ms"][1:] + gt["speed_px_ms"][:-1]) / 2, rtol=2e-3)
    np.testing.assert_allclose(derive_speed_px_ms(gt)[1:-1], gt["speed_px_ms"][1:-1], rtol=2e-3)
    amp = spec.objects[0].trajectory.depth_amp_m
    assert np.all(np.abs(gt["depth_m"] - 3.0) <= amp + 1e-6) and amp > 0


def test_drawn_values_are_recorded_and_reproducible():
    a = split_specs("train", seed=4, duration_s=0.01, appearance="random")
    b = split_specs("train", seed=4, duration_s=0.01, appearance="random")
    c = split_specs("train", seed=5, duration_s=0.01, appearance="random")
    assert a == b and a != c
    keys = ("hfov_deg", "background", "texture", "threshold", "threshold_sigma", "refractory_us", "noise_hz",
            "hot_pixels")
    summ = [appearance_summary(s) for s in a]
    for s in summ:
        for k in keys:
            lo, hi = getattr(RANDOM, k)
            assert lo <= s[k] <= hi, k
        o = s["objects"][0]
        assert RANDOM.size_px[0] - 1e-6 <= o["size_px"] <= RANDOM.size_px[1] + 1e-6
        assert RANDOM.depth_m[0] <= o["depth_m"] <= RANDOM.depth_m[1]
        assert RANDOM.object_contrast[0] - 1e-3 <= abs(o["log_contrast"]) <= RANDOM.object_contrast[1] + 1e-3
    dark = np.mean([s["objects"][0]["polarity"] == "dark" for s in summ])
    assert 0.2 < dark < 0.4                               # dark_fraction 0.3
    assert np.std([s["hfov_deg"] for s in summ]) > 5      # actually drawn
    # image-plane speeds within the target bin's range at the drawn depth and focal length
    for s in a[::24]:
        _, gt = _run(dataclasses.replace(s, duration_s=0.005))
        lo, hi = PROGRAMMED_PX_MS[s.objects[0].target_bin]
        assert lo * 0.9 <= np.median(gt["speed_px_ms"]) <= hi * 1.1


def test_training_skips_the_held_out_region_and_the_appearance_split_draws_from_it():
    def looks(specs):
        out = []
        for s in specs:
            a = appearance_summary(s)
            out += [(o["events_per_edge"], o["size_px"], a["noise_hz"]) for o in a["objects"]]
        return out

    train = looks(split_specs("train", seed=0, duration_s=0.01, appearance="random"))
    held = looks(split_specs("appearance", seed=0, duration_s=0.01))
    assert not any(is_held_out(*x) for x in train)
    assert all(is_held_out(*x) for x in held)
    # every cell of every axis is seen by both: only combinations are held out
    for axis in range(3):
        assert {holdout_cell(*x)[axis] for x in train} == {0, 1, 2}
        assert {holdout_cell(*x)[axis] for x in held} == {0, 1, 2}


def test_pairs_spacing_is_recorded_and_true():
    specs = split_specs("pairs", seed=0, duration_s=0.01)
    assert len(specs) == 32
    spacings = []
    for s in specs[::3]:
        m = s.meta
        assert 3.0 <= m["spacing_radii"] <= 8.0 and len(s.objects) == 2
        assert s.objects[0].target_bin == s.objects[1].target_bin
        _, gt = _run(dataclasses.replace(s, duration_s=0.005))
        xy = np.stack([gt["x"], gt["y"]], 1).reshape(-1, 2, 2)
        d = np.hypot(*(xy[:, 0] - xy[:, 1]).T)
        np.testing.assert_allclose(d, m["spacing_px"], rtol=1e-3)
        r = appearance_summary(s)["objects"][0]["size_px"] / 2
        assert m["spacing_px"] / r == pytest.approx(m["spacing_radii"], rel=1e-3)
        assert gt["visible"].all()
        spacings.append(m["spacing_radii"])
    assert min(spacings) < 4.5 and max(spacings) > 6.5


def test_ranges_with_no_room_outside_the_held_out_region_are_an_error():
    # E = 0.3 / 0.1 = 3 (cell 1), size 20 (cell 0), noise 0 (cell 0): held out, and fixed
    fixed = AppearanceRanges(**{**SMALL, "object_contrast": (0.3, 0.3), "threshold": (0.1, 0.1),
                                "threshold_sigma": (0.0, 0.0), "size_px": (20.0, 20.0)})
    with pytest.raises(ValueError, match="held-out region"):
        split_specs("train", seed=0, appearance="random", ranges=fixed)
