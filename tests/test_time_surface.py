"""ofpd.plane_fit_history (issue 11): the plane fit over each object's time surface of its last K
windows (toffe_deploy/time_surface.py): a slow edge's velocity that one window cannot give, the
ring's window rules, the settings' validation, the fusion at a stream's start, and the streaming
cpu Pipeline (and loihi-sim, and the export's parity) against eval's reference."""
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
from toffe_deploy.plane_fit import PlaneFusion, dense_flow, history_settings, refit_history, refit_settings
from toffe_deploy.time_surface import OnesHistory, history_flow, history_windows

SENSOR = (64, 48)
B, DT = 5, 500


def disc_windows(n_windows, speed_px_ms, angle_deg, radius=7.0, start=(32.0, 24.0)):
    """(t0, sorted linear ones (B, 2, H, W)) of a bright disc translating at speed_px_ms: a
    pixel fires ON in the bin its centre enters the disc, OFF in the bin it leaves."""
    w, h = SENSOR
    yy, xx = np.mgrid[0:h, 0:w]
    a = math.radians(angle_deg)
    v = np.array([math.cos(a), math.sin(a)]) * speed_px_ms / 1000.0        # px per us
    inside_before = None
    out = []
    for wi in range(n_windows):
        ones = []
        for b in range(B):
            t = (wi * B + b + 1) * DT / B
            cx, cy = start[0] + v[0] * t, start[1] + v[1] * t
            inside = (xx - cx) ** 2 + (yy - cy) ** 2 <= radius ** 2
            if inside_before is not None:
                for p, m in ((1, inside & ~inside_before), (0, inside_before & ~inside)):
                    ys, xs = np.nonzero(m)
                    ones.append(((b * 2 + p) * h + ys) * w + xs)
            inside_before = inside
        out.append((wi * DT, np.sort(np.concatenate(ones)).astype(np.int64)))
    return out


def box_ones(idx):
    """(object 0, x, y) of a window's ones: the object's box comes from them."""
    w, h = SENSOR
    pix = idx % (w * h)
    return np.zeros(pix.size, np.int64), pix % w, pix // w


@pytest.mark.parametrize("angle", [0, 60, 135, 250])
def test_slow_edge_velocity_from_the_windows_before(angle):
    """A disc at 1 px/ms moves 0.5 px per window: over 12 windows the fit recovers its velocity
    within 5 deg and 10 %; over its last window alone it cannot (no answer, or far off)."""
    wins = disc_windows(12, 1.0, angle)
    hist = OnesHistory(12, SENSOR, B, DT)
    for t0, idx in wins:
        hist.push(t0, idx)
    ones = box_ones(wins[-1][1])
    f = history_flow(hist, ones, 1, [True], [12], 3)[0] * B * 1000 / DT              # px/ms
    err = abs((math.degrees(math.atan2(f[1], f[0])) - angle + 180) % 360 - 180)
    assert err < 5 and abs(math.hypot(*f) - 1.0) < 0.1, (f, err)
    one = history_flow(hist, ones, 1, [True], [1], 3)[0] * B * 1000 / DT
    assert not np.isfinite(one).all() or abs(math.hypot(*one) - 1.0) > 0.5


def test_one_window_equals_the_one_window_plane_fit():
    """K = 1 over a box holding the whole object is plane_fit's one-window fit: the same surface
    (first bin per pixel and polarity) and planes, visited row by row instead of bin by bin, so
    the IRLS sums and its median sample differ in order only."""
    w, h = SENSOR
    t0, idx = disc_windows(3, 12.0, 30)[-1]
    hist = OnesHistory(4, SENSOR, B, DT)
    hist.push(t0, idx)
    dense = np.zeros(B * 2 * h * w, np.uint8)
    dense[idx] = 1
    ref = dense_flow(dense.reshape(1, B, 2, h, w))
    got = history_flow(hist, box_ones(idx), 1, [True], [1], 0)
    assert np.isfinite(ref).all() and np.allclose(got, ref, rtol=1e-4, atol=0)


def test_window_rules():
    """The next window keeps the ring, a gap of whole windows leaves empty ones between (they
    count as windows), a jump back or a gap that is no multiple of dt forgets it."""
    wins = disc_windows(4, 2.0, 0)
    hist = OnesHistory(6, SENSOR, B, DT)
    hist.push(0, wins[0][1])
    hist.push(DT, wins[1][1])
    assert hist.available == 2
    hist.push(4 * DT, wins[2][1])                      # windows 2 and 3 skipped: no events there
    assert hist.available == 5 and hist.now == 4
    hist.push(4 * DT + 7, wins[3][1])                  # not on the grid: forgotten
    assert hist.available == 1
    hist.push(0, wins[0][1])                           # back in time: forgotten
    assert hist.available == 1
    hist.reset()
    assert hist.available == 0


def test_history_windows_follow_the_speed():
    """K = ceil(D / (s dt)) in 1..K_max; K_max where the speed is 0 or not finite."""
    assert history_windows([0.5, 2.0, 16.0, 100.0, 0.0, float("nan")], 8.0, 20, 500) == [20, 8, 1, 1, 20, 20]


@pytest.mark.parametrize("bad", [[8, 20], [0, 20, 3], [8, 0, 3], [8, 20, -1], [8, 2.5, 3], "8,20,3", [8, True, 3],
                                 [float("nan"), 20, 3]])
def test_bad_history_settings_are_one_line_errors(bad):
    with pytest.raises(ValueError, match="plane_fit_history must be"):
        history_settings(ToffeConfig(ofpd={"plane_fit_history": bad}))
    assert history_settings(ToffeConfig(ofpd={"plane_fit_history": [8, 20, 3]})) == (8.0, 20, 3)
    assert history_settings(ToffeConfig()) is None


def test_an_object_whose_box_is_empty_over_its_windows_has_no_fit_not_an_error():
    """A history that lacks the object's window (the energy benchmark's Loihi host part called
    Pipeline.objects_of on a stale one) left its surface empty: the plane step was 0 and the
    compiled range() raised. Now that object has no fit (NaN), the others theirs."""
    wins = disc_windows(12, 1.0, 0)
    hist = OnesHistory(12, SENSOR, B, DT)
    for t0, idx in wins:
        hist.push(t0, idx)
    obj, xs, ys = box_ones(wins[-1][1])
    far = (np.ones(3, np.int64), np.array([1, 2, 3]), np.array([45, 45, 46]))   # object 1: a corner with no ones
    ones = tuple(np.concatenate([a, b]) for a, b in zip((obj, xs, ys), far))
    f = history_flow(hist, ones, 2, [True, True], [12, 12], 0)
    assert np.isfinite(f[0]).all() and np.isnan(f[1]).all()


def test_fusion_keeps_the_ofpd_speed_until_the_history_holds_k_windows():
    """At a stream's start an object that wants more windows than the ring holds takes the fit's
    direction but keeps the OFPD's speed; once the ring holds them, both come from the fit."""
    cfg = ToffeConfig(ofpd={"plane_fit_weight": 1.0, "plane_fit_min_px_ms": 0.0, "plane_fit_dir_weight": 1.0,
                            "plane_fit_history": [8, 20, 3]})
    fusion = PlaneFusion(cfg)
    speed_ln = np.log([0.5])                            # K = 20 at 0.5 px/ms
    flow = np.array([[0.0, 0.2]])                       # px per bin: 2 px/ms, straight down
    direction = np.array([[1.0, 0.0]])
    s, d = fusion.apply(speed_ln, direction, lambda want, k: flow, available=5)
    assert s[0] == pytest.approx(math.log(0.5)) and d[0] == pytest.approx([0.0, 1.0])
    s, d = fusion.apply(speed_ln, direction, lambda want, k: flow, available=20)
    assert s[0] == pytest.approx(math.log(2.0)) and d[0] == pytest.approx([0.0, 1.0])


def test_refit_takes_k_from_the_fit_and_refits_only_what_changed():
    """K from the first fit's speed; only objects whose K changes are fitted again; one whose new
    fit gives no answer keeps its first flow and K."""
    calls = []
    # px per bin -> px/ms: x 10 at B 5, dt 500. Object 0: fit 2 px/ms (K 8 from D 8) where the
    # OFPD said 0.5 (K 20); object 1: fit agrees with its K; object 2: K changes but no answer.
    first = np.array([[0.2, 0.0], [0.0, 0.8], [0.4, 0.0]])

    def flow_of(want, k):
        calls.append((want.tolist(), list(k)))
        return np.array([[0.0, 0.25], [9.0, 9.0], [np.nan, np.nan]])

    flow, k = refit_history(first, [20, 2, 20], np.ones(3, bool), flow_of, 8.0, 20, DT, 10.0, 1)
    assert calls == [([True, False, True], [8, 0, 4])]
    assert flow.tolist() == [[0.0, 0.25], [0.0, 0.8], [0.4, 0.0]] and k == [8, 2, 20]
    calls.clear()
    flow, k = refit_history(first, [20, 2, 20], np.ones(3, bool), flow_of, 8.0, 20, DT, 10.0, 2)
    assert len(calls) == 2 and calls[1] == ([True, False, True], [7, 0, 4])     # 2.5 px/ms: K 7
    assert refit_history(first, [20, 2, 20], np.ones(3, bool), flow_of, 8.0, 20, DT, 10.0, 0)[1] == [20, 2, 20]


@pytest.mark.parametrize("ofpd", [
    {"plane_fit_weight": 1.0, "plane_fit_min_px_ms": 0.0, "plane_fit_dir_weight": 1.0, "plane_fit_refits": 1},
    {"plane_fit_weight": 0.6, "plane_fit_min_px_ms": 1.5, "plane_fit_dir_weight": 0.0},
    {"plane_fit_weight": 0.0, "plane_fit_min_px_ms": 0.0, "plane_fit_dir_weight": 0.7, "plane_fit_refits": 2}])
@pytest.mark.parametrize("n_windows", [3, 12])
def test_fused_history_equals_apply(ofpd, n_windows):
    """time_surface.fuse_history (the runtime's one compiled call) == PlaneFusion.apply with
    history_flow (eval's form), to the bit: two discs (slow and fast) and an object without
    ones; early in the stream (3 windows: the slow disc is short of windows) and later; weights
    that blend, a speed threshold that leaves an object out, refits."""
    from toffe_deploy.time_surface import fuse_history

    cfg = ToffeConfig(ofpd={**ofpd, "plane_fit_history": [6, 10, 2]})
    fusion = PlaneFusion(cfg)
    slow, fast = disc_windows(n_windows, 0.8, 30, start=(16.0, 14.0)), disc_windows(n_windows, 4.0, 200,
                                                                                   start=(46.0, 32.0))
    hist = OnesHistory(10, SENSOR, B, DT)
    for (t0, a), (_t, b) in zip(slow, fast):
        hist.push(t0, np.union1d(a, b))
    (_, a), (_, b) = slow[-1], fast[-1]
    oa, ob = box_ones(a), box_ones(b)
    ones = (np.concatenate([oa[0], ob[0] + 1]), np.concatenate([oa[1], ob[1]]), np.concatenate([oa[2], ob[2]]))
    speed_ln = np.log([[0.5], [3.0], [2.0]]).astype(np.float32)         # object 2 has no ones
    direction = np.array([[1.0, 0.0], [0.6, -0.8], [0.0, 1.0]], np.float32)
    ref_s, ref_d = fusion.apply(speed_ln, direction, lambda want, k: history_flow(hist, ones, 3, want, k, 2),
                                hist.available)
    got_s, got_d = fuse_history(fusion, hist, speed_ln, direction, ones)
    assert np.asarray(got_s).tolist() == np.asarray(ref_s, np.float64).reshape(-1).tolist()
    assert np.asarray(got_d).tolist() == np.asarray(ref_d, np.float64).reshape(-1, 2).tolist()
    assert np.asarray(got_d).tolist() != direction.astype(np.float64).tolist() or ofpd["plane_fit_dir_weight"] == 0
    changed = np.asarray(got_s).tolist() != speed_ln.astype(np.float64).reshape(-1).tolist()
    assert changed == (n_windows == 12 and ofpd["plane_fit_weight"] > 0)     # at 3 windows both are short


@pytest.mark.parametrize("bad", [-1, 5, 1.0, True, "1"])
def test_bad_refit_settings_are_one_line_errors(bad):
    with pytest.raises(ValueError, match="plane_fit_refits must be"):
        refit_settings(ToffeConfig(ofpd={"plane_fit_history": [8, 20, 3], "plane_fit_refits": bad}))
    with pytest.raises(ValueError, match="needs ofpd.plane_fit_history"):
        refit_settings(ToffeConfig(ofpd={"plane_fit_refits": 1}))
    assert refit_settings(ToffeConfig(ofpd={"plane_fit_history": [8, 20, 3], "plane_fit_refits": 1})) == 1
    assert refit_settings(ToffeConfig()) == 0


HISTORY_OFPD = {"crop_px": 32, "pool": 2, **ofpd_io.CURRENT_LAYOUT, "min_events": 8, "plane_fit_weight": 1.0,
                "plane_fit_min_px_ms": 0.0, "plane_fit_dir_weight": 1.0, "plane_fit_history": [8, 6, 2]}


@pytest.fixture(scope="module")
def env(tmp_path_factory, make_bundle, make_recording):
    root = tmp_path_factory.mktemp("history")
    return {"on": make_bundle(root / "on", sensor=SENSOR, ofpd=HISTORY_OFPD, input_min_cluster=4,
                              input_support=(3, 1, 3, 1)),
            "refit": make_bundle(root / "refit", sensor=SENSOR, ofpd={**HISTORY_OFPD, "plane_fit_refits": 1},
                                 input_min_cluster=4, input_support=(3, 1, 3, 1)),
            "rec": make_recording(root / "rec.h5", sensor=SENSOR, duration=0.008)}


def _windows(rec, cfg):
    with open_events(rec) as src:
        return [(t0, bin_window(ev, t0, cfg.dt_us, cfg.n_bins, cfg.sensor_size))
                for t0, ev in src.iter_windows(cfg.dt_us)]


def _rows(objs):
    return [(o[0], round(o[1], 9), round(o[2], 9), round(o[3], 12), round(o[4], 12)) for o in objs]


def test_cpu_pipeline_equals_reference_and_the_history_changes_it(env):
    """The streaming cpu Pipeline == eval's reference (predict_window with
    sampled_window_history's windows) with the key on: positions, directions and speeds; and
    the key changes the directions (it is read)."""
    from toffe_deploy.deploy.onnx_export import ort_session, run_onnx
    from toffe_deploy.model.reference import fixed_stage_fn, predict_window

    from toffe_deploy.runtime.pipeline import Pipeline

    b = env["on"]
    cfg = b.config
    off = dataclasses.replace(cfg, ofpd={k: v for k, v in cfg.ofpd.items() if k != "plane_fit_history"})
    sess, run = ort_session(b.ofpd_onnx), fixed_stage_fn(b.ofs)
    wins = _windows(env["rec"], cfg)
    assert len(wins) > 8
    with Pipeline(b, "cpu", track=False) as pipe:
        got = list(pipe.process_stream(wins[:5])) + list(pipe.process_stream(wins[5:]))   # kept over calls
    ours, ref, plain = [], [], []
    with open_events(env["rec"]) as src:
        for (t0, _x), res in zip(wins, got):
            binned, recent, history = sampled_window_history(src.read, t0, cfg.dt_us, cfg, cfg.sensor_size,
                                                             src.t_start_us)
            assert history.available == min(6, (t0 - src.t_start_us) // cfg.dt_us + 1)
            preds = predict_window(binned, run, lambda x: run_onnx(sess, x), cfg, recent, history)[0]
            ref.append(_rows([(p.stage, p.x, p.y, p.direction_rad, p.speed_mps) for p in preds]))
            ours.append(_rows([(o.speed_bin, o.x, o.y, o.direction_rad, o.speed_mps) for o in res.objects]))
            plain.append(_rows([(p.stage, p.x, p.y, p.direction_rad, p.speed_mps)
                                for p in predict_window(binned, run, lambda x: run_onnx(sess, x), off, recent)[0]]))
    assert ours == ref
    assert sum(map(len, ours)) > 0 and ours != plain


def test_eval_windows_in_order_continue_the_stream_with_the_same_results(env):
    """eval's WindowHistories: windows asked for in order (and after a gap, where the stream is
    built anew) give the front end's window, the SupportHistory and predictions through the
    ring that sampled_window_history's fresh build gives for each."""
    from toffe_deploy.deploy.onnx_export import ort_session, run_onnx
    from toffe_deploy.events.support import WindowHistories
    from toffe_deploy.model.reference import fixed_stage_fn, predict_window

    b = env["on"]
    cfg = b.config
    sess, run = ort_session(b.ofpd_onnx), fixed_stage_fn(b.ofs)
    wins = [t0 for t0, _x in _windows(env["rec"], cfg)]
    asked = wins[:4] + wins[6:10]
    n_objects = 0
    with open_events(env["rec"]) as src:
        stream = WindowHistories(src.read, cfg.dt_us, cfg, cfg.sensor_size, src.t_start_us)
        for t0 in asked:
            got = stream(t0)
            got_preds = _rows([(p.stage, p.x, p.y, p.direction_rad, p.speed_mps)
                               for p in predict_window(*got[:1], run, lambda x: run_onnx(sess, x), cfg, *got[1:])[0]])
            got_hist = (got[0].copy(), got[1].counts.copy(), got[1].total, got[2].available)
            ref = sampled_window_history(src.read, t0, cfg.dt_us, cfg, cfg.sensor_size, src.t_start_us)
            ref_preds = _rows([(p.stage, p.x, p.y, p.direction_rad, p.speed_mps)
                               for p in predict_window(*ref[:1], run, lambda x: run_onnx(sess, x), cfg, *ref[1:])[0]])
            assert np.array_equal(got_hist[0], ref[0]) and np.array_equal(got_hist[1], ref[1].counts)
            assert got_hist[2:] == (ref[1].total, ref[2].available)
            assert got_preds == ref_preds
            n_objects += len(got_preds)
    assert n_objects > 0 and stream._next == asked[-1] + cfg.dt_us


def test_refits_pipeline_equals_reference(env, monkeypatch):
    """plane_fit_refits: the streaming cpu Pipeline (time_surface.fused_history_flow, one compiled
    call) == eval's reference (PlaneFusion.apply with refit_history), and the refit is read (some
    object's K changes)."""
    from toffe_deploy import plane_fit
    from toffe_deploy.deploy.onnx_export import ort_session, run_onnx
    from toffe_deploy.model.reference import fixed_stage_fn, predict_window
    from toffe_deploy.runtime.pipeline import Pipeline

    b = env["refit"]
    cfg = b.config
    sess, run = ort_session(b.ofpd_onnx), fixed_stage_fn(b.ofs)
    wins = _windows(env["rec"], cfg)
    with Pipeline(b, "cpu", track=False) as pipe:
        got = list(pipe.process_stream(wins))
    changed, refit = [], plane_fit.refit_history

    def spy(flow, k, *a):
        out = refit(flow, k, *a)
        changed.append(out[1] != list(k))
        return out

    monkeypatch.setattr(plane_fit, "refit_history", spy)
    ours, ref = [], []
    with open_events(env["rec"]) as src:
        for (t0, _x), res in zip(wins, got):
            binned, recent, history = sampled_window_history(src.read, t0, cfg.dt_us, cfg, cfg.sensor_size,
                                                             src.t_start_us)
            ours.append(_rows([(o.speed_bin, o.x, o.y, o.direction_rad, o.speed_mps) for o in res.objects]))
            ref.append(_rows([(p.stage, p.x, p.y, p.direction_rad, p.speed_mps)
                              for p in predict_window(binned, run, lambda x: run_onnx(sess, x), cfg, recent,
                                                      history)[0]]))
    assert any(changed)
    assert ours == ref and sum(map(len, ours)) > 0


def test_cpu_equals_loihi_sim_with_history(env, lines_per_target):
    """The Lava target pipelines windows; the history takes each window's ones when its result
    comes out, in order, as on cpu."""
    pytest.importorskip("lava")
    out = lines_per_target(env["on"], _windows(env["rec"], env["on"].config)[:9])
    assert out["cpu"] == out["loihi-sim"]
    assert any(json.loads(s)["objects"] for s in out["cpu"])


def test_parity_runtime_equals_reference_with_history(env):
    """The export's end-to-end parity: held-out windows carry the plane fit's windows before
    them (HeldOut.ones), which the runtime's Pipeline and the reference both read."""
    from toffe_deploy.deploy.parity import _predictions_fixed_reference, _predictions_runtime
    from toffe_deploy.deploy.windows import heldout_windows

    b = env["on"]
    held = heldout_windows(b.config, None, seed=0, n_windows=6)
    assert len(held.ones) == len(held) and held.ones_after(0).available >= 1
    run, ref = _predictions_runtime(b, held), _predictions_fixed_reference(b, held)
    rows = [[[(p.stage, round(p.x, 3), round(p.y, 3), round(p.direction_rad, 6)) for p in r] for r in preds]
            for preds in (run, ref)]
    assert rows[0] == rows[1]
    assert any(rows[0])
