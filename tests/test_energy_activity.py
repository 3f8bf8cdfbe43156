"""Operation counting replays the real arithmetic: its cascade is bit-exact with the reference."""
from __future__ import annotations

import numpy as np
import pytest

from toffe_deploy.baselines.dotie import dotie_separate
from toffe_deploy.cascade import run_cascade
from toffe_deploy.config import ToffeConfig
from toffe_deploy.energy.activity import count_dotie, count_toffe
from toffe_deploy.fixed_point import quantize_ofs, run_ofs_fixed


def _params(n=4):
    w = np.full((1, 2, 3, 3), 0.15)
    w[..., 1, 1] = 0.2
    return [quantize_ofs(w, 1.0 + 0.5 * k, 0.3) for k in range(n)]


def _window(rng, shape=(5, 2, 24, 32)):
    b = (rng.random(shape) < 0.04).astype(np.uint16)
    b[:, :, 4:10, 4:10] = 1
    return b


def test_counted_cascade_equals_reference_and_counts_are_consistent(rng):
    cfg = ToffeConfig(sensor_size=(32, 24))
    params = _params()
    x = _window(rng)
    res, mc = count_toffe(x, params, cfg, ofpd_macs=1000, ofpd_in_elems=10)
    ref = run_cascade(x, lambda k, inp: run_ofs_fixed(inp, params[k - 1]), 4, cfg.mask_kernel)
    for k in range(4):
        assert np.array_equal(res.spikes[k], ref.spikes[k]) and np.array_equal(res.frames[k], ref.frames[k])
        act = mc.loihi[k]
        assert act.steps == 5 and sum(act.spikes) == int(res.spikes[k].sum())
        # every synop comes from an input spike of stage k reaching at most 9 neurons
        assert sum(act.synops) <= 9 * int(res.inputs[k].sum())
        assert all(a >= s for a, s in zip(act.active, act.spikes))
    assert mc.host_all.mac_fp32 == 1000 * mc.extra["ofpd_calls"]
    assert mc.host_all.energy_j() > mc.host_hybrid.energy_j() > 0


def test_dotie_counts_neighbour_pairs_and_both_variants(rng):
    x = _window(rng)
    plain, clus, window, spikes = count_dotie(x)
    assert spikes.shape == (5, 24, 32)
    # DBSCAN runs once per step on that step's separated pixels, only where there are >= 10
    _s, out = dotie_separate(x)
    per_step = out.reshape(5, -1).sum(axis=1)
    assert clus.extra["dbscan_runs"] == int((per_step >= 10).sum()) >= 2
    assert clus.extra["dbscan_points"] == int(per_step[per_step >= 10].sum()) > 0
    assert plain.extra["separated_px"] == int(per_step.sum())
    assert window.extra["dbscan_runs"] == 1 and window.extra["dbscan_points"] == int(out.any(axis=0).sum())
    assert clus.extra["dbscan_neighbour_pairs"] >= clus.extra["dbscan_points"]   # each point is its own neighbour
    assert clus.host_all.energy_j() > plain.host_all.energy_j()
    assert plain.loihi[0].n_neurons == 24 * 32 and plain.loihi[0] is clus.loihi[0]


def test_the_host_part_left_beside_loihi_is_counted_alike_for_both_models():
    """With the spiking layers on Loihi 2, what stays on the host is priced by one rule for TOFFE
    and DOTIE: the event-driven rule without the layers (until 2026-11-30 DOTIE's recovery was
    priced over whole frames, TOFFE's masks over its events). The same events on a 16x larger
    sensor cost both models the same host operations (the blob lies far enough from the borders
    that no morphology box is clipped: DOTIE's reaches 48 px beyond its spikes)."""
    from toffe_deploy.energy import rules

    small = np.zeros((5, 2, 96, 128), np.uint16)
    small[:, 1, 44:52, 60:68] = 3
    big = np.zeros((5, 2, 384, 512), np.uint16)
    big[:, :, :96, :128] = small
    by_size = []
    for x in (small, big):
        h, w = x.shape[-2:]
        _r, toffe = count_toffe(x, _params(), ToffeConfig(sensor_size=(w, h)), ofpd_macs=100, ofpd_in_elems=10)
        plain, clus, _win, spikes = count_dotie(x)
        assert spikes.any()                                # DOTIE's layer fired: there is a recovery to count
        for mc in (toffe, plain, clus):
            assert mc.host_hybrid == rules.host_part(mc.work)
        assert clus.host_hybrid.energy_j() > plain.host_hybrid.energy_j()       # its listing and DBSCAN
        by_size.append((toffe.host_hybrid.energy_j(), clus.host_hybrid.energy_j()))
    assert by_size[0] == pytest.approx(by_size[1])


def test_toffe_input_cost_follows_the_events_not_the_sensor():
    # the cpu target builds its window from the events: the same events on a 16x larger
    # sensor cost the same host operations outside the cascade's own (sensor-independent) work
    params = _params()
    small = np.zeros((5, 2, 24, 32), np.uint16)
    small[:, 1, 4:10, 4:10] = 1
    big = np.zeros((5, 2, 96, 128), np.uint16)
    big[:, 1, 4:10, 4:10] = 1
    _r, a = count_toffe(small, params, ToffeConfig(sensor_size=(32, 24)), ofpd_macs=0, ofpd_in_elems=0)
    _r, b = count_toffe(big, params, ToffeConfig(sensor_size=(128, 96)), ofpd_macs=0, ofpd_in_elems=0)
    assert a.host_all.sram_bytes == b.host_all.sram_bytes and a.host_all.add_int32 == b.host_all.add_int32


def test_toffe_is_counted_on_its_raw_window_with_front_end_and_plane_fit(rng):
    """Like for like with DOTIE, whose count frames are counted on every event: TOFFE's binning
    on every event of the raw window (not on what its front end keeps), its front end, and the
    plane fit and outline bounds of the objects it reports."""
    from types import SimpleNamespace

    from toffe_deploy.energy.activity import front_end_ops, plane_fit_ops

    cfg = ToffeConfig(sensor_size=(32, 24), input_support=(4, 2, 5, 2),
                      ofpd={"plane_fit_history": [10, 20, 3], "outline_centre": [10, 4, 1.0, 0.1]})
    params = _params()
    raw = _window(rng)
    kept = raw.copy()
    kept[:, :, 12:, :] = 0                                 # what a front end could drop
    _r, bare = count_toffe(kept, params, cfg, ofpd_macs=0, ofpd_in_elems=0)
    objs = [SimpleNamespace(n_events=40, speed_px_s=300.0), SimpleNamespace(n_events=40, speed_px_s=9000.0)]
    _r, full = count_toffe(kept, params, cfg, ofpd_macs=0, ofpd_in_elems=0, raw=raw, objects=objs)
    assert full.extra["raw_events"] == int(raw.sum()) > bare.extra["raw_events"] == int(kept.sum())
    assert full.work.input_events == int(raw.sum())
    pixels = int(np.count_nonzero((raw > 0).any(axis=(0, 1))))
    fe = front_end_ops(int(np.count_nonzero(raw)), pixels, 2)
    pf = plane_fit_ops([40, 40], [20, 1], True)            # 10 px at 0.15 px/window: K_max; at 4.5: 3 windows
    assert pf.add_fp32 > plane_fit_ops([40, 40], [3, 1], True).add_fp32 > plane_fit_ops([40, 40], [3, 1], False).add_fp32
    extra = full.host_hybrid.energy_j() - bare.host_hybrid.energy_j()          # the host's own work on Loihi too
    assert extra >= fe.energy_j() > 0 and full.host_all.energy_j() > bare.host_all.energy_j() + extra * 0.99


def test_dotie_count_names_the_events_it_counted(rng):
    raw = _window(rng)
    plain, cl, _w, _s = count_dotie(raw)
    assert plain.extra["raw_events"] == cl.extra["raw_events"] == int(raw.sum()) == plain.work.input_events


def test_both_models_list_frame_pixels_by_the_same_rule(rng):
    """DOTIE's clustering lists its separated pixels and TOFFE's grouping its stage frames'
    pixels, by the rules' scan term alike: per listed pixel by the event-driven rule, per frame
    pixel by the dense one. DOTIE's listing was a full-frame scan by both rules (2 uJ of its 6
    by the event rule on 640x480), and TOFFE's grouping was not counted at all."""
    from toffe_deploy.energy.activity import grouping_ops
    from toffe_deploy.energy.rules import dense, event_driven

    x = np.zeros((5, 2, 96, 128), np.uint16)               # events well inside (morphology's reach)
    x[:, :, 36:60, 48:80] = _window(rng)
    _plain, clus, _w, _s = count_dotie(x)
    _sp, out = dotie_separate(x)
    assert clus.work.scan_event == out.sum() > 0 and clus.work.scan_dense == out.size
    big = np.zeros((5, 2, 192, 256), np.uint16)            # the same events on a 4x larger sensor
    big[:, :, 36:132, 48:176] = x
    _p, clus_big, _w, _s = count_dotie(big)
    assert event_driven(clus_big.work) == event_driven(clus.work)                # the event rule: the events'
    assert dense(clus_big.work).energy_j() > 3 * dense(clus.work).energy_j()       # the dense one: the frames'
    x = _window(rng)
    cfg = ToffeConfig(sensor_size=(32, 24))
    res, mc = count_toffe(x, _params(), cfg, ofpd_macs=0, ofpd_in_elems=0)
    stage_px = sum(int(np.asarray(f).any(axis=0).sum()) for f in res.frames)
    assert mc.work.scan_event == stage_px > 0 and mc.work.scan_dense == 4 * 24 * 32
    ones = sum(int(np.count_nonzero(f)) for f in res.frames)
    g = grouping_ops(stage_px, ones)
    assert mc.host_hybrid.add_int32 >= g.add_int32 > 0 and mc.work.post.mul_int32 >= g.mul_int32 > 0


def test_faint_objects_rule_is_counted_as_the_hosts_work(rng):
    """ofpd.faint_objects' density and search run on the host on every target: counted (as an
    upper bound, faint_ops) when the config has the rule, and only then."""
    from toffe_deploy.energy.activity import faint_ops

    base = dict(sensor_size=(32, 24), input_support=(4, 2, 5, 2))
    raw = _window(rng)
    counts = {}
    for on in (False, True):
        cfg = ToffeConfig(**base, ofpd={"faint_objects": [20, 7]} if on else {})
        _r, counts[on] = count_toffe(raw, _params(), cfg, ofpd_macs=0, ofpd_in_elems=0, raw=raw)
    pixels = int(np.count_nonzero((raw > 0).any(axis=(0, 1))))
    f = faint_ops(pixels, 24, 32)
    assert f.add_int32 > 6 * 3 * pixels > 0
    gap = counts[True].host_hybrid.energy_j() - counts[False].host_hybrid.energy_j()
    assert gap == pytest.approx(f.energy_j())
