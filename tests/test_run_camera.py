"""Camera-aware bundles and `run` on any sensor: a bundle exported at 64x48 runs recordings of
other sizes on cpu and loihi-sim (bit exact), --sensor-size, --depth-m / --focal-px re-express
m/s (px/s unchanged), the manifest's camera section, and bundles written before it still load.

Real parts: the tiny bundle of test_run_pipeline (quantized OFS, OFPD in ONNX, onnxruntime),
recordings from the data-set generator on disk, the Lava simulator.
"""
import json
import math

import numpy as np
import pytest

from toffe_deploy.cli import main
from toffe_deploy.camera import REFERENCE_DEPTH_M, REFERENCE_FOCAL_PX, SpeedScale, focal_px_from_hfov, speed_text
from toffe_deploy.config import ToffeConfig
from toffe_deploy.deploy.bundle import MANIFEST, load_bundle, sha256_file, write_bundle
from toffe_deploy.runtime.run_camera import resolve_camera

BUNDLE_SENSOR = (64, 48)
OTHER = (96, 72)


@pytest.fixture(scope="module")
def cam(tmp_path_factory, make_bundle, make_recording):
    root = tmp_path_factory.mktemp("cam")
    return {"root": root, "bundle": make_bundle(root, sensor=BUNDLE_SENSOR),
            "rec": make_recording(root / "rec96.h5", sensor=OTHER, duration=0.006)}


def run_cli(capsys, *argv):
    rc = main(["run", *map(str, argv), "--no-progress"])
    cap = capsys.readouterr()
    return rc, cap.out, cap.err


def _lines(path):
    """The window lines of a run (after its header)."""
    return [json.loads(s) for s in path.read_text().splitlines()[1:]]


def _objects(path):
    return [o for ln in _lines(path) for o in ln["objects"]]


def test_other_sensor_runs_bit_exact_on_cpu_and_loihi_sim(cam, capsys, tmp_path):
    pytest.importorskip("lava")
    out = {}
    for target in ("cpu", "loihi-sim"):
        rc, out_text, err = run_cli(capsys, cam["bundle"].root, "--target", target, "--events", cam["rec"],
                                    "--max-windows", "6", "--out", tmp_path / f"{target}.jsonl")
        assert rc == 0, err
        assert "camera: 96x72 sensor (the recording's)" in out_text
        out[target] = _lines(tmp_path / f"{target}.jsonl")
    assert out["cpu"] == out["loihi-sim"]
    assert _objects(tmp_path / "cpu.jsonl")          # the comparison covered real objects


def test_smaller_sensor_runs_and_events_outside_the_sensor_are_an_error(cam, capsys, tmp_path, make_recording):
    rec = make_recording(tmp_path / "rec32.h5", sensor=(32, 24), duration=0.002)
    rc, out, err = run_cli(capsys, cam["bundle"].root, "--events", rec, "--out", tmp_path / "s.jsonl")
    assert rc == 0, err
    assert len(_lines(tmp_path / "s.jsonl")) == 4 and "camera: 32x24 sensor" in out
    rc, out, err = run_cli(capsys, cam["bundle"].root, "--events", cam["rec"], "--sensor-size", "40x30")
    assert rc == 2 and out == "" and err.count("\n") == 1
    assert err.startswith(f"toffe-deploy: error: {cam['rec']}") and "40x30" in err


def test_sensor_size_for_a_sensorless_npy(cam, capsys, tmp_path):
    from toffe_deploy.events.io import read_events

    ev = read_events(cam["rec"]).events
    npy = tmp_path / "plain.npy"
    np.save(npy, np.stack([ev["x"], ev["y"], ev["t"], ev["p"]], axis=1).astype(np.int64))
    args = ("--start-us", "0", "--max-windows", "6")
    rc, _, err = run_cli(capsys, cam["bundle"].root, "--events", cam["rec"], *args, "--out", tmp_path / "h5.jsonl")
    assert rc == 0, err
    rc, out, err = run_cli(capsys, cam["bundle"].root, "--events", npy, "--sensor-size", "96x72", *args,
                           "--out", tmp_path / "npy.jsonl")
    assert rc == 0, err
    assert "camera: 96x72 sensor (--sensor-size)" in out
    assert _lines(tmp_path / "npy.jsonl") == _lines(tmp_path / "h5.jsonl")
    rc, out, _ = run_cli(capsys, cam["bundle"].root, "--events", npy, *args, "--out", tmp_path / "inf.jsonl")
    assert rc == 0 and "inferred from the largest event coordinates: pass --sensor-size" in out


def test_depth_doubles_mps_and_leaves_px_s(cam, capsys, tmp_path):
    runs = {}
    for depth in ("5", "10"):
        summ = tmp_path / f"d{depth}.json"
        rc, _, err = run_cli(capsys, cam["bundle"].root, "--events", cam["rec"], "--depth-m", depth,
                             "--out", tmp_path / f"d{depth}.jsonl", "--summary-json", summ)
        assert rc == 0, err
        runs[depth] = (_objects(tmp_path / f"d{depth}.jsonl"), json.loads(summ.read_text())["camera"])
    (near, cam5), (far, cam10) = runs["5"], runs["10"]
    assert near and len(near) == len(far)
    assert [o["speed_px_s"] for o in near] == [o["speed_px_s"] for o in far]
    for a, b in zip(near, far):
        assert b["speed_mps"] == pytest.approx(2 * a["speed_mps"], rel=1e-4, abs=2e-4)
        assert b["speed_bin_mps"] == pytest.approx(2 * a["speed_bin_mps"], rel=1e-4, abs=2e-4)
    assert cam5["depth_m"] == 5 and cam10["depth_m"] == 10 and cam10["depth_from"] == "--depth-m"
    # 96 px wide vs the bundle's 64: the bundle's field of view over the recording's width
    f = REFERENCE_FOCAL_PX * OTHER[0] / BUNDLE_SENSOR[0]
    assert cam5["focal_px"] == pytest.approx(f) and "horizontal FoV over 96 px" in cam5["focal_from"]
    scale = SpeedScale(f, 5.0)
    for o in near:                            # px/s and m/s are one speed through the run's scale
        assert o["speed_px_s"] / 1000 == pytest.approx(scale.to_px_ms(o["speed_mps"]), rel=1e-3, abs=1e-3)
    assert cam5["speed_bins_mps"][0][0] == pytest.approx(scale.to_mps(cam5["speed_bins_px_ms"][0][0]))


def test_focal_and_hfov_options(cam, capsys, tmp_path):
    summ = tmp_path / "s.json"
    rc, _, err = run_cli(capsys, cam["bundle"].root, "--events", cam["rec"], "--max-windows", "2",
                         "--focal-px", "200", "--out", tmp_path / "a.jsonl", "--summary-json", summ)
    assert rc == 0, err
    assert json.loads(summ.read_text())["camera"]["focal_px"] == 200
    rc, _, err = run_cli(capsys, cam["bundle"].root, "--events", cam["rec"], "--max-windows", "2",
                         "--hfov-deg", "90", "--out", tmp_path / "a.jsonl", "--summary-json", summ)
    assert rc == 0, err
    assert json.loads(summ.read_text())["camera"]["focal_px"] == pytest.approx(48.0)
    for bad in (("--depth-m", "0"), ("--focal-px", "-3"), ("--hfov-deg", "180")):
        rc, out, err = run_cli(capsys, cam["bundle"].root, "--events", cam["rec"], *bad)
        assert rc == 2 and out == "" and bad[0] in err and err.count("\n") == 1


def test_resolve_camera_defaults():
    cfg = ToffeConfig(sensor_size=(640, 480))
    same = resolve_camera(cfg, (640, 480))
    assert same.scale == cfg.speed_scale and same.focal_from == "the bundle's"
    davis = resolve_camera(cfg, (346, 260))               # the same 60 deg lens over 346 px
    assert davis.scale.focal_px == pytest.approx(focal_px_from_hfov(346, 60.0))
    assert resolve_camera(cfg, (346, 260), synthetic_focal_px=123.0).scale.focal_px == 123.0
    assert resolve_camera(cfg, (346, 260), focal_px=400.0, hfov_deg=10.0).scale.focal_px == 400.0
    # a sub-pixel focal length (the option's 0.01 px minimum) was written "focal 0.0 px"
    assert "focal 0.01 px" in resolve_camera(cfg, (346, 260), focal_px=0.01).describe(cfg)
    assert "focal 554.3 px" in same.describe(cfg)


def test_synthetic_spec_sensor_and_hfov(cam, capsys, tmp_path):
    summ = tmp_path / "s.json"
    rc, out, err = run_cli(capsys, cam["bundle"].root, "--synthetic", "multi:0,duration=0.002,sensor=96x72,hfov=90",
                           "--out", tmp_path / "s.jsonl", "--summary-json", summ)
    assert rc == 0, err
    c = json.loads(summ.read_text())["camera"]
    assert c["sensor_size"] == [96, 72] and c["focal_px"] == pytest.approx(48.0)
    assert c["focal_from"] == "the synthetic recording's camera" and "pixE" in out
    rc, _, err = run_cli(capsys, cam["bundle"].root, "--synthetic", "multi:0,sensor=96x72", "--sensor-size", "80x60")
    assert rc == 2 and "contradicts --sensor-size" in err and err.count("\n") == 1
    for spec in ("multi,sensor=96", "multi,hfov=0", "multi,sensor=0x5",
                 "multi,sensor=99999x10", "multi,sensor=6x6"):      # the generator's 8..4096 px a side
        rc, _, err = run_cli(capsys, cam["bundle"].root, "--synthetic", spec)
        assert rc == 2 and err.startswith("toffe-deploy: error: --synthetic") and err.count("\n") == 1


def test_malformed_sensor_size_option_is_a_usage_error(cam, capsys):
    with pytest.raises(SystemExit) as e:
        run_cli(capsys, cam["bundle"].root, "--sensor-size", "96by72")
    assert e.value.code == 2 and "sensor size" in capsys.readouterr().err


def test_manifest_records_the_camera(tmp_path):
    cfg = ToffeConfig(sensor_size=(40, 24), focal_px=300.0, depth_m=10.0, ofpd={"crop_px": 16, "pool": 2})
    from toffe_deploy.fixed_point import quantize_ofs

    ofs = [quantize_ofs(np.full((1, 2, 3, 3), 0.1), 0.5, 0.3) for _ in range(4)]
    b = write_bundle(tmp_path / "b", cfg, ofs, b"onnx")
    c = b.manifest["camera"]
    assert c["sensor_size"] == [40, 24] and c["focal_px"] == 300.0 and c["depth_m"] == 10.0
    assert c["hfov_deg"] == pytest.approx(math.degrees(2 * math.atan(20 / 300)))
    assert c["speed_bins_mps"] == [list(x) for x in cfg.speed_bins]
    assert c["speed_bins_px_ms"][1] == pytest.approx([18 * 300 / 10000, 42 * 300 / 10000])
    assert b.manifest["config_summary"]["speed_bins_px_ms"] == c["speed_bins_px_ms"]
    assert "## manifest.json `camera`" in (b.root / "README.md").read_text()


def test_bundle_without_camera_fields_loads_with_the_reference_camera(cam, capsys, tmp_path):
    import shutil

    old = tmp_path / "old"
    shutil.copytree(cam["bundle"].root, old)
    cfg = json.loads((old / "config.json").read_text())
    del cfg["focal_px"], cfg["depth_m"]
    del cfg["input_norm"]
    (old / "config.json").write_text(json.dumps(cfg))
    m = json.loads((old / MANIFEST).read_text())
    del m["camera"]
    m["config"] = cfg                      # an old export's manifest copied its config.json
    for k in ("speed_bins_px_ms", "focal_px", "depth_m"):
        del m["config_summary"][k]
    m["files"]["config.json"] = {"sha256": sha256_file(old / "config.json"), "bytes": (old / "config.json").stat().st_size}
    (old / MANIFEST).write_text(json.dumps(m))
    b = load_bundle(old)
    assert b.config.focal_px == REFERENCE_FOCAL_PX and b.config.depth_m == REFERENCE_DEPTH_M
    rc, out, err = run_cli(capsys, old, "--events", cam["rec"], "--max-windows", "2", "--out", tmp_path / "o.jsonl")
    assert rc == 0, err
    assert "focal 831.4 px (the bundle's 6.6 deg horizontal FoV over 96 px" in out and "depth 5 m (the bundle's)" in out


def test_the_summarys_speed_errors_do_not_follow_the_stated_depth_when_the_truth_knows_it(cam, capsys, tmp_path):
    """Truth with each object's depth and px/ms speed, and a file that states its camera: the
    summary's speedE and bin-only speedE are errors at the true depth, so --depth-m (what the
    JSON lines' m/s assume) moves neither (the bin-only one did: it took the run's m/s back to
    px/ms with the bundle's camera instead of the run's)."""
    from toffe_deploy.events.fmt_toffe import write_events_h5
    from toffe_deploy.events.io import open_events

    rec = tmp_path / "rec_focal.h5"
    with open_events(cam["rec"]) as src:
        write_events_h5(rec, src.read(src.t_start_us, src.t_end_us), src.sensor_size, ground_truth=src.ground_truth,
                        attrs={"focal_px": 120.0}, t_range=(src.t_start_us, src.t_end_us))
    got = []
    for depth in (3, 9):
        rc, _, err = run_cli(capsys, cam["bundle"].root, "--events", rec, "--depth-m", depth, "--focal-px", 150,
                             "--summary-json", tmp_path / f"s{depth}.json")
        assert rc == 0, err
        got.append(json.loads((tmp_path / f"s{depth}.json").read_text())["errors"])
    assert got[0]["n_matched"] > 0
    for key in ("speedE", "speedE_bin_only"):
        assert got[0][key] == pytest.approx(got[1][key], rel=1e-9)


def test_eval_reads_another_sensor_size_as_the_runtime_does(cam, capsys, tmp_path):
    """eval's reference (predict_window on a window and the windows before it, as eval samples
    them) finds on a 96x72 recording what the cpu runtime of a 64x48 bundle finds, window for
    window; and `eval` takes such a data set (it refused any size but the checkpoint's)."""
    from toffe_deploy.deploy.onnx_export import ort_session, run_onnx
    from toffe_deploy.events.io import open_events
    from toffe_deploy.events.support import sampled_window_history
    from toffe_deploy.model.reference import fixed_stage_fn, predict_window
    from toffe_deploy.runtime.pipeline import Pipeline
    from toffe_deploy.runtime.spikes import SpikeVolume

    b = cam["bundle"]
    cfg = b.config
    sess, stage = ort_session(b.ofpd_onnx), fixed_stage_fn(b.ofs)
    with open_events(cam["rec"]) as src:
        wins = [(t0, SpikeVolume.from_events(ev, t0, cfg.dt_us, cfg.n_bins, OTHER))
                for t0, ev in src.iter_windows(cfg.dt_us, t_start=src.t_start_us)]
        ref = []
        for t0, _ in wins:
            binned, recent, history = sampled_window_history(src.read, t0, cfg.dt_us, cfg, OTHER, src.t_start_us)
            ref.append(predict_window(binned, stage, lambda x: run_onnx(sess, x), cfg, recent, history)[0])
    with Pipeline(b, "cpu", sensor_size=OTHER, track=False) as pipe:
        got = list(pipe.process_stream(wins))
    rows = [([(o.speed_bin, round(o.x, 3), round(o.y, 3)) for o in r.objects],
             [(p.stage, round(p.x, 3), round(p.y, 3)) for p in want]) for r, want in zip(got, ref)]
    assert sum(len(a) for a, _ in rows) > 0 and [a for a, _ in rows] == [r for _, r in rows]

    data = tmp_path / "d96"
    assert main(["dataset", "synth", "--out", str(data), "--split", "test", "--limit", "1", "--duration-s", "0.003",
                 "--sensor-size", "96x72", "--no-progress"]) == 0
    capsys.readouterr()
    assert main(["eval", str(b.root.parent / "ckpt"), "--data", str(data), "--dt", "500", "--max-windows", "2",
                 "--no-progress"]) == 0
    assert "| 500 |" in capsys.readouterr().out


def test_speeds_in_summary_lines_have_three_digits_and_an_exponent_only_at_the_extremes():
    assert [speed_text(v) for v in (0.336729, 6.06113, 84.0, 1.0, 1016.4, 5000.0, 0.0012345, 0.0, 999_499.0)] == \
        ["0.337", "6.06", "84", "1", "1020", "5000", "0.00123", "0", "999000"]
    # beyond 1e-4 .. 1e6 (--depth-m 1e-3 --focal-px 1e7, or the reverse) an exponent, both ends alike
    assert [speed_text(v) for v in (3.3e-05, 1e-07, 2.7e9, 999_600.0, -4.2e-4)] == \
        ["3.3e-05", "1e-07", "2.7e+09", "1e+06", "-0.00042"]
