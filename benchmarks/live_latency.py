"""Live-source limits of `toffe-deploy run`: event-to-line latency and the sustained event rate.

A paced sender replays a recording (default: the shipped 640x480 sample, tiled in time) over a
real localhost UDP socket in aestream's timestamped AER format, in real time (every 1 ms it sends
the events whose timestamp has come), keeping a fraction of the events (``--fractions``: 1 = the
sample's full rate). The run listens with ``--events udp://127.0.0.1:PORT`` and its summary gives
the newest-event -> JSON-line latency p50/p99, what was received, dropped (full queue) and late.
``--period-ms P`` keeps only one 500 us slice of events every P ms (a bursty source) and runs
with ``--skip-empty-after 1``, so the run does about 3000 / P windows per second: the latency
of a run that keeps up, when the machine cannot do 2000 windows/s.

    python benchmarks/live_latency.py --bundle export/ --seconds 5 --fractions 0.05,0.25,1
    python benchmarks/live_latency.py --bundle export/ --seconds 5 --fractions 1 --period-ms 50
"""
from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from toffe_deploy.events.io import read_events  # noqa: E402
from toffe_deploy.events.live import aer_words  # noqa: E402
from _args import (OneLineParser, comma_list, existing_file, guarded, json_output, nonneg_float,  # noqa: E402
                   positive_float, positive_int, share)

SAMPLE = ROOT / "toffe_deploy" / "samples" / "sample_multi.h5"
PACKET_EVENTS = 8000                  # 64 kB datagrams (8 bytes per timestamped event)


def udp_listening(port: int) -> bool:
    with open("/proc/net/udp") as f:
        return any(int(line.split()[1].split(":")[1], 16) == port for line in list(f)[1:])


def send_paced(ev: np.ndarray, seconds: float, port: int) -> int:
    """Replay ``ev`` (tiled in time) in real time for ``seconds``; returns the events sent."""
    span = int(ev["t"][-1]) + 1 - int(ev["t"][0])
    t_rel = ev["t"] - ev["t"][0]
    tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    start = time.perf_counter()
    sent = i = lap = 0
    while True:
        now_us = int((time.perf_counter() - start) * 1e6)
        if now_us > seconds * 1e6:
            break
        while lap * span + int(t_rel[i]) <= now_us:
            j = min(int(np.searchsorted(t_rel, now_us - lap * span, side="right")), i + PACKET_EVENTS)
            part = ev[i:j].copy()
            part["t"] = t_rel[i:j] + lap * span
            tx.sendto(aer_words(part).tobytes(), ("127.0.0.1", port))
            sent += j - i
            i = j
            if i == len(ev):
                i, lap = 0, lap + 1
        time.sleep(0.001)
    tx.close()
    return sent


def measure(bundle: str, ev: np.ndarray, sensor, seconds: float, target: str, queue: int | None,
            skip: int | None = None, grace_ms: float | None = None) -> dict:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    with tempfile.TemporaryDirectory(prefix="live-latency-") as tmp:
        argv = [sys.executable, "-m", "toffe_deploy.cli", "run", bundle, "--target", target, "--events",
                f"udp://127.0.0.1:{port}", "--sensor-size", f"{sensor[0]}x{sensor[1]}", "--idle-timeout", "4",
                "--out", f"{tmp}/o.jsonl", "--summary-json", f"{tmp}/s.json", "--no-progress"]
        if queue:
            argv += ["--queue-events", str(queue)]
        if grace_ms is not None:
            argv += ["--window-grace-ms", str(grace_ms)]
        if skip is not None:
            argv += ["--skip-empty-after", str(skip)]
        p = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, cwd=ROOT,
                             env=dict(os.environ, PYTHONPATH=str(ROOT)))
        while not udp_listening(port):
            if p.poll() is not None:
                raise SystemExit(p.stderr.read().decode())
            time.sleep(0.05)
        time.sleep(2.0)                           # the pipeline warms up after the socket opens (the run's
                                                  # --idle-timeout 4 s must not end it before the first event)
        sent = send_paced(ev, seconds, port)
        _, err = p.communicate(timeout=600)
        if p.returncode:
            raise SystemExit(err.decode())
        s = json.loads(Path(f"{tmp}/s.json").read_text())
    live = s["live"]
    return {"sent_events": sent, "events_per_s": sent / seconds, "windows": s["windows"],
            "windows_per_s": s["windows"] / seconds, **{k: live[k] for k in
            ("received_events", "dropped_events", "dropped_chunks", "dropped_windows", "late_events",
             "socket_drops", "peak_queue_events")},
            "latency_p50_ms": live["event_latency_ms"]["p50"], "latency_p99_ms": live["event_latency_ms"]["p99"]}


def main(argv=None) -> int:
    ap = OneLineParser(prog="live_latency.py", description=__doc__.splitlines()[0])
    ap.add_argument("--bundle", default=str(ROOT / "export"))
    ap.add_argument("--events", type=existing_file, default=str(SAMPLE))
    ap.add_argument("--target", default="cpu", choices=("cpu", "cuda", "loihi-sim", "loihi2"),
                    help="run's --target (default cpu)")
    ap.add_argument("--seconds", type=positive_float, default=5.0)
    ap.add_argument("--fractions", type=comma_list(share), default="0.05,0.25,1",
                    help="shares of the recording's events sent, each in (0, 1]")
    ap.add_argument("--queue-events", type=positive_int, default=None)
    ap.add_argument("--window-grace-ms", type=nonneg_float, default=None)
    ap.add_argument("--period-ms", type=nonneg_float, default=0.0,
                    help="bursty source: one 500 us slice every P ms (0: off)")
    ap.add_argument("--json", type=json_output, help="also write the rows here")
    a = ap.parse_args(argv)
    return guarded("live_latency", run, a)


def run(a) -> int:
    from toffe_deploy.deploy.bundle import load_bundle
    from toffe_deploy.errors import InputError
    from toffe_deploy.fileio import atomic_path, check_outputs

    load_bundle(a.bundle)                       # a missing or broken bundle: one line, before the sender starts
    check_outputs(files=[("--json", a.json)])
    rec = read_events(a.events)
    if len(rec) == 0:
        raise InputError(a.events, "no events to send")
    if a.period_ms:
        e = rec.events
        span = int(e["t"][-1]) + 1 - int(e["t"][0])           # tile to one period at least
        reps = max(1, -(-int(a.period_ms * 1000) // span)) * 4
        tiled = np.concatenate([e] * reps)
        tiled["t"] = np.concatenate([e["t"] - e["t"][0] + k * span for k in range(reps)])
        rec.events = tiled[(tiled["t"] % int(a.period_ms * 1000)) < 500]
    rng = np.random.default_rng(0)
    rows = []
    for f in a.fractions:
        ev = rec.events[rng.random(len(rec)) < f] if f < 1 else rec.events
        row = {"fraction": f, "period_ms": a.period_ms,
               **measure(a.bundle, ev, rec.sensor_size, a.seconds, a.target, a.queue_events,
                         1 if a.period_ms else None, a.window_grace_ms)}
        rows.append(row)
        print(f"fraction {f:g}: {row['events_per_s'] / 1e3:.0f} k events/s sent, {row['windows_per_s']:.0f} windows/s, "
              f"received {row['received_events']}, dropped {row['dropped_events']} in {row['dropped_chunks']} "
              f"chunks ({row['dropped_windows']} windows), late {row['late_events']}, kernel-dropped datagrams "
              f"{row['socket_drops']}, peak queue {row['peak_queue_events']}; latency p50 "
              f"{row['latency_p50_ms']:.1f} ms, p99 {row['latency_p99_ms']:.1f} ms", flush=True)
    if a.json:
        with atomic_path(a.json) as tmp:
            tmp.write_text(json.dumps(rows, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
