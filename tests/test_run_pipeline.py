"""`toffe-deploy run` on the cpu target: end-to-end object flow, output, rendering, bad input.

A small real bundle (64x48, untrained DOTIE OFS + random OFPD exported to ONNX) and a real
multi-object recording from the data-set generator, both in tmp dirs; real onnxruntime.
"""
import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from toffe_deploy import ofpd_io
from toffe_deploy.cascade import run_cascade
from toffe_deploy.cli import main
from toffe_deploy.events.io import read_events
from toffe_deploy.config import ToffeConfig
from toffe_deploy.plane_fit import dense_flow, object_planes_flow
from toffe_deploy.fixed_point import run_ofs_fixed
from toffe_deploy.runtime import ofpd_input
from toffe_deploy.compiled import new_scratch
from toffe_deploy.runtime.spikes import SpikeVolume

SENSOR = (64, 48)
ROOT = Path(__file__).resolve().parent.parent


@pytest.fixture(scope="module")
def env(tmp_path_factory, make_bundle, make_recording):
    root = tmp_path_factory.mktemp("run")
    bundle = make_bundle(root)
    rec = make_recording(root / "rec.h5")
    return {"root": root, "bundle": bundle, "rec": rec}


def run_cli(capsys, *argv):
    rc = main(["run", *map(str, argv), "--no-progress"])
    cap = capsys.readouterr()
    return rc, cap.out, cap.err


def _random_window(rng, cfg, n_stages=4):
    """A window's ones split into disjoint stage frames as the cascade makes them: several blobs
    (some off the sensor edge), each mostly in one stage (so one stage often holds several
    objects), a share of each blob's ones spilled into other stages (the leftover edges), noise,
    and some ones in no frame at all."""
    w, h = cfg.sensor_size
    x = np.zeros((cfg.n_bins, 2, h, w), bool)
    home = np.zeros((h, w), np.int64)                     # 0 = noise: any stage
    for _ in range(int(rng.integers(2, 7))):
        cy, cx = rng.integers(-5, h + 5), rng.integers(-5, w + 5)
        ys, xs = slice(max(cy - 6, 0), max(cy + 6, 0)), slice(max(cx - 6, 0), max(cx + 6, 0))
        x[:, :, ys, xs] |= rng.random(x[:, :, ys, xs].shape) < 0.3
        home[ys, xs] = rng.integers(1, n_stages + 1)
    x |= rng.random(x.shape) < 0.002
    vol = SpikeVolume.from_dense(x)
    stage = home.reshape(-1)[vol.pix]
    spill = (stage == 0) | (rng.random(len(vol)) < 0.15)
    stage[spill] = rng.integers(0, n_stages + 1, int(spill.sum()))   # 0 = masked out of every frame
    masks = [stage == k for k in range(1, n_stages + 1)]
    return vol, masks, np.stack([vol.subset(m).to_dense() for m in masks])


@pytest.mark.parametrize("ofpd", [{"crop_px": 32, "pool": 2, "min_events": 10, "dedupe_px": 12},
                                  {"crop_px": 16, "pool": 4, "min_events": 4, "dedupe_px": 20},
                                  {"crop_px": 24, "pool": 3, "min_events": 1, "dedupe_px": 6},
                                  {"crop_px": 16, "pool": 2, "min_events": 6, "dedupe_px": 5},
                                  {"crop_px": 32, "pool": 4, "min_events": 6, "pool_max": 4, **ofpd_io.CURRENT_LAYOUT},
                                  {"crop_px": 16, "pool": 2, "min_events": 3, "link_px": 1, **ofpd_io.CURRENT_LAYOUT,
                                   "plane_fit_weight": 0.7}])
def test_sparse_ofpd_input_equals_ofpd_io(rng, ofpd):
    """The runtime's coordinate path == the dense ofpd_io API (training/export), bit for bit:
    stages, merged frames (hence n_events), has_object and the prepared OFPD input."""
    cfg = ToffeConfig(sensor_size=SENSOR, ofpd=ofpd)
    n_obj, multi, n_flow = 0, 0, 0
    for t in range(16):
        vol, masks, dense = _random_window(rng, cfg)
        ks_ref, merged_ref = ofpd_io.merge_frames(dense, cfg)
        lookup = new_scratch(SENSOR[0] * SENSOR[1]) if t % 2 else None   # both pixel-set paths
        ks, merged = ofpd_input.merge_objects(vol, masks, cfg, lookup)
        assert ks.dtype == ks_ref.dtype and ks.tolist() == ks_ref.tolist()
        assert len(merged) == len(merged_ref)
        for m, ref in zip(merged, merged_ref):
            assert np.array_equal(m.to_dense(), ref) and len(m) == int(ref.sum())
        assert np.array_equal(np.flatnonzero(ofpd_io.has_object(dense, cfg)), np.unique(ks_ref - 1))
        got, ref = ofpd_input.prepare(merged, cfg, lookup), ofpd_io.prepare(merged_ref, cfg)
        assert got.dtype == ref.dtype and got.shape == ref.shape and got.tobytes() == ref.tobytes()
        ks_b, x_b, n_b, ones_b = ofpd_input.batch(vol, masks, cfg, lookup)  # the pipeline's one-pass form
        assert ks_b.tolist() == ks_ref.tolist() and x_b.tobytes() == ref.tobytes()
        if cfg.ofpd.get("plane_fit_weight", 0) > 0:                         # plane_fit: the same bits as eval's
            flow_b = object_planes_flow(*ones_b, ks_b.size, np.ones(ks_b.size, bool))
            assert flow_b.tobytes() == dense_flow(merged_ref).reshape(-1, 2).tobytes()
            n_flow += int(np.isfinite(flow_b[:, 0]).sum())
        assert n_b.tolist() == [int(m.sum()) for m in merged_ref]
        n_obj += ks.size
        multi += int(np.any(np.bincount(ks) > 1))
    assert n_obj > 16 and multi >= 3            # covered windows with several objects in one stage
    assert n_flow >= 3 or not ofpd.get("plane_fit_weight")


@pytest.mark.parametrize("pool,plane_fit", [(1, False), (2, False), (2, True)])
def test_cpu_pipeline_equals_dense_reference(env, make_bundle, tmp_path, pool, plane_fit):
    """Sparse cascade + sparse OFPD input == run_cascade(run_ofs_fixed) + ofpd_io on dense arrays,
    with the OFS on the sensor grid and on the 2x2-pooled one (config.ofs_pool), and with the
    plane fit blended into speed and direction (eval's dense_flow against the runtime's)."""
    from toffe_deploy.plane_fit import PlaneFusion
    import onnxruntime as ort

    from toffe_deploy.events.binning import bin_window
    from toffe_deploy.events.io import open_events
    from toffe_deploy.runtime.pipeline import Pipeline

    fit = {"plane_fit_weight": 0.7, "plane_fit_min_px_ms": 0.5, "plane_fit_dir_weight": 0.5} if plane_fit else None
    b = env["bundle"] if pool == 1 else make_bundle(tmp_path, ofs_pool=pool, **({"ofpd": fit} if fit else {}))
    cfg = b.config
    sess = ort.InferenceSession(str(b.ofpd_onnx), providers=["CPUExecutionProvider"])
    with open_events(env["rec"]) as src:
        wins = [(t0, bin_window(ev, t0, cfg.dt_us, cfg.n_bins, cfg.sensor_size)) for t0, ev in src.iter_windows(cfg.dt_us)]
    with Pipeline(b, "cpu") as pipe:
        got = list(pipe.process_stream(wins))
    assert [r.t0_us for r in got] == [t0 for t0, _ in wins]
    n_obj = n_fit = 0
    for (t0, x), res in zip(wins, got):
        ref = run_cascade(x, lambda k, inp: run_ofs_fixed(inp, b.ofs[k - 1]), cfg.n_speed_bins, cfg.mask_kernel,
                          cfg.ofs_pool)
        ks, merged = ofpd_io.merge_frames(np.stack(ref.frames), cfg)
        assert [o.speed_bin for o in res.objects] == ks.tolist()
        assert [o.n_events for o in res.objects] == [int(m.sum()) for m in merged]
        if ks.size:
            pose, direction, speed = sess.run(None, {"events": ofpd_io.prepare(merged, cfg)})
            fusion = PlaneFusion(cfg)
            assert fusion.on == plane_fit
            if plane_fit:
                flow = dense_flow(merged)
                n_fit += int(np.isfinite(flow[:, 0]).sum())
                speed, direction = fusion.speed(speed, flow), fusion.direction(direction, flow)
            dec = ofpd_io.decode(pose, direction, speed, ks, cfg)
            np.testing.assert_allclose([o.x for o in res.objects], dec["x_px"], rtol=0, atol=1e-5)
            np.testing.assert_allclose([o.direction_rad for o in res.objects], dec["direction_rad"], atol=1e-5)
            np.testing.assert_allclose([o.speed_mps for o in res.objects], dec["speed_mps"], rtol=1e-5)
            n_obj += ks.size
    assert n_obj > 0                          # the comparison covered real objects
    assert n_fit > 0 or not plane_fit


def test_run_cli_writes_jsonl_and_summary_with_ground_truth(env, capsys, tmp_path):
    out = tmp_path / "flow.jsonl"
    summ = tmp_path / "summary.json"
    rc, stdout, stderr = run_cli(capsys, env["bundle"].root, "--target", "cpu", "--events", env["rec"], "--out", out,
                                 "--summary-json", summ)
    assert rc == 0, stderr
    head, *lines = [json.loads(s) for s in out.read_text().splitlines()]
    assert head["type"] == "header" and head["dt_us"] == 500 and head["sensor_size"] == list(SENSOR)
    assert len(lines) == 24                   # 12 ms / 500 us
    assert lines[1]["t0_us"] - lines[0]["t0_us"] == 500 and lines[0]["t1_us"] == lines[0]["t0_us"] + 500
    objs = [o for ln in lines for o in ln["objects"]]
    assert objs and set(objs[0]) == {"speed_bin", "ofs_bin", "speed_mps", "speed_bin_mps", "speed_px_s", "x", "y",
                                     "direction_rad", "direction_deg", "n_events", "speed_clipped", "track_id",
                                     "track"}
    assert all(1 <= o["speed_bin"] <= 4 for o in objs)
    assert all(abs(np.degrees(o["direction_rad"]) - o["direction_deg"]) < 1e-2 for o in objs)
    assert "24 windows" in stdout and "windows/s" in stdout and "pixE" in stdout and "latency per window" in stdout
    s = json.loads(summ.read_text())
    assert s["windows"] == 24 and s["objects"] == len(objs) and s["errors"]["n_gt"] > 0


def test_run_summary_reports_recall_false_positives_per_window_and_bin_accuracy(env, capsys, tmp_path):
    summ = tmp_path / "summary.json"
    rc, stdout, stderr = run_cli(capsys, env["bundle"].root, "--events", env["rec"], "--max-windows", "8",
                                 "--summary-json", summ)
    assert rc == 0, stderr
    e = json.loads(summ.read_text())["errors"]
    assert e["n_windows"] == 8 and e["n_gt"] > 0 and e["gate_px"] == 20.0
    assert e["n_pred"] == sum(len(json.loads(s).get("objects", ())) for s in stdout.splitlines())
    assert f"recall {100 * e['recall']:.1f}% ({e['n_matched']}/{e['n_gt']} objects)" in stderr
    assert f"{e['fp_per_window']:.3f} false positives per window ({e['false_positives']} in 8 windows)" in stderr
    assert f"bin accuracy {e['bin_accuracy']:.3f}" in stderr


def test_run_cli_stdout_is_pure_jsonl_and_max_windows(env, capsys):
    rc, stdout, stderr = run_cli(capsys, env["bundle"].root, "--events", env["rec"], "--max-windows", "3")
    assert rc == 0
    lines = [json.loads(s) for s in stdout.splitlines()]
    assert lines[0]["type"] == "header" and [ln["t0_us"] for ln in lines[1:]] == [0, 500, 1000]
    assert "3 windows" in stderr


def test_a_last_partial_window_is_dropped_and_said_unless_asked_for(env, capsys, tmp_path):
    """A recording that ends 200 us into its last window: that window's objects would come from
    part of it (its slow objects' speeds were wrong), so `run` drops it and says so, as eval
    does; --include-incomplete processes it; a recording shorter than one window is an error."""
    from toffe_deploy.events.io import write_events_npz

    ev = read_events(env["rec"]).events
    cut = tmp_path / "cut.npz"
    write_events_npz(cut, ev[ev["t"] < 3 * 500 + 200], SENSOR)       # no t_range: it ends at its last event
    t_last = int(ev["t"][ev["t"] < 1700][-1])
    t_first = int(ev["t"][0])
    whole = (t_last + 1 - t_first) // 500
    rc, out, err = run_cli(capsys, env["bundle"].root, "--events", cut, "--summary-json", tmp_path / "s.json")
    assert rc == 0 and len(out.splitlines()) == 1 + whole
    tail = t_last + 1 - (t_first + whole * 500)
    assert f"the recording's last {tail} us end inside a window: not processed" in err
    assert json.loads((tmp_path / "s.json").read_text())["incomplete_tail_us"] == tail
    rc, out_all, err = run_cli(capsys, env["bundle"].root, "--events", cut, "--include-incomplete")
    assert rc == 0 and len(out_all.splitlines()) == 2 + whole and "end inside a window" not in err
    assert out_all.splitlines()[:1 + whole] == out.splitlines()
    short = tmp_path / "short.npz"
    write_events_npz(short, ev[ev["t"] < t_first + 300], SENSOR)
    rc, out, err = run_cli(capsys, env["bundle"].root, "--events", short)
    assert rc == 2 and "shorter than one window (500 us)" in err and len(err.strip().splitlines()) == 1
    back = ev[ev["t"] < t_first + 1700].copy()        # its last event back at the first's time: a short span
    back["t"][-1] = t_first                           # from the ends alone, but the error is the order's
    np.savez(tmp_path / "back.npz", x=back["x"], y=back["y"], t=back["t"], p=back["p"], sensor_size=np.array(SENSOR))
    rc, out, err = run_cli(capsys, env["bundle"].root, "--events", tmp_path / "back.npz")
    assert rc == 2 and f"timestamps decrease at event {len(back) - 1}" in err and "shorter" not in err
    rc, out, err = run_cli(capsys, env["bundle"].root, "--events", env["rec"], "--max-windows", "3")
    assert rc == 0 and "end inside a window" not in err                   # stopped early: nothing to say
    gap = ev[ev["t"] < t_first + 1300].copy()                             # a gap the run jumps over: fewer
    later = gap.copy()                                                    # windows done than the grid holds
    later["t"] += 20_000
    write_events_npz(tmp_path / "gap.npz", np.concatenate([gap, later]), SENSOR)
    rc, out, err = run_cli(capsys, env["bundle"].root, "--events", tmp_path / "gap.npz", "--skip-empty-after", "2",
                           "--max-windows", "8")
    assert rc == 0 and len(out.splitlines()) - 1 < 8 and "end inside a window: not processed" in err
    rc, out, err = run_cli(capsys, env["bundle"].root, "--events", tmp_path / "gap.npz", "--include-incomplete")
    assert rc == 0
    empty = tmp_path / "empty.npz"
    write_events_npz(empty, ev[:0], SENSOR)
    rc, out, err = run_cli(capsys, env["bundle"].root, "--events", empty, "--include-incomplete")
    assert rc == 2 and "--include-incomplete processes" not in err and len(err.strip().splitlines()) == 1


def test_epoch_timestamps_give_the_same_object_flow(env, capsys, tmp_path):
    """Cameras stamp events in Unix-epoch microseconds (~1.7e15, a DV camera's clock): the same
    recording shifted there gives the same lines, times shifted (no float32 time anywhere)."""
    from toffe_deploy.events.io import write_events_npz

    ev = read_events(env["rec"]).events
    off = 1_764_000_000_000_000 + 137                      # not on the window grid of the first
    shifted = ev.copy()
    shifted["t"] += off
    for name, e in (("a.npz", ev), ("b.npz", shifted)):
        write_events_npz(tmp_path / name, e, SENSOR)
        rc, out, err = run_cli(capsys, env["bundle"].root, "--events", tmp_path / name, "--out", tmp_path / f"{name}.jsonl")
        assert rc == 0, err
    a, b = ([json.loads(s) for s in (tmp_path / f"{n}.jsonl").read_text().splitlines()[1:]] for n in ("a.npz", "b.npz"))
    for w in b:
        w["t0_us"] -= off
        w["t1_us"] -= off
    assert len(a) > 10 and any(w["objects"] for w in a) and a == b


def test_cpu_target_imports_neither_torch_nor_lava(env, tmp_path):
    code = ("import sys; from toffe_deploy.cli import main; "
            f"rc = main(['run', {str(env['bundle'].root)!r}, '--events', {str(env['rec'])!r}, '--out', "
            f"{str(tmp_path / 'o.jsonl')!r}, '--no-progress']); "
            "heavy = sorted(m for m in sys.modules if m.split('.')[0] in ('torch', 'lava', 'lava_procs')); "
            "print('RC', rc, 'HEAVY', heavy)")
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert "RC 0 HEAVY []" in p.stdout, p.stdout + p.stderr


def test_render_png_frames_and_video(env, capsys, tmp_path):
    rc, _, err = run_cli(capsys, env["bundle"].root, "--events", env["rec"], "--max-windows", "4",
                         "--render", tmp_path / "png", "--out", tmp_path / "a.jsonl")
    assert rc == 0, err
    import cv2

    pngs = sorted((tmp_path / "png").glob("frame_*.png"))
    assert len(pngs) == 4
    img = cv2.imread(str(pngs[0]))
    assert img.shape == (48 * 8, 64 * 8, 3) and img.any()      # a 64x48 sensor is drawn 8x (render.draw)
    rc, _, err = run_cli(capsys, env["bundle"].root, "--events", env["rec"], "--max-windows", "4",
                         "--render", tmp_path / "vid", "--video", "--out", tmp_path / "b.jsonl")
    assert rc == 0, err
    from toffe_deploy.render.video import video_info

    assert video_info(tmp_path / "vid" / "object_flow.mp4") == ("h264", "yuv420p", 4)


def test_synthetic_recording_runs(env, capsys, tmp_path):
    rc, out, err = run_cli(capsys, env["bundle"].root, "--synthetic", "multi:1,duration=0.003", "--out",
                           tmp_path / "s.jsonl")
    assert rc == 0, err
    assert len((tmp_path / "s.jsonl").read_text().splitlines()) == 1 + 6 and "pixE" in out


@pytest.mark.parametrize("spec", ["multi,foo=1", "walk:1", "multi:x", "multi,duration=-1", "multi:99"])
def test_bad_synthetic_spec_is_one_line_error(env, capsys, spec):
    rc, _, err = run_cli(capsys, env["bundle"].root, "--synthetic", spec)
    assert rc == 2 and err.startswith("toffe-deploy: error: --synthetic") and err.count("\n") == 1


def test_unreadable_events_is_one_line_error(env, capsys, tmp_path):
    bad = tmp_path / "garbage.h5"
    bad.write_bytes(b"\x89HDF\r\n\x1a\n" + b"\x00" * 50)
    rc, _, err = run_cli(capsys, env["bundle"].root, "--events", bad)
    assert rc == 2 and err.startswith(f"toffe-deploy: error: {bad}") and err.count("\n") == 1
    rc, _, err = run_cli(capsys, env["bundle"].root, "--events", tmp_path / "missing.h5")
    assert rc == 2 and "missing.h5" in err and err.count("\n") == 1


def test_tampered_or_incomplete_bundle_is_one_line_error(env, capsys, tmp_path):
    b = tmp_path / "b"
    shutil.copytree(env["bundle"].root, b)
    with open(b / "ofpd.onnx", "ab") as f:
        f.write(b"\0")
    rc, _, err = run_cli(capsys, b, "--events", env["rec"])
    assert rc == 2 and "sha256 mismatch" in err and err.count("\n") == 1
    (b / "ofpd.onnx").unlink()
    rc, _, err = run_cli(capsys, b, "--events", env["rec"])
    assert rc == 2 and "ofpd.onnx: missing file" in err
    rc, _, err = run_cli(capsys, tmp_path / "nope", "--events", env["rec"])
    assert rc == 2 and "does not exist" in err
    renamed = tmp_path / "renamed"                      # a manifest naming another fp32 OFPD was ignored
    shutil.copytree(env["bundle"].root, renamed)
    m = json.loads((renamed / "manifest.json").read_text())
    m["ofpd"]["file"] = "mine.onnx"
    (renamed / "manifest.json").write_text(json.dumps(m))
    rc, _, err = run_cli(capsys, renamed, "--events", env["rec"])
    assert rc == 2 and "ofpd.file is 'mine.onnx'" in err and err.count("\n") == 1


def test_cuda_target_without_gpu_provider_says_what_is_missing(env, capsys):
    import onnxruntime as ort

    if "CUDAExecutionProvider" in ort.get_available_providers():
        pytest.skip("this machine has onnxruntime's CUDA provider")
    rc, out, err = run_cli(capsys, env["bundle"].root, "--target", "cuda", "--events", env["rec"])
    assert rc == 2 and out == "" and err.count("\n") == 1
    assert "CUDAExecutionProvider" in err and "onnxruntime-gpu" in err and "--target cpu" in err


def test_bad_options_are_one_line_errors(env, capsys):
    rc, _, err = run_cli(capsys, env["bundle"].root, "--events", env["rec"], "--max-windows", "0")
    assert rc == 2 and "--max-windows" in err
    rc, _, err = run_cli(capsys, env["bundle"].root, "--events", env["rec"], "--video")
    assert rc == 2 and "--render" in err


def _flows(results):
    return [r.to_json() for r in results]


def test_loihi_sim_and_cpu_give_identical_object_flow(env, capsys, tmp_path):
    pytest.importorskip("lava")
    out = {}
    for target in ("cpu", "loihi-sim"):
        rc, _, err = run_cli(capsys, env["bundle"].root, "--target", target, "--events", env["rec"], "--max-windows", "8",
                             "--out", tmp_path / f"{target}.jsonl")
        assert rc == 0, err
        out[target] = (tmp_path / f"{target}.jsonl").read_text().splitlines()[1:]    # the header names the target
    assert out["cpu"] == out["loihi-sim"]
    assert sum(len(json.loads(s)["objects"]) for s in out["cpu"]) > 0


def test_reset_zero_bundle_stock_lava_equals_cpu_and_reports_bridge_traffic(env, capsys, tmp_path, make_bundle):
    """A reset-zero bundle: stock Conv + LIFReset in Lava, the same object flow as the cpu target;
    the summary states the host <-> chip spikes per window, which the cpu target has no bridge for."""
    pytest.importorskip("lava")
    bundle = make_bundle(tmp_path, reset="zero")
    out, summ = {}, {}
    for target in ("cpu", "loihi-sim"):
        rc, text, err = run_cli(capsys, bundle.root, "--target", target, "--events", env["rec"], "--max-windows", "6",
                                "--out", tmp_path / f"{target}.jsonl", "--summary-json", tmp_path / f"{target}.json")
        assert rc == 0, err
        out[target] = (tmp_path / f"{target}.jsonl").read_text().splitlines()[1:]    # the header names the target
        summ[target] = json.loads((tmp_path / f"{target}.json").read_text())
    assert out["cpu"] == out["loihi-sim"]
    assert summ["cpu"]["bridge_traffic"] is None
    t = summ["loihi-sim"]["bridge_traffic"]
    assert t["windows"] == 6 and t["per_window"]["to_chip_spikes"] > 0 and t["per_window"]["to_host_spikes"] > 0
    assert t["per_window"]["to_chip_bytes"] == 4 * t["per_window"]["to_chip_spikes"]
    assert "bridge traffic per window" in text


def test_loihi_sim_and_cpu_agree_on_the_shipped_sample(tmp_path, make_bundle):
    """Full 640x480 on the shipped recording: first windows through both backends."""
    pytest.importorskip("lava")
    from toffe_deploy.commands.run import SAMPLE
    from toffe_deploy.events.io import open_events
    from toffe_deploy.runtime.pipeline import Pipeline

    bundle = make_bundle(tmp_path, sensor=(640, 480), ofpd={})
    cfg = bundle.config
    with open_events(SAMPLE) as src:
        assert tuple(src.sensor_size) == (640, 480)
        wins = [(t0, SpikeVolume.from_events(ev, t0, cfg.dt_us, cfg.n_bins, cfg.sensor_size))
                for _, (t0, ev) in zip(range(3), src.iter_windows(cfg.dt_us, t_start=20_000))]
    flows = {}
    for target in ("cpu", "loihi-sim"):
        with Pipeline(bundle, target) as pipe:
            flows[target] = _flows(pipe.process_stream(wins))
    assert flows["cpu"] == flows["loihi-sim"]
    assert {o["speed_bin"] for r in flows["cpu"] for o in r["objects"]} >= {1, 2}


def test_truth_index_equals_window_truth_on_the_whole_table(env):
    from toffe_deploy.dataset.groundtruth import window_truth
    from toffe_deploy.events.io import open_events
    from toffe_deploy.runtime.truth import TruthIndex

    with open_events(env["rec"]) as src:
        gt = src.ground_truth
    idx = TruthIndex(gt)
    n = 0
    for t0 in range(0, 12_000, 500):
        want = window_truth(gt, t0, 500)
        assert idx.window(t0, 500) == want
        n += len(want)
    assert n > 0


def test_loihi2_without_lava_loihi_and_tag_on_cpu_are_one_line_errors(env, capsys, make_bundle, tmp_path):
    pytest.importorskip("lava")
    # a subtract bundle: no stock Loihi 2 neuron runs it, whether or not lava-loihi is installed
    rc, out, err = run_cli(capsys, env["bundle"].root, "--target", "loihi2", "--events", env["rec"])
    assert rc == 2 and out == "" and err.count("\n") == 1 and "reset: subtract" in err and "loihi-sim" in err
    zero = make_bundle(tmp_path, reset="zero")
    rc, out, err = run_cli(capsys, zero.root, "--target", "loihi2", "--events", env["rec"])
    assert rc == 2 and out == "" and err.count("\n") == 1 and "lava-loihi" in err and "loihi-sim" in err
    rc, out, err = run_cli(capsys, env["bundle"].root, "--tag", "floating_pt", "--events", env["rec"])
    assert rc == 2 and "--tag floating_pt" in err and err.count("\n") == 1


def test_loihi_sim_floating_pt_runs(env, capsys, tmp_path):
    pytest.importorskip("lava")
    rc, _, err = run_cli(capsys, env["bundle"].root, "--target", "loihi-sim", "--tag", "floating_pt", "--events",
                         env["rec"], "--max-windows", "3", "--out", tmp_path / "f.jsonl")
    assert rc == 0, err
    assert len((tmp_path / "f.jsonl").read_text().splitlines()) == 1 + 3


def test_unwritable_outputs_are_one_line_errors(env, capsys, tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    rc, _, err = run_cli(capsys, env["bundle"].root, "--events", env["rec"], "--out", blocker / "o.jsonl")
    assert rc == 2 and err.startswith(f"toffe-deploy: error: {blocker / 'o.jsonl'}: cannot write") and err.count("\n") == 1
    rc, _, err = run_cli(capsys, env["bundle"].root, "--events", env["rec"], "--render", blocker, "--out",
                         tmp_path / "o.jsonl")
    assert rc == 2 and "--render: exists and is not a directory" in err and err.count("\n") == 1
    assert not (tmp_path / "o.jsonl").exists()           # nothing half-written


def test_missing_ofpd_variant_is_one_line_error(env, capsys):
    rc, _, err = run_cli(capsys, env["bundle"].root, "--events", env["rec"], "--ofpd", "int8")
    assert rc == 2 and "no int8 OFPD variant" in err and err.count("\n") == 1


def test_simulator_timing_is_never_called_latency():
    from toffe_deploy.runtime.output import RunSummary

    sim = RunSummary("loihi-sim", windows=2, wall_s=0.1, latencies_s=[0.05, 0.06]).lines()[1]
    cpu = RunSummary("cpu", windows=2, wall_s=0.1, latencies_s=[0.002, 0.003]).lines()[1]
    assert "simulator wall time per window (not Loihi 2 latency)" in sim and "latency per window" not in sim
    assert "latency per window p50 2.50 ms" in cpu


def test_summary_reports_the_real_time_factor():
    from toffe_deploy.runtime.output import RunSummary

    s = RunSummary("cpu", windows=2000, wall_s=0.5, dt_us=500, latencies_s=[0.0002] * 2000)
    assert s.realtime_factor == pytest.approx(2.0) and s.to_json()["realtime_factor"] == pytest.approx(2.0)
    assert "real-time factor 2)" in s.lines()[1]
    s.skip(2000, 500)                          # a gap jumped over is sensor time too
    assert s.realtime_factor == pytest.approx(4.0)
    assert "real-time factor" not in RunSummary("cpu", windows=2, wall_s=0.1).lines()[1]   # no dt: not stated


def test_pipeline_tracks_from_the_decoded_columns_as_tracker_update_does_from_objects(env):
    """The pipeline feeds the tracker the decoder's columns (Tracker.columns) and hands ids and
    states to the objects' constructor; Tracker.update on the same objects, read back field by
    field (the path of objects from elsewhere), gives the same ids, states and coasting lists,
    window by window, across a gap of skipped windows too."""
    import dataclasses

    from toffe_deploy.events.io import open_events
    from toffe_deploy.runtime.pipeline import Pipeline
    from toffe_deploy.tracking import Tracker

    b = env["bundle"]
    cfg = b.config
    with open_events(env["rec"]) as src:
        wins = [(t0, SpikeVolume.from_events(ev, t0, cfg.dt_us, cfg.n_bins, cfg.sensor_size))
                for t0, ev in src.iter_windows(cfg.dt_us)]
    wins = wins[:10] + wins[13:]                              # three windows never seen: the tracks coast
    with Pipeline(b, "cpu") as pipe:
        got = list(pipe.process_stream(wins))
    tr = Tracker(cfg, cfg.dt_us, None, pipe.speed_scale.px_ms_per_mps)

    def tracked(objects, coasting):
        return ([(o.track_id, None if o.track is None else dict(o.track)) for o in objects],
                [(c["track_id"], dict(c["track"])) for c in coasting])

    for res in got:
        objs = [dataclasses.replace(o, track_id=None, track=None) for o in res.objects]
        tr.update(objs, res.t0_us)
        assert tracked(objs, tr.coasting()) == tracked(res.objects, res.coasting)
    assert sum(o.track_id is not None for r in got for o in r.objects) >= 10
    assert any(o.track is not None and o.track["confirmed"] for r in got for o in r.objects)



#: run in a fresh process: a Pipeline (tracking on) over a recording, and a Tracker over an
#: ambiguous window; prints the kernels that gained a compiled signature after start-up
_NO_COMPILE_SCRIPT = """
import json, sys
from toffe_deploy.deploy.bundle import load_bundle
from toffe_deploy.events.io import open_events
from toffe_deploy.runtime.pipeline import ObjectFlow, Pipeline
from toffe_deploy.runtime.spikes import SpikeVolume
from toffe_deploy.tracking import Tracker

def signatures():
    out = {}
    for mod_name, mod in list(sys.modules.items()):
        if mod_name.startswith("toffe_deploy"):
            for name, f in list(vars(mod).items()):
                if hasattr(f, "signatures") and hasattr(f, "py_func"):
                    out[f.py_func.__module__ + "." + name] = len(f.signatures)
    return out

bundle = load_bundle(sys.argv[1])
cfg = bundle.config
with Pipeline(bundle, "cpu") as pipe, open_events(sys.argv[2]) as src:
    tracker = Tracker(cfg, cfg.dt_us)
    before = signatures()
    windows = [(t0, SpikeVolume.from_events(ev, t0, cfg.dt_us, cfg.n_bins, cfg.sensor_size))   # as `run` bins
               for t0, ev in src.iter_windows(cfg.dt_us, t_start=src.t_start_us)]
    n_objects = sum(len(r.objects) for r in pipe.process_stream(windows))
    for w in range(8):          # a track, then two detections in its gate (the Hungarian path), then a gap
        objs = [ObjectFlow(3, 3, 30.0, 30.0, 9000.0, 50.0 + 4.5 * w, 40.0, 0.0, 20)]
        if w == 6:
            objs.append(ObjectFlow(3, 3, 30.0, 30.0, 9000.0, 53.0 + 4.5 * w, 40.0, 0.0, 20))
        tracker.update(objs, (w + 3 * (w == 7)) * cfg.dt_us)
    after = signatures()
print(json.dumps({"n_objects": n_objects, "new": {k: v for k, v in after.items() if v != before.get(k)}}))
"""


def test_a_cpu_runs_windows_compile_no_kernel_after_start_up(tmp_path, make_bundle, make_recording):
    """With the shipped checkpoint's settings (union grouping, splits by polarity, recent_events,
    the plane fit over the windows before, input_support, pooled OFS) and tracking, every numba
    kernel the windows call is compiled, or loaded from numba's cache, at start-up: no window
    pays 10-80 ms for one (the first windows of a run were that slow). Checked in a second fresh
    process, once the first has filled the cache: within one process that compiled a kernel,
    the kernels it calls are registered too, and nothing would show."""
    from pathlib import Path

    shipped = json.loads((ROOT / "ckpt" / "config.json").read_text())
    ofpd = {**shipped["ofpd"], "crop_px": 32, "pool": 2, "min_events": 4}
    bundle = make_bundle(tmp_path, ofpd=ofpd, ofs_pool=shipped["ofs_pool"], reset=shipped["reset"],
                         input_support=shipped["input_support"])
    rec = make_recording(tmp_path / "rec.h5", duration=0.02)
    for _ in range(2):
        p = subprocess.run([sys.executable, "-c", _NO_COMPILE_SCRIPT, str(bundle.root), str(rec)],
                           capture_output=True, text=True, timeout=600)
        assert p.returncode == 0, p.stderr
    got = json.loads(p.stdout.splitlines()[-1])
    assert got["n_objects"] > 0 and got["new"] == {}


_LOADS_NOTHING = r"""
import sys
import importlib, pkgutil
import toffe_deploy
from numba.core.registry import CPUDispatcher
from toffe_deploy.deploy.bundle import load_bundle
from toffe_deploy.events.io import open_events
from toffe_deploy.runtime.pipeline import Pipeline
from toffe_deploy.runtime.spikes import SpikeVolume

mods = [importlib.import_module(m.name) for m in pkgutil.walk_packages(toffe_deploy.__path__, "toffe_deploy.")
        if not any(k in m.name for k in ("lava", "cli", "commands", "model", "deploy.onnx", "render", "baselines"))]
def loaded():
    return {f"{m.__name__}.{k}": len(v.signatures) for m in mods for k, v in vars(m).items()
            if isinstance(v, CPUDispatcher)}
b = load_bundle(sys.argv[1])
cfg = b.config
with open_events(sys.argv[2]) as src:
    wins = [(t0, SpikeVolume.from_events(ev, t0, cfg.dt_us, cfg.n_bins, cfg.sensor_size))
            for t0, ev in src.iter_windows(cfg.dt_us)]
half = sys.argv[3]
pipe = Pipeline(b, "cpu", processes=2 if half == "back" else 1)
if half == "front":
    pipe.half = "front"                  # as split.py's worker sets it (processes=2 sets "back")
with pipe:
    print("groups", pipe.warm_groups())
    before = loaded()
    if half == "front":                  # split.py's worker: front end, cascade, grouping, OFPD
        n = 0
        for t0, w in wins:
            n += len(pipe.ofpd.run(pipe.front_batch(t0, w)[1][1])[0])
    else:
        n = sum(len(r.objects) for r in pipe.process_stream(wins))
    after = loaded()
print("objects", n)
print("loaded in windows", sorted(k for k in after if after[k] != before[k]))
"""


@pytest.mark.parametrize("support, history, half", [(True, True, "all"), (False, True, "all"), (False, False, "all"),
                                                    (True, True, "front"), (True, True, "back")])
def test_the_pipelines_windows_load_no_kernel_after_its_warm_up(tmp_path, make_bundle, make_recording, support,
                                                                 history, half):
    """Pipeline.__enter__ loads only the compiled kernels its own path calls (compiled.warm_up's
    groups: ~0.9 s less start-up); in a fresh process, its windows then load nothing more (a
    kernel first loaded in a window would cost that window 0.1-0.3 s). The shipped ckpt/'s
    settings on a tiny sensor, with and without the front end's temporal support and the plane
    fit's windows before; and each process of processes=2 on its half alone (split.py's worker
    "front", run's own process "back")."""
    shipped = json.loads((ROOT / "ckpt" / "config.json").read_text())
    ofpd = dict(shipped["ofpd"], crop_px=32, pool=2, min_events=4)
    extra = {k: shipped[k] for k in ("input_norm", "input_min_cluster")}
    if support:
        extra["input_support"] = shipped["input_support"]
    else:                                    # both read the front end's windows
        ofpd.pop("recent_events")
        ofpd.pop("faint_objects")
    if not history:                          # the one-window plane fit (ckpt/full/, ckpt/subtract/ before it)
        ofpd.pop("plane_fit_history")
        ofpd.pop("outline_centre")
    b = make_bundle(tmp_path, ofs_pool=2, ofpd=ofpd, **extra)
    rec = make_recording(tmp_path / "rec.h5", duration=0.02)
    p = subprocess.run([sys.executable, "-c", _LOADS_NOTHING, str(b.root), str(rec), half], capture_output=True,
                       text=True, timeout=600, cwd=ROOT)
    assert p.returncode == 0, p.stderr
    out = p.stdout.splitlines()
    assert out[0].startswith("groups (") and int(out[1].split()[1]) > 0, out      # the fast path, real objects
    assert out[2] == "loaded in windows []", out
