"""Every JSON line `run` writes validates against the shipped JSON Schema; the header describes the run."""
import json

import jsonschema
import pytest

from toffe_deploy.cli import main
from toffe_deploy.deploy.bundle import sha256_file
from toffe_deploy.schema import SCHEMA_PATH, load_schema


@pytest.fixture(scope="module")
def env(tmp_path_factory, make_bundle, make_recording):
    root = tmp_path_factory.mktemp("schema")
    return {"bundle": make_bundle(root), "rec": make_recording(root / "rec.h5", duration=0.02)}


def _run(env, capsys, tmp_path, *extra):
    out, summ = tmp_path / "o.jsonl", tmp_path / "s.json"
    rc = main(["run", str(env["bundle"].root), "--events", str(env["rec"]), "--out", str(out), "--summary-json",
               str(summ), "--no-progress", *extra])
    cap = capsys.readouterr()
    assert rc == 0, cap.err
    return [json.loads(s) for s in out.read_text().splitlines()], json.loads(summ.read_text()), cap.out


def test_every_line_of_a_run_validates_and_the_header_comes_first(env, capsys, tmp_path):
    lines, summ, text = _run(env, capsys, tmp_path)
    v = jsonschema.Draft202012Validator(load_schema())
    for ln in lines:
        v.validate(ln)
    head = lines[0]
    assert SCHEMA_PATH.name == "object_flow.v1.schema.json" and head["schema_version"] == 1
    assert head["type"] == "header" and all("type" not in ln for ln in lines[1:]) and len(lines) == 1 + 40
    assert head["bundle"]["manifest_sha256"] == sha256_file(env["bundle"].root / "manifest.json")
    assert head["target"] == "cpu" and head["sensor_size"] == [64, 48] and head["dt_us"] == 500
    assert head["y_axis"] == "down" and head["tracking"]["confirm_hits"] >= 1
    objs = [o for ln in lines[1:] for o in ln["objects"]]
    assert objs and all(isinstance(o["speed_clipped"], bool) for o in objs)
    assert any("track_id" in o for o in objs) and any(ln["coasting"] is not None for ln in lines[1:])
    t = summ["errors"]["tracking"]
    assert t["gt_objects"] == summ["errors"]["n_gt"] and {"mota", "idf1", "id_switches", "motp_px"} <= set(t)
    assert "tracking vs ground truth" in text and f"{t['id_switches']} ID switches" in text
    assert "confirmed tracks, coasting ones included" in text


def test_no_track_run_validates_without_track_fields(env, capsys, tmp_path):
    lines, summ, text = _run(env, capsys, tmp_path, "--no-track")
    v = jsonschema.Draft202012Validator(load_schema())
    for ln in lines:
        v.validate(ln)
    assert lines[0]["tracking"] is None and "tracking" not in summ["errors"] and "tracking vs" not in text
    assert all("track_id" not in o and "coasting" not in ln for ln in lines[1:] for o in ln["objects"])


def test_schema_rejects_a_line_missing_a_field():
    v = jsonschema.Draft202012Validator(load_schema())
    bad = {"t0_us": 0, "t1_us": 500, "objects": [{"speed_bin": 1, "x": 1.0}]}
    assert not v.is_valid(bad) and v.is_valid({"t0_us": 0, "t1_us": 500, "objects": []})


def test_an_objects_json_keeps_its_field_order_rounding_and_a_copy_of_its_track():
    """ObjectFlow.to_json (built field by field): the dataclass fields in order, direction_deg
    after n_events, floats to 4 decimals, speed_clipped / track_id / track only when set, and
    the track a new dict (editing the line leaves the tracker's state as it was)."""
    import math

    import numpy as np

    from toffe_deploy.config import ToffeConfig
    from toffe_deploy.runtime.pipeline import ObjectFlow, WindowResult
    from toffe_deploy.tracking import Tracker

    plain = ObjectFlow(2, 3, 30.123456, 30.0, 3000.987654, 10.000049, 20.5, math.pi / 3, 17).to_json()
    assert list(plain) == ["speed_bin", "ofs_bin", "speed_mps", "speed_bin_mps", "speed_px_s", "x", "y",
                           "direction_rad", "n_events", "direction_deg", "speed_clipped"]
    assert plain["speed_mps"] == 30.1235 and plain["x"] == 10.0 and plain["direction_deg"] == 60.0
    assert plain["speed_clipped"] is False and plain["n_events"] == 17
    tr = Tracker(ToffeConfig(), 500)
    o = ObjectFlow(2, 2, 30.0, 30.0, 3000.0, 100.0, 50.0, 0.0, 9)
    tr.update([o], 0)
    line = WindowResult(0, 500, [o], coasting=tr.coasting()).to_json()["objects"][0]
    assert list(line)[-2:] == ["track_id", "track"] and line["track_id"] == 0
    assert line["track"] == dict(o.track) and line["track"] is not o.track.to_dict()
    line["track"]["x"] = -1.0
    assert o.track["x"] == 100.0 and isinstance(o.track.to_dict()["x"], float)
    unset = ObjectFlow(1, 1, np.float64(1.23456), 1.0, 1.0, 1.0, 1.0, 0.0, 1, None).to_json()
    assert unset["speed_mps"] == 1.2346 and "speed_clipped" not in unset
    # a camera with a tiny metres-per-pixel scale: a non-zero speed is never written as 0.0
    tiny = ObjectFlow(1, 1, 3.21987e-5, 1e-4, 0.0, 1.0, 1.0, -2.4e-7, 1).to_json()
    assert tiny["speed_mps"] == 3.22e-5 and tiny["speed_bin_mps"] == 0.0001
    assert tiny["speed_px_s"] == 0.0 and tiny["direction_rad"] == -2.4e-7
