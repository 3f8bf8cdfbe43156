#!/usr/bin/env python
"""``eval`` of a checkpoint with another setting of the front end's temporal support
(ToffeConfig.input_support, events/support.py): what it gains with the same weights (issue 11).

    python benchmarks/frontend_support.py --split test --support 4,1,5,2 --json /tmp/s.json
    toffe-deploy dataset synth --out data/noise50 --split test --noise-hz 50,50 --seed 1   # the 50 Hz rows
    python benchmarks/frontend_support.py --data data/noise50 --split test --support 4,1,6

The checkpoint is evaluated as it is (evaluate.evaluate: same sampled windows, cascade, grouping
and matching, the K windows before each read from its recording) with its config's
``input_support`` set to ``--support K,r,m[,c]`` (c defaults to 0, a fixed threshold m;
``--support 0,0,0`` removes it: the cluster filter alone), through a temporary copy of the
checkpoint whose weights are links. Prints recall, false positives per window and bin accuracy,
overall and for speed bin 1.
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

import toffe_deploy.evaluate as evaluate  # noqa: E402


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="frontend_support.py", description=__doc__.split("\n\n")[0])
    ap.add_argument("--ckpt", default=str(ROOT / "ckpt"))
    ap.add_argument("--data", default=str(ROOT / "data" / "synth"))
    ap.add_argument("--split", default="test")
    ap.add_argument("--max-windows", type=int, default=6)
    ap.add_argument("--support", default="4,1,5,2",
                    help="K,r,m[,c]: windows before, box radius, min count, noise factor (K = 0: off)")
    ap.add_argument("--json", help="write eval's result dict here")
    a = ap.parse_args(argv)
    k, r, m, c = ([int(v) for v in a.support.split(",")] + [0])[:4]
    src = Path(a.ckpt)
    with tempfile.TemporaryDirectory() as tmp:
        ck = Path(tmp)
        for f in src.iterdir():
            if f.is_file() and f.name != "config.json":
                (ck / f.name).symlink_to(f.resolve())
        cfg = json.loads((src / "config.json").read_text())
        cfg.pop("input_support", None)
        if k:
            cfg["input_support"] = [k, r, m, c]
        (ck / "config.json").write_text(json.dumps(cfg, indent=2))
        res = evaluate.evaluate(evaluate.EvalOptions(ckpt=ck, data=Path(a.data), dts=(500,), split=a.split,
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
