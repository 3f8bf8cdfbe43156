#!/usr/bin/env python
"""Make the sample recording shipped with toffe-deploy (``toffe_deploy/samples/sample_multi.h5``).

What `toffe-deploy run` uses when no --events is given: sequence ``multi_000`` of the data-set
generator's multi-object split (split seed 0): four objects at once, one per speed bin
(1: diamond, 2: square, 3: square, 4: diamond), one per image quadrant, 640x480, 60 deg field of
view, 20 kHz sampling, with the generator's ground truth (so `run` also prints pixE/dirE/speedE).
The generator is deterministic for (spec, seed): re-running this script rewrites the same file.

    .venv/bin/python scripts/make_sample.py [--duration 0.1] [--out toffe_deploy/samples/sample_multi.h5]
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
DEFAULT_OUT = ROOT / "toffe_deploy" / "samples" / "sample_multi.h5"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--duration", type=float, default=0.1, help="seconds of sensor time")
    ap.add_argument("--index", type=int, default=0, help="sequence of the multi split (0 = multi_000, all 4 bins)")
    ap.add_argument("--seed", type=int, default=0, help="split seed of the data-set generator")
    ap.add_argument("--out", type=Path, default=DEFAULT_OUT, help="output HDF5 file")
    args = ap.parse_args(argv)

    from toffe_deploy.dataset.build import sequence_attrs
    from toffe_deploy.dataset.splits import sequence_seed, split_specs
    from toffe_deploy.dataset.synth import generate_sequence
    from toffe_deploy.events.io import write_events_h5

    spec = split_specs("multi", seed=args.seed, duration_s=args.duration)[args.index]
    seed = sequence_seed(args.seed, spec.name)
    t = time.perf_counter()
    events, gt, size = generate_sequence(spec, seed, progress=True)
    attrs = sequence_attrs(spec, seed)
    attrs["made_by"] = "scripts/make_sample.py " + " ".join(sys.argv[1:] if argv is None else argv)
    write_events_h5(args.out, events, size, ground_truth=gt, attrs=attrs,
                    t_range=(0, int(round(spec.duration_s * 1e6))))
    bins = sorted(o.target_bin for o in spec.objects)
    print(f"{args.out}: {spec.name}, {len(events)} events, {spec.duration_s} s, {size[0]}x{size[1]}, "
          f"objects in speed bins {bins}, {args.out.stat().st_size / 1e6:.2f} MB, "
          f"{time.perf_counter() - t:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
