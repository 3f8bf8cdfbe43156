"""`toffe-deploy run [BUNDLE] --target T`: the deployed TOFFE on a stream of events.

Windows of the bundle's dt stream from the recording (never loaded whole) or from a live source
(stdin, UDP AER, DV network stream or camera: events/live.py), each goes through the OFS cascade
on the target's backend and OFPD in onnxruntime, and its object flow is written as one JSON line
as soon as it is done (runtime/output.py: whole lines, flushed). A summary (windows, objects, windows/s, latency percentiles, and pixE/dirE/speedE
when the recording carries ground truth) closes the run: on stderr when the JSON lines go to
stdout, so stdout stays pure JSON lines, on stdout otherwise.

Any sensor size up to 16.8 M pixels (config.MAX_SENSOR_PIXELS, e.g. 4096x4096) runs (the OFS is a
convolution, OFPD sees a crop): the cascade is built for the
recording's sensor (``--sensor-size`` for files without one, or to override it). Speeds are
reported in px/s and in m/s for the camera of ``runtime.run_camera`` (``--depth-m``,
``--focal-px`` / ``--hfov-deg``, else the bundle's).
"""
from __future__ import annotations

import collections
import dataclasses
import math
import os
import sys
import time
from pathlib import Path

from ..config import MAX_SENSOR_PIXELS, sensor_too_large
from ..errors import InputError, ToffeError
from ..events.live import GRACE_S, QUEUE_EVENTS, is_live
from ..signals import signal_behind, signals_deferred
from . import add_progress_flag, show_progress, slow_notice

TARGETS = ("cpu", "cuda", "loihi-sim", "loihi2")
SAMPLE = Path(__file__).resolve().parent.parent / "samples" / "sample_multi.h5"
SYNTH_KEYS = ("split", "index", "duration", "seed", "sensor", "hfov")
#: Default of --skip-empty-after: 1000 windows (0.5 s at dt = 500 us) of nothing before a jump.
SKIP_EMPTY_AFTER = 1000


def register(sub) -> None:
    from ..camera import HFOV_RANGE_DEG

    p = sub.add_parser(
        "run", help="run a deploy bundle on events and print object flow per window",
        description="Run the deployed TOFFE (OFS cascade + OFPD) on a stream of events and print, per "
                    "window, each object's speed bin, speed, position and direction as one JSON line.")
    p.add_argument("bundle", nargs="?", default="export/",
                   help="deploy bundle directory written by `toffe-deploy export` (default: export/)")
    p.add_argument("--target", choices=TARGETS, default="cpu",
                   help="where the OFS cascade runs: cpu (compiled fixed point, no torch/Lava), cuda (OFPD on "
                        "onnxruntime's CUDA/TensorRT provider), loihi-sim (Lava simulator), loihi2 (Loihi 2 "
                        "hardware through lava-loihi); default: cpu")
    src = p.add_mutually_exclusive_group()
    src.add_argument("--events", metavar="FILE",
                     help="event recording (our HDF5, npz/npy, DSEC/MVSEC HDF5, AEDAT4, Prophesee RAW/DAT, "
                          "Metavision HDF5, ROS1 .bag or ROS2 bag directory), or a live source: "
                          "'-' (binary event stream on stdin), 'udp://HOST:PORT' (aestream / SPIF AER packets; "
                          "needs --sensor-size), 'dv://HOST:PORT' (DV network stream), 'dv-camera[:SERIAL]' "
                          "(README: Live sources); default: the shipped multi-object sample")
    src.add_argument("--synthetic", metavar="SPEC",
                     help="generate the recording on the fly with the data-set generator: "
                          "'SPLIT[:INDEX][,duration=S][,seed=N][,sensor=WxH][,hfov=DEG]', e.g. "
                          "'multi:2,duration=0.05,sensor=346x260' (SPLIT: train, test or multi); rendered on a "
                          "pinhole camera of sensor WxH (default: --sensor-size, else the bundle's) and "
                          f"horizontal field of view DEG ({HFOV_RANGE_DEG[0]:g}..{HFOV_RANGE_DEG[1]:g}, default: 60)")
    p.add_argument("--sensor-size", metavar="WxH", type=parse_size,
                   help="the recording's sensor size, e.g. 346x260: for files without one (npz/npy without "
                        "sensor_size are otherwise sized by their largest coordinate) or to override the file's; "
                        "events outside it are an error. Any size up to 16.8 M pixels (4096x4096) runs "
                        "(default: the file's)")
    p.add_argument("--depth-m", type=float, metavar="D",
                   help="object distance in metres that speeds in m/s assume (default: the bundle's, 5 m for "
                        "the shipped one); px/s speeds do not depend on it")
    lens = p.add_mutually_exclusive_group()
    lens.add_argument("--focal-px", type=float, metavar="F",
                      help="focal length of the recording's camera in pixels, for speeds in m/s (default: the "
                           "bundle's when the sensor is as wide as the bundle's, else the bundle's horizontal "
                           "field of view over the recording's width)")
    lens.add_argument("--hfov-deg", type=float, metavar="DEG",
                      help="the recording camera's horizontal field of view instead of --focal-px: "
                           f"F = (W / 2) / tan(DEG / 2); {HFOV_RANGE_DEG[0]:g}..{HFOV_RANGE_DEG[1]:g} degrees")
    p.add_argument("--out", metavar="FILE.jsonl", help="write the JSON lines to this file instead of stdout ('-': "
                                                       "stdout): it replaces an existing file with its first line "
                                                       "(the header), then each window's line is appended whole "
                                                       "as soon as the window is done")
    p.add_argument("--queue-events", type=int, default=None, metavar="N",
                   help=f"live sources: at most N events wait between the reader and the run; when more "
                        f"arrive the oldest chunks are dropped and counted, except on stdin, whose reader "
                        f"waits (a pipe pushes back; a larger read goes in alone) (default: {QUEUE_EVENTS})")
    p.add_argument("--idle-timeout", type=float, default=None, metavar="S",
                   help="live sources: end the run after S seconds without an event, counted from the end of "
                        "the run's start-up until the first event, then from the latest; on stdin also the wait "
                        "for the stream's header (default: 0, never; stdin ends at end of file, dv:// when the "
                        "sender stops, every source on Ctrl-C)")
    p.add_argument("--window-grace-ms", type=float, default=None, metavar="MS",
                   help=f"live sources: how long past a window's end (in host time, the source's clock mapped "
                        f"at its first event) the run waits for late events when nothing newer came; events "
                        f"that come later are dropped and counted (default: {GRACE_S * 1e3:g})")
    p.add_argument("--render", metavar="DIR", help="also write one frame per window (events and flow arrows "
                                                   "coloured by the flow colour wheel) into DIR")
    p.add_argument("--video", action="store_true", help="with --render: one MP4 (DIR/object_flow.mp4) "
                                                        "instead of PNG frames")
    p.add_argument("--fps", type=float, default=None, help="frame rate of the --video file (default: 10)")
    p.add_argument("--theme", choices=("dark", "light"), default="dark",
                   help="with --render: events on black (dark, default) or on white (light)")
    p.add_argument("--report", metavar="FILE.html",
                   help="also write one self-contained HTML page (atomically): tracks over time, speed per "
                        "track, a per-bin summary and the summary figures")
    p.add_argument("--max-windows", type=int, metavar="N", help="stop after N windows")
    p.add_argument("--start-us", type=int, metavar="T", help="first window starts at T >= 0 (default: recording start)")
    p.add_argument("--include-incomplete", action="store_true",
                   help="also process the last window when the recording (or a live stream) ends inside it; by "
                        "default it is dropped and the summary says so, since its objects would come from part of "
                        "a window (a slow one's speed and position from a fraction of its edges), as eval does")
    p.add_argument("--skip-empty-after", type=int, default=SKIP_EMPTY_AFTER, metavar="N",
                   help=f"after N consecutive empty windows jump to the window of the next event (a long gap "
                        f"in the recording costs N windows, not millions); the summary counts the skipped "
                        f"windows; 0 = never skip (default: {SKIP_EMPTY_AFTER})")
    p.add_argument("--tag", choices=("fixed_pt", "floating_pt"), default="fixed_pt",
                   help="Lava process models for the loihi targets: fixed_pt (bit-accurate Loihi 2, default) "
                        "or floating_pt")
    p.add_argument("--ofpd", choices=("fp32", "fp16", "int8"), default="fp32",
                   help="OFPD model of the bundle: fp32 (default, the reference) or the fp16 / int8 variant "
                        "written by `toffe-deploy export --variants`")
    p.add_argument("--processes", type=int, choices=(1, 2), default=1,
                   help="host processes for the cpu and cuda targets: 2 runs the front end, the OFS cascade, the "
                        "grouping and the OFPD of the next window in a second process while this one runs the "
                        "plane fit, the tracker and the output of the window before; bit exact with 1; 1.4-1.5x "
                        "the windows/s on a 2-core VM, for more CPU time and latency (README: Speed); default: 1")
    p.add_argument("--no-track", action="store_true",
                   help="do not track objects over the windows (no track_id / track in the JSON lines, no "
                        "tracking metrics); tracking is on by default (toffe_deploy/tracking.py)")
    p.add_argument("--summary-json", metavar="FILE", help="also write the summary as JSON (atomically)")
    p.add_argument("--dump-spikes", metavar="FILE.npz",
                   help="also write every window's OFS stage inputs and output spikes (t0_us (n,), stage_input "
                        "(n, N, B, 2, H, W), stage_output (n, N, B, H, W) bool; index k-1 = OFS_k) to a compressed "
                        ".npz, to compare a deployment with another runtime; needs --max-windows (about 18 MB per "
                        "640x480 window in memory)")
    add_progress_flag(p)
    p.set_defaults(func=run_command)


def parse_size(text: str) -> tuple[int, int]:
    """'346x260' -> (346, 260); argparse reports a ValueError as a one-line usage error."""
    w, sep, h = str(text).lower().partition("x")
    try:
        size = (int(w), int(h)) if sep else None
    except ValueError:
        size = None
    if size is None or min(size) < 1:
        raise ValueError(f"sensor size must be WIDTHxHEIGHT in pixels, e.g. 346x260, got {text!r}")
    return size


parse_size.__name__ = "sensor size"      # argparse names the type in its error message


def parse_synthetic(spec: str) -> dict:
    """'multi:2,duration=0.05,seed=1,sensor=346x260,hfov=60' -> {split, index, duration, seed,
    sensor, hfov} (ToffeError if malformed)."""
    from ..camera import HFOV_RANGE_DEG
    from ..dataset.splits import MAX_SYNTH_DURATION_S

    out = {"split": "multi", "index": 0, "duration": None, "seed": 0, "sensor": None, "hfov": None}
    for i, tok in enumerate(t.strip() for t in spec.split(",") if t.strip()):
        if "=" not in tok:
            if i:
                raise ToffeError(f"--synthetic {spec!r}: expected key=value after the first item, got {tok!r}")
            split, _, idx = tok.partition(":")
            out["split"] = split
            if idx:
                out["index"] = idx
            continue
        key, _, val = tok.partition("=")
        if key not in SYNTH_KEYS:
            raise ToffeError(f"--synthetic {spec!r}: unknown key {key!r} (known: {', '.join(SYNTH_KEYS)})")
        out[key] = val
    try:
        out["index"] = int(out["index"])
        out["seed"] = int(out["seed"])
        out["duration"] = None if out["duration"] is None else float(out["duration"])
        out["hfov"] = None if out["hfov"] is None else float(out["hfov"])
        out["sensor"] = None if out["sensor"] is None else parse_size(out["sensor"])
    except ValueError as exc:
        raise ToffeError(f"--synthetic {spec!r}: {exc}") from None
    if out["seed"] < 0:
        raise ToffeError(f"--synthetic {spec!r}: seed must be >= 0, got {out['seed']}")
    if out["sensor"] is not None and out["sensor"][0] * out["sensor"][1] > MAX_SENSOR_PIXELS:
        raise ToffeError(f"--synthetic {spec!r}: {sensor_too_large(out['sensor'])}")
    if out["split"] not in ("train", "test", "multi"):
        raise ToffeError(f"--synthetic {spec!r}: split must be train, test or multi, got {out['split']!r}")
    if out["duration"] is not None and not 0 < out["duration"] <= MAX_SYNTH_DURATION_S:
        raise ToffeError(f"--synthetic {spec!r}: duration must be in (0, {MAX_SYNTH_DURATION_S:g}] s "
                         "(the generator holds the whole recording in memory)")
    lo, hi = HFOV_RANGE_DEG
    if out["hfov"] is not None and not lo <= out["hfov"] <= hi:
        raise ToffeError(f"--synthetic {spec!r}: hfov must be in [{lo:g}, {hi:g}] degrees, got {out['hfov']:.12g}")
    return out


def synthetic_source(spec: str, sensor_size: tuple[int, int], override: tuple[int, int] | None = None):
    """An in-memory EventSource with ground truth from the data-set generator, rendered by a
    PinholeCamera of the spec's sensor (else ``override``, i.e. --sensor-size, else ``sensor_size``)
    and hfov (default the generator's); ``attrs["focal_px"]`` is that camera's focal length."""
    from ..camera import PinholeCamera
    from ..dataset.splits import SYNTH_SIDE_PX, split_specs
    from ..dataset.synth import generate_sequence
    from ..events.source import ArraySource

    s = parse_synthetic(spec)
    specs = split_specs(s["split"], seed=s["seed"], duration_s=s["duration"])
    if not 0 <= s["index"] < len(specs):
        raise ToffeError(f"--synthetic {spec!r}: index must be in 0..{len(specs) - 1} for split {s['split']}")
    if s["sensor"] and override and tuple(s["sensor"]) != tuple(override):
        raise ToffeError(f"--synthetic {spec!r}: sensor={s['sensor'][0]}x{s['sensor'][1]} contradicts "
                         f"--sensor-size {override[0]}x{override[1]} (give one)")
    w, h = s["sensor"] or override or sensor_size
    lo, hi = SYNTH_SIDE_PX
    if not (lo <= w <= hi and lo <= h <= hi):        # the generator's sides, as dataset synth's
        raise ToffeError(f"--synthetic {spec!r}: the generator renders sensors of {lo}..{hi} px a side, got {w}x{h}")
    cam = PinholeCamera(width=w, height=h) if s["hfov"] is None else PinholeCamera(width=w, height=h, hfov_deg=s["hfov"])
    seq = dataclasses.replace(specs[s["index"]], camera=cam)
    events, gt, size = generate_sequence(seq, seed=s["seed"])
    return ArraySource(f"synthetic:{seq.name}", events, size, ground_truth=gt,
                       attrs={"generator": "toffe-deploy synth", "sequence": seq.name, "focal_px": cam.f},
                       t_range=(0, int(round(seq.duration_s * 1e6))), validated=True)


def check_run_outputs(args, bundle) -> None:
    """--out, --summary-json and --render may not overwrite the events, the bundle or a bundle file,
    nor each other; checked before any work (see fileio.check_outputs)."""
    from ..fileio import check_outputs

    events = None if args.synthetic or is_live(args.events) else args.events or SAMPLE   # the sample when none given
    inputs = [("the input events", events),
              ("the bundle directory", bundle.root),
              ("the bundle manifest", bundle.root / "manifest.json")]
    inputs += [("bundle file", bundle.root / rel) for rel in bundle.manifest["files"]]
    inputs += [("bundle file", p) for p in bundle.ofpd_variants.values()]
    check_outputs(files=[("--out", args.out), ("--summary-json", args.summary_json),
                         ("--dump-spikes", args.dump_spikes), ("--report", args.report)],
                  dirs=[("--render", args.render)], inputs=inputs, streamed=("--out",))


def _is_stdout(path) -> bool:
    """Whether ``path`` (/dev/stdout, /dev/fd/1, /proc/self/fd/1) names this process's stdout:
    `--out /dev/stdout` is `--out -`, so that the summary goes to stderr, not into the lines."""
    if path is None:
        return False
    try:
        return os.path.samestat(os.stat(path), os.fstat(sys.stdout.fileno()))
    except (OSError, ValueError, AttributeError):
        return False


def open_source(args, bundle_sensor: tuple[int, int]):
    """The recording: its own sensor size (``--sensor-size`` overrides it), whatever the bundle's."""
    from ..events.io import open_events

    if args.synthetic:
        return synthetic_source(args.synthetic, bundle_sensor, args.sensor_size)
    if is_live(args.events):
        from ..events.live import open_live

        return open_live(args.events, args.sensor_size, args.queue_events, args.idle_timeout,
                         args.window_grace_ms / 1e3)
    path = Path(args.events) if args.events else SAMPLE
    if not args.events and not SAMPLE.is_file():
        raise InputError(SAMPLE, "the shipped sample recording is missing (reinstall, or pass --events FILE)")
    return open_events(path, sensor_size=args.sensor_size)


#: at most how many first windows with events run reads for events.convert.TimeUnitCheck's hint (a
#: recording in microseconds decides it at its first timestamp off a multiple of 1000, one in ns at
#: its 100th event; empty windows do not count: a sparse recording in ns has many)
TIME_UNIT_WINDOWS = 1_000


#: what the summary adds to a sensor size the file does not record: the front end's noise rules
#: read the event density over the sensor's area, so one smaller than the camera's loses slow
#: objects (README, "Your camera")
GUESSED_SIZE = "pass --sensor-size WxH: the noise rules read the sensor's area"


def sensor_origin(args, src) -> str:
    """Where the run's sensor size came from, for the summary (an inferred one is worth a warning)."""
    if args.sensor_size:
        return "--sensor-size"
    if getattr(src, "live", False):
        return "the live stream's"
    if args.synthetic:
        return "the synthetic camera's"
    if src.attrs.get("sensor_size_inferred"):
        return f"inferred from the largest event coordinates: {GUESSED_SIZE}"
    if src.attrs.get("sensor_size_default"):
        return f"{src.attrs['sensor_size_default']}'s default, the file records none: {GUESSED_SIZE}"
    return "the recording's"


def run_command(args) -> int:
    from ..deploy.bundle import load_bundle
    from ..runtime.output import (DUMP_MAX_BYTES, RunSummary, SpikeDump, dump_bytes_per_window, jsonl_sink,
                                  write_window)
    from ..runtime.pipeline import Pipeline
    from ..runtime.run_camera import resolve_camera
    from ..runtime.spikes import SpikeVolume
    from ..events.convert import TimeUnitCheck

    if args.max_windows is not None and args.max_windows < 1:
        raise ToffeError("--max-windows must be >= 1")
    if args.dump_spikes and args.max_windows is None:
        raise ToffeError("--dump-spikes needs --max-windows N (it holds every window's dense stage arrays)")
    from ..events.validate import MAX_TIME_US

    if args.start_us is not None and not 0 <= args.start_us <= MAX_TIME_US:
        raise ToffeError(f"--start-us must be in 0..2**53 us, got {args.start_us}")
    if args.skip_empty_after < 0:
        raise ToffeError("--skip-empty-after must be >= 0 (0: never skip)")
    if args.events and "://" in args.events and not is_live(args.events):
        raise ToffeError(f"--events {args.events}: unknown live source (udp://HOST:PORT, dv://HOST:PORT, "
                         "dv-camera[:SERIAL] or - for stdin; anything else is a file path)")
    if is_live(args.events) and args.start_us is not None:
        raise ToffeError("--start-us applies to files: a live source starts at its first event")
    live_only = [f"--{n.replace('_', '-')}" for n in ("queue_events", "idle_timeout", "window_grace_ms")
                 if getattr(args, n) is not None]
    if live_only and not is_live(args.events):
        raise ToffeError(f"{', '.join(live_only)} appl{'ies' if len(live_only) == 1 else 'y'} to live sources "
                         f"(--events -, udp://, dv://, dv-camera); a file is read at its own pace")
    args.queue_events = QUEUE_EVENTS if args.queue_events is None else args.queue_events
    if args.queue_events < 1:
        raise ToffeError(f"--queue-events must be >= 1, got {args.queue_events}")
    args.idle_timeout = 0.0 if args.idle_timeout is None else args.idle_timeout
    args.window_grace_ms = GRACE_S * 1e3 if args.window_grace_ms is None else args.window_grace_ms
    if not all(math.isfinite(v) and v >= 0 for v in (args.idle_timeout, args.window_grace_ms)):
        raise ToffeError(f"--idle-timeout and --window-grace-ms must be finite and >= 0, got {args.idle_timeout}, "
                         f"{args.window_grace_ms}")
    if args.video and not args.render:
        raise ToffeError("--video needs --render DIR")
    if args.fps is not None and not args.video:
        raise ToffeError("--fps sets the --video file's frame rate: add --render DIR --video")
    if args.theme != "dark" and not args.render:
        raise ToffeError("--theme sets the --render frames' background: add --render DIR")
    if args.out == "-" or _is_stdout(args.out):
        args.out = None                              # stdout, as --events - is stdin (the summary goes to stderr)
    if args.processes == 2 and (args.target not in ("cpu", "cuda") or args.dump_spikes):
        raise ToffeError("--processes 2 splits the host steps of --target cpu and cuda" +
                         (", without --dump-spikes" if args.target in ("cpu", "cuda") else
                          f"; the {args.target} target's cascade runs in Lava's own processes"))
    if args.tag != "fixed_pt" and args.target in ("cpu", "cuda"):
        raise ToffeError(f"--tag {args.tag} selects Lava process models: it applies to --target loihi-sim or loihi2; "
                         f"the {args.target} target runs the fixed-point OFS")
    bundle = load_bundle(args.bundle)
    check_run_outputs(args, bundle)
    cfg = bundle.config
    src = open_source(args, cfg.sensor_size)
    live = getattr(src, "live", False)
    with src:
        sensor = tuple(src.sensor_size)
        if sensor[0] * sensor[1] > MAX_SENSOR_PIXELS:       # before a live source says it reads
            raise ToffeError(f"{args.events or 'the recording'}: {sensor_too_large(sensor)}")
        if live:        # read from now on, into the bounded queue: not into a socket buffer that
            src.start()  # overflows while the pipeline starts, nor with a clock anchored late
            udp = hasattr(src, "port")
            where = f"udp port {src.port}" if udp else "stdin" if args.events == "-" else src.path
            # a datagram sent before the socket is open is gone; a pipe keeps what was written early
            print(f"toffe-deploy: reading {args.events} ({where})"
                  + ("; events sent before this line are lost" if udp else ""), file=sys.stderr, flush=True)
        camera = resolve_camera(cfg, sensor, depth_m=args.depth_m, focal_px=args.focal_px, hfov_deg=args.hfov_deg,
                                synthetic_focal_px=src.attrs.get("focal_px") if args.synthetic else None,
                                sensor_from=sensor_origin(args, src))
        if live:                    # the first event fixes the start; the end is the stream's
            t_start, n_total, t_end, incomplete_us = None, args.max_windows, None, 0
        else:
            t_start = src.t_start_us if args.start_us is None else int(args.start_us)
            if args.start_us is not None and t_start >= src.t_end_us:
                raise ToffeError(f"--start-us {t_start} is at or after the end of the recording: it spans "
                                 f"[{src.t_start_us}, {src.t_end_us}) us")
            span = src.t_end_us - t_start
            n_total = max(0, -(-span // cfg.dt_us) if args.include_incomplete else span // cfg.dt_us)
            if n_total == 0:
                if span > 0 or src.num_events:   # a last event back in time makes the span short, or
                    for _chunk in src.iter_chunks():   # negative: its order's error, not this one
                        pass
                raise ToffeError(f"{args.events or 'the recording'}: " + (
                    f"{span} us from the first window's start to the recording's end, shorter than one window "
                    f"({cfg.dt_us} us): nothing whole to process (--include-incomplete processes it as a partial "
                    "window)" if span > 0 else "no events to process"))
            t_end = t_start + n_total * cfg.dt_us
            incomplete_us = max(0, src.t_end_us - t_end)       # said unless --max-windows stops the run first
            if args.max_windows is not None:
                n_total = min(n_total, args.max_windows)
        truth = src.ground_truth
        errors = None
        if truth and len(truth["speed_bin"]) and int(truth["speed_bin"].max()) > cfg.n_speed_bins:
            raise ToffeError(f"{args.events}: its ground truth holds speed bin {int(truth['speed_bin'].max())}, but the "
                             f"bundle has {cfg.n_speed_bins} speed bins (scores against it would be wrong)")
        if truth:
            from ..metrics import FlowErrors, predictions_of
            from ..runtime.truth import TruthIndex, sequence_focal_px

            truth = TruthIndex(truth)
            errors = FlowErrors(n_bins=cfg.n_speed_bins, pred_scale=camera.scale)   # the run's m/s back in px/ms
            focal_px = sequence_focal_px(src.attrs)
        renderer = None
        if args.render:
            from ..render.frames import FrameRenderer, check_frame_size

            check_frame_size(sensor)
            renderer = FrameRenderer(args.render, video=args.video, fps=10.0 if args.fps is None else args.fps,
                                     theme=args.theme, attrs=src.attrs)
        report = None
        if args.report:
            from ..render.report import RunReport

            report = RunReport(sensor, source=str(args.events or args.synthetic or SAMPLE))

        # (t0, volume, time the window was ready, newest event's time or None)
        pending: collections.deque = collections.deque()

        def time_unit_said(unit):
            """The first windows' timestamps: nanoseconds read as us? Said once, at once and in
            the summary; -> None (checked)."""
            summary.time_unit_note = unit.hint()
            if summary.time_unit_note:
                print(f"toffe-deploy: warning: {summary.time_unit_note}", file=sys.stderr, flush=True)

        def windows():
            t_next = t_start
            unit = TimeUnitCheck()
            skip = args.skip_empty_after or None
            dropped = 0              # a live source's windows jumped over after its queue dropped their events
            cut = ({"include_incomplete": args.include_incomplete} if live else {"t_end": t_end})
            for i, (t0, ev) in enumerate(src.iter_windows(cfg.dt_us, t_start=t_start, skip_empty_after=skip, **cut)):
                if n_total is not None and i >= n_total:
                    summary.incomplete_us = 0          # --max-windows ended the run, not the recording
                    break
                if t_next is not None and t0 > t_next:
                    n = (t0 - t_next) // cfg.dt_us
                    if live:         # not empty, not done: the live line counts them, summary.skip does not
                        n -= src.stats.dropped_windows - dropped
                        dropped = src.stats.dropped_windows
                    if n > 0:
                        summary.skip(n, cfg.dt_us)
                t_next = t0 + cfg.dt_us
                if unit is not None:
                    unit.feed(ev["t"])
                    if unit.decided or unit.chunks >= TIME_UNIT_WINDOWS:
                        unit = time_unit_said(unit)
                vol = SpikeVolume.from_events(ev, t0, cfg.dt_us, cfg.n_bins, sensor)
                pending.append((t0, vol, time.perf_counter(), int(ev["t"][-1]) if live and ev.shape[0] else None))
                yield t0, vol
            if unit is not None:                       # a run shorter than the check
                time_unit_said(unit)

        summary = RunSummary(target=args.target, tag=args.tag,          # as the header: cpu and cuda run fixed_pt's arithmetic
                             camera=camera.describe(cfg), camera_json=camera.to_json(cfg),
                             dt_us=cfg.dt_us, incomplete_us=incomplete_us)
        t_setup = time.perf_counter()
        dump = None
        if args.dump_spikes:
            need = n_total * dump_bytes_per_window(cfg.n_speed_bins, cfg.n_bins, *cfg.ofs_grid(sensor))
            if need > DUMP_MAX_BYTES:
                raise ToffeError(f"--dump-spikes: {n_total} windows of {sensor[0]}x{sensor[1]} need "
                                 f"{need / 2**30:.1f} GiB in memory (limit {DUMP_MAX_BYTES / 2**30:.0f}); "
                                 "lower --max-windows")
            dump = SpikeDump(args.dump_spikes)
        with slow_notice(args, "toffe-deploy: loading the compiled kernels (the first run on a machine "
                               "compiles them: about 2 minutes, once)"):
            pipe = Pipeline(bundle, args.target, tag=args.tag, ofpd_variant=args.ofpd, sensor_size=sensor,
                            speed_scale=camera.scale, keep_stages=dump is not None, track=not args.no_track,
                            processes=args.processes)
        tracking = None
        if errors is not None and pipe.tracker is not None:
            from ..tracking_metrics import TrackingErrors

            tracking = TrackingErrors(errors.gate_px)
        ok = interrupted = False
        stream_out = args.out is None
        try:
            from tqdm import tqdm

            with pipe, jsonl_sink(args.out) as sink:
                from ..schema import header, write_header

                head = header(bundle, target=args.target, tag=args.tag, sensor_size=sensor,
                              camera_json=summary.camera_json, ofpd_variant=args.ofpd,
                              tracking=pipe.tracker.settings if pipe.tracker is not None else None)
                summary.startup_s = time.perf_counter() - t_setup
                t_run = time.perf_counter()
                bar = tqdm(total=n_total, unit="win", desc=f"run {args.target}", file=sys.stderr,
                           disable=not show_progress(args) or (n_total or 0) < 2 and not live, leave=False)
                with bar, live_interrupt(live) as stop:
                    for res in pipe.process_stream(windows()):
                        with signals_deferred():            # the window's line and counts, whole
                            t0, vol, t_ready, t_newest = pending.popleft()
                            summary.add(res, time.perf_counter() - t_ready)
                            head = head and write_header(sink, head)      # first line, once the input has proven readable
                            write_window(sink, res)
                            if t_newest is not None:
                                summary.event_latencies_s.append(time.perf_counter() - src.host_time(t_newest))
                            gt = truth.window(res.t0_us, cfg.dt_us) if truth else ()   # once: ~0.1 ms a window
                            if errors is not None:
                                errors.add_window(predictions_of(res.objects), gt, focal_px)
                            if tracking is not None:
                                tracking.add_result(res, gt)
                            if renderer is not None or report is not None:
                                win = res.to_json()
                                if renderer is not None:
                                    renderer.add(vol, win, gt)
                                if report is not None:
                                    report.add(win)
                            if dump is not None:
                                dump.add(res)
                            bar.update(1)
                interrupted = stop.interrupted
                summary.wall_s = time.perf_counter() - t_run
                never_sent = live and not src.stats.received_events     # --out stays as it was
                none_whole = (live and not interrupted and not never_sent and not summary.windows  # and here
                              and not src.stats.dropped_events)
                head = head and not never_sent and not none_whole and write_header(sink, head)
                if dump is not None:
                    dump.write()
            ok = True
        finally:
            if renderer is not None:
                renderer.close(ok)
        if live:
            summary.live = src.stats_json()
            if never_sent and not interrupted:       # a sender that never started, or sent before the socket was open
                invalid = summary.live.get("invalid_events", 0)
                raise InputError(args.events, "no events arrived" + (
                    f" ({invalid:,} invalid ones dropped: addresses outside the {sensor[0]}x{sensor[1]} sensor, "
                    "stray datagrams)" if invalid else " (the stream held its header only)" if args.events == "-"
                    else " (a sender started before 'reading ...' was printed sends into nothing)")
                    + (" before it ended" if src.ended else
                       f" within --idle-timeout {args.idle_timeout:g} s" if args.idle_timeout else ""))
            if none_whole:                           # as a file shorter than one window
                st = summary.live
                raise InputError(args.events, f"the stream ended before its first window was whole ({cfg.dt_us} us): "
                                              f"{st.get('incomplete_events', 0):,} of its {st['received_events']:,} "
                                              "events not processed, nothing whole to process (--include-incomplete "
                                              "processes them as a partial window)")
    if errors is not None:
        summary.errors = errors.summary()
        if tracking is not None:
            summary.errors["tracking"] = tracking.summary()
    if args.summary_json:                  # the files first: a reader closing stdout during the printed
        from ..fileio import atomic_path, json_text   # summary below must not cost them

        with atomic_path(args.summary_json) as tmp:
            tmp.write_text(json_text(summary.to_json(), indent=2) + "\n", encoding="utf-8")
    if report is not None:
        report.write(args.report, summary.to_json())
    out = sys.stderr if stream_out else sys.stdout
    for line in summary.lines():
        print(line, file=sys.stderr if line.startswith("warning: ") else out)   # a warning is stderr's
    sys.stderr.flush()
    out.flush()                            # a closed pipe is a BrokenPipeError here (cli: quiet exit 0), not at exit
    if interrupted:
        print("toffe-deploy: interrupted", file=sys.stderr)
        return 130
    return 0


class live_interrupt:
    """Ctrl-C ends a live run like the end of its stream: the windows done so far are kept and the
    summary is printed (exit 130). File runs let KeyboardInterrupt unwind as before. The Ctrl-C may
    come wrapped, as a SystemError from compiled code (signals.signal_behind)."""

    def __init__(self, live: bool):
        self.live = live
        self.interrupted = False

    def __enter__(self) -> "live_interrupt":
        return self

    def __exit__(self, kind, exc, tb) -> bool:
        if self.live and isinstance(signal_behind(exc), KeyboardInterrupt):
            self.interrupted = True
            return True
        return False
