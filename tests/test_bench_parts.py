"""benchmarks/bench_parts.py --by-call on a real tiny bundle and recording: a window's CPU time
split into compiled kernels, onnxruntime and Python, each call's time exclusive of its callees
(a subprocess: the script pins itself to one core)."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_by_call_splits_the_window_into_compiled_onnxruntime_and_python(tmp_path, make_bundle, make_recording):
    bundle = make_bundle(tmp_path / "b", ofs_pool=2)
    rec = make_recording(tmp_path / "r.h5", duration=0.02)
    out = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "bench_parts.py"), "--by-call", "--repeats", "2",
                          "--bundle", str(bundle.root), "--events", str(rec)],
                         capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr
    lines = out.stdout.strip().splitlines()
    assert len(lines) == 1, out.stdout
    r = json.loads(lines[0])
    groups = ("compiled", "onnxruntime", "python")
    assert all(r[g] > 0 for g in groups), r
    assert abs(sum(r[g] for g in groups) - r["sum_us"]) < 0.5
    assert abs(sum(r["shares"].values()) - 1.0) < 0.01
    calls = r["calls"]
    # every call lands in one group, and the groups are the sums of their calls
    assert all(k.split(":")[0] in groups for k in calls)
    for g in groups:
        assert abs(sum(v for k, v in calls.items() if k.startswith(g + ":")) - r[g]) < 0.1 * len(calls)
    # the steps every window of the cpu target runs, once each
    for name in ("compiled:binned_ones", "compiled:pooled_cascade", "python:Pipeline.front_batch",
                 "python:Pipeline.front", "python:Pipeline._result_of_batch", "python:Tracker.coasting"):
        assert calls[name] > 0 and r["calls_per_window"][name] == 1.0, name
    assert 0 < r["calls_per_window"]["onnxruntime:run"] <= 1.0            # windows with objects only
    assert r["windows"] == 2 * r["recording_windows"] and r["repeats"] == 2
    assert r["wrapper_us_per_call"] > 0             # measured, and taken off the calls (_CallClock.calibrate)
