"""Adaptive-SpikeNet (Pico) baseline: shapes, op counting, flow targets, flow -> objects, shipped weights."""
from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from toffe_deploy.baselines.adaptive_spikenet import (ASNetConfig, AdaptiveSpikeNetBaseline, FlowObject,  # noqa: E402
                                                      build_model, count_ops, flow_objects, host_ops, layer_specs,
                                                      n_params, network_input, save_baseline, sensor_flow,
                                                      to_predictions)
from toffe_deploy.config import ToffeConfig  # noqa: E402
from toffe_deploy.dataset.flowgt import dense_flow, object_radii_px, pixel_flow  # noqa: E402
from toffe_deploy.dataset.groundtruth import ObjectTruth  # noqa: E402
from toffe_deploy.errors import InputError  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
SHIPPED = ROOT / "ckpt" / "baselines" / "adaptive_spikenet"
SMALL = ASNetConfig(downsample=2)


def moving_disc_window(sensor=(96, 64), centre=(40.0, 32.0), radius=10.0, u_px_ms=8.0, dt_us=500, n_bins=5,
                       per_edge=3):
    """(B, 2, H, W) uint8 counts of a bright disc moving along +x (the generator's look: ON where
    the disc arrives, OFF where it leaves, per_edge events per crossing), and its midpoint centre."""
    w, h = sensor
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    out = np.zeros((n_bins, 2, h, w), np.uint8)
    samples = dt_us // 50
    x0 = centre[0] - u_px_ms * dt_us * 1e-3 / 2
    prev = np.hypot(xx - x0, yy - centre[1]) <= radius
    for k in range(1, samples + 1):
        cx = x0 + u_px_ms * k * 50e-3
        now = np.hypot(xx - cx, yy - centre[1]) <= radius
        b = (k * 50 - 1) * n_bins // dt_us
        out[b, 1] += (now & ~prev).astype(np.uint8) * per_edge
        out[b, 0] += (prev & ~now).astype(np.uint8) * per_edge
        prev = now
    return out, centre


def test_shapes_and_param_count():
    model = build_model(SMALL)
    assert sum(p.numel() for p in model.parameters()) == n_params(SMALL)
    assert n_params(ASNetConfig()) == 259_898          # the Pico sizes of the module doc
    binned = np.random.default_rng(0).poisson(0.05, (5, 2, 48, 64)).astype(np.uint8)
    x = network_input(binned, SMALL)
    assert x.shape == (5, 2, 32, 32)                   # 24 x 32 padded to multiples of 16
    with torch.no_grad():
        f = model(torch.from_numpy(x)[None])
    assert f.shape == (1, 2, 32, 32)
    assert sensor_flow(f[0].numpy(), SMALL, (64, 48)).shape == (2, 48, 64)


def test_network_input_sums_blocks():
    binned = np.zeros((5, 2, 48, 64), np.uint8)
    binned[2, 1, 5, 7] = 3
    binned[2, 1, 4, 6] = 2
    x = network_input(binned, SMALL)
    assert x[2, 1, 2, 3] == 5 and x.sum() == 5


def _reach_brute(h, w, y, x, kernel, stride, pad):
    """Outputs of a conv whose receptive field holds input pixel (y, x), by enumeration."""
    ho, wo = -(-h // stride), -(-w // stride)
    n = 0
    for oy in range(ho):
        for ox in range(wo):
            if 0 <= y - (oy * stride - pad) < kernel and 0 <= x - (ox * stride - pad) < kernel:
                n += 1
    return n


def test_op_counts_match_enumeration():
    model = build_model(SMALL)
    x = np.zeros((5, 2, 32, 32), np.float32)
    x[0, 0, 7, 9] = 2.0                                 # one graded input in step 0
    _flow, counts = count_ops(model, x)
    enc1 = counts["layers"][0]
    spec = layer_specs(SMALL)[0]
    assert enc1["event_ops"] == _reach_brute(32, 32, 7, 9, 3, 2, 1) * spec.c_out
    assert enc1["dense_macs"] == 5 * 16 * 16 * 2 * 8 * 9
    for row in counts["layers"]:
        assert row["event_ops"] <= row["dense_macs"]
    t = counts["totals"]
    assert t["dense_macs"] == sum(r["dense_macs"] for r in counts["layers"])
    dense, event = host_ops(counts)
    assert dense.mac_fp32 > t["dense_macs"] and event.energy_j() < dense.energy_j()


def test_pixel_flow_assigns_objects_and_noise():
    truths = [ObjectTruth(0, 20.0, 20.0, 0.0, 10.0, 2, 4.0, 5.0),
              ObjectTruth(1, 60.0, 20.0, math.pi / 2, 10.0, 1, 1.0, 5.0)]
    radii = {0: (8.0, 5.0), 1: (8.0, 5.0)}
    xs = np.array([27, 60, 100])
    ys = np.array([20, 27, 40])
    flow, owner = pixel_flow(xs, ys, truths, radii, 500)
    assert owner.tolist() == [0, 1, -1]
    np.testing.assert_allclose(flow[0], [4.0, 0.0], atol=1e-6)
    np.testing.assert_allclose(flow[1], [0.0, 1.0], atol=1e-6)
    np.testing.assert_allclose(flow[2], [0.0, 0.0])
    mask = np.zeros((48, 128), bool)
    mask[20, 27] = True
    f, o = dense_flow(mask, truths, radii, 500)
    assert o[20, 27] == 0 and o[0, 0] == -2 and f[0, 20, 27] == pytest.approx(4.0)
    assert object_radii_px({"appearance": {"objects": [{"size_px": 44.0, "depth_m": 5.0}]}}) == {0: (22.0, 5.0)}


def test_flow_objects_two_blobs():
    config = ToffeConfig(sensor_size=(96, 64))
    flow = np.zeros((2, 64, 96), np.float32)
    mask = np.zeros((64, 96), bool)
    mask[10:20, 10:20] = True
    flow[:, 10:20, 10:20] = np.array([3.0, 0.0])[:, None, None]        # bin 2, along +x
    mask[40:50, 60:70] = True
    flow[:, 40:50, 60:70] = np.array([0.0, -12.0])[:, None, None]      # bin 4, up
    mask[5, 90] = True                                                 # a lone still pixel: no object
    objs = sorted(flow_objects(flow, mask, config), key=lambda o: o.x)
    assert len(objs) == 2
    assert (objs[0].x, objs[0].y) == pytest.approx((14.5, 14.5))
    assert objs[1].direction_rad == pytest.approx(-math.pi / 2)
    preds = to_predictions(objs, config)
    assert [p.stage for p in preds] == [config.speed_bin_of_px_ms(3.0), 4]
    assert preds[1].speed_px_ms == pytest.approx(12.0)


def test_save_load_roundtrip(tmp_path):
    model = build_model(SMALL)
    save_baseline(tmp_path / "b", model, SMALL)
    base = AdaptiveSpikeNetBaseline.load(tmp_path / "b", ToffeConfig(sensor_size=(64, 48)))
    binned, _c = moving_disc_window(sensor=(64, 48), centre=(30.0, 24.0))
    np.testing.assert_array_equal(base.net_flow(binned), AdaptiveSpikeNetBaseline(model, SMALL, base.config)
                                  .net_flow(binned))
    pytest.importorskip("onnxruntime")
    np.testing.assert_allclose(base.optimised().net_flow(binned), base.net_flow(binned), atol=1e-4)
    (tmp_path / "b" / "weights.safetensors").write_bytes(b"not a safetensors file")
    with pytest.raises(InputError):
        AdaptiveSpikeNetBaseline.load(tmp_path / "b", base.config)
    with pytest.raises(InputError):
        AdaptiveSpikeNetBaseline.load(tmp_path / "missing", base.config)


def test_a_deeply_nested_config_is_one_line(tmp_path):
    """config.json nested deeper than the parser's stack raised RecursionError, not InputError."""
    (tmp_path / "config.json").write_text("[" * 3000 + "]" * 3000)
    (tmp_path / "weights.safetensors").write_bytes(b"x")
    with pytest.raises(InputError, match="config.json: not readable JSON"):
        AdaptiveSpikeNetBaseline.load(tmp_path, ToffeConfig(sensor_size=(64, 48)))


@pytest.mark.skipif(not (SHIPPED / "weights.safetensors").exists(), reason="no shipped baseline weights")
def test_shipped_weights_detect_moving_disc():
    meta = json.loads((SHIPPED / "config.json").read_text())
    assert meta["format"] == "toffe-asnet-baseline"
    config = dataclasses.replace(ToffeConfig(), sensor_size=(128, 96))
    base = AdaptiveSpikeNetBaseline.load(SHIPPED, config)
    binned, (cx, cy) = moving_disc_window(sensor=(128, 96), centre=(60.0, 48.0), radius=16.0, u_px_ms=8.0)
    preds = base.detect_binned(binned)
    assert preds, "the shipped model finds no object on a moving disc"
    best = min(preds, key=lambda p: math.hypot(p.x - cx, p.y - cy))
    assert math.hypot(best.x - cx, best.y - cy) < 10.0
    assert abs(math.remainder(best.direction_rad, 2 * math.pi)) < math.radians(45)
