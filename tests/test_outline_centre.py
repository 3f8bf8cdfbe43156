"""ofpd.outline_centre (issue 11): a slow object's position from its outline over the windows
before (toffe_deploy/outline_centre.py): the centre from one edge, the lag undone, the rules on
which objects qualify (slow, the ring holding K windows), a neighbour kept apart, the settings'
validation, and the streaming cpu Pipeline (and loihi-sim) against eval's reference."""
import dataclasses
import json
import math

import numpy as np
import pytest

from toffe_deploy import ofpd_io
from toffe_deploy.config import ToffeConfig
from toffe_deploy.events.binning import bin_window
from toffe_deploy.events.io import open_events
from toffe_deploy.events.support import sampled_window_history
from toffe_deploy.outline_centre import outline_positions, outline_settings
from toffe_deploy.time_surface import OnesHistory

SENSOR = (96, 64)
B, DT = 5, 500


def discs_ring(n_windows, speed_px_ms, centres, radius=10.0, k=20):
    """An OnesHistory of bright discs (start centres) moving right at speed_px_ms for
    n_windows, a pixel firing ON in the bin its centre enters a disc and OFF in the one it leaves;
    and each disc's leading-edge pixels (ON) of the last window as (x, y)."""
    w, h = SENSOR
    yy, xx = np.mgrid[0:h, 0:w]
    hist = OnesHistory(k, SENSOR, B, DT)
    before = None
    for wi in range(n_windows):
        ones, lead = [], [[] for _ in centres]
        for b in range(B):
            t = (wi * B + b + 1) * DT / B / 1000.0                 # ms
            inside = np.zeros((h, w), bool)
            per = []
            for cx, cy in centres:
                m = (xx - cx - speed_px_ms * t) ** 2 + (yy - cy) ** 2 <= radius ** 2
                per.append(m)
                inside |= m
            if before is not None:
                on, off = inside & ~before, before & ~inside
                for p, m in ((1, on), (0, off)):
                    ys, xs = np.nonzero(m)
                    ones.append(((b * 2 + p) * h + ys) * w + xs)
                for i, m in enumerate(per):
                    ys, xs = np.nonzero(on & m)
                    lead[i] += list(zip(xs.tolist(), ys.tolist()))
            before = inside
        hist.push(wi * DT, np.unique(np.concatenate(ones)).astype(np.int64))
    t_end = n_windows * DT / 1000.0
    return hist, lead, [(cx + speed_px_ms * t_end, cy) for cx, cy in centres]


def object_ones(leads):
    obj = np.concatenate([np.full(len(p), i) for i, p in enumerate(leads)]).astype(np.int64)
    xy = np.array([q for p in leads for q in p], np.int64)
    return obj, xy[:, 0], xy[:, 1]


def test_one_edge_gives_the_centre_with_its_lag_undone():
    """A slow disc (0.4 px/ms: 0.2 px a window) seen as its leading edge only: the edge's
    centroid lies ~6 px ahead of the centre; the outline over K = 20 windows puts it back within
    0.5 px, the lag (1.9 px) undone."""
    hist, lead, truth = discs_ring(25, 0.4, [(40.0, 32.0)])
    ones = object_ones(lead)
    edge_x = float(np.mean(ones[1]))
    assert edge_x - truth[0][0] > 4.0
    x, y = outline_positions((10.0, 4, 1.0, 0.0), hist, ones, [edge_x], [32.0], [0.4], [0.0], DT)
    assert abs(x[0] - truth[0][0]) < 0.5 and abs(y[0] - truth[0][1]) < 0.5
    # without the lag term the outline's centroid trails by about (K - 1) / 2 windows of motion
    x_lag, _ = outline_positions((10.0, 4, 1.0, 0.0), hist, ones, [edge_x], [32.0], [0.4], [math.pi], DT)
    assert truth[0][0] - x_lag[0] == pytest.approx(2 * 0.2 * 19 / 2, abs=0.6)


def test_only_slow_objects_with_their_windows_held_move():
    """A fast object (K = ceil(D / step) < k_min) and a stream's start (the ring holds fewer than
    K windows) keep the decoded position; so does an object without ones."""
    hist, lead, _truth = discs_ring(25, 0.4, [(40.0, 32.0)])
    ones = object_ones(lead)
    x, _ = outline_positions((10.0, 4, 1.0, 0.0), hist, ones, [70.0], [32.0], [8.0], [0.0], DT)   # K = 3 < 4
    assert x[0] == 70.0
    short, lead_s, _t = discs_ring(10, 0.4, [(40.0, 32.0)])                                   # 10 < K = 20
    x, _ = outline_positions((10.0, 4, 1.0, 0.0), short, object_ones(lead_s), [70.0], [32.0], [0.4], [0.0], DT)
    assert x[0] == 70.0
    x, _ = outline_positions((10.0, 4, 1.0, 0.0), hist, (np.zeros(0, np.int64),) * 3, [70.0], [32.0], [0.4], [0.0], DT)
    assert x[0] == 70.0


def test_a_closed_outline_keeps_the_decoded_position():
    """closed_frac: an object whose own pixels of this window lie all round their centroid (each
    quadrant >= the fraction of them) is an outline the OFPD saw whole, or two objects in one
    detection: it keeps the decoded position; one edge still moves."""
    hist, lead, truth = discs_ring(25, 0.4, [(40.0, 32.0)])
    yy, xx = np.mgrid[0:64, 0:96]
    ring = np.abs(np.hypot(xx - truth[0][0], yy - truth[0][1]) - 10.0) < 0.5
    ys, xs = np.nonzero(ring)
    whole = (np.zeros(xs.size, np.int64), xs.astype(np.int64), ys.astype(np.int64))
    x, _ = outline_positions((10.0, 4, 1.0, 0.1), hist, whole, [45.0], [32.0], [0.4], [0.0], DT)
    assert x[0] == 45.0
    x, _ = outline_positions((10.0, 4, 1.0, 0.0), hist, whole, [45.0], [32.0], [0.4], [0.0], DT)
    assert abs(x[0] - truth[0][0]) < 0.5
    ones = object_ones(lead)
    x, _ = outline_positions((10.0, 4, 1.0, 0.1), hist, ones, [45.0], [32.0], [0.4], [0.0], DT)
    assert abs(x[0] - truth[0][0]) < 0.5


@pytest.mark.parametrize("gap, off_px", [(30.0, 3.0), (40.0, None)])
def test_a_neighbour_does_not_pull(gap, off_px):
    """Two slow discs of radius 10 side by side, each seen as its leading edge: 3 radii apart
    with the decoded positions 3 px off their centres, or 4 radii apart with them on the leading
    edges (the worst a one-edge crop gives), each comes out at its own centre: a pixel nearer to
    the other object's decoded position is not counted. (3 radii apart with both on their
    leading edges, one is pulled ~4 px: the limit of the neighbour test.)"""
    hist, lead, truth = discs_ring(25, 0.4, [(20.0, 32.0), (20.0 + gap, 32.0)])
    ones = object_ones(lead)
    if off_px is None:
        xs0 = [float(np.mean(ones[1][ones[0] == i])) for i in range(2)]
    else:
        xs0 = [truth[0][0] + off_px, truth[1][0] - off_px]
    x, y = outline_positions((10.0, 4, 1.0, 0.0), hist, ones, xs0, [32.0, 32.0], [0.4, 0.4], [0.0, 0.0], DT)
    for i in range(2):
        assert abs(x[i] - truth[i][0]) < 0.5 and abs(y[i] - truth[i][1]) < 0.5
    alone, lead1, truth1 = discs_ring(25, 0.4, [(20.0, 32.0)])
    x1, _ = outline_positions((10.0, 4, 1.0, 0.0), alone, object_ones(lead1), xs0[:1], [32.0], [0.4], [0.0], DT)
    assert x1[0] == pytest.approx(x[0], abs=1e-9)


@pytest.mark.parametrize("bad", [[10, 4], [0, 4, 1.0], [10, 0, 1.0], [10, 4.5, 1.0], [10, 4, 0], [10, True, 1],
                                 ["a", 4, 1], [10, 4, float("nan")], 7, [10, 4, 1.0, 0.5],
                                 [10, 4, 1.0, -0.1], [10, 4, 1.0, 0.1, 0]])
def test_bad_settings_are_one_line_errors(bad, tmp_path):
    """outline_settings refuses nonsense and a missing ring; a config.json with it is refused
    on load as one line naming the file."""
    from toffe_deploy.errors import InputError

    with pytest.raises(ValueError, match="outline_centre must be"):
        outline_settings(ToffeConfig(ofpd={"plane_fit_history": [10, 20, 3], "outline_centre": bad}))
    with pytest.raises(ValueError, match="needs ofpd.plane_fit_history"):
        outline_settings(ToffeConfig(ofpd={"outline_centre": [10, 4, 1.0]}))
    assert outline_settings(ToffeConfig(ofpd={"plane_fit_history": [10, 20, 3]})) is None
    cfg = ToffeConfig(ofpd={"plane_fit_history": [10, 20, 3], "outline_centre": [10, 4, 1.0]})
    assert outline_settings(cfg) == (10.0, 4, 1.0, 0.0)
    cfg4 = ToffeConfig(ofpd={"plane_fit_history": [10, 20, 3], "outline_centre": [10, 4, 1.0, 0.1]})
    assert outline_settings(cfg4) == (10.0, 4, 1.0, 0.1)
    d = {**cfg.to_dict(), "ofpd": {"plane_fit_history": [10, 20, 3], "outline_centre": bad}}
    with pytest.raises((InputError, ValueError), match="config.json.*outline_centre|outline_centre must be"):
        ToffeConfig.from_dict(d, tmp_path / "config.json")


OUTLINE_OFPD = {"crop_px": 32, "pool": 2, **ofpd_io.CURRENT_LAYOUT, "min_events": 8, "plane_fit_weight": 1.0,
                "plane_fit_min_px_ms": 0.0, "plane_fit_dir_weight": 1.0, "plane_fit_history": [8, 6, 2],
                "outline_centre": [8, 1, 1.0]}        # k_min 1: every object the tiny recording holds


@pytest.fixture(scope="module")
def bundle_rec(tmp_path_factory, make_bundle, make_recording):
    root = tmp_path_factory.mktemp("outline")
    sensor = (64, 48)
    return (make_bundle(root / "on", sensor=sensor, ofpd=OUTLINE_OFPD, input_min_cluster=4, input_support=(3, 1, 3, 1)),
            make_recording(root / "rec.h5", sensor=sensor, duration=0.008))


def _windows(rec, cfg):
    with open_events(rec) as src:
        return [(t0, bin_window(ev, t0, cfg.dt_us, cfg.n_bins, cfg.sensor_size))
                for t0, ev in src.iter_windows(cfg.dt_us)]


def test_cpu_pipeline_equals_reference_and_the_key_moves_objects(bundle_rec):
    """The streaming cpu Pipeline == eval's reference (predict_window) with the key on, to the
    bit; and the key is read (positions differ from the same bundle without it)."""
    from toffe_deploy.deploy.onnx_export import ort_session, run_onnx
    from toffe_deploy.model.reference import fixed_stage_fn, predict_window
    from toffe_deploy.runtime.pipeline import Pipeline

    b, rec = bundle_rec
    cfg = b.config
    off = dataclasses.replace(cfg, ofpd={k: v for k, v in cfg.ofpd.items() if k != "outline_centre"})
    sess, run = ort_session(b.ofpd_onnx), fixed_stage_fn(b.ofs)
    wins = _windows(rec, cfg)
    with Pipeline(b, "cpu", track=False) as pipe:
        got = list(pipe.process_stream(wins))
    ours, ref, plain = [], [], []
    with open_events(rec) as src:
        for (t0, _x), res in zip(wins, got):
            binned, recent, history = sampled_window_history(src.read, t0, cfg.dt_us, cfg, cfg.sensor_size,
                                                             src.t_start_us)
            for out, c in ((ref, cfg), (plain, off)):
                out.append([(p.stage, p.x, p.y) for p in
                            predict_window(binned, run, lambda x: run_onnx(sess, x), c, recent, history)[0]])
            ours.append([(o.speed_bin, o.x, o.y) for o in res.objects])
    assert ours == ref
    assert sum(map(len, ours)) > 0 and ours != plain


def test_cpu_equals_loihi_sim_with_outline(bundle_rec, lines_per_target):
    pytest.importorskip("lava")
    b, rec = bundle_rec
    out = lines_per_target(b, _windows(rec, b.config)[:9])
    assert out["cpu"] == out["loihi-sim"]
    assert any(json.loads(s)["objects"] for s in out["cpu"])
