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
