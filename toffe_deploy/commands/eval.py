"""`toffe-deploy eval`: Table 1 of the paper (pixE, dirE, speedE per dt) for a checkpoint."""
from __future__ import annotations

from pathlib import Path


def _dts(text: str) -> tuple[int, ...]:
    import argparse

    try:
        vals = tuple(int(v) for v in text.split(",") if v.strip())
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated microseconds, got {text!r}") from None
    if not vals or min(vals) <= 0:
        raise argparse.ArgumentTypeError(f"expected positive microseconds, got {text!r}")
    return vals


def register(sub) -> None:
    p = sub.add_parser(
        "eval", help="evaluate a checkpoint: pixE, dirE, speedE per dt (the paper's Table 1)",
        description="Evaluate a checkpoint on held-out sequences: object flow errors per window length, "
        "per speed bin, detection rate and the OFS speed separation per stage, as a markdown table (stdout) "
        "and optionally JSON.")
    p.add_argument("ckpt", type=Path, help="checkpoint directory")
    p.add_argument("--data", required=True, type=Path, help="data-set directory (holds index.json)")
    p.add_argument("--split", default="test", help="data-set split to evaluate: test (default), multi, train")
    p.add_argument("--dt", type=_dts, default=(200, 500, 1000, 2000, 5000),
                   help="window lengths in us, comma separated (default 200,500,1000,2000,5000)")
    p.add_argument("--max-windows", type=int, default=20,
                   help="windows per sequence and dt, evenly spaced (default 20)")
    p.add_argument("--ofs", choices=("fixed", "float"), default="fixed",
                   help="OFS arithmetic: Loihi fixed point as deployed (default) or the float weights")
    p.add_argument("--max-dist", type=float, default=64.0,
                   help="a prediction farther than this (px) from an object does not match it (default 64)")
    p.add_argument("--json", type=Path, help="also write the results as JSON to this file")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")
    p.set_defaults(func=run)


def run(args) -> int:
    import json

    from ..checkpoint import load_checkpoint
    from ..errors import ToffeError

    if args.max_windows < 1:
        raise ToffeError(f"--max-windows must be >= 1, got {args.max_windows}")
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
    from ..fileio import atomic_path

    torch.set_num_threads(max(1, min(torch.get_num_threads(), 2)))
    res = evaluate(EvalOptions(ckpt=args.ckpt, data=args.data, dts=args.dt, split=args.split,
                               max_windows=args.max_windows, ofs=args.ofs, max_dist_px=args.max_dist,
                               progress=not args.no_progress))
    print(format_markdown(res))
    if args.json:
        with atomic_path(args.json) as tmp:
            tmp.write_text(json.dumps(res, indent=1, allow_nan=True))
    return 0
