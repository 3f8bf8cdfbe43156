"""The parity checks at small size, on hand-made windows where every stage fires, and
each shown able to fail (a check that always passes proves nothing)."""
try:   # Lava sets the multiprocessing start method at import: do it before any tqdm lock exists
    import lava.magma.core.process.process  # noqa: F401
except ImportError:
    pass

import numpy as np
import pytest

from toffe_deploy.checkpoint import load_checkpoint, random_ofpd_state, save_checkpoint
from toffe_deploy.config import ToffeConfig
from toffe_deploy.dataset.groundtruth import ObjectTruth
from toffe_deploy.deploy import parity
from toffe_deploy.deploy.exporter import export_bundle
from toffe_deploy.deploy.onnx_export import build_ofpd
from toffe_deploy.deploy.windows import HeldOut

CFG = ToffeConfig(sensor_size=(48, 32), ofpd={"crop_px": 16, "pool": 2, "min_events": 4})


def moving_squares(n_windows=4, seed=0):
    """Windows with a fast and a slow 6x6 square: events on the whole square in every bin
    (80 % of its pixels, ON for one, OFF for the other), plus the truth at the window midpoint."""
    rng = np.random.default_rng(seed)
    wins, truths = [], []
    for i in range(n_windows):
        w = np.zeros((CFG.n_bins, 2, CFG.height, CFG.width), np.uint16)
        objs = []
        for oid, (x0, y0, vx, pol) in enumerate(((4 + i, 4, 2, 1), (30 - i, 20, -1, 0))):
            for b in range(CFG.n_bins):
                x = x0 + vx * b
                w[b, pol, y0:y0 + 6, x:x + 6] = rng.random((6, 6)) < 0.8
            xm = x0 + vx * (CFG.n_bins - 1) / 2 + 2.5
            objs.append(ObjectTruth(oid, xm, y0 + 2.5, 0.0 if vx > 0 else np.pi, 10.0 * abs(vx), 1))
        wins.append(w)
        truths.append(objs)
    return HeldOut(wins, [i * CFG.dt_us for i in range(n_windows)], truths, {"kind": "test"})


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    root = tmp_path_factory.mktemp("par")
    # Exactly representable stages (weights and thresholds n / 128 with max |w| = 127 / 128, so the
    # weight scale is 128; leak 0.5): the float model then computes the very numbers the integers
    # do and F1 must be 1 unless the export gets a layout, scale or reset timing wrong. The
    # kernels are asymmetric so that a flipped or transposed kernel shows.
    rng = np.random.default_rng(7)
    ofs = []
    for k in range(1, CFG.n_speed_bins + 1):
        w = rng.integers(10, 100, (1, 2, 3, 3)).astype(np.float32)
        w[0, 0, 0, 2] = 127
        w[0, 1, 2, 0] = -30
        ofs.append(dict(weight=w / 128, threshold=(100 + 120 * k) / 128, leak=0.5))
    save_checkpoint(root / "ck", CFG, ofs, random_ofpd_state(CFG, seed=3))
    ck = load_checkpoint(root / "ck")
    bundle = export_bundle(root / "ck", root / "b", checks=(), progress=False, log=None).bundle
    return ck, bundle, build_ofpd(CFG, ck.ofpd_state), moving_squares()


def test_fixed_vs_float_passes_and_every_stage_fires(setup):
    ck, bundle, _model, held = setup
    res = parity.check_fixed_vs_float(bundle, parity.float_ofs_models(ck.ofs, CFG), held, ck.ofs)
    assert res["status"] == "pass"
    for st in res["stages"]:
        assert st["float_spikes"] > 20 and st["f1"] >= 0.99


def test_fixed_vs_float_detects_a_different_model(setup):
    ck, bundle, _model, held = setup
    other = [dict(st, threshold=st["threshold"] * 1.6) for st in ck.ofs]
    res = parity.check_fixed_vs_float(bundle, parity.float_ofs_models(other, CFG), held)
    assert res["status"] == "fail" and min(s["f1"] for s in res["stages"]) < 0.99


def test_fixed_vs_float_flags_a_flipped_kernel_outside_the_quantization_band(setup):
    """A layout bug (kernel flipped, as Lava's true convolution would need) is not excused as
    quantization: its differences fall outside the band."""
    import dataclasses

    ck, bundle, _model, held = setup
    flipped = dataclasses.replace(bundle, ofs=[dataclasses.replace(p, weight=p.weight[:, :, ::-1, ::-1].copy())
                                               for p in bundle.ofs])
    res = parity.check_fixed_vs_float(flipped, parity.float_ofs_models(ck.ofs, CFG), held, ck.ofs)
    assert res["status"] == "fail"
    diff = sum(s["differing"] for s in res["stages"])
    assert diff > 0 and sum(s["differing_in_band"] for s in res["stages"]) < diff / 2
    assert min(s["f1_outside_band"] for s in res["stages"]) < 0.99


def test_lava_simulator_is_bit_exact_on_spiking_crops(setup):
    pytest.importorskip("lava.magma.core.run_configs")
    pytest.importorskip("toffe_deploy.runtime.loihi")
    _ck, bundle, _model, held = setup
    res = parity.check_lava_vs_fixed(bundle, held, n_windows=1)
    assert res["status"] == "pass", res
    assert all(s["differing"] == 0 for s in res["stages"])
    assert sum(s["spikes_reference"] for s in res["stages"]) > 50   # not a vacuous comparison


def test_netx_files_reproduce_a_reset_zero_bundle_in_lava_dl_own_network(setup, tmp_path):
    """netx/ofs_stage<k>.net loaded by lava-dl's netx.hdf5.Network with the manifest's
    reset_interval / reset_offset: 0 differing spikes for a reset-zero export of the same stages;
    the subtract bundle's files do not reproduce it (netx cannot subtract), and the check says so."""
    import dataclasses

    pytest.importorskip("lava.lib.dl.netx")
    ck, bundle, _model, held = setup
    zcfg = dataclasses.replace(CFG, reset="zero")
    save_checkpoint(tmp_path / "ck", zcfg, ck.ofs, ck.ofpd_state)
    zero = export_bundle(tmp_path / "ck", tmp_path / "b", checks=(), progress=False, log=None).bundle
    netx = zero.manifest["netx"]
    assert netx["reproduces_bundle"] is True and netx["reset_interval"] == CFG.n_bins and netx["reset_offset"] == 1
    assert all(p.reset == "zero" for p in zero.ofs)
    res = parity.check_netx_vs_fixed(zero, held, n_windows=1)
    assert res["status"] == "pass", res
    assert sum(s["spikes_reference"] for s in res["stages"]) > 50 and all(s["differing"] == 0 for s in res["stages"])
    # the float model of a zero bundle resets to zero as well (exactly representable stages: F1 1)
    flt = parity.check_fixed_vs_float(zero, parity.float_ofs_models(ck.ofs, zcfg), held, ck.ofs)
    assert flt["status"] == "pass" and min(s["f1"] for s in flt["stages"]) == 1.0
    sub = parity.check_netx_vs_fixed(bundle, held, n_windows=1)
    assert sub["status"] == "informational" and bundle.manifest["netx"]["reproduces_bundle"] is False
    assert sum(s["differing"] for s in sub["stages"]) > 0 and "does NOT reproduce" in bundle.manifest["netx"]["reset_note"]


def test_lava_crops_pick_where_the_reference_fires(setup):
    _ck, bundle, _model, held = setup
    crops = parity.lava_crops(held, bundle.ofs, 2, size=(12, 10))
    assert len(crops) == 2 and crops[0].shape == (CFG.n_bins, 2, 10, 12)
    assert all(c.sum() > 40 for c in crops)


def test_onnx_vs_torch(setup):
    ck, bundle, model, held = setup
    x = parity.ofpd_inputs(held, bundle.ofs, CFG)
    res = parity.check_onnx_vs_torch(bundle, model, x)
    assert res["status"] == "pass" and res["inputs"] >= 4
    assert max(res["max_abs_diff"].values()) < 1e-4
    wrong = build_ofpd(CFG, random_ofpd_state(CFG, seed=99))
    assert parity.check_onnx_vs_torch(bundle, wrong, x)["status"] == "fail"


def test_end_to_end_matches_float_pipeline(setup):
    ck, bundle, model, held = setup
    models = parity.float_ofs_models(ck.ofs, CFG)
    res = parity.check_end_to_end(bundle, models, model, held)
    assert res["status"] == "pass", res
    assert res["deployed_errors"]["n_matched"] > 0 and res["float_errors"]["n_matched"] > 0
    # the deployed side's predictions carry px/ms as the float side's do (its speedE_px_ms was null)
    dep, flt = parity._predictions_runtime(bundle, held), parity._predictions_float(held, models, model, CFG)
    assert any(dep) and all(np.isfinite(p.speed_px_ms) for w in dep + flt for p in w)
    assert np.isfinite(res["deployed_errors"]["speedE_px_ms"]) == np.isfinite(res["float_errors"]["speedE_px_ms"])
    assert all(v <= 0.02 for v in res["relative_difference"].values())
    assert res["agreement"]["matched"] == res["agreement"]["objects_float"] > 0


def test_run_parity_json_is_strict(setup):
    """parity.json must be strict JSON (no NaN) even when a metric is undefined."""
    import json

    ck, bundle, model, _held = setup
    empty = HeldOut([np.zeros((CFG.n_bins, 2, CFG.height, CFG.width), np.uint16)], [0], [[]], {"kind": "test"})
    out = parity.run_parity(bundle, ck, empty, checks=("fixed_vs_float", "end_to_end"), model=model, progress=False,
                            log=None)
    json.loads(json.dumps(out, allow_nan=False))
    assert out["checks"]["end_to_end"]["status"].startswith("skipped")
    assert parity.summary_lines(out)[0].startswith("parity on")


def test_scores_take_each_windows_focal_length_as_eval_does():
    """speedE of the end-to-end check with the window's focal length: the px/ms error at the
    object's true depth (metrics.FlowErrors, as eval and run); a prediction exact in px/ms
    scores 0 m/s whatever depth the bundle states; generated windows record their camera's."""
    from toffe_deploy.camera import PinholeCamera
    from toffe_deploy.deploy.windows import heldout_windows
    from toffe_deploy.metrics import Prediction

    truth = ObjectTruth(0, 10.0, 10.0, 0.0, 40.0, 2, speed_px_ms=4.0, depth_m=2.0)
    pred = Prediction(2, 10.0, 10.0, 0.0, 100.0, 20.0, 4.0)     # exact in px/ms; its m/s at another depth
    got = parity._scores([[pred]], [[truth]], [243.0])
    assert got["speedE"] == pytest.approx(0.0, abs=1e-9) and got["speedE_px_ms"] == pytest.approx(0.0, abs=1e-9)
    assert parity._scores([[pred]], [[truth]], [])["speedE"] == pytest.approx(60.0)    # unknown camera: m/s
    small = ToffeConfig(sensor_size=(96, 72))
    held = heldout_windows(small, seed=0, n_windows=2)
    f = PinholeCamera(96, 72).f                                 # the generator's 60 deg over 96 px
    assert held.source["focal_px"] == pytest.approx(f) and held.focal_px == [pytest.approx(f)] * len(held)


def test_heldout_windows_from_a_data_set(tmp_path):
    """--data DIR: windows come from the held-out 'test' sequences, with their ground truth."""
    import dataclasses

    from toffe_deploy.camera import PinholeCamera
    from toffe_deploy.dataset.splits import split_specs
    from toffe_deploy.dataset.build import build_dataset
    from toffe_deploy.deploy.windows import heldout_windows

    specs = [dataclasses.replace(s, camera=PinholeCamera(CFG.width, CFG.height))
             for s in split_specs("test", seed=0, duration_s=0.004)[:2]]
    build_dataset(tmp_path, {"test": specs}, seed=0, progress=False)
    held = heldout_windows(CFG, data=tmp_path, seed=0, n_windows=4)
    assert held.source["kind"] == "data set" and len(held.source["files"]) == 2
    assert 1 <= len(held) <= 4 and all(w.shape == (CFG.n_bins, 2, CFG.height, CFG.width) for w in held.windows)
    assert all(w.any() for w in held.windows) and all(isinstance(t, list) for t in held.truths)
    # each window keeps its file's focal length, which the end-to-end speedE needs as eval does
    # (without it export stated m/s at the bundle's depth against the truth's, ~12x eval's on DAVIS data)
    assert held.focal_px == [pytest.approx(PinholeCamera(CFG.width, CFG.height).f)] * len(held)
    other = ToffeConfig(sensor_size=(64, 48))
    with pytest.raises(Exception, match="sensor size"):
        heldout_windows(other, data=tmp_path, n_windows=2)
