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
