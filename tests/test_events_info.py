"""`toffe-deploy events info`: the numbers it reports, as text and JSON."""
import json

import numpy as np

from toffe_deploy.cli import main
from toffe_deploy.events import make_events, write_events_h5


def _file(tmp_path):
    # 6 events, 4 ON, over [1000, 3000) us as recorded in the file; two objects of ground truth
    ev = make_events([0, 1, 2, 3, 4, 5], [0, 1, 2, 3, 4, 5], [1000, 1100, 1500, 2000, 2500, 2999],
                     [1, 1, 0, 1, 0, 1])
    gt = {"t": np.array([1000, 1000, 1050, 1050]), "object_id": np.array([0, 1, 0, 1]),
          "x": np.zeros(4), "y": np.zeros(4), "direction": np.zeros(4), "speed": np.array([10.0, 50, 11, 51]),
          "speed_bin": np.array([1, 3, 1, 3]), "visible": np.array([True, True, True, False])}
    path = tmp_path / "seq.h5"
    write_events_h5(path, ev, (40, 30), ground_truth=gt, attrs={"seed": 11, "generator": {"v": 1}},
                    t_range=(1000, 3000))
    return path


def test_info_json(tmp_path, capsys):
    path = _file(tmp_path)
    assert main(["events", "info", "--json", str(path)]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["events"] == 6 and info["format"] == "toffe-events"
    assert (info["sensor_width"], info["sensor_height"]) == (40, 30)
    assert info["duration_s"] == 0.002
    assert info["event_rate_eps"] == 3000.0               # 6 events / 2 ms
    assert (info["on_events"], info["off_events"]) == (4, 2)
    assert info["x_range"] == [0, 5]
    gt = info["ground_truth"]
    assert gt["objects"] == 2 and gt["rows"] == 4 and gt["sample_period_us"] == 50
    assert gt["visible_rows_per_speed_bin"] == {"1": 2, "3": 1}
    assert info["attrs"]["seed"] == 11


def test_info_text(tmp_path, capsys):
    path = _file(tmp_path)
    assert main(["events", "info", "--no-progress", str(path)]) == 0
    out = capsys.readouterr().out
    assert "events:          6" in out
    assert "40 x 30 px" in out
    assert "duration:        0.002000 s" in out
    assert "4 ON / 2 OFF (66.7 % ON)" in out
    assert "2 object(s)" in out and "seed:            11" in out


def test_help_texts(capsys):
    for argv in (["events", "--help"], ["events", "info", "--help"], ["events", "convert", "--help"]):
        try:
            main(argv)
        except SystemExit as exc:
            assert exc.code == 0
        assert "--sensor-size" in capsys.readouterr().out or argv == ["events", "--help"]
