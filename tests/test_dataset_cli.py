"""`toffe-deploy dataset synth|show` end to end on real files in tmp_path."""
from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from toffe_deploy.cli import main
from toffe_deploy.dataset.groundtruth import window_truth
from toffe_deploy.events.io import open_events, write_events_h5


@pytest.fixture(scope="module")
def synth_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("synth")
    assert main(["dataset", "synth", "--out", str(out), "--split", "test", "--limit", "4",
                 "--duration-s", "0.01", "--seed", "3"]) == 0
    return out


def test_synth_writes_files_and_index(synth_dir):
    index = json.loads((synth_dir / "index.json").read_text())
    rows = index["sequences"]
    assert index["splits"] == {"train": 0, "test": 4, "multi": 0, "appearance": 0, "pairs": 0, "crossing": 0}
    assert sorted(r["speed_bin"] for r in rows) == [1, 2, 3, 4]  # --limit keeps every bin
    for r in rows:
        assert {"shape", "trajectory", "orientation_deg", "direction", "sensor_size"} <= set(r)
        with open_events(synth_dir / r["file"]) as src:
            assert src.sensor_size == (640, 480) and src.num_events == r["n_events"] > 0
            assert (src.t_start_us, src.t_end_us) == (0, 10000)
            gt = src.ground_truth
            assert gt["t"].shape[0] == 200 and set(np.unique(gt["speed_bin"])) <= {r["speed_bin"], r["speed_bin"] - 1,
                                                                                r["speed_bin"] + 1}
            assert src.attrs["seed"] == r["seed"] and src.attrs["objects"][0]["shape"] == r["shape"]
            assert len(window_truth(gt, 0, 5000)) == 1


def test_synth_resumes_and_adds_splits(synth_dir, capsys):
    files = sorted(synth_dir.rglob("*.h5"))
    mtimes = [f.stat().st_mtime_ns for f in files]
    assert main(["dataset", "synth", "--out", str(synth_dir), "--split", "test", "--limit", "4",
                 "--duration-s", "0.01", "--seed", "3"]) == 0
    assert [f.stat().st_mtime_ns for f in files] == mtimes  # up to date: not rewritten
    assert main(["dataset", "synth", "--out", str(synth_dir), "--split", "multi", "--multi-count", "1",
                 "--duration-s", "0.005", "--seed", "3"]) == 0
    index = json.loads((synth_dir / "index.json").read_text())
    assert index["splits"] == {"train": 0, "test": 4, "multi": 1, "appearance": 0, "pairs": 0, "crossing": 0}  # test rows kept
    assert index["sequences"][-1]["n_objects"] >= 2
    assert "5 sequences" in capsys.readouterr().out


def test_show_writes_png_with_truth(synth_dir, tmp_path, capsys):
    f = next((synth_dir / "test").glob("*.h5"))
    png = tmp_path / "look.png"
    assert main(["dataset", "show", str(f), "--out", str(png), "--dt-us", "2000", "--frames", "3", "--cols", "3"]) == 0
    img = cv2.imread(str(png))
    assert img.shape == (480, 3 * 640, 3)
    grey = (img[..., 0] == img[..., 1]) & (img[..., 1] == img[..., 2])
    assert ((img[..., 0] == 225) & grey).any() and ((img[..., 0] == 115) & grey).any()  # ON and OFF events
    assert (img.max(2).astype(int) - img.min(2) > 60).any()          # coloured truth outline and arrow
    assert "3 object truths drawn" in capsys.readouterr().out
    light = tmp_path / "light.png"
    assert main(["dataset", "show", str(f), "--out", str(light), "--frames", "1", "--theme", "light"]) == 0
    assert (cv2.imread(str(light)) == 255).all(2).mean() > 0.5                  # mostly white background


def test_show_file_without_ground_truth(tmp_path, random_events):
    f = tmp_path / "plain.h5"
    write_events_h5(f, random_events(500, (64, 48), 10_000), (64, 48))
    assert main(["dataset", "show", str(f), "--out", str(tmp_path / "p.png"), "--frames", "1"]) == 0
    assert cv2.imread(str(tmp_path / "p.png")).shape == (48 * 8, 64 * 8, 3)   # small sensors upscaled (render.draw)


@pytest.mark.parametrize("argv, needle", [
    (["dataset", "show", "{tmp}/missing.h5"], "missing.h5"),
    (["dataset", "show", "{tmp}/bad.h5"], "bad.h5"),
    (["dataset", "show", "{tmp}/plain.npz", "--out", "{tmp}/x.jpg"], "must be a .png"),
    (["dataset", "synth", "--out", "{tmp}/afile"], "not a directory"),
    (["dataset", "synth", "--out", "{tmp}/brokenidx", "--split", "test", "--limit", "1"], "index.json"),
    (["dataset", "synth", "--out", "{tmp}/o", "--threshold", "0.1", "--threshold-sigma", "0.2"], "threshold-sigma"),
    (["dataset", "synth", "--out", "{tmp}/o", "--hfov-deg", "60", "--focal-px", "500"], "exclude each other"),
    # a focal length whose view the generator does not render (170 deg on 346 px: 15.1 px) wrote files with a
    # negative ground-truth depth, which run and events info then refused
    (["dataset", "synth", "--out", "{tmp}/o", "--split", "appearance", "--sensor-size", "346x260", "--focal-px",
      "14"], "15.14..1.982e+05 px"),
    (["dataset", "synth", "--out", "{tmp}/o", "--split", "test", "--size-px", "20"], "--appearance random"),
    (["dataset", "synth", "--out", "{tmp}/o", "--split", "train", "--limit", "1", "--object-contrast", "0.3",
      "--threshold", "0.1", "--threshold-sigma", "0", "--size-px", "20", "--noise-hz", "0"], "held-out region"),
])
def test_bad_input_is_one_line_exit_2(tmp_path, capsys, argv, needle, random_events):
    (tmp_path / "bad.h5").write_bytes(b"not hdf5 at all")
    (tmp_path / "afile").write_text("x")
    (tmp_path / "brokenidx").mkdir()
    (tmp_path / "brokenidx" / "index.json").write_text("{oops")
    from toffe_deploy.events.io import write_events_npz
    write_events_npz(tmp_path / "plain.npz", random_events(10, (32, 24)), (32, 24))
    assert main([a.replace("{tmp}", str(tmp_path)) for a in argv]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("toffe-deploy: error:") and needle in err and "\n" not in err


@pytest.mark.parametrize("edit, needle", [
    (lambda d: d["sequences"][0].__setitem__("file", 5), "sequences[0].file is 5, expected a non-empty string"),
    (lambda d: d["sequences"][0].__setitem__("file", ""), "sequences[0].file is '', expected a non-empty string"),
    (lambda d: d.__setitem__("sequences", [1, 2]), "sequences[0] is 1, expected an object"),
    (lambda d: d["sequences"][1].pop("split"), "sequences[1] lacks 'split'"),
    (lambda d: d["sequences"][0].__setitem__("name", None), "sequences[0].name is None"),
    (lambda d: d["sequences"][0].__setitem__("n_events", "12"), "sequences[0].n_events is '12', expected a whole"),
])
def test_malformed_index_rows_are_one_line_errors(synth_dir, tmp_path, capsys, edit, needle):
    """An index row that is no object, or whose file / name / split / n_events is missing or of the
    wrong type, gave TypeError / KeyError tracebacks (iter_split_files, build_dataset)."""
    d = json.loads((synth_dir / "index.json").read_text())
    edit(d)
    (tmp_path / "d").mkdir()
    (tmp_path / "d" / "index.json").write_text(json.dumps(d))
    for argv in (["train", "--data", str(tmp_path / "d"), "--out", str(tmp_path / "ck")],
                 ["dataset", "synth", "--out", str(tmp_path / "d"), "--split", "test", "--limit", "1"]):
        assert main(argv) == 2
        err = capsys.readouterr().err.strip()
        assert err.startswith("toffe-deploy: error:") and "index.json: " + needle in err and "\n" not in err


def test_bad_option_values_exit_2(tmp_path, capsys):
    for argv in (["--duration-s", "-1"], ["--limit", "0"], ["--noise-hz", "nan"], ["--size-px", "5,2"],
                 ["--sensor-size", "640"], ["--dark-fraction", "1.5"], ["--hot-pixels", "0,2"],
                 ["--threshold", "0.1,0.2,0.3"], ["--hfov-deg", "1e-300"], ["--hfov-deg", "0.05,60"],
                 ["--focal-px", "0.001"], ["--depth-m", "1e-9"], ["--depth-m", "2,1e9"]):
        with pytest.raises(SystemExit) as exc:
            main(["dataset", "synth", "--out", str(tmp_path), *argv])
        assert exc.value.code == 2


def test_synth_records_every_drawn_option(tmp_path):
    out = tmp_path / "r"
    argv = ["dataset", "synth", "--out", str(out), "--split", "test", "--appearance", "random", "--limit", "2",
            "--duration-s", "0.005", "--sensor-size", "96x72", "--hfov-deg", "50,70", "--depth-m", "3",
            "--size-px", "8,12", "--object-contrast", "-1", "--dark-fraction", "0", "--background", "0.3",
            "--threshold", "0.2,0.3", "--threshold-sigma", "0.01", "--refractory-us", "100", "--noise-hz", "5",
            "--hot-pixels", "1e-3", "--texture", "0.1", "--seed", "2"]
    assert main(argv) == 0
    rows = json.loads((out / "index.json").read_text())["sequences"]
    assert len(rows) == 2
    for r in rows:
        a = r["appearance"]
        assert a["sensor_size"] == [96, 72] and 50 <= a["hfov_deg"] <= 70 and a["appearance"] == "random"
        assert 0.2 <= a["threshold"] <= 0.3 and a["threshold_sigma"] == 0.01 and a["refractory_us"] == 100
        assert a["noise_hz"] == 5 and a["hot_pixels"] == 1e-3 and a["texture"] == 0.1 and a["background"] == 0.3
        (o,) = a["objects"]
        assert o["depth_m"] == 3 and 8 <= o["size_px"] <= 12 and o["polarity"] == "dark"
        assert o["log_contrast"] == pytest.approx(-1.0, abs=1e-3)
        with open_events(out / r["file"]) as src:
            assert src.sensor_size == (96, 72) and src.attrs["appearance"] == a
            gt = src.ground_truth
            assert {"speed_px_ms", "depth_m"} <= set(gt) and np.abs(gt["depth_m"] - 3).max() < 0.5
    assert main(argv) == 0   # reproducible: same digests, nothing rewritten
    assert json.loads((out / "index.json").read_text())["sequences"] == rows


def test_sequences_without_events_are_warned_about(tmp_path, capsys):
    assert main(["dataset", "synth", "--out", str(tmp_path / "d"), "--split", "test", "--limit", "1",
                 "--duration-s", "0.002", "--sensor-size", "10x10", "--no-progress"]) == 0
    err = capsys.readouterr().err
    assert "toffe-deploy: warning: 1 sequence(s) without a single event (test_" in err


def test_one_data_set_is_one_camera_and_unlisted_files_are_named(tmp_path, capsys):
    """A split of another sensor size into an existing data set wrote an index of two cameras,
    exit 0 (train and eval read one size): refused, the index as it was. A split regenerated with
    fewer sequences leaves the files it no longer lists: named in a warning (eval --split DIR/SPLIT/
    would read them)."""
    out = tmp_path / "d"
    base = ["dataset", "synth", "--out", str(out), "--duration-s", "0.005", "--no-progress"]
    assert main(base + ["--split", "test", "--limit", "3", "--sensor-size", "64x48"]) == 0
    assert main(base + ["--split", "multi", "--limit", "1", "--multi-count", "1", "--sensor-size", "64x48"]) == 0
    before = (out / "index.json").read_bytes()
    capsys.readouterr()
    assert main(base + ["--split", "test", "--limit", "1", "--sensor-size", "96x72"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "holds multi at 64x48; these splits would be 96x72" in err, err
    assert (out / "index.json").read_bytes() == before
    assert main(base + ["--split", "test", "--limit", "1", "--sensor-size", "64x48"]) == 0
    err = capsys.readouterr().err
    assert "test: 2 .h5 file(s) the index does not list" in err, err
