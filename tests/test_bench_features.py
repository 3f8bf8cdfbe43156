"""benchmarks/bench_features.py at tiny size: a real bundle with the shipped checkpoint's host
features on, a generated recording, every variant through the real cpu Pipeline."""
from __future__ import annotations

import dataclasses
import importlib.util
import json
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
BENCH = ROOT / "benchmarks"


def _load():
    if str(BENCH) not in sys.path:
        sys.path.insert(0, str(BENCH))
    spec = importlib.util.spec_from_file_location("bench_features_t", BENCH / "bench_features.py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod
    spec.loader.exec_module(mod)
    return mod


@pytest.fixture(scope="module")
def shipped_tiny(tmp_path_factory, make_bundle, make_recording):
    """(bundle, recording): the shipped ckpt/'s settings (faint objects, plane fit over the windows
    before, outline positions, temporal support, pooled OFS) on a 64x48 sensor."""
    tmp = tmp_path_factory.mktemp("features")
    shipped = json.loads((ROOT / "ckpt" / "config.json").read_text())
    ofpd = dict(shipped["ofpd"], crop_px=32, pool=2, min_events=4)
    extra = {k: shipped[k] for k in ("input_norm", "input_min_cluster", "input_support")}
    bundle = make_bundle(tmp, ofs_pool=2, ofpd=ofpd, reset=shipped["reset"], **extra)
    return bundle, make_recording(tmp / "rec.h5", duration=0.02)


def test_each_switch_turns_its_feature_off_in_the_pipeline(shipped_tiny):
    mod = _load()                                  # puts benchmarks/ on sys.path
    from _args import apply_overrides

    from toffe_deploy.runtime.pipeline import Pipeline

    bundle, _rec = shipped_tiny

    def pipeline(name):
        overrides, track = mod.variant(name)
        cfg = apply_overrides(bundle.config, list(overrides.items()), [])
        return Pipeline(dataclasses.replace(bundle, config=cfg), "cpu", track=track)

    no_faint = pipeline("faint")
    base = Pipeline(bundle, "cpu")
    assert base.faint is not None and base.ones_history is not None and base._outline is not None
    assert base.tracker is not None and base._fusion.on
    assert no_faint.faint is None and no_faint.ones_history is not None and no_faint._outline is not None
    assert pipeline("outline")._outline is None and pipeline("outline").ones_history is not None
    hist = pipeline("history")
    assert hist.ones_history is None and hist._outline is None and hist._fusion.on     # the one-window fit
    assert not pipeline("plane_fit")._fusion.on
    assert pipeline("tracking").tracker is None and pipeline("tracking").faint is not None
    everything = pipeline("all")
    assert (everything.faint, everything.ones_history, everything._outline, everything.tracker) == (None,) * 4
    assert not everything._fusion.on


def test_the_order_rotates_so_that_each_variant_holds_each_position_equally_often():
    mod = _load()
    names = ["default", "faint", "history", "all"]
    seen = {n: [0] * len(names) for n in names}
    for window in range(2 * len(names)):
        order = mod.rotation(names, window)
        assert sorted(order) == sorted(names)
        for pos, n in enumerate(order):
            seen[n][pos] += 1
    assert all(counts == [2] * len(names) for counts in seen.values()), seen


def test_it_times_every_variant_and_skips_a_switch_that_changes_nothing(shipped_tiny, tmp_path, make_bundle,
                                                                         capsys):
    import os

    mod = _load()
    bundle, rec = shipped_tiny
    affinity = os.sched_getaffinity(0)
    core = str(min(affinity))
    assert mod.main(["--bundle", str(bundle.root), "--events", str(rec), "--repeats", "2", "--core", core,
                     "--features", "faint,all,faint"]) == 0
    assert os.sched_getaffinity(0) == affinity                    # the caller is not left pinned
    out = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    v = out["variants"]
    assert list(v) == ["default", "faint", "all"] and out["skipped"] == []   # default first, a name once
    assert out["repeats"] == 2 and out["recording_windows"] == 40
    assert v["default"]["ratio"] == 1.0 and v["default"]["ratio_passes"] == [1.0, 1.0]
    for row in v.values():
        assert row["p50_us"] > 0 and row["mean_us"] > 0 and row["windows_per_s_cpu_time"] > 0
    assert v["all"]["tracker"] is False and v["faint"]["ofpd_off"] == {"faint_objects": None}
    assert set(v["all"]["ofpd_off"]) == {"faint_objects", "outline_centre", "plane_fit_history", "plane_fit_refits",
                                         "plane_fit_weight", "plane_fit_dir_weight"}
    assert v["default"]["objects"] > 0                          # real windows with objects were timed

    # a bundle without the faint objects and the outline positions: those switches are not timed as "free"
    ofpd = {k: val for k, val in bundle.config.ofpd.items() if k not in ("faint_objects", "outline_centre")}
    plain = make_bundle(tmp_path, ofs_pool=2, ofpd=ofpd, reset=bundle.config.reset,
                        **{k: getattr(bundle.config, k) for k in ("input_norm", "input_min_cluster", "input_support")})
    assert mod.main(["--bundle", str(plain.root), "--events", str(rec), "--repeats", "1", "--core", core,
                     "--features", "faint,outline,history"]) == 0
    out = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert out["skipped"] == ["faint", "outline"] and list(out["variants"]) == ["default", "history"]


def test_the_history_switches_turn_off_the_refits_that_need_the_history(shipped_tiny, tmp_path, make_bundle):
    """A bundle with ofpd.plane_fit_refits (valid only with plane_fit_history): the history and
    plane-fit switches still make a valid config (before, the whole run stopped on it)."""
    mod = _load()
    from _args import apply_overrides

    bundle, _rec = shipped_tiny
    refits = make_bundle(tmp_path, ofs_pool=2, ofpd={**bundle.config.ofpd, "plane_fit_refits": 1},
                         reset=bundle.config.reset,
                         **{k: getattr(bundle.config, k) for k in ("input_norm", "input_min_cluster", "input_support")})
    for name in ("history", "plane_fit", "all"):
        cfg = apply_overrides(refits.config, list(mod.variant(name)[0].items()), [])
        assert cfg.ofpd["plane_fit_refits"] == 0 and cfg.ofpd["plane_fit_history"] is None
