"""Honest evaluation: one-to-one gated matching, recall, false positives per window, bin accuracy
and confusion, speedE in px/ms at the true depth, breakdown by a sequence attribute; `eval` on an
unlisted split with --by, and `run`'s summary with ground truth."""
import json
import math

import numpy as np
import pytest

from toffe_deploy.breakdown import Breakdown, attr_value, bucket_labels, bucket_order
from toffe_deploy.camera import SpeedScale
from toffe_deploy.dataset.groundtruth import ObjectTruth
from toffe_deploy.metrics import FlowErrors, Prediction, match_gated, min_cost_assignment


def T(x, y, b=2, speed=30.0, **kw):
    return ObjectTruth(0, x, y, 0.0, speed, b, **kw)


def P(x, y, stage=2, mps=30.0, bin_mps=30.0, **kw):
    return Prediction(stage, x, y, 0.0, mps, bin_mps, **kw)


def test_one_prediction_out_of_gate_gives_recall_half_and_one_false_positive():
    e = FlowErrors(gate_px=20)
    e.add_window([P(105, 100), P(200, 150)], [T(100, 100), T(160, 150)])   # 2nd is 40 px off: outside
    s = e.summary()
    assert (s["n_matched"], s["n_gt"], s["recall"], s["false_positives"]) == (1, 2, 0.5, 1)
    assert s["fp_per_window"] == 1.0 and s["pixE"] == pytest.approx(5.0)
    e64 = FlowErrors(gate_px=64)
    e64.add_window([P(105, 100), P(200, 150)], [T(100, 100), T(160, 150)])
    assert e64.summary()["recall"] == 1.0 and e64.summary()["false_positives"] == 0


def test_two_predictions_near_one_object_are_one_match_and_one_false_positive():
    e = FlowErrors(gate_px=20)
    e.add_window([P(103, 100), P(101, 100)], [T(100, 100)])
    s = e.summary()
    assert (s["n_matched"], s["false_positives"], s["recall"]) == (1, 1, 1.0)
    assert s["pixE"] == pytest.approx(1.0)                 # the nearer one is the match


def test_assignment_is_optimal_where_greedy_is_not():
    # greedy takes (t0, p0) at 1 px and leaves t1 without a prediction in its gate; optimal finds both
    true_xy = [(0, 0), (-15, 0)]
    pred_xy = [(-1, 0), (15, 0)]
    assert match_gated(pred_xy, true_xy, 20) == [(0, 1), (1, 0)]
    c = np.array([[4.0, 1, 3], [2, 0, 5], [3, 2, 2]])
    assert sum(c[i, j] for i, j in min_cost_assignment(c)) == 5.0            # (0,1) (1,0) (2,2)
    assert len(min_cost_assignment(c[:, :2])) == 2 and len(min_cost_assignment(c[:2].T)) == 2


def test_empty_windows_count_in_false_positives_per_window():
    e = FlowErrors(gate_px=20)
    e.add_window([P(10, 10)], [])                          # no object: the prediction is a false positive
    e.add_window([], [])
    e.add_window([], [])
    e.add_window([P(50, 50)], [T(52, 50)])
    s = e.summary()
    assert s["n_windows"] == 4 and s["false_positives"] == 1 and s["fp_per_window"] == 0.25
    assert s["recall"] == 1.0


def test_swapped_bins_fill_the_confusion_matrix_and_bin_accuracy():
    e = FlowErrors(gate_px=20, n_bins=4)
    e.add_window([P(10, 10, stage=2), P(100, 10, stage=1), P(200, 10, stage=3)],
                 [T(10, 10, b=1), T(100, 10, b=2), T(200, 10, b=3)])
    s = e.summary()
    c = s["confusion"]
    assert c["labels"] == [1, 2, 3, 4]
    assert c["matrix"][0][1] == 1 and c["matrix"][1][0] == 1 and c["matrix"][2][2] == 1
    assert np.asarray(c["matrix"]).sum() == 3
    assert s["bin_accuracy"] == pytest.approx(1 / 3)
    assert e.summary(1)["bin_accuracy"] == 0.0 and e.summary(3)["bin_accuracy"] == 1.0
    assert e.summary(4)["n_gt"] == 0 and math.isnan(e.summary(4)["recall"])


def test_speed_error_in_px_ms_converted_at_the_true_depth():
    ref = SpeedScale()                                     # 554.26 px, 5 m: what the prediction's m/s used
    e = FlowErrors(gate_px=20, pred_scale=ref)
    v_true = 2.0                                           # px/ms
    pred_mps = ref.to_mps(2.5)                             # predicted 2.5 px/ms, stated in m/s at 5 m
    e.add_window([P(10, 10, mps=pred_mps)], [T(10, 10, speed=99.0, speed_px_ms=v_true, depth_m=10.0)], focal_px=500.0)
    s = e.summary()
    assert s["speedE_px_ms"] == pytest.approx(0.5)
    assert s["speedE"] == pytest.approx(SpeedScale(500.0, 10.0).to_mps(0.5))       # 10 m/s, not |pred - 99|
    e2 = FlowErrors(gate_px=20, pred_scale=ref)           # a px/ms prediction is taken as is
    e2.add_window([P(10, 10, speed_px_ms=1.0)], [T(10, 10, speed_px_ms=v_true, depth_m=10.0)], focal_px=500.0)
    assert e2.summary()["speedE_px_ms"] == pytest.approx(1.0)
    e3 = FlowErrors(gate_px=20, pred_scale=ref)           # no depth / focal: today's m/s difference
    e3.add_window([P(10, 10, mps=31.0)], [T(10, 10, speed=30.0)])
    assert e3.summary()["speedE"] == pytest.approx(1.0) and math.isnan(e3.summary()["speedE_px_ms"])


def test_breakdown_finds_attributes_and_buckets_them():
    attrs = {"name": "s", "generator": {"spec": {"dvs": {"noise_rate_hz": 20.0}}},
             "objects": [{"size_px": 30}, {"size_px": 50}], "contrast": 0.5}
    assert attr_value(attrs, "contrast") == ("contrast", 0.5)
    assert attr_value(attrs, "noise") == ("generator.spec.dvs.noise_rate_hz", 20.0)
    assert attr_value(attrs, "size") == ("mean of size_px", 40.0)
    assert attr_value(attrs, "spacing") is None
    assert attr_value(attrs, "generator.spec.dvs.noise_rate_hz")[1] == 20.0
    vals = [10.0, 25.0, None, 200.0, 20.0]
    labels = bucket_labels(vals, (20.0, 80.0))
    assert labels == ["< 20", "20-80", "n/a", ">= 80", "20-80"]
    assert bucket_order(labels, vals) == ["< 20", "20-80", ">= 80", "n/a"]
    assert bucket_labels([1.0, 2.0, 1.0], None) == ["1", "2", "1"]
    assert Breakdown.parse("size=20,80") == Breakdown("size", (20.0, 80.0))
    for bad in ("=1", "size=3,2", "size=a"):
        with pytest.raises(ValueError):
            Breakdown.parse(bad)


SENSOR = (64, 48)


@pytest.fixture(scope="module")
def eval_env(tmp_path_factory):
    """An untrained 64x48 checkpoint and a split directory the (absent) index does not list:
    two short multi-object recordings whose attrs give an object size."""
    import dataclasses

    from toffe_deploy.camera import PinholeCamera
    from toffe_deploy.checkpoint import init_checkpoint
    from toffe_deploy.config import ToffeConfig
    from toffe_deploy.dataset.splits import split_specs
    from toffe_deploy.dataset.synth import generate_sequence
    from toffe_deploy.events.io import write_events_h5

    root = tmp_path_factory.mktemp("eval")
    ck = init_checkpoint(root / "ck", ToffeConfig(sensor_size=SENSOR, ofpd={"crop_px": 32, "pool": 2}), seed=1)
    specs = split_specs("multi", seed=0, duration_s=0.006)
    for i, size in enumerate((12, 40)):
        spec = dataclasses.replace(specs[i], camera=PinholeCamera(width=SENSOR[0], height=SENSOR[1]))
        ev, gt, size_wh = generate_sequence(spec, seed=0)
        write_events_h5(root / "data" / "appearance" / f"s{i}.h5", ev, size_wh, ground_truth=gt,
                        attrs={"size_px": size}, t_range=(0, 6000))
    return {"ck": ck, "data": root / "data"}


def test_eval_any_split_directory_with_breakdown(eval_env, tmp_path, capsys):
    from toffe_deploy.cli import main

    out = tmp_path / "e.json"
    assert main(["eval", str(eval_env["ck"]), "--data", str(eval_env["data"]), "--split", "appearance", "--dt", "500",
                 "--max-windows", "3", "--by", "size=20", "--json", str(out), "--no-progress"]) == 0
    table = capsys.readouterr().out
    assert "recall" in table and "FP / window" in table and "bin acc." in table and "pred 1" in table
    assert "By `size` (sequence attribute: size_px)" in table
    assert table.count("| speedE (px/ms) |") == 3 and "| speedE (px/ms) | speedE bin-only" in table   # all, per bin, --by
    r = json.loads(out.read_text())["per_dt"][0]
    a = r["all"]
    assert a["n_windows"] == 6 and a["gate_px"] == 20.0 and a["n_gt"] > 0
    assert a["n_pred"] == a["n_matched"] + a["false_positives"]
    (by,) = r["by"]
    assert [b["bucket"] for b in by["buckets"]] == ["< 20", ">= 20"]
    assert [b["sequences"] for b in by["buckets"]] == [1, 1]
    assert sum(b["n_gt"] for b in by["buckets"]) == a["n_gt"]
    assert sum(b["false_positives"] for b in by["buckets"]) == a["false_positives"]
    # an attribute no sequence has is an error before the work, naming the ones there are
    assert main(["eval", str(eval_env["ck"]), "--data", str(eval_env["data"]), "--split", "appearance",
                 "--by", "shape", "--json", str(tmp_path / "f.json"), "--no-progress"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "--by shape" in err and "size_px" in err
    assert not (tmp_path / "f.json").exists()
    assert main(["eval", str(eval_env["ck"]), "--data", str(eval_env["data"]), "--split", "appearance",
                 "--dt", "3", "--no-progress"]) == 2                  # shorter than its 5 time bins
    assert "--dt 3: a window of 5 time bins" in capsys.readouterr().err
    assert main(["eval", str(eval_env["ck"]), "--data", str(eval_env["data"]), "--split", "appearance",
                 "--dt", "500,900000", "--no-progress"]) == 2             # longer than every sequence: no table
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "--dt 900000: no sequence" in err and "holds a whole window" in err
    from toffe_deploy.commands.eval import _dts
    assert _dts("500,200,500") == (500, 200)                          # each dt once


def test_eval_skip_stream_start_leaves_out_each_first_window(eval_env, tmp_path, capsys):
    """The same sample less each sequence's first window: 2 sequences x 3 windows -> 4."""
    from toffe_deploy.cli import main

    out = tmp_path / "e.json"
    assert main(["eval", str(eval_env["ck"]), "--data", str(eval_env["data"]), "--split", "appearance", "--dt", "500",
                 "--max-windows", "3", "--skip-stream-start", "--json", str(out), "--no-progress"]) == 0
    assert "3 windows each less its first" in capsys.readouterr().out
    r = json.loads(out.read_text())
    assert r["skip_stream_start"] is True and r["per_dt"][0]["all"]["n_windows"] == 4


def test_eval_at_another_dt_converts_motion_with_that_window_length(eval_env, monkeypatch, capsys):
    """At a --dt other than the checkpoint's, the predictions' px/ms (plane fit, decode, outline
    lag) come from that window's length: every window is predicted with config.dt_us = its dt
    (with the training dt, bins came out one slower at 200 us and speedE tripled)."""
    from toffe_deploy.cli import main
    from toffe_deploy.model import reference

    seen = []
    real = reference.predict_window

    def spy(binned, run_stage, ofpd, config, *a):
        seen.append(config.dt_us)
        return real(binned, run_stage, ofpd, config, *a)

    monkeypatch.setattr(reference, "predict_window", spy)
    assert main(["eval", str(eval_env["ck"]), "--data", str(eval_env["data"]), "--split", "appearance",
                 "--dt", "1000,500", "--max-windows", "2", "--no-progress"]) == 0
    assert seen == [1000] * 4 + [500] * 4
    assert "1000*" in capsys.readouterr().out


def test_eval_data_that_is_a_file_says_so(eval_env, tmp_path, capsys):
    from toffe_deploy.cli import main

    f = tmp_path / "rec.h5"
    f.write_bytes(b"x")
    assert main(["eval", str(eval_env["ck"]), "--data", str(f), "--dt", "500", "--no-progress"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "rec.h5" in err and "is a file, not a data-set directory" in err


def test_eval_unknown_split_names_the_splits_there(eval_env, capsys):
    from toffe_deploy.cli import main

    assert main(["eval", str(eval_env["ck"]), "--data", str(eval_env["data"]), "--split", "pairs", "--dt", "500",
                 "--no-progress"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "split 'pairs'" in err and "appearance" in err


def test_sequence_focal_length_from_attrs_and_summary_lines():
    from toffe_deploy.runtime.output import truth_lines
    from toffe_deploy.runtime.truth import sequence_focal_px

    spec = {"generator": {"spec": {"camera": {"width": 640, "height": 480, "hfov_deg": 60.0}}}}
    assert sequence_focal_px(spec) == pytest.approx(554.256, abs=1e-3)
    assert sequence_focal_px({"focal_px": 1000.0, **spec}) == 1000.0
    assert sequence_focal_px({"generator": "dv"}) is None and sequence_focal_px({}) is None
    e = FlowErrors(gate_px=20)
    e.add_window([P(500, 500)], [T(10, 10)])
    (line,) = truth_lines(e.summary())                    # nothing matched: no error line, no "nan"
    assert "recall 0.0% (0/1 objects)" in line and "1.000 false positives per window" in line and "nan" not in line
    e = FlowErrors(gate_px=20)
    e.add_window([P(500, 500)], [])
    assert truth_lines(e.summary()) == ["vs ground truth: no object in the truth, 1.000 false positives per window "
                                        "(1 in 1 windows)"]


@pytest.mark.parametrize("dt, needle", [("99999999999999999999", "expected microseconds in 1..1000000000"),
                                        ("1000000001", "expected microseconds in 1..1000000000"),
                                        ("500,,600", "empty item in '500,,600'"), ("500,", "empty item")])
def test_eval_dt_items_beyond_a_window_or_empty_are_refused(tmp_path, capsys, dt, needle):
    """A dt longer than any sequence evaluated 0 windows with exit 0; an empty item was dropped."""
    from toffe_deploy.cli import main

    with pytest.raises(SystemExit) as exc:
        main(["eval", str(tmp_path), "--data", str(tmp_path), "--dt", dt])
    err = capsys.readouterr().err
    assert exc.value.code == 2 and err.count("\n") == 1 and f"argument --dt: {needle}" in err
