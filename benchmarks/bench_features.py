#!/usr/bin/env python
"""What each host-side feature of the cpu target costs per window, and what is left without them.

    .venv/bin/python benchmarks/bench_features.py [--bundle export/] [--events FILE] [--core 1]
                                                  [--repeats 4] [--features faint,outline,history,plane_fit,tracking,all]

One Pipeline per variant, all in this process: the bundle as it is (``default``) and the bundle
with one feature switched off (its config.ofpd overrides, as ``--ofpd`` gives them elsewhere):

    faint      ofpd.faint_objects null            (the faint slow objects' density and search)
    outline    ofpd.outline_centre null           (slow objects' positions from their outlines)
    history    ofpd.plane_fit_history null        (the plane fit over one window instead of the K
               and ofpd.outline_centre null        before; the outline positions and the refits
               and ofpd.plane_fit_refits 0         read that history)
    plane_fit  the three above, and ofpd.plane_fit_weight, plane_fit_dir_weight 0 (no plane fit)
    tracking   the Pipeline without its tracker   (run --no-track)
    all        every switch above at once: the host steps the accuracy work added on top of the
               core (binning, front end with its temporal support and recent_events, OFS
               cascade, grouping, OFPD), which stays as it is

A switch that changes nothing (the bundle has the feature off already) is not timed: the JSON
lists it under ``skipped``, so that "free" is never read off a feature that was not there.

Why in one process and window by window: on a shared machine the CPU time of a pass swings by
tens of percent from minute to minute (README, "Speed of toffe-deploy run": compare only
interleaved). Here each window of the recording runs through every variant in turn, and each is
timed with the thread's CPU time; a drift hits every variant alike. The order rotates from window
to window (``rotation``: over a pass each variant runs first, second, ... equally often), because
the position matters by itself: a variant run right after another finds the caches as that one
left them (measured: "all" 0.70 of default when default ran first on every window, 0.72 when it
ran last). The passes' ratios then agree to about 0.01-0.05 where whole passes minutes apart
differ by 20 % and more.

Prints one JSON line: per variant the median and mean CPU time per window (us), the ratio of its
summed time to default's (``ratio``) with the lowest and highest ratio of a single pass, the
windows per second that CPU time gives, and the objects it reported (switching a feature off
changes what is found: the accuracy side of the trade is eval's and bench_tracking.py's, README
"What the goal would take"). What it does not say: the cost on another machine; rerun it there.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from _args import OneLineParser, comma_list, cpu_core, default_core, existing_file, guarded, positive_int  # noqa: E402

#: each switch: (config.ofpd overrides, whether the Pipeline keeps its tracker)
SWITCHES = {
    "faint": ({"faint_objects": None}, True),
    "outline": ({"outline_centre": None}, True),
    "history": ({"plane_fit_history": None, "outline_centre": None, "plane_fit_refits": 0}, True),
    "plane_fit": ({"plane_fit_history": None, "outline_centre": None, "plane_fit_refits": 0, "plane_fit_weight": 0.0,
                   "plane_fit_dir_weight": 0.0}, True),
    "tracking": ({}, False),
}
FEATURES = (*SWITCHES, "all")


def feature(text: str) -> str:
    """An argparse type: one of FEATURES."""
    if text not in FEATURES:
        raise argparse.ArgumentTypeError(f"unknown feature {text!r} (choose from {', '.join(FEATURES)})")
    return text


def rotation(names: list[str], window: int) -> list[str]:
    """The order in which the variants run window ``window``: ``names`` rotated by its index, so
    that over len(names) windows each variant holds each position once."""
    k = window % len(names)
    return names[k:] + names[:k]


def variant(name: str) -> tuple[dict, bool]:
    """(config.ofpd overrides, keep the tracker) of a feature name; "all" is every switch."""
    if name != "all":
        return SWITCHES[name]
    ofpd: dict = {}
    for overrides, _track in SWITCHES.values():
        ofpd.update(overrides)
    return ofpd, False


def features_on(pipe) -> tuple[bool, ...]:
    """Which host features a Pipeline runs: (faint objects, outline positions, the windows
    before for the plane fit, any plane fit, tracker)."""
    return (pipe.faint is not None, pipe._outline is not None, pipe.ones_history is not None, pipe._fusion.on,
            pipe.tracker is not None)


def main(argv=None) -> int:
    ap = OneLineParser(prog="bench_features.py",
                       description="CPU time per window of the cpu target with each host feature off, interleaved.")
    ap.add_argument("--bundle", default=str(ROOT / "export"), help="deploy bundle (toffe-deploy export ckpt/)")
    ap.add_argument("--events", type=existing_file, default=None, help="recording (default: the shipped sample)")
    ap.add_argument("--core", type=cpu_core, default=default_core(),
                    help="CPU core to pin to (default 1, or 0 on a one-core machine)")
    ap.add_argument("--repeats", type=positive_int, default=4, help="passes over the recording (default 4)")
    ap.add_argument("--features", type=comma_list(feature), default=list(FEATURES),
                    help=f"comma list of {', '.join(FEATURES)} (default: all of them)")
    args = ap.parse_args(argv)
    return guarded("bench_features", run, args)


def run(args) -> int:
    import dataclasses

    from _args import apply_overrides
    from bench_run import load_windows, pin_one_core
    from toffe_deploy.commands.run import SAMPLE
    from toffe_deploy.deploy.bundle import load_bundle
    from toffe_deploy.runtime.pipeline import Pipeline
    from toffe_deploy.runtime.spikes import SpikeVolume

    bundle = load_bundle(args.bundle)
    cfg = bundle.config
    names, skipped, pipes = ["default"], [], {"default": Pipeline(bundle, "cpu")}
    for name in dict.fromkeys(args.features):
        overrides, track = variant(name)
        config = apply_overrides(cfg, list(overrides.items()), [])
        pipe = Pipeline(dataclasses.replace(bundle, config=config), "cpu", track=track)
        if features_on(pipe) == features_on(pipes["default"]):
            skipped.append(name)                 # the bundle has it off already: nothing to time
            continue
        names.append(name)
        pipes[name] = pipe
    path = Path(args.events) if args.events else SAMPLE
    windows = load_windows(path, cfg)
    affinity = os.sched_getaffinity(0)
    pin_one_core(args.core)
    times = {name: np.zeros((args.repeats, len(windows))) for name in names}
    objects = dict.fromkeys(names, 0)
    clock = time.thread_time_ns
    try:
        for p in pipes.values():
            p.__enter__()
            for t0, ev in windows[:10]:          # warm: loads, first-window allocations
                next(p.process_stream([(t0, SpikeVolume.from_events(ev, t0, cfg.dt_us, cfg.n_bins, cfg.sensor_size))]))
        for r in range(args.repeats):
            for i, (t0, ev) in enumerate(windows):
                for name in rotation(names, i + r):
                    a = clock()
                    vol = SpikeVolume.from_events(ev, t0, cfg.dt_us, cfg.n_bins, cfg.sensor_size)
                    res = next(pipes[name].process_stream([(t0, vol)]))
                    times[name][r, i] = (clock() - a) / 1e3
                    objects[name] += len(res.objects)
                    del vol, res                  # freed here, not inside the next variant's timing
    finally:
        for p in pipes.values():
            p.close()
        os.sched_setaffinity(0, affinity)        # a caller in the same process (a test) is not left pinned
    base = times["default"]
    out = {}
    for name in names:
        t = times[name]
        per_pass = t.sum(axis=1) / base.sum(axis=1)
        overrides, track = variant(name) if name != "default" else ({}, True)
        out[name] = {"p50_us": round(float(np.median(t)), 1), "mean_us": round(float(t.mean()), 1),
                     "ratio": round(float(t.sum() / base.sum()), 3),
                     "ratio_passes": [round(float(per_pass.min()), 3), round(float(per_pass.max()), 3)],
                     "windows_per_s_cpu_time": round(float(t.size / (t.sum() / 1e6)), 1),
                     "objects": objects[name] // args.repeats, "ofpd_off": overrides, "tracker": track}
    print(json.dumps({"variants": out, "skipped": skipped, "recording_windows": len(windows), "repeats": args.repeats,
                      "load_1min": round(os.getloadavg()[0], 2),
                      "unit": "us of the thread's CPU time per window (binning included), every variant run on each "
                              "window in turn; ratio: summed time over default's"}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
