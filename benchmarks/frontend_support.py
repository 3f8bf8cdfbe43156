#!/usr/bin/env python
"""``eval`` of a checkpoint with the front end's temporal support (events/support.py), before it
is wired into the runtime targets (issue 11): what it would gain with the shipped weights.

    python benchmarks/frontend_support.py --split test --support 4,1,5,2 --json /tmp/s.json
    toffe-deploy dataset synth --out data/noise50 --split test --noise-hz 50,50 --seed 1   # the 50 Hz rows
    python benchmarks/frontend_support.py --data data/noise50 --split test --support 4,1,6

Everything is evaluate.evaluate (same sampled windows, cascade, grouping and matching), except
that each window's front end is events/support.py's ``support_dense`` with the counts of the K
windows before it, read from the same recording ([t0 - K dt, t0), as a reader streaming the
windows in order would have them). ``--support K,r,m[,c]`` (module doc of events/support.py; c
defaults to 0, a fixed threshold m); ``--support 0,0,0`` (K = 0) is the checkpoint's own front end.
Prints recall, false positives per window and bin accuracy, overall and for speed bin 1.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

import toffe_deploy.evaluate as evaluate  # noqa: E402
import toffe_deploy.events.io as events_io  # noqa: E402
from toffe_deploy.events.binning import bin_window  # noqa: E402
from toffe_deploy.events.frontend import apply_dense  # noqa: E402
from toffe_deploy.events.support import event_pixels, support_dense  # noqa: E402


class _Recorded:
    """An event source that remembers its last read window, so the front end can read the K
    windows before it (evaluate.py reads each window just before it bins it)."""

    last: dict = {}

    def __init__(self, src):
        self._src = src

    def __getattr__(self, k):
        return getattr(self._src, k)

    def __enter__(self):
        self._src.__enter__()
        return self

    def __exit__(self, *exc):
        return self._src.__exit__(*exc)

    def read(self, t0, t1):
        _Recorded.last = {"src": self._src, "t0": int(t0), "dt": int(t1) - int(t0)}
        return self._src.read(t0, t1)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="frontend_support.py", description=__doc__.split("\n\n")[0])
    ap.add_argument("--ckpt", default=str(ROOT / "ckpt"))
    ap.add_argument("--data", default=str(ROOT / "data" / "synth"))
    ap.add_argument("--split", default="test")
    ap.add_argument("--max-windows", type=int, default=6)
    ap.add_argument("--support", default="4,1,5,2",
                    help="K,r,m[,c]: windows before, box radius, min count, noise factor")
    ap.add_argument("--json", help="write eval's result dict here")
    a = ap.parse_args(argv)
    k, r, m, c = ([int(v) for v in a.support.split(",")] + [0])[:4]

    def front_end(volume, norm, min_cluster, *_rest):
        if k == 0:
            return apply_dense(volume, norm, min_cluster)
        src, t0, dt = _Recorded.last["src"], _Recorded.last["t0"], _Recorded.last["dt"]
        counts = np.zeros(volume.shape[-2:], np.uint8)
        for j in range(1, k + 1):
            s = t0 - j * dt
            counts += event_pixels(bin_window(src.read(s, s + dt), s, dt, volume.shape[0], src.sensor_size))
        return support_dense(volume, norm, min_cluster, counts, r, m, c)

    open_events = events_io.open_events
    events_io.open_events = lambda *args, **kw: _Recorded(open_events(*args, **kw))
    evaluate.apply_dense = front_end
    res = evaluate.evaluate(evaluate.EvalOptions(ckpt=Path(a.ckpt), data=Path(a.data), dts=(500,), split=a.split,
                                                 max_windows=a.max_windows, progress=False))
    if a.json:
        Path(a.json).write_text(json.dumps(res, indent=1))
    row = res["per_dt"][0]
    for name, s in (("all", row["all"]), ("bin 1", row["per_bin"]["1"])):
        print(f"{a.split} K,r,m,c={k},{r},{m},{c} {name}: recall {s['recall']:.3f}  FP/window {s['fp_per_window']:.3f}  "
              f"bin acc {s['bin_accuracy']:.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
