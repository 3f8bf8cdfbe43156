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


def faint_events(n=40, seed=5):
    """Per window, the events of a faint slow square in 34 Hz noise (window_pixels), spread over
    the window with random polarities."""
    from toffe_deploy.events.core import EVENT_DTYPE

    rng = np.random.default_rng(seed)
    out = []
    for w in range(n):
        pix = window_pixels(rng, w)
        ev = np.zeros(pix.size, dtype=EVENT_DTYPE)
        ev["x"], ev["y"], ev["p"] = pix % SENSOR[0], pix // SENSOR[0], rng.integers(0, 2, pix.size)
        ev["t"] = w * DT + rng.integers(0, DT, pix.size)
        out.append(ev[np.argsort(ev["t"], kind="stable")])
    return out


def faint_windows(n_bins, n=40, seed=5):
    """(t0, SpikeVolume) windows of faint_events."""
    from toffe_deploy.runtime.spikes import SpikeVolume

    return [(w * DT, SpikeVolume.from_events(ev, w * DT, DT, n_bins, SENSOR))
            for w, ev in enumerate(faint_events(n, seed))]


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


def edges_pixels(rng, w, *, cx=80, cy=60, half=24, edge_p=0.5, noise_p=0.017):
    """One window of a big slow square moving sideways (< 0.1 px a window): only its two edges
    across the motion fire (2 px wide each), 2 half apart; noise as window_pixels'."""
    w_, h_ = SENSOR
    ys = np.arange(cy - half, cy + half + 1)
    xs = np.concatenate([np.full(ys.size, cx + d) for d in (-half, 1 - half, half - 1, half)])
    ys = np.tile(ys, 4)
    keep = rng.random(xs.size) < edge_p
    pix = np.concatenate([np.flatnonzero(rng.random(w_ * h_) < noise_p), ys[keep] * w_ + xs[keep]])
    return np.unique(pix).astype(np.int64)


def test_a_big_object_reported_from_one_edge_is_not_reported_again_from_the_other():
    """A 48 px square whose two edges are regions of their own, reported by the cascade at its
    centre from its left edge's ones in some windows only: in the windows between, the rule does not
    report it again at an edge (a second track 24 px off its centre); without the reports it
    does. A small object reported a window before is still reported (the cascade's misses)."""
    left = (np.zeros(49, np.int64), np.full(49, 56), np.arange(36, 85))          # its left edge's ones
    found = {}
    for reported in (False, True):
        rng = np.random.default_rng(7)
        dens = FaintDensity(SETTINGS, SENSOR, DT)
        xs = []
        for w in range(40):
            rep = reported and w % 3 == 0
            fx = dens.step(w * DT, edges_pixels(rng, w), left if rep else NOTHING, [1] if rep else [],
                           [80.0] if rep else [], [60.0] if rep else [])   # the OFPD's position: its centre
            if w >= 25 and not rep:
                xs.extend(fx[0].tolist())
        found[reported] = xs
    assert len(found[False]) >= 8 and all(abs(abs(x - 80) - 24) < 8 for x in found[False])   # at an edge
    assert found[True] == []
    rng = np.random.default_rng(8)
    dens = FaintDensity(SETTINGS, SENSOR, DT)
    small = (np.zeros(4, np.int64), np.array([72, 88, 80, 80]), np.array([60, 60, 52, 68]))   # 16 px: a small box
    hits = 0
    for w in range(40):
        rep = w % 2 == 0
        fx = dens.step(w * DT, window_pixels(rng, w, half=8, edge_p=0.6), small if rep else NOTHING,
                       [1] if rep else [], [80.0] if rep else [], [60.0] if rep else [])
        hits += int(w >= 25 and not rep and fx[0].size > 0)
    assert hits >= 5                                  # of the 7 windows between reports


def test_evals_reference_reports_the_pipelines_faint_objects(tmp_path, make_bundle):
    """eval's tracking pass (model.reference.predict_window over a stream's windows, a
    FaintDensity per sequence) reports the cpu Pipeline's faint objects, to the bit, position
    only."""
    from toffe_deploy.deploy.onnx_export import ort_session, run_onnx
    from toffe_deploy.events.fmt_toffe import write_events_h5
    from toffe_deploy.events.io import open_events
    from toffe_deploy.events.support import WindowHistories
    from toffe_deploy.model.reference import fixed_stage_fn, predict_window
    from toffe_deploy.runtime.pipeline import Pipeline

    bundle = faint_bundle(make_bundle, tmp_path)
    cfg = bundle.config
    events = faint_events(n=32)
    rec = tmp_path / "faint.h5"
    write_events_h5(rec, np.concatenate(events), SENSOR, t_range=(0, 32 * DT))
    with Pipeline(bundle, "cpu", sensor_size=SENSOR, track=False) as pipe:
        got = [[(o.x, o.y, o.direction_rad) for o in r.objects if o.faint]
               for r in pipe.process_stream(faint_windows(cfg.n_bins, n=32))]
    sess, run = ort_session(bundle.ofpd_onnx), fixed_stage_fn(bundle.ofs)
    density = FaintDensity(faint_settings(cfg), SENSOR, DT)
    ref = []
    with open_events(rec) as src:
        stream = WindowHistories(src.read, DT, cfg, SENSOR, src.t_start_us)
        for w in range(32):
            binned, recent, history = stream(w * DT)
            preds = predict_window(binned, run, lambda x: run_onnx(sess, x), cfg, recent, history, (density, w * DT))[0]
            assert all(not p.measured and p.stage == 1 for p in preds)
            ref.append([(p.x, p.y, p.direction_rad) for p in preds])
    assert got == ref and sum(map(len, got)) >= 5
