#!/usr/bin/env python
"""`toffe-deploy run --processes 1` against `--processes 2`: windows/s, CPU time, identical lines.

    .venv/bin/python benchmarks/bench_processes.py [--bundle export/] [--events FILE] [--seconds 2]
                                                   [--rounds 3] [--out benchmarks/results/bench_processes.json]

What a user sees: `run` end to end as a command (it reads the file, bins each window, runs the
pipeline and writes every JSON line), on the recording tiled in time to ``--seconds`` (default:
the shipped sample, 2 s = 4,000 windows of 500 us; no ground truth, so no scoring), with one and
with two host processes in turn, ``--rounds`` times (rounds alternate which goes first: a shared
machine drifts from minute to minute, so only ratios inside a round count). Per run: windows/s
and the real-time factor from `run`'s own summary (``--summary-json``: the loop after start-up),
wall time and the CPU time of the run and its worker (getrusage of the children), and whether its
JSON lines are byte-identical to the one-process run of the round.

Two processes need two free cores: on a machine whose other cores are busy the second process
waits for one. Prints one JSON object and writes it to ``--out``.
"""
from __future__ import annotations

import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from _args import OneLineParser, existing_file, guarded, json_output, positive_float, positive_int  # noqa: E402


def main(argv=None) -> int:
    ap = OneLineParser(prog="bench_processes.py",
                       description="run --processes 1 against --processes 2: windows/s, CPU time, identical lines.")
    ap.add_argument("--bundle", default=str(ROOT / "export"), help="deploy bundle (toffe-deploy export ckpt/)")
    ap.add_argument("--events", type=existing_file, default=None, help="recording (default: the shipped sample)")
    ap.add_argument("--seconds", type=positive_float, default=2.0, help="tile the recording to this length (s)")
    ap.add_argument("--rounds", type=positive_int, default=3, help="pairs of runs (1 and 2 processes)")
    ap.add_argument("--out", type=json_output, default=str(ROOT / "benchmarks" / "results" / "bench_processes.json"))
    args = ap.parse_args(argv)
    return guarded("bench_processes", run, args)


def one_run(bundle: str, events: Path, processes: int, tmp: Path) -> dict:
    """`toffe-deploy run` as a command: its summary's windows/s, wall and CPU time, its lines."""
    out, summary = tmp / f"p{processes}.jsonl", tmp / f"p{processes}.json"
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t = time.perf_counter()
    r = subprocess.run([sys.executable, "-m", "toffe_deploy.cli", "run", bundle, "--events", str(events),
                        "--processes", str(processes), "--no-progress", "--out", str(out),
                        "--summary-json", str(summary)], capture_output=True, text=True,
                       env=dict(os.environ, PYTHONPATH=str(ROOT)))
    wall = time.perf_counter() - t
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if r.returncode != 0:
        raise RuntimeError(f"run --processes {processes} failed: {r.stderr.strip().splitlines()[-1:]}")
    s = json.loads(summary.read_text())
    return {"processes": processes, "windows": s["windows"], "windows_per_s": round(s["windows_per_s"], 1),
            "realtime_factor": round(s["realtime_factor"], 4), "loop_s": round(s["wall_s"], 3),
            "startup_s": round(s["startup_s"], 2), "wall_s": round(wall, 2),
            "cpu_s": round((after.ru_utime + after.ru_stime) - (before.ru_utime + before.ru_stime), 2),
            "latency_p50_ms": round(s["latency_ms"]["p50"], 3), "lines": out.read_bytes()}


def run(args) -> int:
    from bench_run import machine, make_long_recording
    from toffe_deploy.commands.run import SAMPLE
    from toffe_deploy.deploy.bundle import load_bundle

    load_bundle(args.bundle)                    # a bad bundle: one line here, not in every run
    rounds = []
    with tempfile.TemporaryDirectory(prefix="bench_processes_") as td:
        tmp = Path(td)
        rec = tmp / "long.h5"
        info = make_long_recording(Path(args.events) if args.events else SAMPLE, args.seconds, rec)
        for k in range(args.rounds):
            order = (1, 2) if k % 2 == 0 else (2, 1)
            got = {p: one_run(args.bundle, rec, p, tmp) for p in order}
            same = got[1].pop("lines") == got[2].pop("lines")
            rounds.append({"order": list(order), "one": got[1], "two": got[2], "identical_lines": same,
                           "throughput_ratio": round(got[2]["windows_per_s"] / got[1]["windows_per_s"], 3),
                           "cpu_ratio": round(got[2]["cpu_s"] / got[1]["cpu_s"], 3)})
    ratios = sorted(r["throughput_ratio"] for r in rounds)
    res = {"recording": {"seconds": info["seconds"], "events": info["events"]}, "machine": machine(),
           "load_1min": round(os.getloadavg()[0], 2), "rounds": rounds,
           "throughput_ratio_median": ratios[len(ratios) // 2], "identical_lines": all(r["identical_lines"] for r in rounds),
           "unit": "windows_per_s and realtime_factor: run's summary (its loop, start-up apart); cpu_s: the run's "
                   "and its worker's CPU time, start-up included"}
    Path(args.out).write_text(json.dumps(res, indent=2) + "\n")
    print(json.dumps(res))
    return 0 if res["identical_lines"] else 1


if __name__ == "__main__":
    sys.exit(main())
