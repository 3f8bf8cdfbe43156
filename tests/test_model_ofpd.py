"""OFPD pre/post-processing semantics, ONNX parity, metrics and the reference cascade."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from toffe_deploy import ofpd_io
from toffe_deploy.checkpoint import init_checkpoint, load_checkpoint
from toffe_deploy.config import ToffeConfig
from toffe_deploy.metrics import FlowErrors, Prediction, angle_error_deg, match_nearest
from toffe_deploy.model.ofpd import OFPD

CFG = ToffeConfig(sensor_size=(64, 48))


def _frame(x0, y0, w=8, h=6, shape=(48, 64)):
    f = np.zeros((5, 2, *shape), bool)
    f[:, 1, y0:y0 + h, x0:x0 + w] = True
    return f


def test_prepare_centres_crop_on_events_and_encodes_position():
    x = ofpd_io.prepare(np.stack([_frame(10, 5), _frame(40, 30)]), CFG)
    c, g, _ = ofpd_io.input_shape(CFG)
    assert x.shape == (2, c, g, g) and x.dtype == np.float32
    # the mean of the coordinate planes is the event centroid (to the rounding of the crop)
    centre = x[:, -2:].mean(axis=(2, 3)) * ofpd_io.COORD_SCALE
    np.testing.assert_allclose(centre, [[13.5, 7.5], [43.5, 32.5]], atol=0.51)
    # the event planes hold all events (pooled means of binary pixels) and the same pattern
    pool = ofpd_io.crop_origins(np.stack([_frame(10, 5), _frame(40, 30)]), CFG)[:, 2] // g
    assert pool.tolist() == [2, 2]          # scaled crop: an 8 px object gets the smallest, 64 px
    assert x[0, :10].sum() * 4 == pytest.approx(5 * 8 * 6)
    np.testing.assert_array_equal(x[0, :10], x[1, :10])


def test_has_object_counts_event_pixels():
    f = np.zeros((3, 5, 2, 48, 64), bool)
    f[1, 0, 0, 0, :11] = True
    f[2, 0, 0, 0, :12] = True
    assert ofpd_io.has_object(f, CFG).tolist() == [False, False, True]


def test_decode_angles_and_speed_within_bin():
    sc = CFG.speed_scale
    d = ofpd_io.decode(np.array([[1.0, 2.0], [3.0, 4.0]]), np.array([[0.0, -2.0], [-1.0, 0.0]]),
                       np.log([[50.0], [sc.to_px_ms(25.0)]]), np.array([4, 2]), CFG)
    np.testing.assert_allclose(d["direction_rad"], [-np.pi / 2, np.pi])
    np.testing.assert_allclose(d["speed_px_ms"], [ofpd_io.MAX_SPEED_PX_MS, sc.to_px_ms(25.0)])   # clipped into bin 4
    np.testing.assert_allclose(d["speed_mps"], [sc.to_mps(ofpd_io.MAX_SPEED_PX_MS), 25.0])
    np.testing.assert_allclose(d["speed_bin_mps"], [114.0, 30.0])
    # a legacy-layout OFPD (config.ofpd without "grouping") regresses ln m/s
    old = ToffeConfig(sensor_size=(64, 48), ofpd={"crop_px": 128})
    d = ofpd_io.decode(np.zeros((2, 2)), np.ones((2, 2)), np.log([[500.0], [25.0]]), np.array([4, 2]), old)
    np.testing.assert_allclose(d["speed_mps"], [ofpd_io.MAX_SPEED_MPS, 25.0])
    np.testing.assert_allclose(d["speed_px_ms"], sc.to_px_ms(np.array([ofpd_io.MAX_SPEED_MPS, 25.0])))
    with pytest.raises(ValueError):
        ofpd_io.decode(np.zeros((1, 2)), np.ones((1, 2)), np.zeros((1, 1)), np.array([5]), CFG)


def test_onnx_export_matches_torch(tmp_path):
    import onnxruntime as ort

    ck = load_checkpoint(init_checkpoint(tmp_path / "ck", CFG, seed=1))
    m = OFPD.from_config(ck.config).eval()
    m.load_state_dict({k: torch.from_numpy(v) for k, v in ck.ofpd_state.items()})
    x = ofpd_io.prepare(np.stack([_frame(10, 5), _frame(30, 20, 12, 12)]), CFG)
    torch.onnx.export(m, torch.from_numpy(x), tmp_path / "m.onnx", input_names=["events"],
                      output_names=["pose", "direction", "speed"], dynamic_axes={"events": {0: "N"}}, opset_version=17)
    outs = ort.InferenceSession(str(tmp_path / "m.onnx"), providers=["CPUExecutionProvider"]).run(None, {"events": x[:1]})
    with torch.no_grad():
        ref = [t.numpy() for t in m(torch.from_numpy(x[:1]))]
    for a, b in zip(outs, ref):
        np.testing.assert_allclose(a, b, atol=1e-4)
    # pose is the crop centre plus the head's residual, in sensor pixels
    assert abs(outs[0][0, 0] - 13.5) < 64


def test_angle_error_wraps_to_0_180():
    np.testing.assert_allclose(angle_error_deg([np.pi - 0.1, 0.0, 3 * np.pi], [-np.pi + 0.1, np.pi / 2, 0.0]),
                               [np.degrees(0.2), 90.0, 180.0], atol=1e-9)


def test_matching_counts_misses_and_false_positives():
    class T:  # a ground-truth object
        def __init__(self, x, y, b):
            self.x, self.y, self.direction, self.speed, self.speed_bin = x, y, 0.0, 30.0, b

    e = FlowErrors(gate_px=20)
    preds = [Prediction(2, 11, 10, 0.1, 31.0, 30.0), Prediction(3, 100, 100, 0.0, 60.0, 63.0)]
    e.add_window(preds, [T(10, 10, 2), T(50, 50, 1)])
    s = e.summary()
    assert s["n_matched"] == 1 and s["n_gt"] == 2 and s["recall"] == 0.5 and s["false_positives"] == 1
    assert s["pixE"] == pytest.approx(1.0) and s["speedE"] == pytest.approx(1.0) and s["speedE_bin_only"] == 0.0
    assert match_nearest([[0, 0], [5, 5]], [[4, 4], [1, 1]]) == [(0, 1), (1, 0)] or \
        sorted(match_nearest([[0, 0], [5, 5]], [[4, 4], [1, 1]])) == [(0, 1), (1, 0)]


@pytest.mark.parametrize("stages", ["union", "join"])
def test_fastest_stage_reports_and_leftovers_join_its_object(stages):
    cfg = ToffeConfig(sensor_size=(200, 160), ofpd={**ofpd_io.OFPD_DEFAULTS, "stages": stages})
    frames = np.zeros((4, 5, 2, 160, 200), bool)
    frames[2, :, 1, 20:30, 20:30] = True           # stage 3 takes most of object A
    frames[1, 0, 0, 20:30, 31:33] = True           # stage 2 gets A's leftover edge (20 px)
    frames[0, 0, 0, 24, 34:40] = True              # stage 1 gets a few more of A
    frames[0, :, 1, 130:140, 160:170] = True       # ... and object B, slow, far away
    assert ofpd_io.has_object(frames, cfg).tolist() == [True, False, True, False]
    ks, merged = ofpd_io.merge_frames(frames, cfg)
    assert ks.tolist() == [3, 1]
    left = np.arange(200) < 100
    np.testing.assert_array_equal(merged[0], frames[2] | frames[1] | (frames[0] & left))   # all of A
    np.testing.assert_array_equal(merged[1], frames[0] & ~left)                            # only B
    objs = ofpd_io.report_objects(ofpd_io.event_pixels(frames), cfg)
    assert [o[0] for o in objs] == [2, 0]
    # "join": the centroid of the stage that reports it; "union": of all of its pixels
    ys, xs = np.nonzero(ofpd_io.event_pixels(merged[:1])[0] if stages == "union" else frames[2].any(axis=(0, 1)))
    assert objs[0][1:] == pytest.approx((xs.mean(), ys.mean())) and objs[1][1:] == pytest.approx((164.5, 134.5))


def test_two_objects_of_one_bin_are_reported_separately():
    cfg = ToffeConfig(sensor_size=(320, 240))
    frames = np.zeros((4, 5, 2, 240, 320), bool)
    frames[1, :, 1, 20:30, 20:30] = True
    frames[1, :, 0, 200:212, 280:290] = True
    objs = ofpd_io.report_objects(ofpd_io.event_pixels(frames), cfg)
    assert sorted((o[0], round(o[1], 1), round(o[2], 1)) for o in objs) == [(1, 24.5, 24.5), (1, 284.5, 205.5)]
    ks, merged = ofpd_io.merge_frames(frames, cfg)
    assert ks.tolist() == [2, 2] and merged.sum() == frames.sum()
