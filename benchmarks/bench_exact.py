#!/usr/bin/env python
"""Bit-exactness check of the cpu target between two versions of the code (e.g. before and after
a speed-up): dump one version's full output, then compare two dumps.

    PYTHONPATH=OLD .venv/bin/python benchmarks/bench_exact.py dump --bundle B --events REC -o old.json
    PYTHONPATH=NEW .venv/bin/python benchmarks/bench_exact.py dump --bundle B --events REC -o new.json
    .venv/bin/python benchmarks/bench_exact.py compare old.json new.json

A dump holds, per window: every object's fields as ``Pipeline`` reports them, at full float
precision (repr of the float64, not the 4 decimals of the JSON lines), track ids included, and a
SHA-256 of the window's cascade result (each stage's input, spikes and frame masks) and of the
OFPD input batch (as ``Pipeline.objects_of`` makes it: with the front end's windows before,
``ofpd.recent_events``). ``compare`` prints the first differing window.

Exit codes: 0 identical (compare) or written (dump); 1 the dumps differ; 2 bad input (a bad
option, a missing bundle or recording, a dump file that is missing, not JSON or not a dump),
one line on stderr. The code compared is the ``toffe_deploy`` on PYTHONPATH (this script adds
only benchmarks/ to sys.path, for its argument helpers).
"""
from __future__ import annotations

import hashlib
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT / "benchmarks") not in sys.path:
    sys.path.insert(0, str(ROOT / "benchmarks"))   # _args only: toffe_deploy comes from PYTHONPATH

from _args import OneLineParser, guarded, json_output, positive_int  # noqa: E402
EXIT_SAME, EXIT_DIFFERS, EXIT_BAD_INPUT = 0, 1, 2


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
            # as Pipeline.objects_of: recent = the front end's windows before, after this window
            ks, x, n_ev, _ones = ofpd_input.batch(fe, frames, cfg, pipe._scratch, hist, pipe._batch)
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


def load_dump(path: str) -> dict:
    """A dump file's content; InputError (exit 2) for a missing, malformed or foreign file."""
    from toffe_deploy.errors import InputError
    from toffe_deploy.fileio import read_json

    d = read_json(path)
    if not (isinstance(d, dict) and isinstance(d.get("windows"), list) and "recording" in d
            and all(isinstance(w, dict) and "t0_us" in w and "objects" in w for w in d["windows"])):
        raise InputError(path, "not a bench_exact.py dump (no 'recording' and 'windows' of t0_us / objects)")
    return d


def compare(a: dict, b: dict) -> int:
    wa, wb = a["windows"], b["windows"]
    if len(wa) != len(wb):
        print(f"different window counts: {len(wa)} vs {len(wb)}")
        return EXIT_DIFFERS
    n_obj = 0
    for i, (x, y) in enumerate(zip(wa, wb)):
        if x != y:
            print(f"window {i} (t0 {x['t0_us']} us) differs:\n  {json.dumps(x)[:2000]}\n  {json.dumps(y)[:2000]}")
            return EXIT_DIFFERS
        n_obj += len(x["objects"])
    print(f"identical: {len(wa)} windows, {n_obj} objects ({a['recording']})")
    return EXIT_SAME


def main(argv=None) -> int:
    ap = OneLineParser(prog="bench_exact.py", description="Bit-exactness check of the cpu target between two code "
                       "versions. Exit 0: identical / written, 1: the dumps differ, 2: bad input.")
    sub = ap.add_subparsers(dest="cmd", required=True)
    d = sub.add_parser("dump", help="run the cpu pipeline and write its full output")
    d.add_argument("--bundle", default=str(ROOT / "export"))
    d.add_argument("--events", default=None, help="recording (default: the shipped sample)")
    d.add_argument("--max-windows", type=positive_int, default=None)
    d.add_argument("-o", "--out", type=json_output, required=True)
    c = sub.add_parser("compare", help="compare two dumps")
    c.add_argument("a")
    c.add_argument("b")
    args = ap.parse_args(argv)
    return guarded("bench_exact", _run, args)


def _run(args) -> int:
    from toffe_deploy.fileio import atomic_path       # from PYTHONPATH: the version under test

    if args.cmd == "dump":
        out = dump(args.bundle, args.events, args.max_windows)
        with atomic_path(args.out) as tmp:
            tmp.write_text(json.dumps(out))
        return EXIT_SAME
    return compare(load_dump(args.a), load_dump(args.b))


if __name__ == "__main__":
    sys.exit(main())
