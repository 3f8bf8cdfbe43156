"""`toffe-deploy eval`: Table 1 of the paper (pixE, dirE, speedE per dt) for a checkpoint, with
recall, false positives per window and bin accuracy, optionally broken down by a sequence attribute."""
from __future__ import annotations

from pathlib import Path

from . import add_progress_flag, show_progress


def _dts(text: str) -> tuple[int, ...]:
    """Window lengths: whole microseconds 1..MAX_DT_US, no empty item (``500,,600`` was read as
    500,600, and a dt longer than every sequence evaluated 0 windows with exit 0)."""
    import argparse

    from ..config import MAX_DT_US

    items = [v.strip() for v in text.split(",")]
    if "" in items:
        raise argparse.ArgumentTypeError(f"empty item in {text!r}: expected comma-separated microseconds")
    try:
        vals = tuple(int(v) for v in items)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated microseconds, got {text!r}") from None
    if min(vals) <= 0 or max(vals) > MAX_DT_US:
        raise argparse.ArgumentTypeError(f"expected microseconds in 1..{MAX_DT_US} ({MAX_DT_US / 1e6:g} s), "
                                         f"got {text!r}")
    return tuple(dict.fromkeys(vals))             # each once, in the order given


def _by(text: str):
    import argparse

    from ..breakdown import Breakdown

    try:
        return Breakdown.parse(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def register(sub) -> None:
    from ..config import MAX_DT_US
    from ..metrics import GATE_PX

    p = sub.add_parser(
        "eval", help="evaluate a checkpoint: recall, false positives, bin accuracy, pixE, dirE, speedE per dt",
        description="Evaluate a checkpoint on held-out sequences: recall, false positives per window, bin "
        "accuracy and its confusion matrix, and object flow errors over matched objects, per window length and "
        "per speed bin, the OFS speed separation per stage, optionally per bucket of a sequence attribute "
        "(--by); markdown tables on stdout and optionally JSON.")
    p.add_argument("ckpt", type=Path, help="checkpoint directory")
    p.add_argument("--data", required=True, type=Path, help="data-set directory (holds index.json)")
    p.add_argument("--split", default="test",
                   help="data-set split to evaluate: any split the index lists or any DIR/NAME/ holding .h5 files "
                   "(test (default), multi, train, appearance, pairs, ...)")
    p.add_argument("--dt", type=_dts, default=(200, 500, 1000, 2000, 5000),
                   help=f"window lengths in us (each 1..{MAX_DT_US}), comma separated (default 200,500,1000,2000,5000)")
    p.add_argument("--max-windows", type=int, default=20,
                   help="windows per sequence and dt, evenly spaced (default 20); at least as many as a "
                        "recording holds (200 for 100 ms at 500 us) is every window: the whole stream, as "
                        "`run` sees it (windows in a row continue one stream, so each costs one front end)")
    p.add_argument("--skip-stream-start", action="store_true",
                   help="leave each sequence's first window out of the sample: there the front end's temporal "
                        "support and the plane fit have no windows before it, which a running stream has "
                        "(1 window in 200 of a recording, 1 in --max-windows of this sample)")
    p.add_argument("--ofs", choices=("fixed", "float"), default="fixed",
                   help="OFS arithmetic: Loihi fixed point as deployed (default) or the float weights")
    p.add_argument("--gate", type=float, default=GATE_PX,
                   help=f"matching gate: a prediction farther than this (px) from an object's centre does not find it "
                   f"(default {GATE_PX:g})")
    p.add_argument("--by", type=_by, action="append", default=[], metavar="NAME[=EDGES]",
                   help="also break recall / FP / bin accuracy / pixE down by a numeric sequence attribute, e.g. "
                   "size, spacing, noise, contrast, bucketed at the given comma-separated edges (default: one bucket "
                   "per value); repeatable")
    p.add_argument("--track-windows", type=int, default=0, metavar="N",
                   help="also track objects (toffe_deploy/tracking.py) over the first N consecutive windows of each "
                   "sequence and report CLEAR MOT (MOTA, MOTP), IDF1, ID switches per dt (default 0: off)")
    p.add_argument("--json", type=Path, help="also write the results as JSON to this file")
    add_progress_flag(p)
    p.set_defaults(func=run)


def run(args) -> int:
    from ..checkpoint import load_checkpoint
    from ..errors import ToffeError

    if args.max_windows < 1:
        raise ToffeError(f"--max-windows must be >= 1, got {args.max_windows}")
    if args.track_windows < 0:
        raise ToffeError(f"--track-windows must be >= 0, got {args.track_windows}")
    if not args.gate > 0:
        raise ToffeError(f"--gate must be > 0 px, got {args.gate}")
    load_checkpoint(args.ckpt)          # fail fast on a bad checkpoint, before reading data
    if args.json:
        from ..fileio import check_outputs

        inputs = [("the checkpoint", args.ckpt), ("the data set", args.data),
                  ("the data-set index", args.data / "index.json")]
        inputs += [("checkpoint file", f) for f in args.ckpt.iterdir()]
        inputs += [("data-set file", f) for f in args.data.rglob("*.h5")] if args.data.is_dir() else []
        check_outputs(files=[("--json", args.json)], inputs=inputs)
    import torch

    from ..evaluate import EvalOptions, evaluate, format_markdown
    from ..fileio import atomic_path, json_text

    torch.set_num_threads(max(1, min(torch.get_num_threads(), 2)))
    res = evaluate(EvalOptions(ckpt=args.ckpt, data=args.data, dts=args.dt, split=args.split,
                               max_windows=args.max_windows, ofs=args.ofs, gate_px=args.gate,
                               by=tuple(args.by), progress=show_progress(args), track_windows=args.track_windows,
                               skip_stream_start=args.skip_stream_start))
    print(format_markdown(res))
    if args.json:
        with atomic_path(args.json) as tmp:
            tmp.write_text(json_text(res, indent=1) + "\n")
    return 0
