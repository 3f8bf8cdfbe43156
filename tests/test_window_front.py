"""runtime/window_front.py: the cpu pipeline's steps before the OFPD in one compiled call give the
same bits as the step-by-step path (Pipeline.front, then Pipeline.batch), window by window."""
import copy
import json
from pathlib import Path

import numpy as np
import pytest

from toffe_deploy.events.io import open_events
from toffe_deploy.ofpd_io import recent_args
from toffe_deploy.runtime.pipeline import Pipeline
from toffe_deploy.runtime.spikes import SpikeVolume

ROOT = Path(__file__).resolve().parent.parent


def _shipped_bundle(tmp_path, make_bundle, support=True):
    """A tiny bundle with the shipped checkpoint's front end and grouping (temporal support,
    recent events, the plane fit's windows before), OFS grid pooled 2 x 2."""
    shipped = json.loads((ROOT / "ckpt" / "config.json").read_text())
    ofpd = dict(shipped["ofpd"], crop_px=32, pool=2, min_events=4)
    extra = {k: shipped[k] for k in ("input_norm", "input_min_cluster")}
    if support:
        extra["input_support"] = shipped["input_support"]
    else:
        ofpd.pop("recent_events")
        ofpd.pop("faint_objects")
    return make_bundle(tmp_path, ofs_pool=2, ofpd=ofpd, **extra)


def _windows(bundle, rec):
    """The recording's windows, then: a gap of 3 whole windows, an empty window, a jump back in
    time (the histories start afresh) and the first windows again."""
    cfg = bundle.config
    with open_events(rec) as src:
        wins = [(t0, SpikeVolume.from_events(ev, t0, cfg.dt_us, cfg.n_bins, cfg.sensor_size))
                for t0, ev in src.iter_windows(cfg.dt_us)]
    shape = wins[0][1].shape
    last = wins[-1][0]
    empty = (last + 5 * cfg.dt_us, SpikeVolume(np.zeros(0, np.int64), shape))
    gap = [(last + 4 * cfg.dt_us, wins[3][1])]
    return wins + gap + [empty] + wins[:6]


def test_window_front_gives_the_step_by_step_paths_bits(tmp_path, make_bundle, make_recording):
    b = _shipped_bundle(tmp_path, make_bundle)
    wins = _windows(b, make_recording(tmp_path / "rec.h5", duration=0.02))
    fused, steps = Pipeline(b, "cpu", track=False), Pipeline(b, "cpu", track=False)
    assert fused._window_front is not None
    steps._window_front = None                         # the reference: Pipeline.front, then Pipeline.batch
    n_objects = 0
    with fused, steps:
        for i, (t0, w) in enumerate(wins):
            if i % 5 == 4:           # another history handed in, as deploy/parity.py does for each window
                fused.support, steps.support = copy.deepcopy(steps.support), copy.deepcopy(steps.support)
            got = fused.front_batch(t0, SpikeVolume(w.idx, w.shape))
            want = steps.front_batch(t0, SpikeVolume(w.idx, w.shape))
            vol_g, vol_w = got[0], want[0]
            for a, e in ((vol_g.idx, vol_w.idx), (vol_g.bc, vol_w.bc), (vol_g.pix, vol_w.pix),
                         *zip(vol_g.pixel_index(), vol_w.pixel_index())):
                np.testing.assert_array_equal(a, e)
            (ks, x, n_ev, ones), (ks_w, x_w, n_ev_w, ones_w) = got[1], want[1]
            np.testing.assert_array_equal(ks, ks_w)
            assert x.dtype == x_w.dtype == np.float32 and x.tobytes() == x_w.tobytes()
            np.testing.assert_array_equal(n_ev, n_ev_w)
            for a, e in zip(ones, ones_w, strict=True):
                np.testing.assert_array_equal(a, e)
            np.testing.assert_array_equal(got[3], want[3])      # the window's event pixels (faint objects)
            # ofpd.recent_events' rule as the grouping read it: the history's total after this window
            np.testing.assert_array_equal(fused._window_front._args[-1], recent_args(steps._batch[0], steps.support)[1])
            np.testing.assert_array_equal(fused.support.counts, steps.support.counts)
            assert fused.support.total == steps.support.total == int(steps.support.counts.sum())
            assert fused.support.last_t0 == steps.support.last_t0
            n_objects += len(ks)
    assert n_objects > 0                               # real objects went through both


def test_a_stream_through_window_front_writes_the_same_lines(tmp_path, make_bundle, make_recording):
    """process_stream (tracker on) over the same windows, fast path against step by step."""
    b = _shipped_bundle(tmp_path, make_bundle)
    wins = _windows(b, make_recording(tmp_path / "rec.h5", duration=0.02))
    lines = []
    for fast in (True, False):
        pipe = Pipeline(b, "cpu")
        if not fast:
            pipe._window_front = None
        with pipe:
            lines.append([json.dumps(r.to_json(), sort_keys=True) for r in pipe.process_stream(wins)])
    assert lines[0] == lines[1]
    assert any('"objects": [{' in line for line in lines[0])


@pytest.mark.parametrize("support, keep_stages", [(False, False), (True, True)])
def test_window_front_is_only_the_fast_paths(tmp_path, make_bundle, support, keep_stages):
    """Without temporal support, or with the dense stages kept, the Pipeline runs step by step."""
    b = _shipped_bundle(tmp_path, make_bundle, support=support)
    assert Pipeline(b, "cpu", keep_stages=keep_stages)._window_front is None
