"""`toffe-deploy dataset`: generate the synthetic high-speed data set and look at it.

    toffe-deploy dataset synth --out data/synth [--split all] [--duration-s S] [--seed 0]
    toffe-deploy dataset show FILE [--out PNG] [--t0-us T] [--dt-us 5000] [--frames 4]
"""
from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

from ..errors import ToffeError

SPLIT_CHOICES = ("train", "test", "multi", "all")


def _number(cast, low: float, strict: bool):
    """An argparse type: ``cast(text)``, finite, and > low (strict) or >= low, else a one-line error."""
    kind = "a number" if cast is float else "an integer"
    bound = f"{'>' if strict else '>='} {low:g}"

    def parse(text: str):
        try:
            v = cast(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"not {kind}: {text!r}") from None
        if not math.isfinite(v) or (v <= low if strict else v < low):
            raise argparse.ArgumentTypeError(f"must be {bound}, got {text}")
        return v
    return parse


_positive_float = _number(float, 0, strict=True)
_nonneg_float = _number(float, 0, strict=False)
_positive_int = _number(int, 1, strict=False)
_nonneg_int = _number(int, 0, strict=False)


def register(sub) -> None:
    p = sub.add_parser("dataset", help="generate the synthetic high-speed data set, render samples to PNG",
                       description="The synthetic TOFFE data set: objects on closed trajectories seen by "
                       "an emulated 640x480 DVS at 20,000 samples/s, with per-sample ground truth.")
    dsub = p.add_subparsers(dest="dataset_command", metavar="ACTION")
    p.set_defaults(func=lambda args: (p.print_help(), 2)[1])

    s = dsub.add_parser("synth", help="generate train/test/multi-object sequences (HDF5 + index.json)",
                        description="Write one HDF5 file per sequence (events + ground truth) under "
                        "OUT/<split>/ and an index OUT/index.json. Deterministic for a seed; up-to-date "
                        "files are kept, so an interrupted run resumes.")
    s.add_argument("--out", type=Path, default=Path("data/synth"),
                   help="output directory (default: data/synth)")
    s.add_argument("--split", choices=SPLIT_CHOICES, default="all",
                   help="which split to generate: train (384 sequences), test (64), multi "
                   "(--multi-count sequences of 2-4 objects) or all (default: all)")
    s.add_argument("--duration-s", type=_positive_float, default=None,
                   help="sensor time per sequence in seconds (default: 0.1 for train/test, 0.25 for multi)")
    s.add_argument("--seed", type=_nonneg_int, default=0, help="data-set seed (default: 0)")
    s.add_argument("--multi-count", type=_positive_int, default=16,
                   help="number of multi-object sequences (default: 16)")
    s.add_argument("--limit", type=_positive_int, default=None,
                   help="at most this many sequences per split, drawn round-robin over the speed bins "
                   "(a quick, still balanced subset; default: all)")
    s.add_argument("--threshold", type=_positive_float, default=0.25,
                   help="mean DVS contrast threshold, log-intensity units (default: 0.25)")
    s.add_argument("--threshold-sigma", type=_nonneg_float, default=0.03,
                   help="per-pixel threshold mismatch, standard deviation (default: 0.03)")
    s.add_argument("--noise-hz", type=_nonneg_float, default=0.0,
                   help="background-activity noise rate per pixel in Hz (default: 0, off)")
    s.add_argument("--contrast", choices=("bright", "dark", "mixed"), default="bright",
                   help="objects brighter than the background (default), darker, or either per object "
                        "(mixed makes the direction of slow objects ambiguous within one window; see data/README.md)")
    s.add_argument("--texture", type=_nonneg_float, default=0.0,
                   help="relative amplitude of a smooth background texture, e.g. 0.1 (default: 0, uniform)")
    s.add_argument("--jobs", type=_positive_int, default=1,
                   help="worker processes (default: 1)")
    s.add_argument("--force", action="store_true", help="regenerate files even when up to date")
    s.set_defaults(func=_synth)

    w = dsub.add_parser("show", help="render accumulated event frames with ground truth to PNG (as Fig. 5b)",
                        description="Accumulate the events of a few windows into frames (ON red, OFF blue) "
                        "and draw each object's ground truth: centre, motion direction, speed and bin.")
    w.add_argument("file", type=Path, help="an events file with ground truth (written by `dataset synth`)")
    w.add_argument("--out", type=Path, default=None,
                   help="PNG to write (default: FILE with the extension .png)")
    w.add_argument("--t0-us", type=_nonneg_int, default=None,
                   help="start of the first window in microseconds (default: the file's start)")
    w.add_argument("--dt-us", type=_positive_int, default=5000,
                   help="window length in microseconds (default: 5000)")
    w.add_argument("--frames", type=_positive_int, default=4, help="number of windows (default: 4)")
    w.add_argument("--stride-us", type=_positive_int, default=None,
                   help="time between window starts (default: spread the frames over the file)")
    w.add_argument("--cols", type=_positive_int, default=2, help="panels per row (default: 2)")
    w.set_defaults(func=_show)


def _synth(args) -> int:
    from ..dataset.build import build_dataset
    from ..dataset.dvs import DVSParams
    from ..dataset.splits import MAX_SYNTH_DURATION_S, SPLITS, balanced_subset, split_specs

    if args.threshold_sigma >= args.threshold:
        raise ToffeError(f"--threshold-sigma ({args.threshold_sigma}) must be smaller than --threshold "
                         f"({args.threshold})")
    if args.duration_s is not None and args.duration_s < 100e-6:
        raise ToffeError(f"--duration-s {args.duration_s} is shorter than two samples (100 us)")
    if args.duration_s is not None and args.duration_s > MAX_SYNTH_DURATION_S:
        raise ToffeError(f"--duration-s {args.duration_s:g} is longer than {MAX_SYNTH_DURATION_S:g} s (each "
                         "sequence is generated in memory)")
    dvs = DVSParams(threshold=args.threshold, threshold_sigma=args.threshold_sigma, noise_rate_hz=args.noise_hz)
    splits = SPLITS if args.split == "all" else (args.split,)
    specs = {}
    for split in splits:
        lst = split_specs(split, seed=args.seed, duration_s=args.duration_s, dvs=dvs, texture=args.texture,
                          multi_count=args.multi_count, contrast=args.contrast)
        if args.limit is not None:
            lst = balanced_subset(lst, args.limit, seed=args.seed)
        specs[split] = lst
    from ..fileio import check_outputs

    check_outputs(dirs=[("--out", args.out)])
    t = time.perf_counter()
    index = build_dataset(args.out, specs, seed=args.seed, jobs=args.jobs, force=args.force)
    el = time.perf_counter() - t
    size = sum(f.stat().st_size for f in Path(args.out).rglob("*.h5"))
    counts = ", ".join(f"{k} {v}" for k, v in index["splits"].items() if v)
    print(f"{args.out}: {len(index['sequences'])} sequences ({counts}), {index['n_events']:,} events, "
          f"{size / 1e6:.1f} MB; index {Path(args.out) / 'index.json'} ({el:.1f} s)")
    return 0


def _show(args) -> int:
    from ..dataset.show import show_file

    from ..fileio import check_outputs

    out = args.out or args.file.with_suffix(".png")
    check_outputs(files=[("--out", out)], inputs=[("the input file", args.file)])
    info = show_file(args.file, out, t0_us=args.t0_us, dt_us=args.dt_us, n_frames=args.frames,
                     stride_us=args.stride_us, cols=args.cols)
    print(f"{out}: {info}", file=sys.stdout)
    return 0
