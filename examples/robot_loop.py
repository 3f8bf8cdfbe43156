#!/usr/bin/env python
"""A robot loop on toffe_deploy's Python API: events in packets, object flow and tracks out.

    python examples/robot_loop.py [--bundle export/] [--events FILE] [--sensor-size WxH] [--target cpu]
                                  [--packet-us 2000] [--max-ms 50]

A camera driver hands over event packets (here: the shipped sample recording, or --events, read
in --packet-us slices to stand in for it); each packet goes into ``api.FlowStream.feed``, which
returns the windows it completed, with every object's flow and track. The loop keeps the
confirmed tracks and, per packet, picks the one to react to: the fastest track heading towards
the image centre (a stand-in for "the object about to cross the robot's path"). Make the bundle
first: `toffe-deploy export ckpt/` (writes export/).
"""
from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from toffe_deploy import api  # noqa: E402
from toffe_deploy.commands.run import parse_size  # noqa: E402
from toffe_deploy.errors import ToffeError  # noqa: E402
from toffe_deploy.events.io import open_events  # noqa: E402

SAMPLE = ROOT / "toffe_deploy" / "samples" / "sample_multi.h5"


def approaching(track: dict, centre: tuple[float, float]) -> bool:
    """Whether a track moves towards the image centre (its direction within 90 deg of the centre's)."""
    to_c = math.atan2(centre[1] - track["y"], centre[0] - track["x"])
    d = math.radians(track["direction_deg"]) - to_c
    return math.cos(d) > 0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--bundle", default="export/",
                    help="deploy bundle (default: export/ in the current directory, as `toffe-deploy export` "
                         "writes it and `toffe-deploy run` reads it)")
    ap.add_argument("--events", default=str(SAMPLE))
    ap.add_argument("--target", default="cpu", choices=api.TARGETS)
    ap.add_argument("--packet-us", type=int, default=2000, help="packet length, in us of recording (a camera driver's packet of events)")
    ap.add_argument("--max-ms", type=float, default=50.0, help="stop after this much recording (inf: all of it)")
    ap.add_argument("--sensor-size", default=None, metavar="WxH",
                    help="the camera's width and height in px, for files that do not record it (.npz, .npy, .txt)")
    a = ap.parse_args(argv)
    if a.packet_us <= 0 or not a.max_ms > 0:
        ap.error(f"--packet-us and --max-ms must be > 0, got {a.packet_us}, {a.max_ms}")
    if a.sensor_size is not None:           # WxH as `toffe-deploy run` takes it (W,H also works)
        try:
            a.sensor_size = parse_size(a.sensor_size.replace(",", "x"))
        except ValueError as exc:
            ap.error(f"--sensor-size: {exc}")
    try:
        return loop(a)
    except ToffeError as exc:           # a missing or broken bundle or recording: one line, exit 2
        print(f"robot_loop: error: {exc}", file=sys.stderr)
        return exc.exit_code


def loop(a) -> int:
    """The loop of ``main`` over the parsed arguments."""
    bundle = api.load_bundle(a.bundle)
    n_windows, ids = 0, set()
    with open_events(a.events, sensor_size=a.sensor_size) as src, \
            api.FlowStream(bundle, a.target, sensor_size=src.sensor_size,
                           t_start_us=src.t_start_us) as flow:   # run's window grid
        print(f"{a.events}: {src.sensor_size[0]}x{src.sensor_size[1]} sensor")
        centre = (src.sensor_size[0] / 2.0, src.sensor_size[1] / 2.0)
        t_end = src.t_end_us if math.isinf(a.max_ms) else min(src.t_end_us, src.t_start_us + int(a.max_ms * 1000))
        for t in range(src.t_start_us, t_end, a.packet_us):
            packet = src.read(t, min(t + a.packet_us, t_end))          # what a driver would hand over
            windows = flow.feed(packet["x"], packet["y"], packet["t"], packet["p"])
            n_windows += len(windows)
            tracks = flow.tracks()
            ids.update(tr["track_id"] for tr in tracks)
            threat = max((tr for tr in tracks if approaching(tr["track"], centre)),
                         key=lambda tr: tr["track"]["speed_px_s"], default=None)
            if threat is None:
                print(f"t={t / 1000:7.1f} ms: {len(tracks)} tracks, none approaching")
            else:
                s = threat["track"]
                print(f"t={t / 1000:7.1f} ms: {len(tracks)} tracks; react to track {threat['track_id']} at "
                      f"({s['x']:.0f}, {s['y']:.0f}) px, heading {s['direction_deg']:.0f} deg, "
                      f"{s['speed_px_s']:.0f} px/s (bin {s['speed_bin']})")
        n_windows += len(flow.flush(t_end_us=t_end))                  # the windows read up to t_end
    print(f"{n_windows} windows, {len(ids)} confirmed tracks: {sorted(ids)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
