"""ofpd.recent_events (issue 11): a group short of min_events is an object when the latest
windows' event pixels around it reach a threshold (compiled.recent_reaches) and it lies apart
from every object; the key's validation, the rule at its threshold, and the streaming cpu
Pipeline (and loihi-sim) against eval's reference fed the same history."""
import dataclasses
import json

import numpy as np
import pytest

from toffe_deploy import ofpd_io
from toffe_deploy.config import ToffeConfig
from toffe_deploy.events.binning import bin_window
from toffe_deploy.events.io import open_events
from toffe_deploy.events.support import Latest, sampled_window_recent

SENSOR = (96, 64)
SUPPORT = (4, 1, 5, 2)
LAYOUT = {**ofpd_io.CURRENT_LAYOUT, "min_events": 12}


def cfg_with(rule, support=SUPPORT):
    return ToffeConfig(sensor_size=SENSOR, input_support=support, ofpd={**LAYOUT, "recent_events": rule})


def one_stage(xs, ys):
    e = np.zeros(0, np.int64)
    return [(np.asarray(xs, np.int64), np.asarray(ys, np.int64)), (e, e), (e, e), (e, e)]


def recent_of(points, reps=1):
    """Latest of pixels ``points`` (x, y) each counted ``reps`` times."""
    counts = np.zeros(SENSOR[0] * SENSOR[1], np.uint8)
    for x, y in points:
        counts[y * SENSOR[0] + x] += reps
    return Latest(counts, int(counts.sum(dtype=np.int64)))


ARC = [(40 + i, 30) for i in range(0, 8, 2)] + [(40, 31)]        # 5 pixels, one group (link 4), < 12


def test_key_validation_and_default():
    assert ofpd_io.ofpd_settings(ToffeConfig())["recent_events"] is None
    assert ofpd_io.ofpd_settings(cfg_with([2, 10, 2]))["recent_events"] == [2, 10, 2]
    for bad in ([2, 10], [2, -1, 2], [2, 1.5, 2], "2,10,2", [True, 1, 1]):
        with pytest.raises(ValueError, match="recent_events must be"):
            ofpd_io.ofpd_settings(cfg_with(bad))
    with pytest.raises(ValueError, match="input_support"):
        ofpd_io.ofpd_settings(cfg_with([2, 10, 2], support=None))
    with pytest.raises(ValueError, match="union"):
        ofpd_io.ofpd_settings(ToffeConfig(input_support=SUPPORT, ofpd={**LAYOUT, "stages": "join",
                                                                      "recent_events": [2, 10, 2]}))


def test_short_group_is_an_object_when_the_latest_windows_reach_the_threshold():
    """S = the counts in the group's box grown by r; the group is reported at S >= m (c = 0)
    and not at m = S + 1; without the windows (or with the key off) min_events alone decides."""
    xs, ys = zip(*ARC)
    hist = ARC + [(41, 30), (43, 31), (45, 29), (47, 32), (60, 50)]         # the last one outside the box
    recent = recent_of(hist, reps=2)
    s = 2 * (len(hist) - 1)
    for r_, m, want in ((1, s, 1), (1, s + 1, 0), (0, s - 4, 1), (0, s - 3, 0)):   # r 0: (45, 29), (47, 32) outside
        objs, claims = ofpd_io.group_objects_xy(one_stage(xs, ys), SENSOR, cfg_with([r_, m, 0]), recent)
        assert len(objs) == want, (r_, m)
    objs, _ = ofpd_io.group_objects_xy(one_stage(xs, ys), SENSOR, cfg_with([1, s, 0]), recent)
    assert objs[0][0] == 0 and abs(objs[0][1] - np.mean(xs)) < 1e-9 and abs(objs[0][2] - np.mean(ys)) < 1e-9
    assert ofpd_io.group_objects_xy(one_stage(xs, ys), SENSOR, cfg_with([1, s, 0]), None)[0] == []
    off = ToffeConfig(sensor_size=SENSOR, input_support=SUPPORT, ofpd=LAYOUT)
    assert ofpd_io.group_objects_xy(one_stage(xs, ys), SENSOR, off, recent)[0] == []


def test_noise_term_raises_the_threshold():
    """T = m + floor(c * A * E / (H * W)): the same group, box counts 10, passes at c = 0 and
    fails once the rest of the sensor holds enough event pixels (E) for c * A * E / HW >= 1."""
    xs, ys = zip(*ARC)
    counts = np.zeros(SENSOR[0] * SENSOR[1], np.uint8)
    for x, y in ARC:
        counts[y * SENSOR[0] + x] = 2
    near = Latest(counts, 10)
    area = (7 + 2) * (2 + 2)                                        # box 40..46 x 30..31 grown by 1
    assert len(ofpd_io.group_objects_xy(one_stage(xs, ys), SENSOR, cfg_with([1, 10, 1]), near)[0]) == 1
    e_needed = -(-SENSOR[0] * SENSOR[1] // area)                    # c * A * E / HW >= 1
    far = Latest(counts, 10 + e_needed)                             # E counts pixels elsewhere on the sensor
    assert len(ofpd_io.group_objects_xy(one_stage(xs, ys), SENSOR, cfg_with([1, 10, 1]), far)[0]) == 0
    assert len(ofpd_io.group_objects_xy(one_stage(xs, ys), SENSOR, cfg_with([1, 10, 0]), far)[0]) == 1


def test_a_leftover_next_to_an_object_is_not_reported():
    """A short group within edge_merge_frac * an object's extent of that object is its leftover
    edge: not rescued however many event pixels the latest windows put there; far away it is."""
    ring = [(20 + i, 20) for i in range(13)] + [(20 + i, 32) for i in range(13)]
    ring += [(20, 20 + j) for j in range(1, 12)] + [(32, 20 + j) for j in range(1, 12)]   # a 13 px square outline
    for piece_x, want in ((40, 1), (80, 2)):        # gap 8 px <= 1.5 * 13; gap 48 px > 19.5
        piece = [(piece_x + i, 26) for i in range(0, 6, 2)]
        xs, ys = zip(*(ring + piece))
        recent = recent_of(piece, reps=8)
        objs, _ = ofpd_io.group_objects_xy(one_stage(xs, ys), SENSOR, cfg_with([1, 8, 0]), recent)
        assert len(objs) == want, piece_x


@pytest.fixture(scope="module")
def env(tmp_path_factory, make_bundle, make_recording):
    root = tmp_path_factory.mktemp("recent")
    ofpd = {"crop_px": 32, "pool": 2, **ofpd_io.CURRENT_LAYOUT, "min_events": 8, "recent_events": [1, 3, 0]}
    return {"on": make_bundle(root / "on", sensor=(64, 48), ofpd=ofpd, input_min_cluster=4, input_support=(3, 1, 3, 1)),
            "rec": make_recording(root / "rec.h5", sensor=(64, 48), duration=0.008)}


def _windows(rec, cfg):
    with open_events(rec) as src:
        return [(t0, bin_window(ev, t0, cfg.dt_us, cfg.n_bins, cfg.sensor_size)) for t0, ev in src.iter_windows(cfg.dt_us)]


def test_cpu_pipeline_equals_reference_and_rescues_objects(env):
    """The streaming cpu Pipeline == eval's reference (predict_window with the history of
    sampled_window_recent) with the key on, and it reports objects the key off does not."""
    from toffe_deploy.deploy.onnx_export import ort_session, run_onnx
    from toffe_deploy.model.reference import fixed_stage_fn, predict_window
    from toffe_deploy.runtime.pipeline import Pipeline

    b = env["on"]
    cfg = b.config
    off = dataclasses.replace(cfg, ofpd={k: v for k, v in cfg.ofpd.items() if k != "recent_events"})
    sess, run = ort_session(b.ofpd_onnx), fixed_stage_fn(b.ofs)
    wins = _windows(env["rec"], cfg)
    with Pipeline(b, "cpu") as pipe:
        got = list(pipe.process_stream(wins[:8])) + list(pipe.process_stream(wins[8:]))   # history kept over calls
    rows, n_off = [], 0
    with open_events(env["rec"]) as src:
        for (t0, _x), res in zip(wins, got):
            binned, recent = sampled_window_recent(src.read, t0, cfg.dt_us, cfg, cfg.sensor_size)
            ref = predict_window(binned, run, lambda x: run_onnx(sess, x), cfg, recent)[0]
            n_off += len(predict_window(binned, run, lambda x: run_onnx(sess, x), off, recent)[0])
            rows.append(([(o.speed_bin, round(o.x, 3), round(o.y, 3)) for o in res.objects],
                         [(p.stage, round(p.x, 3), round(p.y, 3)) for p in ref]))
    assert [a for a, _ in rows] == [r for _, r in rows]
    assert sum(len(a) for a, _ in rows) > n_off


def test_cpu_equals_loihi_sim_with_recent_events(env, lines_per_target):
    """The Lava target pipelines windows: each keeps a copy of the history after it."""
    pytest.importorskip("lava")
    out = lines_per_target(env["on"], _windows(env["rec"], env["on"].config)[:8])
    assert out["cpu"] == out["loihi-sim"]
    assert any(json.loads(s)["objects"] for s in out["cpu"])


def test_parity_runtime_equals_reference_with_recent_events(env):
    """The export's end-to-end parity: the reference reads each held-out window's history after
    it (HeldOut.recent), as the runtime's Pipeline holds it."""
    from toffe_deploy.deploy.parity import _predictions_fixed_reference, _predictions_runtime
    from toffe_deploy.deploy.windows import heldout_windows

    b = env["on"]
    held = heldout_windows(b.config, None, seed=0, n_windows=6)
    assert held.recent(0, b.config) is not None
    run, ref = _predictions_runtime(b, held), _predictions_fixed_reference(b, held)
    rows = [[[(p.stage, round(p.x, 3), round(p.y, 3)) for p in r] for r in preds] for preds in (run, ref)]
    assert rows[0] == rows[1]
    assert any(rows[0])
