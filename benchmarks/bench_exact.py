#!/usr/bin/env python
"""Bit-exactness check of the cpu target between two versions of the code (e.g. before and after
a speed-up): dump one version's full output, then compare two dumps.

    PYTHONPATH=OLD .venv/bin/python benchmarks/bench_exact.py dump --bundle B --events REC -o old.json
    PYTHONPATH=NEW .venv/bin/python benchmarks/bench_exact.py dump --bundle B --events REC -o new.json
    .venv/bin/python benchmarks/bench_exact.py compare old.json new.json

A dump holds, per window: every object's fields as ``Pipeline`` reports them, at full float
precision (repr of the float64, not the 4 decimals of the JSON lines), track ids included, and a
SHA-256 of the window's cascade result (each stage's input, spikes and frame masks) and of the
OFPD input batch. ``compare`` prints the first differing window and exits 1, else 0. The code
compared is the ``toffe_deploy`` on PYTHONPATH (this script adds nothing to sys.path).
"""
from __future__ import annotations

import argparse
import hashlib
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent


def _digest(*arrays) -> str:
    h = hashlib.sha256()
    for a in arrays:
        a = np.ascontiguousarray(a)
        h.update(str((a.dtype.str, a.shape)).encode())
        h.update(a.tobytes())
    return h.hexdigest()[:16]


def dump(bundle_dir: str, events: str | None, limit: int | None) -> dict:
    from toffe_deploy.commands.run import SAMPLE
    from toffe_deploy.deploy.bundle import load_bundle
    from toffe_deploy.events.io import open_events
    from toffe_deploy.events.support import SupportHistory, front_end
    from toffe_deploy.runtime import ofpd_input
    from toffe_deploy.runtime.pipeline import Pipeline, up_frames
    from toffe_deploy.runtime.spikes import SpikeVolume

    bundle = load_bundle(bundle_dir)
    cfg = bundle.config
    path = Path(events) if events else SAMPLE
    out = []
    with open_events(path) as src, Pipeline(bundle, "cpu", sensor_size=src.sensor_size) as pipe:
        hist = (SupportHistory(cfg.input_support[0], pipe.sensor_size, cfg.dt_us)   # the windows before, as pipe keeps them
                if cfg.input_support is not None else None)
        for t0, ev in src.iter_windows(cfg.dt_us):
            if limit and len(out) >= limit:
                break
            vol = SpikeVolume.from_events(ev, t0, cfg.dt_us, cfg.n_bins, pipe.sensor_size)
            # the cascade and the OFPD input of the window, as the pipeline computes them
            fe = front_end(vol, cfg, hist, t0)
            grid, inverse = fe.pool(cfg.ofs_pool)
            res = pipe.cascade.cascade_sparse(grid)
            frames = np.asarray(up_frames(res.frames, inverse))
            spikes = np.zeros((len(res.spikes),) + res.volume.shape[:1] + (res.volume.n_pixels,), bool)
            for k, s in enumerate(res.spikes):
                spikes[k][:, res.window.active] = s
            ks, x, n_ev, _ones = ofpd_input.batch(fe, frames, cfg, pipe._scratch)
            wr = next(pipe.process_stream([(t0, vol)]))
            objs = []
            for o in wr.objects:
                d = {k: (repr(float(v)) if isinstance(v, float) else v) for k, v in vars(o).items() if k != "track"}
                d["track"] = None if o.track is None else {k: repr(v) for k, v in dict(o.track).items()}
                objs.append(d)
            out.append({"t0_us": int(t0), "n_ones": int(len(fe)), "objects": objs,
                        "cascade": _digest(np.asarray(res.inputs), spikes, frames),
                        "ofpd_input": _digest(ks, x, n_ev)})
    return {"recording": str(path), "windows": out}


def compare(a: dict, b: dict) -> int:
    wa, wb = a["windows"], b["windows"]
    if len(wa) != len(wb):
        print(f"different window counts: {len(wa)} vs {len(wb)}")
        return 1
    n_obj = 0
    for i, (x, y) in enumerate(zip(wa, wb)):
        if x != y:
            print(f"window {i} (t0 {x['t0_us']} us) differs:\n  {json.dumps(x)[:2000]}\n  {json.dumps(y)[:2000]}")
            return 1
        n_obj += len(x["objects"])
    print(f"identical: {len(wa)} windows, {n_obj} objects ({a['recording']})")
    return 0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description="Bit-exactness check of the cpu target between two code versions.")
    sub = ap.add_subparsers(dest="cmd", required=True)
    d = sub.add_parser("dump", help="run the cpu pipeline and write its full output")
    d.add_argument("--bundle", default=str(ROOT / "export"))
    d.add_argument("--events", default=None, help="recording (default: the shipped sample)")
    d.add_argument("--max-windows", type=int, default=None)
    d.add_argument("-o", "--out", required=True)
    c = sub.add_parser("compare", help="compare two dumps")
    c.add_argument("a")
    c.add_argument("b")
    args = ap.parse_args(argv)
    from toffe_deploy.errors import ToffeError        # from PYTHONPATH: the version under test
    from toffe_deploy.fileio import atomic_path

    try:
        if args.cmd == "dump":
            out = dump(args.bundle, args.events, args.max_windows)
            with atomic_path(args.out) as tmp:
                tmp.write_text(json.dumps(out))
            return 0
        return compare(json.loads(Path(args.a).read_text()), json.loads(Path(args.b).read_text()))
    except ToffeError as exc:
        print(f"bench_exact: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
