"""The plane-fit velocity of an object's time surface and its fusion with the OFPD speed
(toffe_deploy/plane_fit.py)."""
import math

import numpy as np
import pytest

from toffe_deploy.config import ToffeConfig
from toffe_deploy.plane_fit import dense_flow, flow_px_ms, fuse_speed, object_planes_flow

B = 5


def moving_disc_ones(vx, vy, radius=9.0, size=64, polarity_of_leading=1):
    """Ones (x, y, ch = 2 b + p) of a disc translating at (vx, vy) px per bin: each pixel's first
    spike is the bin in which the disc's edge reaches it (leading edge: polarity 1, trailing: 0)."""
    yy, xx = np.mgrid[0:size, 0:size].astype(float)
    c0 = np.array([size / 2 - 2 * vx, size / 2 - 2 * vy])
    inside = []
    for b in range(B + 1):
        c = c0 + b * np.array([vx, vy])
        inside.append((xx - c[0]) ** 2 + (yy - c[1]) ** 2 <= radius ** 2)
    xs, ys, ch = [], [], []
    for b in range(B):
        for p, fired in ((polarity_of_leading, inside[b + 1] & ~inside[b]), (1 - polarity_of_leading, inside[b] & ~inside[b + 1])):
            y, x = np.nonzero(fired)
            xs.append(x), ys.append(y), ch.append(np.full(x.size, 2 * b + p))
    return (np.concatenate(xs).astype(np.int64), np.concatenate(ys).astype(np.int64),
            np.concatenate(ch).astype(np.int64))


def flow_of(xs, ys, ch):
    return object_planes_flow(np.zeros(xs.size, np.int64), xs, ys, ch, 1, np.ones(1, bool))[0]


@pytest.mark.parametrize("angle_deg", [0, 30, 90, 135, 200, 315])
@pytest.mark.parametrize("speed", [1.0, 2.0])
def test_translating_disc_velocity_recovered(angle_deg, speed):
    a = math.radians(angle_deg)
    v = flow_of(*moving_disc_ones(speed * math.cos(a), speed * math.sin(a)))
    assert np.all(np.isfinite(v))
    assert abs(math.hypot(*v) - speed) < 0.25 * speed
    err = abs((math.degrees(math.atan2(v[1], v[0])) - angle_deg + 180) % 360 - 180)
    assert err < 10


def test_dark_object_same_velocity():
    """Polarity swapped (a dark object): the time surface, hence the velocity, is the same."""
    a = flow_of(*moving_disc_ones(1.5, -0.5, polarity_of_leading=1))
    b = flow_of(*moving_disc_ones(1.5, -0.5, polarity_of_leading=0))
    assert np.allclose(a, b, rtol=1e-12, atol=0)     # the planes summed in another order: last bits only


def sorted_ones(xs, ys, ch):
    """The order every path hands the ones over in: bin, polarity, y, x (np.nonzero's)."""
    order = np.lexsort((xs, ys, ch))
    return xs[order], ys[order], ch[order]


def test_order_of_ones_changes_the_result_little(rng):
    """Another order sums the planes in another order and takes the IRLS scale from other
    residuals (every k-th of them): within 1 %, and the same bits for the same order."""
    xs, ys, ch = sorted_ones(*moving_disc_ones(1.3, 0.7))
    ref = flow_of(xs, ys, ch)
    assert flow_of(xs.copy(), ys.copy(), ch.copy()).tobytes() == ref.tobytes()
    perm = rng.permutation(xs.size)
    assert np.allclose(flow_of(xs[perm], ys[perm], ch[perm]), ref, rtol=1e-2, atol=0)


def test_several_objects_in_one_call_equal_one_by_one():
    parts = [sorted_ones(*moving_disc_ones(1.0, 0.0)), sorted_ones(*moving_disc_ones(0.0, 2.0)),
             sorted_ones(*moving_disc_ones(-1.5, 1.5))]
    obj = np.concatenate([np.full(p[0].size, j) for j, p in enumerate(parts)]).astype(np.int64)
    xs, ys, ch = (np.concatenate([p[i] for p in parts]) for i in range(3))
    order = np.lexsort((xs, ys, ch))                 # objects interleaved, each one's ones still in order
    got = object_planes_flow(obj[order], xs[order], ys[order], ch[order], 3, np.ones(3, bool))
    for j, p in enumerate(parts):
        assert got[j].tobytes() == flow_of(*p).tobytes()
    some = object_planes_flow(obj, xs, ys, ch, 3, np.array([False, True, False]))    # the runtime's fast ones only
    assert np.isnan(some[[0, 2]]).all() and some[1].tobytes() == got[1].tobytes()


def test_too_few_ones_or_a_line_gives_nan():
    assert np.isnan(flow_of(np.array([3, 4], np.int64), np.array([3, 3], np.int64), np.array([0, 2], np.int64))).all()
    xs = np.arange(10, 30, dtype=np.int64)                  # one straight line of pixels: no plane
    assert np.isnan(flow_of(xs, np.full(20, 5, np.int64), (xs % B) * 2)).all()
    assert object_planes_flow(np.zeros(0, np.int64), *(np.zeros(0, np.int64),) * 3, 2, np.ones(2, bool)).shape == (2, 2)


def test_dense_flow_equals_flat():
    xs, ys, ch = sorted_ones(*moving_disc_ones(2.0, 1.0))
    frame = np.zeros((1, B, 2, 64, 64), np.uint8)
    frame[0, ch >> 1, ch & 1, ys, xs] = 1
    assert dense_flow(frame)[0].tobytes() == flow_of(xs, ys, ch).tobytes()


def test_fuse_speed_rules():
    cfg = ToffeConfig(sensor_size=(64, 48), dt_us=500, ofpd={"plane_fit_weight": 0.5, "plane_fit_min_px_ms": 4.0})
    flow = np.array([[0.8, 0.6], [0.8, 0.6], [np.nan, np.nan]])     # 1 px per bin = 10 px/ms at dt 500, B 5
    assert np.allclose(flow_px_ms(flow[:1], cfg), 10.0)
    s = np.log([6.0, 2.0, 6.0])
    out = fuse_speed(s, flow, cfg)
    assert math.isclose(math.exp(out[0]), math.sqrt(6.0 * 10.0))   # above the threshold: geometric blend
    assert out[1] == s[1] and out[2] == s[2]                         # below it, or no plane fit: the OFPD's
    off = ToffeConfig(sensor_size=(64, 48), ofpd={})
    assert np.array_equal(fuse_speed(s, flow, off), s)              # older checkpoints: off
    with pytest.raises(ValueError, match="plane_fit_weight"):
        fuse_speed(s, flow, ToffeConfig(sensor_size=(64, 48), ofpd={"plane_fit_weight": 1.5}))


def test_selection_median_equals_numpy(rng):
    from toffe_deploy.plane_fit import _median

    for n in (1, 2, 3, 10, 64, 65):
        for a in (rng.random(n), np.round(rng.random(n) * 4) / 4):        # ties too
            assert _median(a.copy(), n) == np.median(a)


@pytest.mark.parametrize("bad", [{"plane_fit_weight": "x"}, {"plane_fit_weight": -0.1}, {"plane_fit_min_px_ms": -1},
                                 {"plane_fit_dir_weight": 2},
                                 {"split_frac": "wide"}])
def test_bad_plane_fit_settings_are_one_line_errors(tmp_path, bad):
    import dataclasses
    import json

    from toffe_deploy.config import load_config
    from toffe_deploy.errors import InputError

    d = dataclasses.asdict(ToffeConfig(sensor_size=(64, 48)))
    d["ofpd"] = {**(d.get("ofpd") or {}), **bad}
    path = tmp_path / "config.json"
    path.write_text(json.dumps(d))
    with pytest.raises(InputError, match="config.json"):
        load_config(path)


def test_fuse_direction_blends_unit_vectors():
    from toffe_deploy.plane_fit import PlaneFusion, fuse_direction

    cfg = ToffeConfig(sensor_size=(64, 48), ofpd={"plane_fit_dir_weight": 0.5})
    d = np.array([[2.0, 0.0], [0.0, 3.0], [1.0, 0.0]])            # the OFPD's (cos, sin), any length
    flow = np.array([[0.0, 0.5], [0.0, 0.7], [np.nan, np.nan]])   # plane fit: straight down, down, none
    out = fuse_direction(d, flow, cfg)
    assert math.isclose(math.degrees(math.atan2(out[0, 1], out[0, 0])), 45.0)   # halfway, by unit vectors
    assert math.isclose(math.degrees(math.atan2(out[1, 1], out[1, 0])), 90.0)
    assert np.array_equal(out[2], d[2])                            # no plane fit: the OFPD's
    fusion = PlaneFusion(cfg)
    assert fusion.on and fusion.wanted(np.log([0.5, 9.0])).all()   # direction blending wants every object
    off = PlaneFusion(ToffeConfig(sensor_size=(64, 48), ofpd={"plane_fit_weight": 0.7}))
    assert off.wanted(np.log([0.5, 9.0])).tolist() == [False, True] and np.array_equal(off.direction(d, flow), d)
