"""Generator speed: one second of sensor time at 640x480, one object, per speed bin.

Target (issue 2): under 10 s of one core per second of sensor time. Generation only (events
and ground truth in memory); the HDF5 write is timed separately.

    .venv/bin/python benchmarks/bench_synth.py [--duration-s 1] [--bins 1 2 3 4] [--json FILE]
"""
from __future__ import annotations

import json
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _args import OneLineParser, json_output, positive_float  # noqa: E402
from toffe_deploy.dataset.shapes import SHAPES  # noqa: E402
from toffe_deploy.dataset.splits import DEPTH_AMP_M, PROGRAMMED_SPEEDS, SCALE_M, SIZE_M  # noqa: E402
from toffe_deploy.dataset.synth import ObjectSpec, SequenceSpec, generate_sequence  # noqa: E402
from toffe_deploy.dataset.trajectories import CURVES, Trajectory, lap_time_for_speeds  # noqa: E402
from toffe_deploy.events.io import write_events_h5  # noqa: E402
from toffe_deploy.fileio import atomic_path  # noqa: E402


def main(argv=None) -> int:
    ap = OneLineParser(prog="bench_synth.py", description=__doc__.splitlines()[0])
    ap.add_argument("--duration-s", type=positive_float, default=1.0, help="sensor time per run (default 1 s)")
    ap.add_argument("--bins", type=int, nargs="+", default=[1, 2, 3, 4], choices=sorted(PROGRAMMED_SPEEDS),
                    metavar="BIN", help=f"speed bins to time ({', '.join(map(str, sorted(PROGRAMMED_SPEEDS)))})")
    ap.add_argument("--shape", default="square", choices=SHAPES, help="object shape (default square)")
    ap.add_argument("--curve", default="lemniscate", choices=sorted(CURVES), help="trajectory (default lemniscate)")
    ap.add_argument("--json", type=json_output, default=None, help="also write the results as JSON here")
    args = ap.parse_args(argv)
    rows = []
    print(f"{'bin':>3} {'speed m/s':>13} {'events':>10} {'gen s':>7} {'write s':>8} {'MB':>6}  (1 object, "
          f"640x480, {args.duration_s:g} s sensor time, one process)")
    for b in args.bins:
        rng = np.random.default_rng(b)
        lo, hi = PROGRAMMED_SPEEDS[b]
        lap = lap_time_for_speeds(args.curve, SCALE_M, DEPTH_AMP_M, lo, hi, rng)
        traj = Trajectory(args.curve, lap, scale_m=SCALE_M, depth_amp_m=DEPTH_AMP_M)
        spec = SequenceSpec(f"bench_b{b}", (ObjectSpec(args.shape, traj, size_m=SIZE_M, target_bin=b),),
                            duration_s=args.duration_s)
        t = time.perf_counter()
        ev, gt, size = generate_sequence(spec, seed=b)
        gen = time.perf_counter() - t
        with tempfile.TemporaryDirectory() as d:
            path = Path(d) / "b.h5"
            t = time.perf_counter()
            write_events_h5(path, ev, size, ground_truth=gt)
            wr = time.perf_counter() - t
            mb = os.path.getsize(path) / 1e6
        row = {"bin": b, "speed_min_mps": float(gt["speed"].min()), "speed_max_mps": float(gt["speed"].max()),
               "events": int(ev.shape[0]), "generate_s": round(gen, 3), "write_s": round(wr, 3),
               "file_mb": round(mb, 2), "duration_s": args.duration_s}
        rows.append(row)
        print(f"{b:>3} {row['speed_min_mps']:6.1f}-{row['speed_max_mps']:6.1f} {row['events']:>10,} {gen:7.2f} "
              f"{wr:8.2f} {mb:6.1f}", flush=True)
    worst = max(r["generate_s"] / r["duration_s"] for r in rows)
    print(f"slowest: {worst:.2f} s per second of sensor time (target < 10 s)")
    if args.json:
        with atomic_path(args.json) as tmp:
            tmp.write_text(json.dumps({"cpu_count": os.cpu_count(), "rows": rows}, indent=1) + "\n")
    return 0 if worst < 10 else 1


if __name__ == "__main__":
    sys.exit(main())
