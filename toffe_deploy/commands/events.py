"""`toffe-deploy events`: inspect and convert event recordings (any supported format)."""
from __future__ import annotations

import argparse
import json
import sys

from . import add_progress_flag, show_progress
from .run import parse_size

FORMATS_HELP = ("our HDF5 layout (toffe-events), DSEC HDF5, MVSEC HDF5, .npz, .npy, AEDAT4, "
                "Prophesee RAW (EVT2/EVT3) and DAT, Metavision HDF5, ROS1 .bag / ROS2 bag directory; "
                "recognised by content")


def _add_common(p: argparse.ArgumentParser) -> None:
    p.add_argument("--sensor-size", type=parse_size, metavar="WxH", default=None,
                   help="sensor width and height in pixels, WxH as `run` takes it (W H also works); overrides "
                        "the file's (defaults for files without one: DSEC 640x480, MVSEC 346x260, npz/npy "
                        "inferred from the coordinates; RAW, DAT, Metavision HDF5 and ROS bags carry theirs)")
    p.add_argument("--sort", action="store_true",
                   help="sort events by time instead of rejecting decreasing timestamps "
                        "(loads the whole file into memory)")


def register(sub) -> None:
    p = sub.add_parser("events", help="inspect and convert event recordings",
                       description=f"Inspect and convert event recordings. Formats: {FORMATS_HELP}.")
    p.set_defaults(func=lambda args: (p.print_help(), 2)[1])
    s = p.add_subparsers(dest="events_command", metavar="ACTION")

    info = s.add_parser("info", help="events, duration, sensor size, event rate, polarity balance, "
                                     "ground truth",
                        description="Summarize an event file in one streaming pass; every event is "
                                    "checked on the way (coordinates, timestamps), so this also validates it.")
    info.add_argument("file", metavar="FILE", help=f"event file ({FORMATS_HELP})")
    info.add_argument("--json", action="store_true", help="print the summary as JSON on stdout")
    add_progress_flag(info)
    _add_common(info)
    info.set_defaults(func=_info)

    conv = s.add_parser("convert", help="convert an event file to our HDF5 layout (.h5) or .npz",
                        description="Read any supported event file and write it as our HDF5 layout "
                                    "(OUT ending in .h5/.hdf5; ground truth and attributes carried over) "
                                    "or as .npz (x, y, t, p, sensor_size). Loads the whole file. "
                                    "Written atomically.")
    conv.add_argument("input", metavar="IN", help=f"event file ({FORMATS_HELP})")
    conv.add_argument("output", metavar="OUT", help="output file: .h5/.hdf5 (our layout) or .npz")
    conv.add_argument("--force", action="store_true", help="overwrite OUT if it exists")
    add_progress_flag(conv)
    _add_common(conv)
    conv.set_defaults(func=_convert)


def _size(args):
    return tuple(args.sensor_size) if args.sensor_size else None


def _info(args) -> int:
    from ..events.info import format_info, summarize

    info = summarize(args.file, sensor_size=_size(args), sort=args.sort,
                     progress=show_progress(args) and not args.json)
    if args.json:
        json.dump(info, sys.stdout, indent=2, default=str)
        sys.stdout.write("\n")
    else:
        print(format_info(info))
    return 0


def _convert(args) -> int:
    from pathlib import Path

    from ..errors import InputError
    from ..events.io import open_events, write_events_h5, write_events_npz
    from ..fileio import check_outputs

    out = Path(args.output)
    suffix = out.suffix.lower()
    if suffix not in (".h5", ".hdf5", ".npz"):
        raise InputError(out, "output must end in .h5, .hdf5 (our HDF5 layout) or .npz")
    check_outputs(files=[("OUT", out)], inputs=[("the input file", args.input)])
    if out.exists() and not args.force:
        raise InputError(out, "exists (use --force to overwrite)")
    with open_events(args.input, sensor_size=_size(args), sort=args.sort) as src:
        ev = src.read_all()
        if suffix == ".npz":
            write_events_npz(out, ev.events, ev.sensor_size)
            lost = (["the ground truth"] if src.ground_truth else []) + (
                [f"the recording's span [{src.t_start_us}, {src.t_end_us}) us (an .npz spans its events)"]
                if len(ev) and (src.t_start_us, src.t_end_us) != (int(ev.events["t"][0]), int(ev.events["t"][-1]) + 1)
                else [])
            if lost:
                print(f"note: .npz holds x, y, t, p and the sensor size only: {' and '.join(lost)} not kept "
                      "(write .h5 to keep them)", file=sys.stderr)
        else:
            attrs = {k: v for k, v in src.attrs.items()}
            attrs.setdefault("converted_from", {"path": str(args.input), "format": src.format_name})
            write_events_h5(out, ev.events, ev.sensor_size, ground_truth=src.ground_truth, attrs=attrs,
                            t_range=(src.t_start_us, src.t_end_us))
    print(f"wrote {out}: {len(ev):,} events, {ev.sensor_size[0]}x{ev.sensor_size[1]}", file=sys.stderr)
    return 0
