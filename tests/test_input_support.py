"""ToffeConfig.input_support wired through every path (issue 11): the config key, the streaming
SupportHistory against the windows read before, and the pipeline (cpu and Lava) against the
dense reference fed the same history."""
import copy
import dataclasses
import json

import numpy as np
import pytest

from toffe_deploy.config import ToffeConfig, load_config
from toffe_deploy.errors import InputError
from toffe_deploy.events.binning import bin_window
from toffe_deploy.events.frontend import apply_dense
from toffe_deploy.events.io import open_events
from toffe_deploy.events.support import SupportHistory, front_end, sampled_window, window_pixels
from toffe_deploy.runtime.spikes import SpikeVolume

SENSOR = (64, 48)
SUPPORT = (3, 1, 3, 1)       # low threshold: on a tiny sensor it must keep some pixels the clusters drop


@pytest.fixture(scope="module")
def env(tmp_path_factory, make_bundle, make_recording):
    root = tmp_path_factory.mktemp("support")
    return {"on": make_bundle(root / "on", sensor=SENSOR, input_min_cluster=4, input_support=SUPPORT),
            "rec": make_recording(root / "rec.h5", sensor=SENSOR, duration=0.008)}


def _windows(rec, cfg):
    with open_events(rec) as src:
        return [(t0, bin_window(ev, t0, cfg.dt_us, cfg.n_bins, cfg.sensor_size)) for t0, ev in src.iter_windows(cfg.dt_us)]


def test_config_round_trip_validation_and_absent_key(tmp_path):
    on = ToffeConfig(input_support=(4, 1, 5, 2))
    d = on.to_dict()
    assert d["input_support"] == [4, 1, 5, 2]
    assert ToffeConfig.from_dict(json.loads(json.dumps(d))) == on
    off = ToffeConfig()
    assert "input_support" not in off.to_dict()            # configs written before it stay as they were
    assert ToffeConfig.from_dict(off.to_dict()).input_support is None
    assert ToffeConfig.from_dict({**off.to_dict(), "input_support": None}).input_support is None
    for bad in ([4, 1, 5], [0, 1, 5, 2], [4, 1, 0, 2], [4, -1, 5, 2], [4, 1, 5, 2.5], "4,1,5,2", [True, 1, 5, 2]):
        with pytest.raises(InputError, match="input_support must be"):
            ToffeConfig.from_dict({**off.to_dict(), "input_support": bad}, tmp_path / "c.json")


def test_bundle_carries_the_key(env):
    cfg = load_config(env["on"].root / "config.json")
    assert cfg.input_support == SUPPORT
    manifest = json.loads((env["on"].root / "manifest.json").read_text())
    assert manifest["config"]["input_support"] == list(SUPPORT)


def test_without_the_key_the_front_end_is_the_old_one(env):
    cfg = dataclasses.replace(env["on"].config, input_support=None)
    for t0, x in _windows(env["rec"], cfg)[:6]:
        want = apply_dense(x, cfg.input_norm, cfg.input_min_cluster)
        assert np.array_equal(front_end(x, cfg), want)
        vol = SpikeVolume.from_dense(x > 0)
        assert np.array_equal(front_end(vol, cfg).to_dense(), want)


def test_streaming_history_equals_the_windows_read_before(env):
    cfg = env["on"].config
    k = cfg.input_support[0]
    hist = SupportHistory(k, SENSOR, cfg.dt_us)
    with open_events(env["rec"]) as src:
        wins = list(src.iter_windows(cfg.dt_us))
        for i, (t0, ev) in enumerate(wins):
            if i == 5:
                continue                                   # a skipped window: a gap of 2 dt
            hist.advance(t0)
            before = SupportHistory.before(src.read, t0, cfg.dt_us, k, SENSOR)
            if i == 6:       # the skipped window's pixels are missing from the stream, not from the read
                missing = window_pixels(wins[5][1], wins[5][0], cfg.dt_us, SENSOR)
                assert np.array_equal(before.counts - hist.counts, np.isin(np.arange(hist.counts.size), missing))
            elif i < 6 or i > 6 + k:
                assert np.array_equal(hist.counts, before.counts) and hist.total == before.total
            hist.push(t0, window_pixels(ev, t0, cfg.dt_us, SENSOR))
        assert hist.total > 0
        hist.advance(wins[2][0])                           # a jump back forgets
        assert hist.total == 0 and not hist.counts.any()


def test_support_keeps_more_and_sampled_equals_streamed(env):
    cfg = env["on"].config
    off = dataclasses.replace(cfg, input_support=None)
    hist = SupportHistory(cfg.input_support[0], SENSOR, cfg.dt_us)
    n_on = n_off = 0
    with open_events(env["rec"]) as src:
        for t0, x in _windows(env["rec"], cfg):
            streamed = front_end(SpikeVolume.from_dense(x > 0), cfg, hist, t0).to_dense()
            sampled = sampled_window(src.read, t0, cfg.dt_us, cfg, SENSOR)
            assert np.array_equal(streamed, sampled)
            n_on += int(sampled.sum())
            n_off += int(apply_dense(x, off.input_norm, off.input_min_cluster).sum())
    assert n_on > n_off


def test_cpu_pipeline_with_support_equals_dense_reference(env):
    """The streaming cpu Pipeline == eval's reference (model.reference.predict_window: dense
    fixed-point cascade, OFPD in onnxruntime) on the windows read with their K windows before."""
    from toffe_deploy.deploy.onnx_export import ort_session, run_onnx
    from toffe_deploy.model.reference import fixed_stage_fn, predict_window
    from toffe_deploy.runtime.pipeline import Pipeline

    b = env["on"]
    cfg = b.config
    sess, run = ort_session(b.ofpd_onnx), fixed_stage_fn(b.ofs)
    wins = _windows(env["rec"], cfg)
    with Pipeline(b, "cpu") as pipe:
        got = list(pipe.process_stream(wins[:8])) + list(pipe.process_stream(wins[8:]))   # history kept over calls
    rows = []
    with open_events(env["rec"]) as src:
        for (t0, _x), res in zip(wins, got):
            ref = predict_window(sampled_window(src.read, t0, cfg.dt_us, cfg, SENSOR), run,
                                 lambda x: run_onnx(sess, x), cfg)[0]
            rows.append(([(o.speed_bin, round(o.x, 3), round(o.y, 3)) for o in res.objects],
                         [(p.stage, round(p.x, 3), round(p.y, 3)) for p in ref]))
    assert [a for a, _ in rows] == [r for _, r in rows]
    assert sum(len(a) for a, _ in rows) > 0


def test_cpu_equals_loihi_sim_with_support(env, lines_per_target):
    pytest.importorskip("lava")
    out = lines_per_target(env["on"], _windows(env["rec"], env["on"].config)[:6])
    assert out["cpu"] == out["loihi-sim"]
    assert any(json.loads(s)["objects"] for s in out["cpu"])


def test_training_crops_of_the_whole_sensor_front_end(env):
    """model/data.py: with support the crop is cut from the whole window's front end (its
    threshold follows the sensor's event density); without, crop_index == crop_window."""
    from toffe_deploy.events.support import sampled_index
    from toffe_deploy.model.data import crop_index, crop_window

    cfg = env["on"].config
    plain = dataclasses.replace(cfg, input_support=None, input_norm="first", input_min_cluster=1)
    with open_events(env["rec"]) as src:
        for t0, ev in list(src.iter_windows(cfg.dt_us))[3:9]:
            for centre in ((20.4, 30.0), (3.0, 44.6)):                     # the second one partly outside
                want = crop_window(ev, t0, cfg.dt_us, cfg.n_bins, centre, 24, "first", 1)
                got = crop_index(sampled_index(src.read, t0, cfg.dt_us, plain, SENSOR), SENSOR, centre, 24)
                assert np.array_equal(got[0], want[0]) and np.array_equal(got[1], want[1])
                dense = sampled_window(src.read, t0, cfg.dt_us, cfg, SENSOR)
                x0, y0 = got[1]
                pad = np.zeros((cfg.n_bins, 2, 24 + 2 * 48, 24 + 2 * 64), bool)
                pad[:, :, 48:96, 64:128] = dense
                idx, _ = crop_index(sampled_index(src.read, t0, cfg.dt_us, cfg, SENSOR), SENSOR, centre, 24)
                assert np.array_equal(idx, np.flatnonzero(pad[:, :, 48 + y0:72 + y0, 64 + x0:88 + x0]))


def test_noise_crops_with_support_are_packed(env):
    """Training's noise-only crops get K noise windows before them: m = 1 keeps every pixel the
    cluster filter drops, so more events are packed than without support."""
    from toffe_deploy.model.data import WindowSet
    from toffe_deploy.model.train import pack_training_windows

    empty = WindowSet(5, 32, np.zeros(0, np.int32), np.zeros(1, np.int64), np.zeros((0, 2), np.int64),
                      *[np.zeros(0) for _ in range(7)])
    n_event = {}
    for support in (None, (4, 1, 1, 0)):
        sw, bins = pack_training_windows(empty, 3, 0, False, "first", 4, 1, support=support)
        assert bins.tolist() == [0, 0, 0, 0]
        n_event[support] = int(sw.event.sum())
    assert n_event[(4, 1, 1, 0)] > n_event[None]


def test_parity_windows_and_runtime_with_support(env):
    """deploy/windows.py keeps each held-out window's raw form and history, so the runtime's
    Pipeline redoes the same front end: its objects equal the reference cascade's."""
    from toffe_deploy.deploy.parity import _predictions_fixed_reference, _predictions_runtime
    from toffe_deploy.deploy.windows import heldout_windows

    b = env["on"]
    held = heldout_windows(b.config, None, seed=0, n_windows=4)
    assert len(held.support) == len(held.windows) == 4
    for t0, w, (raw, hist) in zip(held.t0, held.windows, held.support):
        assert np.array_equal(front_end(raw, b.config, copy.deepcopy(hist), t0), w)
    run, ref = _predictions_runtime(b, held), _predictions_fixed_reference(b, held)
    rows = [[[(p.stage, round(p.x, 3), round(p.y, 3)) for p in r] for r in preds] for preds in (run, ref)]
    assert rows[0] == rows[1]
    assert any(rows[0])
