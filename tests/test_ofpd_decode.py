"""ofpd_io.decode: where the reported speed bin comes from (ofpd.bin_from)."""
import numpy as np
import pytest

from toffe_deploy import ofpd_io
from toffe_deploy.config import ToffeConfig


def _decode(bin_from, speeds_px_ms, stage):
    cfg = ToffeConfig(ofpd={**ofpd_io.CURRENT_LAYOUT, "bin_from": bin_from})
    n = len(speeds_px_ms)
    return ofpd_io.decode(np.zeros((n, 2)), np.tile([1.0, 0.0], (n, 1)), np.log(speeds_px_ms), np.full(n, stage), cfg), cfg


def test_bin_from_ofpd_reports_the_bin_of_the_measured_speed():
    cfg = ToffeConfig()
    edges = [lo for lo, _hi in cfg.speed_bins_px_ms]                  # lower edges of bins 1..4
    speeds = [edges[0] * 0.5, edges[1] * 0.99, edges[1], edges[2] * 1.01, edges[3] * 1.2, 1e3]
    d, _ = _decode("ofpd", speeds, stage=1)
    assert d["speed_bin"].tolist() == [1, 1, 2, 3, 4, 4]
    assert d["speed_px_ms"][0] == pytest.approx(edges[0])             # clipped to the bins' overall range
    assert d["speed_px_ms"][-1] == pytest.approx(ofpd_io.MAX_SPEED_PX_MS)
    assert d["speed_px_ms"][3] == pytest.approx(speeds[3])            # not clipped into stage 1's bin
    assert np.allclose(d["speed_bin_mps"], np.asarray(cfg.representative_speeds)[d["speed_bin"] - 1])


def test_bin_from_ofs_keeps_the_stage_and_clips_into_it():
    cfg = ToffeConfig()
    lo, hi = cfg.speed_bins_px_ms[1]
    d, _ = _decode("ofs", [lo * 0.5, (lo + hi) / 2, hi * 3], stage=2)
    assert d["speed_bin"].tolist() == [2, 2, 2]
    assert d["speed_px_ms"].tolist() == pytest.approx([lo, (lo + hi) / 2, hi])


def test_bin_from_ofpd_needs_px_ms_and_old_configs_keep_the_ofs_bin():
    with pytest.raises(ValueError, match="bin_from"):
        ofpd_io.ofpd_settings(ToffeConfig(ofpd={**ofpd_io.CURRENT_LAYOUT, "speed_unit": "mps"}))
    old = ToffeConfig(ofpd={"grouping": "blobs", "crop": "scaled", "speed_unit": "px_ms"})
    assert ofpd_io.ofpd_settings(old)["bin_from"] == "ofs"
    assert ofpd_io.ofpd_settings(ToffeConfig())["bin_from"] == "ofpd"


def _numpy_decode(pose, direction, speed, k, cfg):
    """decode's definition in whole-array numpy (its implementation before Decoder.columns)."""
    s = ofpd_io.ofpd_settings(cfg)
    pose, direction = np.asarray(pose, np.float64), np.asarray(direction, np.float64)
    reg = np.exp(np.clip(np.asarray(speed, np.float64).reshape(-1), -10.0, 10.0))
    f = cfg.speed_scale.px_ms_per_mps
    if s["speed_unit"] == "mps":
        b = ofpd_io.speed_bounds(cfg)[k - 1]
        v_mps = np.clip(reg, b[:, 0], b[:, 1])
        v_px, clipped = v_mps * f, v_mps != reg
    else:
        edges = ofpd_io.speed_bounds_px_ms(cfg)
        if s["bin_from"] == "ofpd":
            v_px = np.clip(reg, edges[0, 0], edges[-1, 1])
            k = np.searchsorted(edges[1:, 0], v_px, side="right") + 1
        else:
            v_px = np.clip(reg, edges[k - 1, 0], edges[k - 1, 1])
        v_mps, clipped = v_px / f, v_px != reg
    return {"x_px": pose[:, 0], "y_px": pose[:, 1], "direction_rad": np.arctan2(direction[:, 1], direction[:, 0]),
            "speed_px_ms": v_px, "speed_mps": v_mps, "speed_bin": k, "speed_clipped": clipped,
            "speed_bin_mps": np.asarray(cfg.representative_speeds, np.float64)[k - 1]}


@pytest.mark.parametrize("layout", [{"bin_from": "ofpd"}, {"bin_from": "ofs"}, {"bin_from": "ofs", "speed_unit": "mps"}])
def test_decoder_rows_are_the_whole_array_definition_bit_for_bit(layout):
    """Decoder.columns clips, bins and scales per row in Python floats: the same IEEE results as
    the numpy arrays, NaN, bin edges and values beyond the clip range included."""
    cfg = ToffeConfig(ofpd={**ofpd_io.CURRENT_LAYOUT, **layout})
    rng = np.random.default_rng(3)
    edges = np.asarray(cfg.speed_bins_px_ms if layout.get("speed_unit") != "mps" else cfg.speed_bins, np.float64)
    speed = np.concatenate([rng.normal(0.0, 4.0, 200), np.log(edges.ravel()[np.isfinite(edges.ravel())]),
                            [np.nan, 30.0, -30.0, np.inf, -np.inf]]).astype(np.float32)
    n = speed.size
    pose = rng.normal(300.0, 100.0, (n, 2)).astype(np.float32)
    direction = rng.normal(0.0, 1.0, (n, 2)).astype(np.float32)
    k = rng.integers(1, cfg.n_speed_bins + 1, n)
    want = _numpy_decode(pose, direction, speed, k, cfg)
    dec = ofpd_io.Decoder(cfg)
    got, cols = dec(pose, direction, speed, k), dec.columns(pose, direction, speed, k)
    for key, a in want.items():
        assert got[key].dtype == a.dtype, key
        np.testing.assert_array_equal(got[key], a, err_msg=key)      # NaN == NaN here, values bit for bit
        assert np.asarray(cols[key], a.dtype).tobytes() == a.tobytes(), key
    empty = dec(np.zeros((0, 2), np.float32), np.zeros((0, 2), np.float32), np.zeros((0, 1), np.float32), np.zeros(0, int))
    assert all(v.shape == (0,) and v.dtype == want[key].dtype for key, v in empty.items())
    with pytest.raises(ValueError, match="stage_k"):
        dec(pose[:1], direction[:1], speed[:1], [cfg.n_speed_bins + 1])
    # positions of any dtype come back as Python floats (float32 ones read as they are)
    for p in (pose[:3].astype(np.float64), np.round(pose[:3]).astype(np.int32)):
        c = dec.columns(p, direction[:3], speed[:3], k[:3])
        assert [type(v) for v in c["x_px"] + c["y_px"]] == [float] * 6
        assert c["x_px"] == p[:, 0].astype(np.float64).tolist() and c["y_px"] == p[:, 1].astype(np.float64).tolist()
