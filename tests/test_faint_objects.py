"""ofpd.faint_objects (issue 11): a slow object at the sensor's threshold in noise is found from
the event density of the last L windows; noise, hot pixels, reported objects and fast objects'
trails are not; the key's validation; the tracker takes a faint object's position only; scoring
leaves its direction out; the Pipeline reports it on a real recording and its line validates."""
import dataclasses
import json
import math

import numpy as np
import pytest

from toffe_deploy import ofpd_io
from toffe_deploy.config import ToffeConfig
from toffe_deploy.faint_objects import FaintDensity, FaintSettings, faint_settings
from toffe_deploy.fixed_point import VTH_MANT_MAX
from toffe_deploy.metrics import FlowErrors, Prediction
from toffe_deploy.tracking import Detections, Tracker, raw_detections

SENSOR = (160, 120)
DT = 500
SETTINGS = FaintSettings(20, 7.0)
NOTHING = (np.zeros(0, np.int64),) * 3


def window_pixels(rng, w, *, noise_p=0.017, obj=(80.0, 60.0), half=14, edge_p=0.35, speed_px=0.125, hot=()):
    """One window's unique event pixels: noise firing with probability noise_p per pixel, the
    outline of a square (side 2 half) moving right at speed_px per window whose edge pixels fire
    with probability edge_p (a sensor at its threshold), and hot pixels firing every window."""
    w_, h_ = SENSOR
    pix = [np.flatnonzero(rng.random(w_ * h_) < noise_p)]
    if obj is not None:
        cx, cy = obj[0] + speed_px * w, obj[1]
        xs = np.arange(int(cx - half), int(cx + half) + 1)
        ys = np.arange(int(cy - half), int(cy + half) + 1)
        ring = np.concatenate([np.stack([xs, np.full_like(xs, ys[0])], 1), np.stack([xs, np.full_like(xs, ys[-1])], 1),
                               np.stack([np.full_like(ys, xs[0]), ys], 1), np.stack([np.full_like(ys, xs[-1]), ys], 1)])
        ring = ring[rng.random(len(ring)) < edge_p]
        pix.append(ring[:, 1] * w_ + ring[:, 0])
    pix.append(np.asarray(hot, np.int64))
    return np.unique(np.concatenate(pix)).astype(np.int64)


def run(density, rng, n=40, reported=None, bins=(), **kw):
    """Step ``n`` windows; -> the faint objects of each window (x, y arrays)."""
    out = []
    for w in range(n):
        ones, xs, ys = NOTHING, [], []
        if reported is not None:
            ones, xs, ys = reported(w)
        fx = density.step(w * DT, window_pixels(rng, w, **kw), ones, list(bins), xs, ys)
        out.append((fx[0], fx[1]))
    return out


def test_a_slow_object_at_threshold_in_noise_is_found_where_it_is():
    rng = np.random.default_rng(0)
    found = run(FaintDensity(SETTINGS, SENSOR, DT), rng)
    assert all(x.size == 0 for x, _ in found[:SETTINGS.min_windows - 1])      # needs its windows first
    late = found[25:]
    hits = [(x[0], y[0]) for x, y in late if x.size]
    assert len(hits) >= 0.9 * len(late) and all(x.size <= 1 for x, _ in late)
    for w, (x, y) in zip(range(25, 40), late):
        if x.size:
            assert math.hypot(x[0] - (80 + 0.125 * w), y[0] - 60) < 10


def test_noise_alone_and_hot_pixels_give_nothing():
    rng = np.random.default_rng(1)
    hot = rng.choice(SENSOR[0] * SENSOR[1], 12, replace=False)
    for noise_p in (0.017, 0.0002):                     # 34 Hz and 0.4 Hz per pixel at 500 us
        found = run(FaintDensity(SETTINGS, SENSOR, DT), rng, n=60, obj=None, noise_p=noise_p, hot=hot)
        assert sum(x.size for x, _ in found) == 0


def test_a_reported_object_is_not_reported_again_and_a_fast_ones_trail_is_not_an_object():
    rng = np.random.default_rng(2)

    def at_object(w):                                   # the OFS path reported the object, its ones on the outline
        xs = np.array([66, 94, 80, 80]) + int(0.125 * w)
        ys = np.array([60, 60, 46, 74])
        return (np.zeros(4, np.int64), xs, ys), [80 + 0.125 * w], [60.0]

    found = run(FaintDensity(SETTINGS, SENSOR, DT), rng, reported=at_object, bins=[1])
    assert sum(x.size for x, _ in found) == 0

    def passed_by(w):                                   # a fast object (bin 3) crossed the square's place before
        if w < 15:
            xs = np.arange(40, 120, 2)
            return (np.zeros(xs.size, np.int64), xs, np.full(xs.size, 60)), [80.0], [60.0]
        return NOTHING, [], []

    dens = FaintDensity(SETTINGS, SENSOR, DT)
    found = run(dens, rng, reported=passed_by, bins=[3], speed_px=0.0)
    assert sum(x.size for x, _ in found[20:34]) == 0     # its trail's cells stay excluded for L windows
    assert sum(x.size for x, _ in found[36:]) >= 3       # then the slow one beneath is found


def test_a_gap_shifts_in_empty_windows_and_a_jump_back_starts_afresh():
    rng = np.random.default_rng(3)
    dens = FaintDensity(SETTINGS, SENSOR, DT)
    run(dens, rng, n=25)
    dens.step(30 * DT, window_pixels(rng, 30), NOTHING, [], [], [])     # 4 empty windows shifted in
    assert len(dens._ring) == SETTINGS.windows
    dens.step(0, window_pixels(rng, 0), NOTHING, [], [], [])            # back in time: afresh
    assert len(dens._ring) == 1 and dens.tot_l == int(np.sum(np.minimum(dens._cnt[:, 0], 3)))


def test_key_validation_and_default():
    support = (4, 2, 5, 2)
    layout = {**ofpd_io.CURRENT_LAYOUT}
    assert faint_settings(ToffeConfig()) is None
    cfg = ToffeConfig(input_support=support, ofpd={**layout, "faint_objects": [20, 7]})
    assert faint_settings(cfg) == FaintSettings(20, 7.0)
    for bad in ([20], [3, 7], [20, 0], [20, -1], [20.5, 7], "20,7", [True, 7], [20, math.nan], [256, 7]):
        with pytest.raises(ValueError, match="faint_objects must be"):
            ofpd_io.ofpd_settings(ToffeConfig(input_support=support, ofpd={**layout, "faint_objects": bad}))
    with pytest.raises(ValueError, match="input_support"):
        ofpd_io.ofpd_settings(ToffeConfig(ofpd={**layout, "faint_objects": [20, 7]}))


@dataclasses.dataclass
class Obj:
    x: float
    y: float
    direction_rad: float
    speed_px_s: float
    speed_bin: int = 1
    faint: bool = False
    track_id: int | None = None
    track: dict | None = None


def test_the_tracker_takes_a_faint_objects_position_only():
    """A confirmed track moving right at 2,000 px/s keeps its motion through faint detections
    whose direction (a guess) points up; a plain detection with that direction turns it."""
    z = Detections(np.array([[1.0, 2.0, 0.0, 0.0, 0.0, 1.0]]))
    assert z.a.shape == (1, 8) and z.a[0, 7] == 0.0
    assert np.isnan(raw_detections([Obj(1, 2, 0.5, 100.0, faint=True)])[2])
    turned = {}
    for faint in (True, False):
        tr = Tracker(ToffeConfig(), DT)
        for w in range(16):
            x = 50 + 2000 * (w + 0.5) * DT * 1e-6
            o = Obj(x, 100, 0.0, 2000.0) if w < 10 else Obj(x, 100, -math.pi / 2, 1186.0, faint=faint)
            tr.update([o], w * DT)
        turned[faint] = abs(o.track["direction_deg"])
        assert abs(o.track["x"] - x) < 3                      # the position follows either way
    assert turned[True] < 2.0 and turned[False] > 20.0


def test_scoring_leaves_a_faint_objects_direction_and_speed_out_but_counts_it():
    truth = [dataclasses.make_dataclass("T", ["x", "y", "direction", "speed", "speed_bin"])(10.0, 10.0, 0.0, 5.0, 1),
             dataclasses.make_dataclass("T", ["x", "y", "direction", "speed", "speed_bin"])(100.0, 10.0, 0.0, 5.0, 1)]
    fe = FlowErrors()
    fe.add_window([Prediction(1, 11.0, 10.0, 0.1, 5.0, 9.5),
                   Prediction(1, 101.0, 10.0, math.pi, 9.5, 9.5, measured=False)], truth)
    s = fe.summary()
    assert s["recall"] == 1.0 and s["n_position_only"] == 1 and s["pixE"] == pytest.approx(1.0)
    assert s["dirE"] == pytest.approx(math.degrees(0.1))       # the faint one's 180 deg left out


def faint_bundle(make_bundle, root):
    """A real tiny bundle with the rule on whose untrained OFS sits at the highest threshold: no
    stage fires, as a trained one on so faint a square."""
    layout = {**ofpd_io.CURRENT_LAYOUT, "crop_px": 32, "pool": 2, "min_events": 4}
    bundle = make_bundle(root, sensor=SENSOR, ofpd={**layout, "faint_objects": [20, 7]}, input_support=(4, 2, 5, 2))
    return dataclasses.replace(bundle, ofs=[dataclasses.replace(p, vth_mant=VTH_MANT_MAX) for p in bundle.ofs])


def faint_windows(n_bins, n=40, seed=5):
    """(t0, SpikeVolume) windows of a faint slow square in 34 Hz noise (window_pixels), events
    spread over each window with random polarities."""
    from toffe_deploy.runtime.spikes import SpikeVolume

    rng = np.random.default_rng(seed)
    out = []
    for w in range(n):
        pix = window_pixels(rng, w)
        ev = np.zeros(pix.size, dtype=[("x", "<u2"), ("y", "<u2"), ("t", "<i8"), ("p", "u1")])
        ev["x"], ev["y"], ev["p"] = pix % SENSOR[0], pix // SENSOR[0], rng.integers(0, 2, pix.size)
        ev["t"] = w * DT + rng.integers(0, DT, pix.size)
        ev = ev[np.argsort(ev["t"], kind="stable")]
        out.append((w * DT, SpikeVolume.from_events(ev, w * DT, DT, n_bins, SENSOR)))
    return out


def test_pipeline_reports_a_faint_object_and_its_line_validates(tmp_path, make_bundle):
    """The cpu Pipeline (tracker on) on windows of a faint slow square in 34 Hz noise, with and
    without the rule: only with it is the square reported, ``faint``, in bin 1, and every line
    validates against the shipped JSON Schema."""
    import jsonschema

    from toffe_deploy.runtime.pipeline import Pipeline
    from toffe_deploy.schema import load_schema

    bundle = faint_bundle(make_bundle, tmp_path)
    windows = faint_windows(bundle.config.n_bins)
    v = jsonschema.Draft202012Validator(load_schema())
    found = {}
    for on in (False, True):
        cfg = dataclasses.replace(bundle.config, ofpd={**bundle.config.ofpd, "faint_objects": [20, 7] if on else None})
        with Pipeline(dataclasses.replace(bundle, config=cfg), "cpu", sensor_size=SENSOR, track=True) as pipe:
            res = list(pipe.process_stream(windows))
        found[on] = [(w, o) for w, r in enumerate(res) for o in r.objects if o.faint]
        for r in res:
            v.validate(json.loads(json.dumps(r.to_json())))
    assert not found[False]
    late = [o for w, o in found[True] if w >= 25]
    assert len(late) >= 10
    assert all(math.hypot(o.x - 80 - 0.125 * w, o.y - 60) < 12 and o.speed_bin == 1 for w, o in found[True])
    assert all(o.to_json()["faint"] is True for _w, o in found[True])


def test_loihi_sim_reports_the_same_faint_objects_as_cpu(tmp_path, make_bundle, lines_per_target):
    """The real Lava runtime (loihi-sim pipelines its windows: each window's event pixels travel
    with it to the host's rule) gives the cpu target's lines, faint objects included."""
    bundle = faint_bundle(make_bundle, tmp_path)
    lines = lines_per_target(bundle, faint_windows(bundle.config.n_bins, n=24))
    assert lines["cpu"] == lines["loihi-sim"]
    assert sum('"faint": true' in ln for ln in lines["cpu"]) >= 5
