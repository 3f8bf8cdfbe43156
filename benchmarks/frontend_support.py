#!/usr/bin/env python
"""``eval`` of a checkpoint with another setting of the front end's temporal support
(ToffeConfig.input_support, events/support.py): what it gains with the same weights (issue 11).

    python benchmarks/frontend_support.py --split test --support 4,1,5,2 --json /tmp/s.json
    toffe-deploy dataset synth --out data/noise50 --split test --noise-hz 50,50 --seed 1   # the 50 Hz rows
    python benchmarks/frontend_support.py --data data/noise50 --split test --support 4,1,6

The checkpoint is evaluated as it is (evaluate.evaluate: same sampled windows, cascade, grouping
and matching, the K windows before each read from its recording) with its config's
``input_support`` set to ``--support K,r,m[,c]`` (c defaults to 0, a fixed threshold m;
``--support 0,0,0`` removes it: the cluster filter alone, and with it ``ofpd.recent_events``,
which reads the front end's windows before and cannot run without them), through a temporary
copy of the checkpoint whose weights are links. Prints recall, false positives per window and bin accuracy,
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
sys.path.insert(0, str(ROOT / "benchmarks"))

import toffe_deploy.evaluate as evaluate  # noqa: E402
from toffe_deploy.errors import InputError  # noqa: E402
from toffe_deploy.events.frontend import check_support  # noqa: E402
from toffe_deploy.fileio import atomic_path, check_outputs, json_text, read_json  # noqa: E402
from _args import OneLineParser, comma_list, existing_dir, guarded, json_output, nonneg_int, positive_int  # noqa: E402


def main(argv=None) -> int:
    ap = OneLineParser(prog="frontend_support.py", description=__doc__.split("\n\n")[0])
    ap.add_argument("--ckpt", type=existing_dir, default=str(ROOT / "ckpt"))
    ap.add_argument("--data", type=Path, default=str(ROOT / "data" / "synth"))
    ap.add_argument("--split", default="test")
    ap.add_argument("--max-windows", type=positive_int, default=6)
    ap.add_argument("--support", type=comma_list(nonneg_int, 3, 4), default="4,1,5,2",
                    help="K,r,m[,c]: windows before, box radius, min count, noise factor (K = 0: off; default "
                         "4,1,5,2, the setting before ckpt/'s 4,2,5,2, which the study compared it with)")
    ap.add_argument("--json", type=json_output, help="write eval's result dict here")
    a = ap.parse_args(argv)
    k, r, m, c = (a.support + [0])[:4]
    if k:
        try:
            check_support([k, r, m, c])
        except ValueError as exc:
            ap.error(f"argument --support: {exc}")
    return guarded("frontend_support", run, a, (k, r, m, c))


def run(a, support) -> int:
    k, r, m, c = support
    src = Path(a.ckpt)
    check_outputs(files=[("--json", a.json)])
    cfg = read_json(src / "config.json")
    if not isinstance(cfg, dict):
        raise InputError(src / "config.json", "not a checkpoint config (a JSON object)")
    cfg.pop("input_support", None)
    if k:
        cfg["input_support"] = [k, r, m, c]
    elif isinstance(cfg.get("ofpd"), dict) and cfg["ofpd"].get("recent_events") is not None:
        cfg["ofpd"] = {kk: v for kk, v in cfg["ofpd"].items() if kk != "recent_events"}   # it needs input_support
    with tempfile.TemporaryDirectory() as tmp:
        ck = Path(tmp)
        for f in src.iterdir():
            if f.is_file() and f.name != "config.json":
                (ck / f.name).symlink_to(f.resolve())
        (ck / "config.json").write_text(json.dumps(cfg, indent=2))
        res = evaluate.evaluate(evaluate.EvalOptions(ckpt=ck, data=Path(a.data), dts=(500,), split=a.split,
                                                     max_windows=a.max_windows, progress=False))
    if a.json:
        with atomic_path(a.json) as tmp:
            tmp.write_text(json_text(res, indent=1))
    row = res["per_dt"][0]
    for name, s in (("all", row["all"]), ("bin 1", row["per_bin"]["1"])):
        print(f"{a.split} K,r,m,c={k},{r},{m},{c} {name}: recall {s['recall']:.3f}  FP/window {s['fp_per_window']:.3f}  "
              f"bin acc {s['bin_accuracy']:.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
