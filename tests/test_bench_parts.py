"""benchmarks/bench_parts.py --by-call on the shipped bundle and sample: a window's CPU time
split into compiled kernels, onnxruntime and Python, each call's time exclusive of its callees
(a subprocess: the script pins itself to one core)."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_by_call_splits_the_window_into_compiled_onnxruntime_and_python():
    out = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "bench_parts.py"), "--by-call", "--repeats", "1"],
                         capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr
    lines = out.stdout.strip().splitlines()
    assert len(lines) == 1, out.stdout
    r = json.loads(lines[0])
    groups = ("compiled", "onnxruntime", "python")
    assert all(r[g] > 0 for g in groups)
    assert abs(sum(r[g] for g in groups) - r["sum_us"]) < 0.5
    assert abs(sum(r["shares"].values()) - 1.0) < 0.01
    calls = r["calls"]
    # every call lands in one group, and the groups are the sums of their calls
    assert all(k.split(":")[0] in groups for k in calls)
    for g in groups:
        assert abs(sum(v for k, v in calls.items() if k.startswith(g + ":")) - r[g]) < 0.1 * len(calls)
    # the steps the cpu target runs on the shipped config, each once a window
    for name in ("onnxruntime:run", "compiled:pooled_cascade", "compiled:window_objects", "compiled:binned_ones",
                 "python:Decoder.columns", "python:Tracker.columns"):
        assert calls[name] > 0, name
        assert 0.5 <= r["calls_per_window"][name] <= 1.0, name
    assert r["windows"] == r["recording_windows"] == 200 and r["repeats"] == 1
