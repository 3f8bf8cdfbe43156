"""`toffe-deploy dataset`: generate the synthetic high-speed data set and look at it.

    toffe-deploy dataset synth --out data/synth [--split all] [--appearance paper|random] [--duration-s S]
                               [--seed 0] [camera / scene / appearance / sensor ranges, see --help]
    toffe-deploy dataset show FILE [--out PNG] [--t0-us T] [--dt-us 5000] [--frames 4]
"""
from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

from ..errors import ToffeError, warn
from . import add_progress_flag, show_progress

SPLIT_CHOICES = ("train", "test", "multi", "appearance", "pairs", "crossing", "all")


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


def _range(low: float, strict: bool, high: float | None = None):
    """An argparse type for ``LO,HI`` or a single value V (= V,V): both finite, > low (strict) or
    >= low, <= high when given, and LO <= HI; returns (lo, hi)."""
    one = _number(float, low, strict)

    def parse(text: str):
        parts = text.split(",")
        if len(parts) not in (1, 2):
            raise argparse.ArgumentTypeError(f"expected LO,HI or one value, got {text!r}")
        lo, hi = one(parts[0]), one(parts[-1])
        if high is not None and hi > high:
            raise argparse.ArgumentTypeError(f"must be <= {high:g}, got {text}")
        if lo > hi:
            raise argparse.ArgumentTypeError(f"LO must not exceed HI, got {text}")
        return (lo, hi)
    return parse


def _sensor_size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected WIDTHxHEIGHT, e.g. 640x480, got {text!r}") from None
    from ..dataset.splits import SYNTH_SIDE_PX

    lo, hi = SYNTH_SIDE_PX
    if not (lo <= w <= hi and lo <= h <= hi):
        raise argparse.ArgumentTypeError(f"width and height must be in {lo}..{hi}, got {text}")
    return (w, h)


def _fraction(text: str) -> float:
    v = _number(float, 0, strict=False)(text)
    if v > 1:
        raise argparse.ArgumentTypeError(f"must be <= 1, got {text}")
    return v


_positive_float = _number(float, 0, strict=True)
_nonneg_float = _number(float, 0, strict=False)
_positive_int = _number(int, 1, strict=False)
MAX_FRAMES = 64          # panels of one PNG (5,000 ran out of memory)


def _frames(text: str) -> int:
    v = _positive_int(text)
    if v > MAX_FRAMES:
        raise argparse.ArgumentTypeError(f"must be 1..{MAX_FRAMES}, got {text}")
    return v
_nonneg_int = _number(int, 0, strict=False)


#: the widest horizontal view the generator renders (deg): its pinhole image beyond is mostly
#: stretched edge (run's --hfov-deg, a unit conversion only, takes up to 179)
SYNTH_HFOV_MAX_DEG = 170.0


def register(sub) -> None:
    from ..camera import DEPTH_RANGE_M, FOCAL_RANGE_PX, HFOV_RANGE_DEG

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
                   "(--multi-count sequences of 2-4 objects), appearance (40: held-out appearance "
                   "combinations, single and multi-object), pairs (32: two objects of one bin 3-8 radii "
                   "apart), crossing (16: 2-3 objects whose paths cross while the sequence runs, one bin or "
                   "distinct bins) or all six (default: all)")
    s.add_argument("--appearance", choices=("paper", "random"), default=None,
                   help="appearance of train/test/multi: paper (the paper protocol: 640x480, 60 deg, 5 m, "
                   "0.4 m, bright, C=0.25+-0.03, no noise) or random (camera, scene, object and sensor "
                   "drawn per sequence from the ranges below; train skips the held-out region). Default: "
                   "random for train, paper for test and multi. appearance, pairs and crossing are always random")
    s.add_argument("--duration-s", type=_positive_float, default=None,
                   help="sensor time per sequence in seconds (default: 0.1 for train/test, 0.25 for multi)")
    s.add_argument("--seed", type=_nonneg_int, default=0, help="data-set seed (default: 0)")
    s.add_argument("--multi-count", type=_positive_int, default=16,
                   help="number of multi-object sequences (default: 16)")
    s.add_argument("--limit", type=_positive_int, default=None,
                   help="at most this many sequences per split, drawn round-robin over the speed bins "
                   "(a quick, still balanced subset; default: all)")
    r = s.add_argument_group("ranges", "LO,HI draws per sequence (log-uniform for scales: focal, depth, sizes, "
                             "background, noise, hot pixels, when LO > 0; else uniform); one value fixes it. "
                             "Defaults: random / paper appearance. Camera, scene and appearance options apply to "
                             "random splits only; sensor options to all")
    r.add_argument("--sensor-size", type=_sensor_size, default=None, metavar="WxH",
                   help="sensor size in pixels (default: 640x480)")
    r.add_argument("--hfov-deg", type=_range(HFOV_RANGE_DEG[0], False, SYNTH_HFOV_MAX_DEG), default=None,
                   metavar="LO,HI",
                   help=f"horizontal field of view, degrees, {HFOV_RANGE_DEG[0]:g}..{SYNTH_HFOV_MAX_DEG:g} (random: "
                        f"40,90; paper: 60; the generator's pinhole image beyond {SYNTH_HFOV_MAX_DEG:g} is mostly "
                        "stretched edge, where run's --hfov-deg, a unit conversion only, takes up to 179)")
    r.add_argument("--focal-px", type=_range(FOCAL_RANGE_PX[0], False, FOCAL_RANGE_PX[1]), default=None,
                   metavar="LO,HI",
                   help="focal length in pixels, instead of --hfov-deg; it must give a field of view in --hfov-deg's "
                        f"range on the sensor's width ({HFOV_RANGE_DEG[0]:g}..{SYNTH_HFOV_MAX_DEG:g} deg: 28..366,693 "
                        "px at 640 px)")
    r.add_argument("--depth-m", type=_range(DEPTH_RANGE_M[0], False, DEPTH_RANGE_M[1]), default=None,
                   metavar="LO,HI",
                   help=f"object depth, metres, per object, {DEPTH_RANGE_M[0]:g}..{DEPTH_RANGE_M[1]:g} (random: 2,12)")
    r.add_argument("--size-px", type=_range(0, True), default=None, metavar="LO,HI",
                   help="apparent object diameter in pixels at its depth, per object (random: 15,200; "
                   "size_m = size_px * depth / f)")
    r.add_argument("--size-m", type=_range(0, True), default=None, metavar="LO,HI",
                   help="physical object size in metres, instead of --size-px")
    r.add_argument("--object-contrast", type=_range(-10, False, 10.0), default=None, metavar="LO,HI",
                   help="signed log contrast of object vs background, per object; negative = dark object, "
                   "e.g. --object-contrast=-1.5,-0.3 (random: 0.3,2.0)")
    r.add_argument("--dark-fraction", type=_fraction, default=None, metavar="F",
                   help="probability that an object's drawn contrast changes sign (random: 0.3; 0 when "
                   "--object-contrast is given: the sign given is kept)")
    r.add_argument("--background", type=_range(0, True, 1.0), default=None, metavar="LO,HI",
                   help="background linear intensity (random: 0.1,0.6; paper: 0.4)")
    r.add_argument("--threshold", type=_range(0, True), default=None, metavar="LO,HI",
                   help="mean DVS contrast threshold, log-intensity units (random: 0.1,0.5; paper: 0.25)")
    r.add_argument("--threshold-sigma", type=_range(0, False), default=None, metavar="LO,HI",
                   help="per-pixel threshold mismatch, standard deviation (random: 0,0.06; paper: 0.03)")
    r.add_argument("--refractory-us", type=_range(0, False), default=None, metavar="LO,HI",
                   help="refractory period in microseconds: a pixel's scene events (objects, texture) come at "
                   "least this far apart; background noise and hot pixels are added after it, not thinned "
                   "(random: 0,500; paper: 0)")
    r.add_argument("--noise-hz", type=_range(0, False), default=None, metavar="LO,HI",
                   help="background-activity noise rate per pixel in Hz (random: 0.1,50; paper: 0)")
    r.add_argument("--hot-pixels", type=_range(0, False, 1.0), default=None, metavar="LO,HI",
                   help="fraction of pixels that are hot, firing 1 kHz of one polarity (random: 0,1e-4; paper: 0)")
    r.add_argument("--texture", type=_range(0, False, 1.0), default=None, metavar="LO,HI",
                   help="relative amplitude of a smooth background texture (random: 0,0.3; paper: 0)")
    s.add_argument("--contrast", choices=("bright", "dark", "mixed"), default="bright",
                   help="paper splits: objects brighter than the background (default), darker, or either per "
                        "object (mixed makes the direction of slow objects ambiguous within one window; see "
                        "data/README.md)")
    s.add_argument("--jobs", type=_positive_int, default=1,
                   help="worker processes (default: 1)")
    s.add_argument("--force", action="store_true", help="regenerate files even when up to date")
    add_progress_flag(s)
    s.set_defaults(func=_synth)

    w = dsub.add_parser("show", help="render accumulated event frames with ground truth to PNG (as Fig. 5b)",
                        description="Accumulate the events of a few windows into frames (ON bright, OFF dim) "
                        "and draw each object's ground truth: outline, motion direction (hue = direction), "
                        "speed and bin, in the style of `run --render`.")
    w.add_argument("file", type=Path, help="an events file with ground truth (written by `dataset synth`)")
    add_progress_flag(w)
    w.add_argument("--out", type=Path, default=None,
                   help="PNG to write (default: FILE with the extension .png)")
    w.add_argument("--t0-us", type=_nonneg_int, default=None,
                   help="start of the first window in microseconds (default: the file's start)")
    w.add_argument("--dt-us", type=_positive_int, default=5000,
                   help="window length in microseconds (default: 5000)")
    w.add_argument("--frames", type=_frames, default=4, help=f"number of windows, 1..{MAX_FRAMES} (default: 4)")
    w.add_argument("--stride-us", type=_positive_int, default=None,
                   help="time between window starts (default: spread the frames over the file)")
    w.add_argument("--cols", type=_positive_int, default=2, help="panels per row (default: 2)")
    w.add_argument("--theme", choices=("dark", "light"), default="dark",
                   help="events on black (dark, default) or on white (light); the style of run --render")
    w.set_defaults(func=_show)


#: Options that only the random appearance honours (the paper geometry is fixed in metres).
RANDOM_ONLY = ("hfov_deg", "focal_px", "depth_m", "size_px", "size_m", "object_contrast", "dark_fraction",
               "background")


def _split_appearance(split: str, appearance: str | None) -> str:
    """The appearance a split is generated with (see --appearance)."""
    if split in ("appearance", "pairs", "crossing"):
        return "random"
    return appearance or ("random" if split == "train" else "paper")


def _ranges(args, splits):
    """(random ranges, paper ranges) from the presets and the options given; ToffeError on
    contradictory or inapplicable options."""
    import dataclasses

    from ..dataset.appearance import PAPER, RANDOM, SENSOR_FIELDS

    for a, b in (("hfov_deg", "focal_px"), ("size_px", "size_m")):
        if getattr(args, a) is not None and getattr(args, b) is not None:
            raise ToffeError(f"--{a.replace('_', '-')} and --{b.replace('_', '-')} exclude each other")
    given = {k: getattr(args, k) for k in RANDOM_ONLY + SENSOR_FIELDS + ("sensor_size",)
             if getattr(args, k) is not None}
    randoms = [s for s in splits if _split_appearance(s, args.appearance) == "random"]
    unused = [k for k in RANDOM_ONLY if k in given]
    if unused and not randoms:
        raise ToffeError(f"--{unused[0].replace('_', '-')} applies to random-appearance splits only "
                         f"(add --appearance random)")
    if "object_contrast" in given and given["object_contrast"] == (0.0, 0.0):
        raise ToffeError("--object-contrast 0: an object of the background's intensity fires no events")
    if "object_contrast" in given and "dark_fraction" not in given:
        given["dark_fraction"] = 0.0            # the sign given is the sign drawn
    papers_asked = [s for s in splits if s not in randoms]
    if unused and papers_asked:
        warn(f"--{unused[0].replace('_', '-')} applies to the random-appearance splits only: "
             f"{', '.join(papers_asked)} keep the paper protocol (640x480, 60 deg, 5 m; --appearance random "
             f"to change them)")
    if args.contrast != "bright" and not papers_asked:
        warn(f"--contrast {args.contrast} applies to paper-appearance splits only (random ones draw "
             f"--object-contrast and --dark-fraction)")
    rnd = dataclasses.replace(RANDOM, **given)
    if "focal_px" in given:
        rnd = dataclasses.replace(rnd, hfov_deg=RANDOM.hfov_deg)
        _check_focal(given["focal_px"], rnd.sensor_size[0])
    if "size_m" in given:
        rnd = dataclasses.replace(rnd, size_px=RANDOM.size_px)
    paper = dataclasses.replace(PAPER, **{k: v for k, v in given.items() if k in SENSOR_FIELDS + ("sensor_size",)})
    papers = [s for s in splits if s not in randoms]
    if papers and tuple(paper.sensor_size) != tuple(PAPER.sensor_size):
        from ..camera import REFERENCE_DEPTH_M, REFERENCE_FOCAL_PX, focal_px_from_hfov

        f = focal_px_from_hfov(paper.sensor_size[0], PAPER.hfov_deg[0])
        warn(f"{', '.join(papers)} at {paper.sensor_size[0]}x{paper.sensor_size[1]}: the paper's 60 deg view gives "
             f"a {f:.0f} px focal length, so an object programmed for bin k (m/s at {REFERENCE_DEPTH_M:g} m; the file "
             f"name's _bK, index.json's speed_bin) moves {f / REFERENCE_FOCAL_PX:.2f}x as many px/ms as at 640x480, "
             "and its ground truth's speed_bin (the image-plane bin the model is scored on) may be another")
    for name, rr, used in (("random", rnd, randoms), ("paper", paper, papers)):
        if used and rr.threshold_sigma[1] >= rr.threshold[0]:
            raise ToffeError(f"--threshold-sigma ({rr.threshold_sigma[1]:g}) must be smaller than --threshold "
                             f"({rr.threshold[0]:g}) ({name} appearance)")
    return rnd, paper


def _check_focal(focal_px: tuple[float, float], width: int) -> None:
    """ToffeError unless the focal lengths give fields of view the generator renders on a sensor
    ``width`` px wide (--hfov-deg's range): a 0.001 px focal length on 346 px gave files whose
    ground truth held a negative depth, which `run` and `events info` then refused."""
    from ..camera import HFOV_RANGE_DEG, focal_px_from_hfov

    lo = focal_px_from_hfov(width, SYNTH_HFOV_MAX_DEG)
    hi = focal_px_from_hfov(width, HFOV_RANGE_DEG[0])
    if focal_px[0] < lo or focal_px[1] > hi:
        raise ToffeError(f"--focal-px {focal_px[0]:g},{focal_px[1]:g}: on a {width} px wide sensor the generator takes "
                         f"{lo:.4g}..{hi:.4g} px (fields of view {HFOV_RANGE_DEG[0]:g}..{SYNTH_HFOV_MAX_DEG:g} deg, "
                         "as --hfov-deg)")


def _synth(args) -> int:
    from ..dataset.build import build_dataset
    from ..dataset.splits import MAX_SYNTH_DURATION_S, SPLITS, balanced_subset, split_specs

    if args.duration_s is not None and args.duration_s < 100e-6:
        raise ToffeError(f"--duration-s {args.duration_s} is shorter than two samples (100 us)")
    if args.duration_s is not None and args.duration_s > MAX_SYNTH_DURATION_S:
        raise ToffeError(f"--duration-s {args.duration_s:g} is longer than {MAX_SYNTH_DURATION_S:g} s (each "
                         "sequence is generated in memory)")
    splits = SPLITS if args.split == "all" else (args.split,)
    if Path(args.out).is_dir():           # another camera's data set there: before the warnings below
        from ..dataset.appearance import PAPER
        from ..dataset.build import check_one_camera, read_index

        check_one_camera(Path(args.out), read_index(Path(args.out)), {tuple(args.sensor_size or PAPER.sensor_size)},
                         splits)
    rnd, paper = _ranges(args, splits)
    specs = {}
    for split in splits:
        app = _split_appearance(split, args.appearance)
        try:
            lst = split_specs(split, seed=args.seed, duration_s=args.duration_s, multi_count=args.multi_count,
                              contrast=args.contrast, appearance=app, ranges=rnd if app == "random" else paper)
        except ValueError as exc:
            raise ToffeError(f"split {split}: {exc}") from None
        if args.limit is not None:
            lst = balanced_subset(lst, args.limit, seed=args.seed)
        specs[split] = lst
    from ..fileio import check_outputs

    check_outputs(dirs=[("--out", args.out)])
    t = time.perf_counter()
    index = build_dataset(args.out, specs, seed=args.seed, jobs=args.jobs, force=args.force,
                          progress=show_progress(args))
    el = time.perf_counter() - t
    size = sum(f.stat().st_size for f in Path(args.out).rglob("*.h5"))
    counts = ", ".join(f"{k} {v}" for k, v in index["splits"].items() if v)
    print(f"{args.out}: {len(index['sequences'])} sequences ({counts}), {index['n_events']:,} events, "
          f"{size / 1e6:.1f} MB; index {Path(args.out) / 'index.json'} ({el:.1f} s)")
    empty = [q["name"] for q in index["sequences"] if not q.get("n_events")]
    if empty:
        more = ", ..." if len(empty) > 3 else ""
        warn(f"{len(empty)} sequence(s) without a single event ({', '.join(empty[:3])}{more}): nothing to train or "
             "evaluate on (a sensor too small for the scene, or a duration too short?)")
    return 0


def _show(args) -> int:
    from ..dataset.show import show_file

    from ..fileio import check_outputs

    out = args.out or args.file.with_suffix(".png")
    check_outputs(files=[("--out", out)], inputs=[("the input file", args.file)])
    info = show_file(args.file, out, t0_us=args.t0_us, dt_us=args.dt_us, n_frames=args.frames,
                     stride_us=args.stride_us, cols=args.cols, theme=args.theme)
    print(f"{out}: {info}", file=sys.stdout)
    return 0
