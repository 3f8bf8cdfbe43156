#!/usr/bin/env python
"""CPU time per window of the cpu target, by part: where `run --target cpu` spends its time.

    .venv/bin/python benchmarks/bench_parts.py [--bundle export/] [--events FILE] [--core 1] [--repeats 5]

Each window of the recording (default: the shipped sample) goes through the steps of
``Pipeline.process_stream`` one at a time, each timed with the thread's CPU time
(time.thread_time_ns: what this thread ran, not what the other processes of a shared machine
took from it, so parts compare across runs on a busy machine better than wall time):

    bin      SpikeVolume.from_events (event index, sorted unique ones)
    front    the input front end (first spike, cluster filter)
    cascade  CpuCascade.pooled_frames (pool, the N OFS stages, closings, masks, Up_p; one compiled call)
             or, unpooled, CpuCascade.cascade_sparse
    batch    runtime.ofpd_input.batch (object grouping, crops, OFPD input)
    ort      the onnxruntime call
    decode   the plane fit of the fast objects and its fusion (ofpd.plane_fit_weight > 0: plane_fit),
             ofpd_io.Decoder.columns, slow objects' positions from their outlines
             (ofpd.outline_centre: Pipeline.place) and pipeline.speeds_of
    faint    ofpd.faint_objects' density and search (faint_objects.FaintDensity.step; 0 when off)

Prints one JSON line: the median of each part over windows and repeats (us), the median and
mean of their sum, ``windows``: the number of timed windows (the recording's windows times
--repeats), ``recording_windows`` and ``repeats`` apart, and the 1-minute load average when it ended.
"""
from __future__ import annotations

import json
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from _args import OneLineParser, cpu_core, default_core, existing_file, guarded, positive_int  # noqa: E402

PARTS = ("bin", "front", "cascade", "batch", "ort", "decode", "faint")


def main(argv=None) -> int:
    ap = OneLineParser(prog="bench_parts.py", description="CPU time per window of the cpu target, by part.")
    ap.add_argument("--bundle", default=str(ROOT / "export"), help="deploy bundle (toffe-deploy export ckpt/)")
    ap.add_argument("--events", type=existing_file, default=None, help="recording (default: the shipped sample)")
    ap.add_argument("--core", type=cpu_core, default=default_core(),
                    help="CPU core to pin to (default 1, or 0 on a one-core machine)")
    ap.add_argument("--repeats", type=positive_int, default=5, help="passes over the recording")
    args = ap.parse_args(argv)
    return guarded("bench_parts", run, args)


def run(args) -> int:
    from bench_run import load_windows, pin_one_core
    from toffe_deploy.commands.run import SAMPLE
    from toffe_deploy.deploy.bundle import load_bundle
    from toffe_deploy.events.support import front_end
    from toffe_deploy.runtime import ofpd_input
    from toffe_deploy.runtime.pipeline import Pipeline, sensor_frames, speeds_of
    from toffe_deploy.runtime.spikes import SpikeVolume

    bundle = load_bundle(args.bundle)
    cfg = bundle.config
    path = Path(args.events) if args.events else SAMPLE
    windows = load_windows(path, cfg)
    pin_one_core(args.core)
    clock = time.thread_time_ns
    parts: dict[str, list[float]] = {p: [] for p in PARTS}
    total = []
    with Pipeline(bundle, "cpu") as pipe:
        for _ in range(args.repeats):
            for t0, ev in windows:
                t = [clock()]
                vol = SpikeVolume.from_events(ev, t0, cfg.dt_us, cfg.n_bins, cfg.sensor_size)
                t.append(clock())
                vol = front_end(vol, cfg, pipe.support, t0)       # the Pipeline's own windows before (input_support)
                pixels = pipe.support.latest_pixels if pipe.faint is not None else None
                if pipe.ones_history is not None:
                    pipe.ones_history.push(t0, vol.idx, (vol.bc, vol.pix))   # the plane fit's windows (plane_fit_history)
                t.append(clock())
                frames = (pipe.cascade.pooled_frames(vol, cfg.ofs_pool) if cfg.ofs_pool > 1   # as Pipeline runs it
                          else sensor_frames(pipe.cascade, vol, cfg.ofs_pool))
                t.append(clock())
                ks, x, _n, ones = ofpd_input.batch(vol, frames, cfg, pipe._scratch, pipe.support, pipe._batch)   # as Pipeline.objects_of
                t.append(clock())
                out = pipe.ofpd.run(x) if ks.size else None
                t.append(clock())
                if ks.size:
                    pose, direction, speed = out                                 # as Pipeline.objects_of
                    speed, direction = pipe.fuse(speed, direction, ones, ks.size)          # as Pipeline.objects_of
                    dec = pipe.place(pipe._decode.columns(pose, direction, speed, ks), ones)   # as Pipeline.objects_of
                    speeds_of(dec, cfg, pipe.speed_scale)                                      # as Pipeline.objects_of
                t.append(clock())
                if pipe.faint is not None:                                                     # as Pipeline._faint_columns
                    xy = (dec["speed_bin"], dec["x_px"], dec["y_px"]) if ks.size else ([], [], [])
                    pipe.faint.step(t0, pixels, ones, *xy)
                t.append(clock())
                for name, a, b in zip(PARTS, t[:-1], t[1:]):
                    parts[name].append((b - a) / 1e3)
                total.append((t[-1] - t[0]) / 1e3)
    res = {name: round(float(np.median(v)), 1) for name, v in parts.items()}
    res.update(sum_median_us=round(float(np.median(total)), 1), sum_mean_us=round(float(np.mean(total)), 1),
               windows=len(total), recording_windows=len(windows), repeats=args.repeats, load_1min=round(os.getloadavg()[0], 2),
               unit="us of the thread's CPU time per window: each part's median over the windows; sum_median_us is "
                    "the median of the per-window sums (not the sum of the medians)")
    print(json.dumps(res))
    return 0


if __name__ == "__main__":
    sys.exit(main())
