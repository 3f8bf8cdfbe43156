#!/usr/bin/env python
"""Robustness to sensor noise, TOFFE against DOTIE, measured (issue 14, item 7).

    python benchmarks/noise_ablation.py                  # the shipped sample, 100 windows
    python benchmarks/noise_ablation.py --quick          # a few windows (the test suite's size)

The same recording with ground truth (default: the shipped multi-object sample) is corrupted
by the data-set generator's own noise models (dataset/dvs.py): background activity, Poisson
events at --noise Hz per pixel with random polarity, and hot pixels, a fraction --hot of the
pixels firing at --hot-rate Hz (one polarity each). The same windows then go through TOFFE (the
deployed cpu Pipeline) and DOTIE with clustering (per-window protocol, optimised level: the
same boxes as the reference port); each is scored by the gated matching of `eval` (20 px):
recall (all and per speed bin), pixE, dirE, speedE (TOFFE only: DOTIE reports boxes) and false
positives per window. Before the timed settings, the first --warmup windows of the recording
(without added noise) go through both models untimed (compiled kernels, caches; the Pipeline's
tracks and windows before are reset after it), so the first setting's CPU time is not inflated.
Writes noise_ablation.{md,json} to --out (default benchmarks/results/, --quick: benchmarks/results/quick/; strict JSON: a figure
that does not exist, e.g. DOTIE's direction error, is null).
"""
from __future__ import annotations

import datetime as _dt
import math
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

sys.path.insert(0, str(ROOT / "benchmarks"))

from toffe_deploy.errors import InputError  # noqa: E402
from _args import OneLineParser, guarded, nonneg_int, positive_float  # noqa: E402

SAMPLE = ROOT / "toffe_deploy" / "samples" / "sample_multi.h5"
WARMUP = 10           # untimed windows before the first setting (energy_latency.py warms up 10 per model)


def parse_args(argv=None):
    ap = OneLineParser(prog="noise_ablation.py", description=__doc__.split("\n\n")[0])
    ap.add_argument("--bundle", default=str(ROOT / "export"), help="deploy bundle (default export/)")
    ap.add_argument("--events", default=str(SAMPLE), help="recording with ground truth (default: the shipped sample)")
    ap.add_argument("--windows", type=int, default=100, help="windows scored per setting (default 100)")
    ap.add_argument("--noise", default="0,10,20,50,100", help="background noise rates, Hz per pixel (default 0,10,20,50,100)")
    ap.add_argument("--hot", default="0.001,0.01", help="hot-pixel fractions, each with no background noise (default 0.001,0.01)")
    ap.add_argument("--hot-rate", type=positive_float, default=1000.0, help="hot-pixel rate, Hz (default 1000, the generator's)")
    ap.add_argument("--seed", type=nonneg_int, default=0, help="noise seed (default 0)")
    ap.add_argument("--warmup", type=nonneg_int, default=None,
                    help=f"untimed windows through both models before the first setting (default {WARMUP}, quick 2)")
    ap.add_argument("--quick", action="store_true", help="6 windows, noise 0 and 50 Hz, one hot-pixel setting")
    ap.add_argument("--out", default=None,
                    help="output directory (default benchmarks/results/, --quick: benchmarks/results/quick/, so that "
                         "a quick run never replaces the full table)")
    a = ap.parse_args(argv)
    if a.out is None:
        a.out = str(ROOT / "benchmarks" / "results" / ("quick" if a.quick else ""))
    if a.quick:
        a.windows, a.noise, a.hot = min(a.windows, 6), "0,50", "0.01"
    if a.warmup is None:
        a.warmup = 2 if a.quick else WARMUP
    try:
        a.noise = [float(v) for v in a.noise.split(",") if v.strip()]
        a.hot = [float(v) for v in a.hot.split(",") if v.strip()]
    except ValueError:
        ap.error("--noise and --hot take comma-separated numbers")
    if a.windows < 1 or not all(0 <= v < math.inf for v in a.noise + a.hot) or any(v > 1 for v in a.hot):
        ap.error("--windows >= 1, rates >= 0, hot fractions in [0, 1]")
    return a


def corrupt(events: np.ndarray, t_start: int, t_end: int, size, noise_hz: float, hot: float, hot_rate: float,
            sample_us: int, rng) -> np.ndarray:
    """The recording plus the generator's noise and hot-pixel events over [t_start, t_end)."""
    from toffe_deploy.dataset.dvs import hot_pixel_events, noise_events

    n = max((t_end - t_start) // sample_us, 2)
    extra = [noise_events(noise_hz, n, sample_us, size, rng), hot_pixel_events(hot, hot_rate, n, sample_us, size, rng)]
    for e in extra:
        e["t"] += t_start
    ev = np.concatenate([events] + extra)
    return ev[np.argsort(ev["t"], kind="stable")]


def run(a) -> int:
    from toffe_deploy.baselines.dotie_fast import FastDotie
    from toffe_deploy.baselines.registry import toffe_predictions, window_objects
    from toffe_deploy.deploy.bundle import is_bundle_dir, load_bundle
    from toffe_deploy.events.binning import window_slice
    from toffe_deploy.events.io import open_events
    from toffe_deploy.fileio import atomic_path, check_outputs, json_text
    from toffe_deploy.metrics import FlowErrors
    from toffe_deploy.runtime.pipeline import Pipeline
    from toffe_deploy.runtime.spikes import SpikeVolume
    from toffe_deploy.runtime.truth import TruthIndex, sequence_focal_px

    if not Path(a.bundle).exists() or not is_bundle_dir(Path(a.bundle)):
        raise InputError(Path(a.bundle), "no deploy bundle here; run `toffe-deploy export ckpt/` first (or pass --bundle DIR)")
    check_outputs(dirs=[("--out", a.out)])
    bundle = load_bundle(Path(a.bundle))
    cfg = bundle.config
    dt, nb = cfg.dt_us, cfg.n_bins
    with open_events(a.events) as src:
        size = tuple(src.sensor_size)
        if size != tuple(cfg.sensor_size):
            raise InputError(Path(a.events), f"sensor size {size[0]}x{size[1]} differs from the bundle's")
        if src.ground_truth is None:
            raise InputError(Path(a.events), "has no ground truth (needed to score)")
        truth = TruthIndex(src.ground_truth)
        focal = sequence_focal_px(src.attrs)
        t_start = int(src.t_start_us)
        t_end = min(int(src.t_end_us), t_start + a.windows * dt)
        base = np.array(src.read(t_start, t_end))
        spec = (src.attrs.get("generator") or {}).get("spec") or {}
    starts = range(t_start, t_end - dt + 1, dt)
    if not len(starts):
        raise InputError(Path(a.events), f"shorter than one window of {dt} us: nothing to score")
    sample_us = int(spec.get("sample_us", 50)) if isinstance(spec, dict) else 50
    settings = [(hz, 0.0) for hz in a.noise] + [(0.0, h) for h in a.hot if h > 0]
    rng = np.random.default_rng(a.seed)
    results = []
    with Pipeline(bundle, "cpu") as pipe:
        warm = FastDotie(size, nb, dt)                  # warm-up: untimed, unscored, no noise drawn
        for t0 in starts[:a.warmup]:
            w = window_slice(base, t0, dt)
            list(pipe.process_stream([(t0, SpikeVolume.from_events(w, t0, dt, nb, size))]))
            warm.detect(w, t0)
        pipe.reset_tracks()                             # the first setting starts as from a fresh Pipeline
        for hz, hot in settings:
            ev = corrupt(base, t_start, t_end, size, hz, hot, a.hot_rate, sample_us, rng)
            fast = FastDotie(size, nb, dt)
            errs = {m: FlowErrors(n_bins=cfg.n_speed_bins, pred_scale=cfg.speed_scale) for m in ("toffe", "dotie_cluster")}
            cpu = {m: 0.0 for m in errs}
            n_ev = []
            for t0 in starts:
                w = window_slice(ev, t0, dt)
                n_ev.append(len(w))
                gt = truth.window(t0, dt)
                c0 = time.process_time()
                objs = list(pipe.process_stream([(t0, SpikeVolume.from_events(w, t0, dt, nb, size))]))[0].objects
                c1 = time.process_time()
                boxes = fast.detect(w, t0)
                c2 = time.process_time()
                cpu["toffe"] += c1 - c0
                cpu["dotie_cluster"] += c2 - c1
                errs["toffe"].add_window(toffe_predictions(objs), gt, focal)
                errs["dotie_cluster"].add_window(window_objects(boxes), gt, focal)
            for m, fe in errs.items():
                q = fe.summary()
                q.pop("confusion", None)
                results.append({"noise_hz": hz, "hot_fraction": hot, "hot_rate_hz": a.hot_rate if hot else 0.0,
                                "events_per_window": float(np.mean(n_ev)), "model": m, "windows": len(n_ev),
                                "cpu_ms_per_window": cpu[m] / max(len(n_ev), 1) * 1e3, **q,
                                "recall_by_bin": [fe.summary(k)["recall"] for k in range(1, cfg.n_speed_bins + 1)]})
            print(f"[noise_ablation] noise {hz:g} Hz, hot {hot:g}: {len(n_ev)} windows, "
                  f"{np.mean(n_ev):.0f} events/window", file=sys.stderr, flush=True)
    res = {"format": "toffe-noise-ablation", "format_version": 1,
           "created": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
           "command": " ".join([Path(sys.argv[0]).name] + sys.argv[1:]), "input": str(a.events),
           "bundle": str(bundle.root), "seed": a.seed, "warmup_windows": a.warmup, "rows": results}
    md = render(res)
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    with atomic_path(out / "noise_ablation.json") as tmp:
        tmp.write_text(json_text(res, indent=1))
    with atomic_path(out / "noise_ablation.md") as tmp:
        tmp.write_text(md)
    print(md)
    print(f"[noise_ablation] wrote {out / 'noise_ablation'}.{{md,json}}", file=sys.stderr)
    return 0


def _f(v, d=2):
    return "-" if v is None or not np.isfinite(v) else f"{v:.{d}f}"


def render(res: dict) -> str:
    lines = ["| background noise (Hz/px) | hot pixels | events/window | model | recall | recall by bin 1/2/3/4 | "
             "pixE px | dirE deg | speedE m/s | FP/window | CPU ms/window |", "|" + "---|" * 11]
    for r in res["rows"]:
        hot = f"{r['hot_fraction'] * 100:g}% at {r['hot_rate_hz']:g} Hz" if r["hot_fraction"] else "-"
        lines.append(f"| {r['noise_hz']:g} | {hot} | {r['events_per_window']:.0f} | "
                     f"{'TOFFE' if r['model'] == 'toffe' else 'DOTIE + DBSCAN'} | {_f(r['recall'])} | "
                     + "/".join(_f(v) for v in r["recall_by_bin"])
                     + f" | {_f(r['pixE'])} | {_f(r['dirE'], 1)} | {_f(r['speedE'])} | {_f(r['fp_per_window'])} | "
                       f"{_f(r['cpu_ms_per_window'])} |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    return guarded("noise_ablation", run, parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
