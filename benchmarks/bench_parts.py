#!/usr/bin/env python
"""CPU time per window of the cpu target, by part: where `run --target cpu` spends its time.

    .venv/bin/python benchmarks/bench_parts.py [--bundle export/] [--events FILE] [--core 1] [--repeats 5] [--by-call]

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

``--by-call`` instead runs ``Pipeline.process_stream`` itself, as `run --target cpu` does (with
the tracker), and splits each window's thread CPU time by what runs it, each call's time
exclusive of the calls it makes:

    compiled     every numba kernel of the package called from Python (argument unboxing and the
                 boxing of returned arrays included: that is what a call from Python costs)
    onnxruntime  the OFPD session's run
    python       the interpreter and numpy between them: the Pipeline's steps by name (front_batch,
                 front, batch, _result_of_batch, ..., Decoder.columns, Tracker.columns, ...) and
                 "(rest)", what no named step holds (process_stream's own loop among it)

The parts the per-part mode times hold Python too (``decode`` is mostly Python around two
kernels), which is why the two splits differ. One JSON line: ``compiled``, ``onnxruntime``,
``python`` (us per window, mean over every window and repeat), their ``shares``, ``calls`` (us
per window of each, largest first), ``calls_per_window`` and ``wrapper_us_per_call``: what the
timing of one call costs (two reads of the thread's CPU clock, ~1-3 us on a VM), measured on a
wrapped no-op before the passes and taken off each call and its caller (_CallClock).
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
    ap.add_argument("--by-call", action="store_true",
                    help="split the CPU time by call (compiled kernels, onnxruntime, Python), not by part")
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
    if args.by_call:
        print(json.dumps(by_call(bundle, windows, args.repeats)))
        return 0
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


class _CallClock:
    """Exclusive thread CPU time by name of the wrapped callables (``wrap``), for ``by_call``.

    Reading the thread's CPU clock is a system call (~1 us on a VM), so a wrapped call costs
    microseconds of its own: part lands inside the call's own interval, part in its caller's.
    ``calibrate`` measures both on a wrapped no-op, and ``exclusive`` takes them off: each
    call's share from its own time, the rest from its caller's (per wrapped call it made)."""

    TOP = "python:(rest)"

    def __init__(self):
        self.ns: dict[str, int] = {self.TOP: 0}
        self.calls: dict[str, int] = {self.TOP: 0}
        self.children: dict[str, int] = {self.TOP: 0}     # wrapped calls made directly from each
        self._stack = [0]                                  # time spent in wrapped callees of each open call
        self._names = [self.TOP]
        self.inside_ns = self.outside_ns = 0.0

    def wrap(self, name: str, fn):
        clock, stack, names, ns, calls, children = (time.thread_time_ns, self._stack, self._names, self.ns,
                                                    self.calls, self.children)
        for d in (ns, calls, children):
            d.setdefault(name, 0)

        def timed(*a, **k):
            t = clock()
            children[names[-1]] += 1
            stack.append(0)
            names.append(name)
            try:
                return fn(*a, **k)
            finally:
                spent = clock() - t
                names.pop()
                ns[name] += spent - stack.pop()
                calls[name] += 1
                stack[-1] += spent
        return timed

    def calibrate(self, n: int = 20000) -> None:
        """The wrapper's own cost per call: inside its interval and outside it (in the caller)."""
        probe = _CallClock()
        f = probe.wrap("probe", _noop)
        clock = time.thread_time_ns
        t = clock()
        for _ in range(n):
            _noop()
        plain = clock() - t
        t = clock()
        for _ in range(n):
            f()
        wrapped = clock() - t
        self.inside_ns = probe.ns["probe"] / n
        self.outside_ns = max(0.0, (wrapped - plain) / n - self.inside_ns)

    def exclusive(self, total_ns: int) -> dict[str, float]:
        """ns of each name, the wrapper's cost taken off; TOP gets what no wrapped call holds."""
        out = {k: v - self.calls[k] * self.inside_ns - self.children[k] * self.outside_ns
               for k, v in self.ns.items() if k != self.TOP and self.calls[k]}
        out[self.TOP] = total_ns - sum(self.ns[k] for k in out) - self.children[self.TOP] * self.outside_ns
        return out


def _noop():
    return None


def by_call(bundle, windows, repeats: int) -> dict:
    """``--by-call``: the windows through Pipeline.process_stream, CPU time split by call (module doc)."""
    from numba.core.registry import CPUDispatcher

    from toffe_deploy.faint_objects import FaintDensity
    from toffe_deploy.ofpd_io import Decoder
    from toffe_deploy.runtime import ofpd_input, pipeline
    from toffe_deploy.runtime.pipeline import Pipeline
    from toffe_deploy.runtime.spikes import SpikeVolume
    from toffe_deploy.time_surface import OnesHistory
    from toffe_deploy.tracking import Tracker

    cfg = bundle.config

    def volumes():                                     # binned in the loop, as `run` does
        return ((t0, SpikeVolume.from_events(ev, t0, cfg.dt_us, cfg.n_bins, cfg.sensor_size)) for t0, ev in windows)

    cc = _CallClock()
    patched = []                                       # (owner, attribute, original), undone at the end

    def patch(owner, attr, name):
        orig = getattr(owner, attr)
        patched.append((owner, attr, orig))
        setattr(owner, attr, cc.wrap(name, orig))

    with Pipeline(bundle, "cpu") as pipe:
        for _ in pipe.process_stream(volumes()):       # one pass untimed: kernels loaded, caches warm
            pass
        try:
            for mod in [m for n, m in list(sys.modules.items()) if n.startswith("toffe_deploy") and m is not None]:
                for attr, value in list(vars(mod).items()):
                    if isinstance(value, CPUDispatcher):
                        patch(mod, attr, "compiled:" + value.py_func.__name__)
            patch(pipe.ofpd, "_run", "onnxruntime:run")
            patch(type(pipe.ofpd), "run", "python:OFPDRunner.run")
            patch(SpikeVolume, "from_events", "python:SpikeVolume.from_events")
            for attr in ("front_batch", "front", "batch", "_result", "_result_of_batch", "objects_of_batch", "objects_of_ofpd",
                         "fuse", "place", "_faint_columns"):
                patch(Pipeline, attr, "python:Pipeline." + attr)
            for attr in ("front_end", "speeds_of", "fuse_history", "outline_positions"):
                patch(pipeline, attr, "python:" + attr)
            patch(ofpd_input, "batch", "python:ofpd_input.batch")
            for cls, attrs in ((Decoder, ("columns",)), (Tracker, ("columns", "coasting")),
                               (FaintDensity, ("step",)), (OnesHistory, ("push",))):
                for attr in attrs:
                    patch(cls, attr, f"python:{cls.__name__}.{attr}")
            cc.calibrate()
            clock = time.thread_time_ns
            t = clock()
            for _ in range(repeats):
                for _res in pipe.process_stream(volumes()):
                    pass
            total = clock() - t
        finally:
            for owner, attr, orig in reversed(patched):
                setattr(owner, attr, orig)
    n = repeats * len(windows)
    per = {k: v / 1e3 / n for k, v in cc.exclusive(total).items()}
    groups = {g: sum(v for k, v in per.items() if k.startswith(g + ":")) for g in ("compiled", "onnxruntime", "python")}
    whole = sum(groups.values())
    return {**{g: round(v, 1) for g, v in groups.items()}, "sum_us": round(whole, 1),
            "shares": {g: round(v / whole, 3) for g, v in groups.items()},
            "calls": {k: round(v, 1) for k, v in sorted(per.items(), key=lambda kv: -kv[1])},
            "calls_per_window": {k: round(cc.calls[k] / n, 2) for k in per if k != cc.TOP},
            "wrapper_us_per_call": round((cc.inside_ns + cc.outside_ns) / 1e3, 2),
            "windows": n, "recording_windows": len(windows), "repeats": repeats,
            "load_1min": round(os.getloadavg()[0], 2),
            "unit": "us of the thread's CPU time per window (mean), each call exclusive of the calls it makes"}


if __name__ == "__main__":
    sys.exit(main())
