#!/usr/bin/env python
"""Benchmark of `toffe-deploy run`: latency per window, throughput and peak memory per target.

    .venv/bin/python benchmarks/bench_run.py [--bundle export/] [--events FILE] [--targets cpu,loihi-sim]

What it measures (640x480, B = 5, N = 4 with the shipped bundle and sample):
- cpu latency per window, batch 1, after warm-up, pinned to ONE core (sched_setaffinity, OpenCV
  and onnxruntime single-threaded): p50/p90/p99 of events -> object flow (binning included) and of
  the pipeline alone (binned window -> object flow, what `run` reports); the first also as the
  thread's CPU time (``events_to_flow_cpu_time``, ``windows_per_s_cpu_time``: what a machine
  shared with other work does not inflate).
- the same for the straightforward dense implementation (bin_window, run_cascade with
  run_ofs_fixed, ofpd_io on dense frames, one onnxruntime call per object): the "before" of the
  event-driven path, and the speed-up ratio.
- peak memory (max RSS of the `toffe-deploy run --target cpu` process) on the 0.1 s sample and
  on a >= 10 s recording (the sample tiled in time, written to a temporary file): memory must not
  grow with length because windows stream from disk.
- loihi-sim (when listed): windows/s and latency per window of simulator wall time (not Loihi
  latency), start-up time. Lava's /dev/shm use is measured by benchmarks/bench_lava.py.
Results: printed as markdown and saved to benchmarks/results/bench_run.json.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from _args import (OneLineParser, at_least_two, comma_list, cpu_core, existing_file, guarded, json_output,  # noqa: E402
                   positive_float, positive_int)

TARGETS = ("cpu", "loihi-sim")


def machine() -> dict:
    """This machine in words: CPU model (/proc/cpuinfo, else platform), cores, Python version."""
    out = {"cpu": platform.processor() or platform.machine(), "cores": os.cpu_count(),
           "python": platform.python_version()}
    try:
        with open("/proc/cpuinfo") as f:
            out["cpu"] = next(line.split(":", 1)[1].strip() for line in f if line.startswith("model name"))
    except (OSError, StopIteration):
        pass
    return out


def target(text: str) -> str:
    """An argparse type: one of TARGETS."""
    if text not in TARGETS:
        raise argparse.ArgumentTypeError(f"unknown target {text!r} (known: {', '.join(TARGETS)})")
    return text


def pct(seconds) -> dict:
    a = np.asarray(seconds) * 1e3
    return {"p50_ms": float(np.percentile(a, 50)), "p90_ms": float(np.percentile(a, 90)),
            "p99_ms": float(np.percentile(a, 99)), "mean_ms": float(a.mean()), "n": int(a.size)}


def pin_one_core(core: int) -> None:
    import cv2

    os.sched_setaffinity(0, {core})
    cv2.setNumThreads(1)


def load_windows(path, cfg, limit=None):
    """The recording's (t0, events) windows of cfg.dt_us (the first ``limit``); InputError when
    it holds none (nothing to time)."""
    from toffe_deploy.errors import InputError
    from toffe_deploy.events.io import open_events

    with open_events(path) as src:
        out = []
        for t0, ev in src.iter_windows(cfg.dt_us):
            out.append((t0, ev))
            if limit and len(out) >= limit:
                break
    if not out:
        raise InputError(path, f"no whole window of {cfg.dt_us} us: nothing to time")
    return out


def bench_cpu(bundle, windows, repeats: int, warmup: int, track: bool = True) -> dict:
    from toffe_deploy.runtime.pipeline import Pipeline
    from toffe_deploy.runtime.spikes import SpikeVolume

    cfg = bundle.config
    total, pipe_only, cpu, n_obj, n_ev = [], [], [], 0, []
    best = np.full(len(windows), np.inf)
    with Pipeline(bundle, "cpu", track=track) as pipe:
        for w in windows[:warmup]:
            vol = SpikeVolume.from_events(w[1], w[0], cfg.dt_us, cfg.n_bins, cfg.sensor_size)
            list(pipe.process_stream([(w[0], vol)]))
        for _ in range(repeats):
            for i, (t0, ev) in enumerate(windows):
                ta = time.thread_time()
                a = time.perf_counter()
                vol = SpikeVolume.from_events(ev, t0, cfg.dt_us, cfg.n_bins, cfg.sensor_size)
                b = time.perf_counter()
                res = next(pipe.process_stream([(t0, vol)]))
                c = time.perf_counter()
                cpu.append(time.thread_time() - ta)
                total.append(c - a)
                best[i] = min(best[i], c - a)
                pipe_only.append(c - b)
                n_obj += len(res.objects)
                n_ev.append(len(ev))
    return {"events_to_flow": pct(total), "pipeline": pct(pipe_only), "events_to_flow_cpu_time": pct(cpu),
            "windows_per_s_cpu_time": len(cpu) / sum(cpu), "events_to_flow_best_of_repeats": pct(best), "objects_per_window": n_obj / len(total),
            "events_per_window_median": float(np.median(n_ev)), "windows_per_s": len(total) / sum(total),
            "realtime_factor": len(total) * cfg.dt_us * 1e-6 / sum(total)}


def bench_dense(bundle, windows) -> dict:
    """The 'before': dense binning, dense reference cascade, ofpd_io on dense frames, one call per object."""
    from toffe_deploy import ofpd_io
    from toffe_deploy.cascade import run_cascade
    from toffe_deploy.events.binning import bin_window
    from toffe_deploy.events.support import SupportHistory, front_end
    from toffe_deploy.fixed_point import run_ofs_fixed
    from toffe_deploy.runtime.ofpd_runner import OFPDRunner

    cfg = bundle.config
    ofpd = OFPDRunner(bundle.ofpd_onnx, "cpu", threads=1)
    times = []
    hist = SupportHistory(cfg.input_support[0], cfg.sensor_size, cfg.dt_us) if cfg.input_support is not None else None
    for i, (t0, ev) in enumerate(windows):
        a = time.perf_counter()
        x = front_end(bin_window(ev, t0, cfg.dt_us, cfg.n_bins, cfg.sensor_size), cfg, hist, t0)
        res = run_cascade(x, lambda k, inp: run_ofs_fixed(inp, bundle.ofs[k - 1]), cfg.n_speed_bins, cfg.mask_kernel)
        ks, merged = ofpd_io.merge_frames(np.stack(res.frames), cfg, hist)
        for k, m in zip(ks, merged):                   # one OFPD call per object
            out = ofpd.run(ofpd_io.prepare(m[None], cfg))
            ofpd_io.decode(*out, np.array([k]), cfg)
        if i:                                          # first window is the warm-up
            times.append(time.perf_counter() - a)
    return {"events_to_flow": pct(times)}


def make_long_recording(sample: Path, seconds: float, out: Path) -> dict:
    """The sample tiled in time to ``seconds`` (no ground truth), written in our HDF5 layout."""
    from toffe_deploy.events.io import open_events, write_events_h5

    with open_events(sample) as src:
        ev = src.read(src.t_start_us, src.t_end_us)
        span = src.t_end_us - src.t_start_us
        size = src.sensor_size
    reps = int(np.ceil(seconds * 1e6 / span))
    tiled = np.concatenate([ev] * reps)
    tiled["t"] += np.repeat(np.arange(reps, dtype=np.int64) * span, len(ev))
    write_events_h5(out, tiled, size, t_range=(0, reps * span))
    return {"seconds": reps * span / 1e6, "events": int(len(tiled)), "file_mb": out.stat().st_size / 1e6}


def peak_rss_mb(cmd: list[str]) -> tuple[float, float]:
    """(peak RSS in MB, wall s) of a child process (a fresh Python, so children's max RSS is its own)."""
    probe = ("import resource, subprocess, sys, time; t = time.time(); "
             "r = subprocess.run(sys.argv[1:], stdout=subprocess.DEVNULL); "
             "print(resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024, time.time() - t, r.returncode)")
    out = subprocess.run([sys.executable, "-c", probe, *cmd], capture_output=True, text=True, check=True).stdout.split()
    if out[2] != "0":
        raise RuntimeError(f"{' '.join(cmd)} failed with exit code {out[2]}")
    return float(out[0]), float(out[1])


def load_bundle_config(bundle_dir: Path):
    from toffe_deploy.deploy.bundle import load_bundle

    return load_bundle(bundle_dir).config


def bench_memory(bundle_dir: Path, sample: Path, seconds: float) -> dict:
    exe = str(Path(sys.executable).with_name("toffe-deploy"))
    res = {}
    with tempfile.TemporaryDirectory(prefix="bench_run_") as tmp:
        long_rec = Path(tmp) / "long.h5"
        res["long_recording"] = make_long_recording(sample, seconds, long_rec)
        one_s = str(int(1e6 // load_bundle_config(bundle_dir).dt_us))
        for name, rec, extra in (("sample", sample, []), ("long_1s", long_rec, ["--max-windows", one_s]),
                                 ("long", long_rec, [])):
            mb, wall = peak_rss_mb(["nice", "-n", "10", exe, "run", str(bundle_dir), "--target", "cpu", "--events",
                                    str(rec), "--out", str(Path(tmp) / f"{name}.jsonl"), "--no-progress", *extra])
            res[f"peak_rss_mb_{name}"] = mb
            res[f"wall_s_{name}"] = wall
    return res


def bench_lava(bundle, windows, n: int) -> dict:
    from toffe_deploy.runtime.pipeline import Pipeline
    from toffe_deploy.runtime.spikes import SpikeVolume

    cfg = bundle.config
    vols = [(t0, SpikeVolume.from_events(ev, t0, cfg.dt_us, cfg.n_bins, cfg.sensor_size)) for t0, ev in windows[:n]]
    a = time.perf_counter()
    with Pipeline(bundle, "loihi-sim") as pipe:
        started = time.perf_counter()
        stamps = []
        for _ in pipe.process_stream(vols):
            stamps.append(time.perf_counter())
    gaps = np.diff([started] + stamps)
    # the steady state, as wall_per_window: after the first window, which fills the Lava pipeline
    # (~1.4 s; counted in, the rate said 2.3 windows/s beside a p50 of 259 ms)
    steady = gaps[1:] if len(gaps) > 1 else gaps          # (--lava-windows >= 2; a recording of one window)
    total = float(np.sum(steady))
    return {"startup_s": started - a, "first_window_s": float(gaps[0]), "windows": len(stamps),
            "steady_windows": len(steady),
            "windows_per_s": len(steady) / total, "realtime_factor": len(steady) * bundle.config.dt_us * 1e-6 / total,
            "wall_per_window": pct(steady) if len(steady) > 1 else None,
            "note": "simulator wall time on this machine, not Loihi latency; rates after the first window"}


def main(argv=None) -> int:
    ap = OneLineParser(prog="bench_run.py", description="Benchmark toffe-deploy run (latency, throughput, memory).")
    ap.add_argument("--bundle", default=str(ROOT / "export"), help="deploy bundle (toffe-deploy export ckpt/)")
    ap.add_argument("--events", type=existing_file, default=None, help="recording (default: the shipped sample)")
    ap.add_argument("--targets", type=comma_list(target), default="cpu",
                    help=f"comma list of {', '.join(TARGETS)}")
    ap.add_argument("--core", type=cpu_core, default=0, help="CPU core to pin the cpu measurements to")
    ap.add_argument("--repeats", type=positive_int, default=3, help="passes over the recording for cpu latency")
    ap.add_argument("--dense-windows", type=positive_int, default=40, help="windows for the dense 'before' measurement")
    ap.add_argument("--lava-windows", type=at_least_two, default=40,
                    help="windows for loihi-sim, >= 2 (the first fills the pipeline; the rate is the windows' after it)")
    ap.add_argument("--long-seconds", type=positive_float, default=10.0, help="length of the memory-test recording")
    ap.add_argument("--skip-memory", action="store_true", help="skip the peak-memory runs")
    ap.add_argument("--no-track", action="store_true", help="cpu latency without the tracker (its cost: compare)")
    ap.add_argument("--out", type=json_output, default=str(ROOT / "benchmarks" / "results" / "bench_run.json"))
    args = ap.parse_args(argv)
    return guarded("bench_run", run, args)


def run(args) -> int:
    from toffe_deploy.commands.run import SAMPLE
    from toffe_deploy.deploy.bundle import load_bundle
    from toffe_deploy.fileio import atomic_path, check_outputs

    bundle = load_bundle(args.bundle)          # its error says how to make one
    cfg = bundle.config
    sample = Path(args.events) if args.events else SAMPLE
    check_outputs(files=[("--out", args.out)], inputs=[("the recording", sample)])
    windows = load_windows(sample, cfg)
    targets = args.targets
    out = {"machine": machine(),
           "bundle": str(args.bundle), "recording": str(sample), "sensor_size": list(cfg.sensor_size),
           "n_bins": cfg.n_bins, "n_speed_bins": cfg.n_speed_bins, "dt_us": cfg.dt_us, "windows": len(windows)}
    if "cpu" in targets:
        allowed = os.sched_getaffinity(0)
        pin_one_core(args.core)
        out["cpu"] = bench_cpu(bundle, windows, args.repeats, warmup=20, track=not args.no_track)
        out["cpu_dense_before"] = bench_dense(bundle, windows[: args.dense_windows + 1])
        out["cpu_speedup_p50"] = out["cpu_dense_before"]["events_to_flow"]["p50_ms"] / out["cpu"]["events_to_flow"]["p50_ms"]
        os.sched_setaffinity(0, allowed)
        if not args.skip_memory:
            out["cpu_memory"] = bench_memory(Path(args.bundle), sample, args.long_seconds)
    if "loihi-sim" in targets:
        out["loihi-sim"] = bench_lava(bundle, windows, args.lava_windows)
    with atomic_path(args.out) as tmp:
        tmp.write_text(json.dumps(out, indent=2) + "\n")
    print(f"# bench_run ({cfg.sensor_size[0]}x{cfg.sensor_size[1]}, B={cfg.n_bins}, N={cfg.n_speed_bins}, "
          f"a recording of {len(windows)} windows of {cfg.dt_us} us, {out['machine']['cpu']})\n")
    print("| target | measure | p50 ms | p90 ms | p99 ms |\n|---|---|---|---|---|")
    if "cpu" in out:
        for key, label in (("events_to_flow", "events -> flow, 1 core"), ("pipeline", "binned window -> flow, 1 core"),
                           ("events_to_flow_cpu_time", "events -> flow, 1 core, CPU time of the thread"),
                           ("events_to_flow_best_of_repeats", "events -> flow, per-window best of the passes")):
            r = out["cpu"][key]
            print(f"| cpu | {label} | {r['p50_ms']:.3f} | {r['p90_ms']:.3f} | {r['p99_ms']:.3f} |")
        r = out["cpu_dense_before"]["events_to_flow"]
        print(f"| cpu (dense reference, before) | events -> flow, 1 core | {r['p50_ms']:.2f} | {r['p90_ms']:.2f} | "
              f"{r['p99_ms']:.2f} |")
    if out.get("loihi-sim", {}).get("wall_per_window"):
        r = out["loihi-sim"]["wall_per_window"]
        print(f"| loihi-sim | simulator wall time per window | {r['p50_ms']:.1f} | {r['p90_ms']:.1f} | {r['p99_ms']:.1f} |")
    print()
    if "cpu" in out:
        c = out["cpu"]
        print(f"cpu: {c['windows_per_s']:.0f} windows/s on one core (real-time factor {c['realtime_factor']:.2f}: "
              f"sensor time / wall time; {c['windows_per_s_cpu_time']:.0f} windows/s of CPU time), {c['events_per_window_median']:.0f} events and "
              f"{c['objects_per_window']:.2f} objects per window; speed-up over the dense reference "
              f"(p50) {out['cpu_speedup_p50']:.1f}x")
    if "cpu_memory" in out:
        m = out["cpu_memory"]
        print(f"cpu peak RSS: {m['peak_rss_mb_sample']:.0f} MiB on the {len(windows) * cfg.dt_us / 1e6:.1f} s sample, "
              f"{m['peak_rss_mb_long_1s']:.0f} MiB on the first 1 s and "
              f"{m['peak_rss_mb_long']:.0f} MiB on the whole of a {m['long_recording']['seconds']:.1f} s recording "
              f"({m['long_recording']['events']} events, {m['wall_s_long']:.0f} s wall)")
    if "loihi-sim" in out:
        s = out["loihi-sim"]
        print(f"loihi-sim: {s['windows_per_s']:.1f} windows/s (real-time factor {s['realtime_factor']:.3f}) over "
              f"{s['steady_windows']} windows after the first ({s['first_window_s']:.1f} s: the pipeline's fill), start-up "
              f"{s['startup_s']:.1f} s (simulator wall time, not Loihi latency)")
    print(f"\nsaved {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
