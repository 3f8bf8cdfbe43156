"""End to end on a tiny synthetic data set: train (and resume), then eval with JSON."""
from __future__ import annotations

import json

import numpy as np
import pytest

from toffe_deploy.checkpoint import load_checkpoint
from toffe_deploy.cli import main


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    d = tmp_path_factory.mktemp("synth")
    for split in ("train", "test"):
        assert main(["dataset", "synth", "--out", str(d), "--split", split, "--limit", "4", "--duration-s", "0.01"]) == 0
    return d


def test_train_resume_and_eval(data, tmp_path, capsys):
    ck = tmp_path / "ck"
    args = ["train", "--data", str(data), "--out", str(ck), "--ofs-epochs", "1", "--windows-per-seq", "5",
            "--no-progress", "--seed", "3"]
    assert main(args + ["--epochs", "1"]) == 0
    first = load_checkpoint(ck)
    state = json.loads((ck / ".train_state" / "state.json").read_text())
    assert state["ofs_done"] == [1, 2, 3, 4] and state["ofpd_epoch"] == 1
    assert (ck / ".train_state" / "ofpd_partial.pt").is_file()        # what --resume continues from
    log = json.loads((ck / "train_log.json").read_text())
    assert len(log["ofs_separation_train"]) == 4 and log["train_windows"] > 0
    done = capsys.readouterr().out.strip().splitlines()[-1]           # says more than where, without bars
    assert done.startswith(f"checkpoint written to {ck} ({log['train_windows']:,} training windows; ") and \
        "OFPD losses of its last epoch: pose " in done and done.endswith(f"{ck / 'train_log.json'})"), done

    assert main(args + ["--epochs", "2", "--resume"]) == 0          # continues: OFS kept, one more OFPD epoch
    second = load_checkpoint(ck)
    assert json.loads((ck / ".train_state" / "state.json").read_text())["ofpd_epoch"] == 2
    assert len(json.loads((ck / "train_log.json").read_text())["ofpd_loss"]) == 2   # epoch 2 only, not 1 + 2
    for a, b in zip(first.ofs, second.ofs):
        np.testing.assert_array_equal(a["weight"], b["weight"])
    assert any(not np.array_equal(first.ofpd_state[k], second.ofpd_state[k]) for k in first.ofpd_state)
    capsys.readouterr()
    stamps = {p.name: p.stat().st_mtime_ns for p in ck.iterdir() if p.is_file()}
    assert main(args + ["--epochs", "2", "--resume"]) == 0          # finished: nothing to do, nothing rewritten
    cap = capsys.readouterr()
    assert "nothing to resume" in cap.err and "checkpoint written" not in cap.out
    assert {p.name: p.stat().st_mtime_ns for p in ck.iterdir() if p.is_file()} == stamps
    assert main(args + ["--epochs", "1", "--resume"]) == 0          # fewer epochs than done: said, not silent
    assert "had trained 2 OFPD epochs, more than --epochs 1: its OFPD is kept as it is" in capsys.readouterr().err
    assert main(args + ["--epochs", "2", "--resume", "--ofpd-pool", "2"]) == 2   # other OFPD settings: refused,
    assert "cannot resume" in capsys.readouterr().err                          # as for an interrupted run
    # keys the host sets after training (benchmarks/fit_plane_fit.py --write) stay: a resume of the
    # finished run took them for other OFPD settings, trained a random OFPD and wrote the old ones back
    cfg = json.loads((ck / "config.json").read_text())
    cfg["ofpd"].update(plane_fit_dir_weight=0.9, plane_fit_history=[4, 20, 3])
    (ck / "config.json").write_text(json.dumps(cfg))
    assert main(args + ["--epochs", "2", "--resume"]) == 0
    assert "nothing to resume" in capsys.readouterr().err
    losses = json.loads((ck / "train_log.json").read_text())["ofpd_loss"]
    assert main(args + ["--epochs", "3", "--resume"]) == 0          # trains on: the OFPD's epoch 3, not a new one
    assert json.loads((ck / ".train_state" / "state.json").read_text())["ofpd_epoch"] == 3
    assert json.loads((ck / "train_log.json").read_text())["ofpd_loss"][:2] == losses   # epochs 1-2 kept
    assert load_checkpoint(ck).config.ofpd["plane_fit_history"] == [4, 20, 3]
    assert load_checkpoint(ck).config.ofpd["plane_fit_dir_weight"] == 0.9
    capsys.readouterr()

    out_json = tmp_path / "eval.json"
    assert main(["eval", str(ck), "--data", str(data), "--dt", "500,1000", "--max-windows", "3",
                 "--track-windows", "6", "--json", str(out_json), "--no-progress"]) == 0
    table = capsys.readouterr().out
    assert "| 500 |" in table and "| 1000* |" in table and "paper pixE" in table
    assert "Tracking (tracking.Tracker" in table and "| MOTA | IDF1 |" in table
    res = json.loads(out_json.read_text())
    assert [r["dt_us"] for r in res["per_dt"]] == [500, 1000]
    # the data and its camera, beside the checkpoint's (eval said nothing of what it evaluated on)
    assert res["data"] == str(data) and res["data_sensor_size"] == [res["checkpoint_sensor_size"]]
    assert res["data_focal_px"] is None or res["data_focal_px"] > 0
    assert f"data `{data}`: {res['data_sensor_size'][0][0]}x{res['data_sensor_size'][0][1]}" in table
    trk = res["per_dt"][0]["tracking"]
    assert trk["windows"] == 4 * 6 and trk["gt_objects"] > 0 and {"mota", "idf1", "id_switches"} <= set(trk)
    assert res["per_dt"][0]["all"]["n_gt"] > 0 and set(res["per_dt"][0]["separation"]) == {"1", "2", "3", "4"}


def test_resume_after_an_ofs_only_run_may_pick_the_ofpd_grid(data, tmp_path, capsys):
    """A finished `--stage ofs` run trained no OFPD, so its progress holds no OFPD settings to
    keep: `--resume --stage all --ofpd-pool 2` trains the OFPD on that grid (a review of the
    fix for fitted keys found it refused as "other settings")."""
    ck = tmp_path / "ck"
    args = ["train", "--data", str(data), "--out", str(ck), "--ofs-epochs", "1", "--windows-per-seq", "3",
            "--no-progress"]
    assert main(args + ["--stage", "ofs"]) == 0
    capsys.readouterr()
    assert main(args + ["--stage", "all", "--resume", "--epochs", "1", "--ofpd-pool", "2"]) == 0, capsys.readouterr().err
    assert load_checkpoint(ck).config.ofpd["pool"] == 2 and "OFPD" not in load_checkpoint(ck).config.untrained


def test_train_rejects_missing_data_in_one_line(tmp_path, capsys):
    assert main(["train", "--data", str(tmp_path / "nope"), "--out", str(tmp_path / "ck")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "data directory does not exist" in err


def test_train_out_naming_a_file_or_the_data_is_refused_before_training(data, tmp_path, capsys):
    """--out at an existing file trained a stage, then moved the file aside to a hidden name,
    left a half-trained checkpoint in its place (which export took) and failed: now one line,
    before any training, the file as it was; --out at the data set is refused too."""
    f = tmp_path / "notes.txt"
    f.write_text("mine")
    for out, needle in ((f, "not a directory"), (data, "would overwrite the data set")):
        assert main(["train", "--data", str(data), "--out", str(out), "--ofs-epochs", "1", "--epochs", "1",
                     "--windows-per-seq", "1", "--no-progress"]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and needle in err, err
    assert f.read_text() == "mine" and sorted(p.name for p in tmp_path.iterdir()) == ["notes.txt"]
    assert (data / "index.json").is_file()


def test_out_at_a_bundle_and_untrained_parts_are_refused_before_training(data, tmp_path, capsys, make_bundle):
    """--out at a deploy bundle: training wrote its checkpoint into it, exit 0, and the bundle's
    hashes failed from then on. --epochs 0 / --ofs-epochs 0 from scratch wrote a random OFPD or
    DOTIE's OFS stages, exit 0 (with --init-from, 0 keeps that checkpoint's: a test above)."""
    bundle = make_bundle(tmp_path / "b")
    before = sorted((p.name, p.read_bytes()) for p in bundle.root.iterdir() if p.is_file())
    base = ["train", "--data", str(data), "--windows-per-seq", "1", "--no-progress"]
    for extra, needle in (([f"--out={bundle.root}", "--epochs", "1", "--ofs-epochs", "1"],
                           "a deploy bundle (export's output), which training would overwrite"),
                          (["--out", str(tmp_path / "c1"), "--epochs", "0"], "--epochs 0 would leave the OFPD untrained"),
                          (["--out", str(tmp_path / "c2"), "--ofs-epochs", "0", "--stage", "ofs"],
                           "--ofs-epochs 0 would leave the OFS stages untrained"),
                          (["--out", str(tmp_path / "c3"), "--epochs", "-1"], "--epochs must be >= 0, got -1")):
        assert main(base + extra) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and needle in err, err
    assert sorted((p.name, p.read_bytes()) for p in bundle.root.iterdir() if p.is_file()) == before
    assert not any((tmp_path / c).exists() for c in ("c1", "c2", "c3"))


def test_training_on_data_without_some_speed_bins_warns(tmp_path, capsys):
    """One training sequence holds one speed bin: the other stages trained on nothing, silently
    (their loss curves alike, export's parity a pass on no spikes); now a warning names them."""
    d = tmp_path / "one"
    assert main(["dataset", "synth", "--out", str(d), "--split", "train", "--limit", "1", "--duration-s", "0.01",
                 "--no-progress"]) == 0
    capsys.readouterr()
    assert main(["train", "--data", str(d), "--out", str(tmp_path / "ck"), "--stage", "ofs", "--ofs-epochs", "1",
                 "--windows-per-seq", "2", "--no-progress"]) == 0
    log = json.loads((tmp_path / "ck" / "train_log.json").read_text())["windows_per_bin"]
    empty = [k for k, n in log.items() if n == 0]
    assert empty and f"no training window of speed bin {', '.join(empty)}" in capsys.readouterr().err


def test_stage_ofpd_needs_trained_ofs(data, tmp_path, capsys):
    assert main(["train", "--data", str(data), "--out", str(tmp_path / "empty"), "--stage", "ofpd"]) == 2
    assert "--stage ofpd needs a checkpoint" in capsys.readouterr().err


def test_stage_ofpd_and_resume_refuse_data_of_another_sensor_and_record_the_data(data, tmp_path, capsys):
    """--stage ofpd (and --resume) go on training a checkpoint at its sensor size: data of
    another size is refused, one line, the checkpoint as it was (it trained, exit 0, and kept
    saying the old size and data set); another data set of that size is recorded."""
    from toffe_deploy.checkpoint import init_checkpoint
    from toffe_deploy.config import ToffeConfig

    small = tmp_path / "small"
    assert main(["dataset", "synth", "--out", str(small), "--split", "train", "--limit", "1", "--duration-s", "0.005",
                 "--sensor-size", "64x48", "--no-progress"]) == 0
    ck = tmp_path / "ck"
    init_checkpoint(ck, ToffeConfig(dataset={"data_dir": "/elsewhere"}), seed=1)
    before = (ck / "ofpd.safetensors").read_bytes()
    capsys.readouterr()
    assert main(["train", "--data", str(small), "--out", str(ck), "--epochs", "1", "--no-progress", "--stage",
                 "ofpd"]) == 2                           # (--resume of a run goes through the same check)
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "its sequences are 64x48" in err and "is for 640x480" in err, err
    assert (ck / "ofpd.safetensors").read_bytes() == before
    assert main(["train", "--data", str(data), "--out", str(ck), "--stage", "ofpd", "--epochs", "1",
                 "--windows-per-seq", "2", "--no-progress"]) == 0
    got = load_checkpoint(ck).config.dataset
    assert got["data_dir"] == str(data) and got["ofs_dataset"] == {"data_dir": "/elsewhere"}


def test_a_stage_ofs_checkpoint_says_its_ofpd_is_untrained_until_trained(data, tmp_path, capsys):
    """--stage ofs from scratch writes a random OFPD: export bundled it without a word (end to
    end "pass"); now the checkpoint records it, export warns, and --stage ofpd clears it."""
    ck = tmp_path / "ck"
    base = ["train", "--data", str(data), "--out", str(ck), "--windows-per-seq", "2", "--no-progress"]
    assert main(base + ["--stage", "ofs", "--ofs-epochs", "1"]) == 0
    assert load_checkpoint(ck).config.dataset["untrained"] == ["OFPD"]
    capsys.readouterr()
    assert main(["export", str(ck), "-o", str(tmp_path / "b"), "--checks", "none", "--no-progress"]) == 0
    err = capsys.readouterr().err
    assert "warning: the checkpoint holds parts never trained: OFPD" in err, err
    manifest = json.loads((tmp_path / "b" / "manifest.json").read_text())
    assert any("never trained: OFPD" in w for w in manifest["warnings"])
    assert main(base + ["--stage", "ofpd", "--epochs", "1"]) == 0
    assert "untrained" not in load_checkpoint(ck).config.dataset


def test_resume_on_another_data_set_records_it(data, capsys):
    """A --resume on another data set of the same camera went on (with a warning) but the
    checkpoint kept naming the first data set; now it names the one it finished on."""
    from toffe_deploy.config import ToffeConfig
    from toffe_deploy.model.data import find_sequences
    from toffe_deploy.model.train import same_camera_data

    first = ToffeConfig(dataset={"data_dir": "/elsewhere"})
    got = same_camera_data(first, find_sequences(data, "train"), data, 0, data / "ck", resume=True).dataset
    assert got["data_dir"] == str(data) and got["resumed_from_dataset"] == {"data_dir": "/elsewhere"}
    assert "began on /elsewhere; it goes on with this data set" in capsys.readouterr().err


def test_ofpd_pool_retrains_only_the_ofpd(data, tmp_path, capsys):
    from toffe_deploy.checkpoint import init_checkpoint
    from toffe_deploy.config import ToffeConfig
    from toffe_deploy.ofpd_io import input_shape

    ck = tmp_path / "ck"
    init_checkpoint(ck, ToffeConfig(ofpd={"pool": 2}), seed=1)
    before = load_checkpoint(ck)
    (ck / "train_log.json").write_text(json.dumps({"ofs_stage1": {"threshold": 1.5}, "ofpd_loss": [[9, 9, 9]]}))
    assert main(["train", "--data", str(data), "--out", str(ck), "--stage", "ofpd", "--ofpd-pool", "8",
                 "--ofpd-kernels", "5,3", "--epochs", "1", "--windows-per-seq", "3", "--no-progress"]) == 0
    after = load_checkpoint(ck)
    assert after.config.ofpd["pool"] == 8 and input_shape(after.config)[1:] == (16, 16)
    assert after.config.ofpd["conv_kernels"] == [5, 3] and after.ofpd_state["conv1.weight"].shape[-1] == 5
    assert after.ofpd_state["fc.weight"].shape[1] < before.ofpd_state["fc.weight"].shape[1]
    log = json.loads((ck / "train_log.json").read_text())
    assert log["ofpd_samples"] > 0 and len(log["ofpd_loss"]) == 1 and log["ofpd_loss"] != [[9, 9, 9]]
    assert log["ofs_stage1"] == {"threshold": 1.5}          # the kept OFS stages keep their record
    for a, b in zip(before.ofs, after.ofs):            # the OFS stages are kept as they were
        np.testing.assert_array_equal(a["weight"], b["weight"])
    capsys.readouterr()
    assert main(["train", "--data", str(data), "--out", str(ck), "--stage", "ofpd", "--ofpd-pool", "3",
                 "--epochs", "1", "--no-progress"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "--ofpd-pool 3" in err and load_checkpoint(ck).config.ofpd["pool"] == 8
    assert main(["train", "--data", str(data), "--out", str(ck), "--stage", "ofpd", "--ofpd-kernels", "4,3",
                 "--epochs", "1", "--no-progress"]) == 2
    assert "two odd sizes" in capsys.readouterr().err


def test_speed_loss_options_train_and_are_logged(data, tmp_path):
    """--speed-balance / --speed-edge-weight reach the OFPD training (their loss: test_train_speed_loss)
    and are logged; without them the log says nothing (the plain L1)."""
    from toffe_deploy.checkpoint import init_checkpoint
    from toffe_deploy.config import ToffeConfig

    states = []
    for extra in ([], ["--speed-balance", "--speed-edge-weight", "2"]):
        ck = tmp_path / ("ck" + str(len(states)))
        init_checkpoint(ck, ToffeConfig(), seed=1)
        assert main(["train", "--data", str(data), "--out", str(ck), "--stage", "ofpd", "--epochs", "1",
                     "--windows-per-seq", "3", "--no-progress", "--seed", "2"] + extra) == 0
        log = json.loads((ck / "train_log.json").read_text())
        assert log.get("ofpd_speed_loss") == ({"balance": True, "edge_weight": 2.0} if extra else None)
        assert log["ofpd_samples"] > 0 and len(log["ofpd_loss"]) == 1
        states.append(ck)


def test_resume_goes_on_with_the_interrupted_ofpd_settings():
    from toffe_deploy.config import ToffeConfig
    from toffe_deploy.model.train import resolve_ofpd_settings
    from toffe_deploy.ofpd_io import ofpd_settings

    ck = ToffeConfig(ofpd={"pool": 2, "conv_kernels": [5, 3]})     # on disk until the OFPD run ends
    cfg, fresh = resolve_ofpd_settings(ck, 4, (3, 3))
    assert fresh and ofpd_settings(cfg)["pool"] == 4
    saved = ofpd_settings(cfg)                                       # the interrupted run's settings
    for pool, kernels in ((None, None), (4, (3, 3))):               # --resume, with or without the options
        again, fresh = resolve_ofpd_settings(ck, pool, kernels, saved)
        assert fresh and ofpd_settings(again) == saved
    with pytest.raises(ValueError, match="cannot resume"):
        resolve_ofpd_settings(ck, 8, None, saved)
    same, fresh = resolve_ofpd_settings(cfg, None, None, saved)     # finished run: nothing changes
    assert not fresh and same is cfg


def test_init_from_fine_tunes_in_the_zero_reset_arithmetic(data, tmp_path, capsys):
    """--init-from CKPT --reset zero: the config says zero, the OFS stages start from CKPT's
    (not DOTIE's) and change; --stage ofpd cannot switch the reset of trained stages."""
    from toffe_deploy.checkpoint import dotie_ofs, init_checkpoint
    from toffe_deploy.config import ToffeConfig

    src = tmp_path / "src"
    cfg = ToffeConfig(sensor_size=(640, 480), ofpd={"pool": 4})
    init_checkpoint(src, cfg, seed=1)
    base = load_checkpoint(src)
    base.ofs[0]["threshold"] = 0.7                    # not DOTIE's: the start point must be visible
    from toffe_deploy.checkpoint import save_checkpoint
    save_checkpoint(src, base.config, base.ofs, base.ofpd_state)
    ck = tmp_path / "ck"
    assert main(["train", "--data", str(data), "--out", str(ck), "--stage", "ofs", "--init-from", str(src),
                 "--reset", "zero", "--ofs-epochs", "1", "--windows-per-seq", "3", "--no-progress"]) == 0
    got = load_checkpoint(ck)
    assert got.config.reset == "zero" and got.config.dataset["init_from"] == str(src)
    assert base.config.reset == "subtract"
    assert any(not np.allclose(a["weight"], b["weight"]) for a, b in zip(got.ofs, dotie_ofs(cfg)))
    trained = json.loads((ck / "train_log.json").read_text())["ofs_stage1"]["trained_threshold"]
    assert abs(trained - 0.7) < abs(trained - dotie_ofs(cfg)[0]["threshold"])   # started from src's 0.7
    capsys.readouterr()
    assert main(["train", "--data", str(data), "--out", str(tmp_path / "ck2"), "--stage", "ofs", "--init-from",
                 str(src), "--dt", "1000", "--ofs-epochs", "1", "--no-progress"]) == 2    # fine-tuning keeps dt
    assert "the --init-from checkpoint has dt 500, so --dt 1000 would not apply" in capsys.readouterr().err
    before = {f.name: f.read_bytes() for f in src.iterdir() if f.is_file()}   # --out the checkpoint it starts
    assert main(["train", "--data", str(data), "--out", str(src), "--stage", "ofs", "--init-from", str(src),  # from:
                 "--ofs-epochs", "1", "--windows-per-seq", "3", "--no-progress"]) == 2                 # refused,
    err = capsys.readouterr().err                                                 # before any work (it was
    assert "--out would overwrite the --init-from checkpoint" in err and len(err.strip().splitlines()) == 1
    assert {f.name: f.read_bytes() for f in src.iterdir() if f.is_file()} == before   # silently replaced)
    assert main(["train", "--data", str(data), "--out", str(ck), "--stage", "ofpd", "--reset", "subtract",
                 "--no-progress"]) == 2
    assert "reset 'zero'" in capsys.readouterr().err


def test_train_and_eval_with_input_support(data, tmp_path, capsys):
    """--input-support reaches the new checkpoint's config; training crops, noise crops and eval
    (with tracking: consecutive windows) run through the front end with the K windows before."""
    ck = tmp_path / "ck"
    assert main(["train", "--data", str(data), "--out", str(ck), "--ofs-epochs", "1", "--windows-per-seq", "5",
                 "--no-progress", "--epochs", "1", "--input-support", "4,1,5,2"]) == 0
    assert load_checkpoint(ck).config.input_support == (4, 1, 5, 2)
    assert json.loads((ck / "config.json").read_text())["input_support"] == [4, 1, 5, 2]
    out_json = tmp_path / "eval.json"
    assert main(["eval", str(ck), "--data", str(data), "--max-windows", "2", "--track-windows", "3",
                 "--json", str(out_json), "--no-progress"]) == 0
    assert json.loads(out_json.read_text())["per_dt"][0]["all"]["n_gt"] > 0
    capsys.readouterr()
    assert main(["train", "--data", str(data), "--out", str(tmp_path / "bad"), "--input-support", "4,1,5"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "--input-support" in err and "input_support must be" in err


def test_a_data_set_of_one_camera_states_the_bins_for_that_camera(tmp_path, random_events):
    """make_config: training files all recorded with one focal length (an EVK4's 1646 px) give a
    config stated for that camera (manifest and `run` without --focal-px then speak of it), with
    the same image-plane bins (px/ms) as the reference; files of several focal lengths (the
    randomized data set) the reference camera's 60 deg field of view over the data's width (they
    kept its 554 px at every width)."""
    from pathlib import Path

    from toffe_deploy.config import ToffeConfig
    from toffe_deploy.events.fmt_toffe import write_events_h5
    from toffe_deploy.model.train import make_config

    from toffe_deploy.camera import focal_px_from_hfov

    ref = ToffeConfig()
    for focals, want in (((1646.0, 1646.0), 1646.0), ((1646.0, 900.0), focal_px_from_hfov(128, 60.0))):
        files = []
        for i, f in enumerate(focals):
            path = tmp_path / f"{len(focals)}_{f:g}_{i}.h5"
            write_events_h5(path, random_events(sensor_size=(128, 72)), (128, 72), attrs={"focal_px": f})
            files.append(path)
        cfg = make_config(files, Path(tmp_path), 500, 0, "first", 5, 4)
        assert cfg.sensor_size == (128, 72) and cfg.focal_px == pytest.approx(want)
        assert np.allclose(cfg.speed_bins_px_ms, ref.speed_bins_px_ms, rtol=1e-12)
        assert np.allclose(cfg.speed_scale.to_px_ms(np.array(cfg.representative_speeds)),
                           ref.speed_scale.to_px_ms(np.array(ref.representative_speeds)), rtol=1e-12)


def test_init_from_takes_the_camera_of_the_data_it_trains_on(tmp_path):
    """--init-from: the start checkpoint's model settings, but the new data's sensor size and
    focal length (speed bins in m/s for that camera, the same px/ms bins) and provenance."""
    from toffe_deploy.config import ToffeConfig
    from toffe_deploy.model.data import find_sequences
    from toffe_deploy.model.train import init_config

    d = tmp_path / "cam"
    assert main(["dataset", "synth", "--out", str(d), "--split", "train", "--limit", "1", "--duration-s", "0.005",
                 "--appearance", "random", "--sensor-size", "160x120", "--focal-px", "140,140", "--no-progress"]) == 0
    start = ToffeConfig(sensor_size=(640, 480), ofpd={"pool": 4}, input_min_cluster=3)
    got = init_config(start, find_sequences(d, "train"), d, 5, tmp_path / "src")
    assert got.sensor_size == (160, 120) and got.focal_px == pytest.approx(140.0)
    assert got.input_min_cluster == 3                                   # the model's settings are kept
    np.testing.assert_allclose(got.speed_bins_px_ms, start.speed_bins_px_ms)
    assert got.speed_bins[0][1] == pytest.approx(start.speed_bins[0][1] * start.focal_px / 140.0)
    assert got.dataset["init_from"] == str(tmp_path / "src") and got.dataset["train_seed"] == 5


def test_init_from_starts_the_ofpd_from_that_checkpoints(data, tmp_path, capsys):
    """--init-from CKPT (--stage all) fine-tunes CKPT's OFPD: it trained a new one from random
    weights (with --epochs 0 the written OFPD was not CKPT's)."""
    from toffe_deploy.checkpoint import init_checkpoint
    from toffe_deploy.config import ToffeConfig

    src = tmp_path / "src"
    init_checkpoint(src, ToffeConfig(sensor_size=(640, 480)), seed=1)
    ck = tmp_path / "ck"
    assert main(["train", "--data", str(data), "--out", str(ck), "--init-from", str(src), "--ofs-epochs", "1",
                 "--epochs", "0", "--windows-per-seq", "2", "--no-progress"]) == 0
    capsys.readouterr()
    want, got = load_checkpoint(src).ofpd_state, load_checkpoint(ck).ofpd_state
    assert set(got) == set(want) and all(np.array_equal(np.asarray(got[k]), np.asarray(want[k])) for k in want)


def test_an_interrupted_run_leaves_the_checkpoint_as_it_was_and_resume_finishes_it(data, tmp_path, capsys,
                                                                                     monkeypatch):
    """Training into an existing checkpoint, stopped after its OFS stages (Ctrl-C while the OFPD's
    set is built): --out keeps the old checkpoint byte for byte (no new OFS stages beside an OFPD
    trained for the old ones); the finished stages wait in .train_state/checkpoint, and --resume
    continues from them and writes them, with the OFPD, into --out."""
    import toffe_deploy.model.train as tr

    ck = tmp_path / "ck"
    args = ["train", "--data", str(data), "--out", str(ck), "--ofs-epochs", "1", "--windows-per-seq", "5",
            "--no-progress", "--epochs", "1"]
    assert main(args + ["--seed", "3"]) == 0
    files = ("config.json", "ofs.safetensors", "ofpd.safetensors")
    before = {f: (ck / f).read_bytes() for f in files}

    def stop(*a, **k):
        raise KeyboardInterrupt
    with monkeypatch.context() as m:
        m.setattr(tr, "build_ofpd_set", stop)
        capsys.readouterr()
        assert main(args + ["--seed", "4"]) == 130
    err = capsys.readouterr().err.strip().splitlines()          # what is left, and how to go on
    assert err[-2:] == [f"toffe-deploy: {ck}: left as it was; `train ... --resume` with the same options continues "
                        "from the stages this run finished", "toffe-deploy: interrupted"], err
    assert {f: (ck / f).read_bytes() for f in files} == before
    pending = load_checkpoint(ck / ".train_state" / "checkpoint")
    old = load_checkpoint(ck)
    assert any(not np.array_equal(a["weight"], b["weight"]) for a, b in zip(pending.ofs, old.ofs))
    capsys.readouterr()

    assert main(args + ["--seed", "4", "--resume"]) == 0
    new = load_checkpoint(ck)
    for a, b in zip(pending.ofs, new.ofs):
        np.testing.assert_array_equal(a["weight"], b["weight"])
    assert not (ck / ".train_state" / "checkpoint").exists()


def test_resume_continues_only_its_own_run(data, tmp_path, capsys, monkeypatch):
    """--resume after a run stopped inside its OFS stages: --stage ofpd --resume is refused (an
    OFPD on half-new OFS stages), another --seed is refused; a new run without --resume drops the
    progress of the runs before it, so a --resume after its own early stop is a new run (with a
    warning), never a continuation of an older run."""
    import toffe_deploy.model.train as tr

    ck = tmp_path / "ck"
    args = ["train", "--data", str(data), "--out", str(ck), "--ofs-epochs", "1", "--windows-per-seq", "5",
            "--no-progress", "--epochs", "1"]
    assert main(args + ["--seed", "3"]) == 0
    real, calls = tr.train_ofs_stage, []

    def stop_at(n):
        def stage(*a, **k):
            calls.append(1)
            if len(calls) >= n:
                raise KeyboardInterrupt
            return real(*a, **k)
        return stage
    with monkeypatch.context() as m:                     # seed 4 stopped after 2 of its 4 OFS stages
        m.setattr(tr, "train_ofs_stage", stop_at(3))
        assert main(args + ["--seed", "4"]) == 130
    capsys.readouterr()
    assert main(args + ["--seed", "4", "--stage", "ofpd", "--resume"]) == 2
    assert "finished OFS stages [1, 2] of 1-4" in capsys.readouterr().err
    assert main(args + ["--seed", "5", "--resume"]) == 2
    assert "--seed 4, not 5" in capsys.readouterr().err
    # options the resumed run cannot honour: refused (--reset zero rewrote the config over stages
    # trained with subtract; --dt 1000 trained and wrote a 500 us checkpoint, both exit 0)
    for extra, says in ((["--reset", "zero"], "trains reset 'subtract', not --reset zero"),
                        (["--dt", "1000"], "has dt 500, so --dt 1000 would not apply"),
                        (["--ofs-kernel", "3"], "has ofs-kernel 5, so --ofs-kernel 3"),
                        (["--input-support", "4,2,5,2"], "has input-support off, so --input-support 4,2,5,2")):
        assert main(args + ["--seed", "4", "--resume"] + extra) == 2
        err = capsys.readouterr().err
        assert says in err and "resume with its options" in err and len(err.strip().splitlines()) == 1, err
    assert main(args + ["--seed", "4", "--stage", "ofpd", "--min-cluster", "2"]) == 2       # --out's checkpoint
    assert "the checkpoint --stage ofpd trains on has min-cluster 4" in capsys.readouterr().err

    calls.clear()
    with monkeypatch.context() as m:                     # a new run (seed 6) stopped before any stage finished
        m.setattr(tr, "train_ofs_stage", stop_at(1))
        assert main(args + ["--seed", "6"]) == 130
    assert not (ck / ".train_state").exists()            # seed 4's progress is not seed 6's
    capsys.readouterr()
    assert main(args + ["--seed", "6", "--resume"]) == 0
    assert "no training progress to resume" in capsys.readouterr().err
    assert json.loads((ck / ".train_state" / "state.json").read_text())["seed"] == 6


def test_a_deeply_nested_training_progress_is_one_line(tmp_path):
    """state.json nested deeper than the parser's stack raised RecursionError, not InputError."""
    from toffe_deploy.errors import InputError
    from toffe_deploy.model.train import STATE_DIR, _load_state

    (tmp_path / STATE_DIR).mkdir()
    (tmp_path / STATE_DIR / "state.json").write_text("[" * 3000 + "]" * 3000)
    with pytest.raises(InputError, match="state.json: cannot read the training progress"):
        _load_state(tmp_path)


def test_train_dt_beyond_the_longest_window_is_refused(tmp_path, capsys):
    """A --dt the saved config would refuse (config.MAX_DT_US) is refused before the training."""
    assert main(["train", "--data", str(tmp_path), "--out", str(tmp_path / "ck"), "--dt", "10000000000"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--dt must be <= 1000000000 us" in err and not (tmp_path / "ck").exists()


def test_a_directory_with_only_a_stopped_runs_progress_says_resume(tmp_path, capsys):
    """export of an --out whose first training run was stopped (only .train_state/ in it) said
    "not a checkpoint directory" and nothing of how to finish it."""
    (tmp_path / "ck" / ".train_state").mkdir(parents=True)
    assert main(["export", str(tmp_path / "ck"), "-o", str(tmp_path / "b"), "--checks", "none", "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "not a checkpoint directory" in err and "--resume" in err, err
