"""How the command line reads what users type: option errors on one line, negative ranges,
--sensor-size W H, options that apply to part of a request, and inputs that are refused
before any work (real parser, real files on disk)."""
from __future__ import annotations

import argparse
import json

import numpy as np
import pytest

from toffe_deploy.cli import join_negative_values, main
from toffe_deploy.events.core import make_events
from toffe_deploy.events.fmt_toffe import write_events_h5


def _error(capsys, argv) -> tuple[int, str]:
    try:
        rc = main(argv)
    except SystemExit as exc:
        rc = exc.code
    return rc, capsys.readouterr().err


def test_a_bad_option_value_is_one_line_and_exit_2(capsys):
    rc, err = _error(capsys, ["run", "--target", "nope"])
    assert rc == 2 and err.count("\n") == 1
    assert err.startswith("toffe-deploy run: error: argument --target") and "--help for usage" in err


@pytest.mark.parametrize("argv, prog", [(["run", "--bogus"], "toffe-deploy run"),
                                        (["run", "a", "b"], "toffe-deploy run"),
                                        (["events", "info", "x", "--bogus"], "toffe-deploy events info"),
                                        (["events", "--bogus"], "toffe-deploy events"),
                                        (["--bogus"], "toffe-deploy")])
def test_an_unknown_option_names_the_command_it_was_given_to(capsys, argv, prog):
    """An unknown option or a stray argument is the command's error, with its --help (it was
    reported by the top-level parser: "toffe-deploy: error: unrecognized arguments")."""
    rc, err = _error(capsys, argv)
    assert rc == 2 and err.count("\n") == 1
    assert err.startswith(f"{prog}: error: unrecognized arguments: ") and f"({prog} --help for usage)" in err


def test_negative_ranges_and_two_word_sensor_sizes_are_read_as_typed():
    assert join_negative_values(["--object-contrast", "-1.5,-0.3", "--seed", "-2"]) == \
        ["--object-contrast=-1.5,-0.3", "--seed", "-2"]
    assert join_negative_values(["info", "--sensor-size", "640", "480", "f.npy"]) == \
        ["info", "--sensor-size", "640x480", "f.npy"]


def test_synth_keeps_a_given_negative_contrast_dark_and_refuses_zero(tmp_path, capsys):
    out = tmp_path / "d"
    assert main(["dataset", "synth", "--out", str(out), "--split", "appearance", "--limit", "1", "--duration-s",
                 "0.002", "--sensor-size", "64x48", "--object-contrast", "-1.0", "--no-progress"]) == 0
    (seq,) = json.loads((out / "index.json").read_text())["sequences"]
    assert [o["polarity"] for o in seq["appearance"]["objects"]] == ["dark"]
    rc, err = _error(capsys, ["dataset", "synth", "--out", str(tmp_path / "z"), "--split", "appearance",
                              "--object-contrast", "0"])
    assert rc == 2 and "fires no events" in err


def test_synth_warns_when_camera_options_skip_the_paper_splits(tmp_path, capsys):
    assert main(["dataset", "synth", "--out", str(tmp_path / "d"), "--split", "appearance", "--limit", "1",
                 "--duration-s", "0.002", "--sensor-size", "64x48", "--focal-px", "80", "--no-progress"]) == 0
    assert "warning" not in capsys.readouterr().err            # every split asked for honours it
    from toffe_deploy.commands import dataset as ds

    parser = argparse.ArgumentParser()
    ds.register(parser.add_subparsers())
    args = parser.parse_args(["dataset", "synth", "--out", "x", "--focal-px", "80"])
    ds._ranges(args, ("train", "test", "appearance"))   # train is random by default, test paper
    err = capsys.readouterr().err
    assert "warning: --focal-px applies to the random-appearance splits only: test keep" in err


def test_run_refuses_an_unknown_live_scheme_and_nan_timeouts(capsys, make_bundle, tmp_path):
    rc, err = _error(capsys, ["run", "--events", "tcp://127.0.0.1:7777"])
    assert rc == 2 and "unknown live source" in err
    rc, err = _error(capsys, ["run", "--events", "udp://127.0.0.1:9", "--sensor-size", "64x48", "--idle-timeout",
                              "nan"])
    assert rc == 2 and "finite" in err
    bundle = str(make_bundle(tmp_path).root)
    rc, err = _error(capsys, ["run", bundle, "--events", "udp://127.0.0.1:99999", "--sensor-size", "64x48"])
    assert rc == 2 and err.strip() == "toffe-deploy: error: udp://127.0.0.1:99999: port 99999 is out of range (0..65535)"
    rc, err = _error(capsys, ["run", bundle, "--events", "udp://127.0.0.1:9", "--sensor-size", "64x48",
                              "--queue-events", "0"])
    assert rc == 2 and err.strip() == "toffe-deploy: error: --queue-events must be >= 1, got 0"
    rc, err = _error(capsys, ["run", bundle, "--events", "udp://127.0.0.1:0", "--sensor-size", "40000x40000"])
    assert rc == 2 and "reading" not in err and "larger than" in err and err.count("\n") == 1


def test_convert_to_npz_says_what_it_cannot_keep(tmp_path, capsys):
    ev = make_events(np.array([1, 2]), np.array([1, 2]), np.array([100, 200]), np.array([0, 1]))
    src = tmp_path / "a.h5"
    gt = {"t": np.array([0, 300]), "object_id": np.zeros(2, np.int64), "x": np.ones(2), "y": np.ones(2),
          "speed": np.ones(2), "direction": np.zeros(2), "speed_bin": np.ones(2, np.int64),
          "visible": np.ones(2, bool)}
    write_events_h5(src, ev, (8, 8), ground_truth=gt, t_range=(0, 500))
    assert main(["events", "convert", str(src), str(tmp_path / "a.npz"), "--no-progress"]) == 0
    err = capsys.readouterr().err
    assert "the ground truth and the recording's span [0, 500) us" in err and "not kept" in err
