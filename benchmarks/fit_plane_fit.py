#!/usr/bin/env python
"""Fit the plane-fit fusion of a checkpoint (config.ofpd ``plane_fit_weight``,
``plane_fit_min_px_ms``, ``plane_fit_dir_weight`` and, with ``--history``,
``plane_fit_history``; toffe_deploy/plane_fit.py, time_surface.py) on a training split, never
on held-out data.

    .venv/bin/python benchmarks/fit_plane_fit.py --ckpt ckpt --data data/synth --split train
        [--max-windows 3] [--limit N] [--check appearance,test] [--write] [--json FILE]
        [--history 4,6,8,10,12,16 --history-windows 20,40 --history-margin 3 --refits 0,1] [--per-bin]

Runs the checkpoint as eval does (OFS in fixed point, OFPD in torch) on ``--max-windows``
windows of each sequence of ``--split``, matches the objects to the ground truth (one to one,
20 px), and keeps for each matched object the OFPD's regressed speed and direction, its
plane-fit velocity and the true image-plane speed (px/ms) and direction. Then two grid
searches: speed weight w in 0.1 .. 1.0 (step 0.1) and threshold 0 (no threshold) or 2 .. 8 px/ms
(step 0.5),
minimising the mean |fused - true| px/ms; direction weight 0 .. 1 (step 0.1), minimising the
mean direction error. Prints the OFPD's errors, the fused ones and bin accuracy for the fit
split and each ``--check`` split (read-only: shown, never used to choose), and with
``--write`` sets the keys in CKPT/config.json (atomically; every other key as it was).

``--history D,D,..``: the plane fit reads each object's time surface of its last K windows,
K = ceil(D / (s dt)) up to ``--history-windows`` (the windows before each sampled one come
from a stream started at the recording's start, as eval reads them); each D gets the grid
search above, and the D whose fused speed and direction errors, each relative to the OFPD's,
sum least is kept. ``--refits R,R,..`` (default 0): each D is tried with each number of refits
too (``plane_fit_refits``: K again from the fit's own speed, plane_fit.refit_history), and the
pair (D, refits) that sums least is kept. ``--history-windows K,K,..``: each pair with each
K_max too, from one pass (the windows before are read once, for the largest K_max: a smaller
one reads the latest K of them and counts the same windows as missing at a stream's start).
``--per-bin``: each candidate's fused speed and direction errors per true speed bin as well.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from toffe_deploy.errors import InputError, ToffeError  # noqa: E402
from toffe_deploy.fileio import json_text  # noqa: E402
from _args import (OneLineParser, comma_list, existing_dir, guarded, int_in, json_output,  # noqa: E402
                   positive_float, positive_int)

WEIGHTS = np.round(np.arange(0.1, 1.01, 0.1), 2)
THRESHOLDS = np.concatenate([[0.0], np.arange(2.0, 8.01, 0.5)])
DIR_WEIGHTS = np.round(np.arange(0.0, 1.01, 0.1), 2)


def collect(ckpt: Path, data: Path, split: str, max_windows: int, limit: int | None, progress: bool,
            history: tuple = ()) -> dict:
    """Matched objects of a split: OFPD ln px/ms and (cos, sin), plane-fit flow (px per bin),
    true px/ms, bin and direction. history = (candidates, K_max, margin), candidates (D,
    refits) pairs: the flow over the time surface for each too (``flow_D``: (n,
    len(candidates), 2)) and the windows each object had (``short_D``: its K exceeded them);
    k_max: an int, or one per candidate (the ring holds the largest)."""
    from tqdm import tqdm

    from toffe_deploy.dataset.groundtruth import window_truth
    from toffe_deploy.evaluate import _sample_starts, reference_models, split_files
    from toffe_deploy.events.io import open_events
    from toffe_deploy.events.support import sampled_window, sampled_window_history
    from toffe_deploy.metrics import match_gated
    from toffe_deploy.model.reference import window_outputs
    from toffe_deploy.ofpd_io import decode
    from toffe_deploy.plane_fit import dense_flow, px_ms_per_px_bin, refit_history
    from toffe_deploy.time_surface import dense_history_flow, history_windows

    cfg, run_stage, ofpd = reference_models(ckpt)
    if history:
        candidates, k_max, margin = history
        k_maxes = [int(k) for k in k_max] if isinstance(k_max, (list, tuple)) else [int(k_max)] * len(candidates)
        cfg = dataclasses.replace(cfg, ofpd={**(cfg.ofpd or {}),
                                             "plane_fit_history": [candidates[0][0], max(k_maxes), margin]})
    files = split_files(data, split)[:limit]
    rows = {"speed_ln": [], "direction": [], "flow": [], "true": [], "bin": [], "true_dir": [], "flow_D": [],
            "short_D": []}
    for path in tqdm(files, desc=f"{split}", unit="seq", disable=not progress):
        with open_events(path) as src:
            gt = src.ground_truth
            for t0 in _sample_starts(src.t_start_us, src.t_end_us, cfg.dt_us, max_windows):
                truth = window_truth(gt, int(t0), cfg.dt_us)
                if history:
                    binned, recent, ring = sampled_window_history(src.read, int(t0), cfg.dt_us, cfg, src.sensor_size,
                                                                  src.t_start_us)
                else:
                    binned = sampled_window(src.read, int(t0), cfg.dt_us, cfg, src.sensor_size)
                    recent = ring = None
                ks, merged, pose, direction, speed, _res = window_outputs(binned, run_stage, ofpd, cfg, recent)
                if ks.size == 0 or not truth:
                    continue
                d = decode(pose, direction, speed, ks, cfg)
                flow = dense_flow(merged)
                flow_d, short_d = [], []
                if history:
                    s_px_ms = np.exp(np.asarray(speed, dtype=np.float64).reshape(-1))
                    every = np.ones(ks.size, np.bool_)

                    def flow_of(want, k):
                        return dense_history_flow(merged, ring, want, k, margin)

                    for (dist, refits), k_cap in zip(candidates, k_maxes):
                        k = history_windows(s_px_ms, dist, k_cap, cfg.dt_us)
                        f = flow_of(every, k)
                        if refits:                  # as PlaneFusion.apply: short by either K
                            f, k_fit = refit_history(f, k, every, flow_of, dist, k_cap, cfg.dt_us,
                                                     px_ms_per_px_bin(cfg), refits)
                            k = [max(a, b) for a, b in zip(k, k_fit)]
                        flow_d.append(f)
                        short_d.append(np.asarray(k) > ring.available)
                for i, j in match_gated(np.stack([d["x_px"], d["y_px"]], 1), [(t.x, t.y) for t in truth], 20.0):
                    t = truth[i]
                    if t.speed_px_ms is None:
                        continue
                    rows["speed_ln"].append(float(np.asarray(speed).reshape(-1)[j]))
                    rows["direction"].append(np.asarray(direction, dtype=np.float64).reshape(-1, 2)[j])
                    rows["true_dir"].append(float(t.direction))
                    rows["flow"].append(flow[j])
                    rows["true"].append(float(t.speed_px_ms))
                    rows["bin"].append(int(t.speed_bin))
                    if history:
                        rows["flow_D"].append([f[j] for f in flow_d])
                        rows["short_D"].append([sh[j] for sh in short_d])
    return {k: np.asarray(v, dtype=np.float64) for k, v in rows.items()} | {"config": cfg}


def score(rows: dict, weight: float, threshold: float, dir_weight: float = 0.0, d_index: int | None = None) -> dict:
    """Mean |error| px/ms, bin accuracy and mean direction error (deg) of the OFPD alone and
    fused with (weight, threshold, dir_weight); d_index: with the time-surface flow of that
    distance (an object short of its windows keeps the OFPD's speed, as PlaneFusion does)."""
    from toffe_deploy.metrics import angle_error_deg
    from toffe_deploy.ofpd_io import Decoder
    from toffe_deploy.plane_fit import fuse_direction, fuse_speed

    cfg = rows["config"]
    n = rows["true"].size
    if n == 0:
        return {"n": 0}
    flow = rows["flow"].reshape(-1, 2)
    speed_flow = flow
    if d_index is not None:
        flow = rows["flow_D"][:, d_index].reshape(-1, 2)
        speed_flow = np.where(rows["short_D"][:, d_index].reshape(-1, 1) > 0, np.nan, flow)
    fused = fuse_speed(rows["speed_ln"], speed_flow, cfg, weight, threshold)
    fused_dir = fuse_direction(rows["direction"].reshape(-1, 2), flow, cfg, dir_weight)
    dec = Decoder(cfg)
    out = {"n": int(n)}
    for name, s, u in (("ofpd", rows["speed_ln"], rows["direction"].reshape(-1, 2)), ("fused", fused, fused_dir)):
        d = dec(np.zeros((n, 2)), u, s, np.ones(n, np.int64))
        out[f"{name}_err_px_ms"] = float(np.mean(np.abs(d["speed_px_ms"] - rows["true"])))
        out[f"{name}_bin_acc"] = float(np.mean(d["speed_bin"] == rows["bin"]))
        out[f"{name}_dir_err_deg"] = float(np.mean(angle_error_deg(d["direction_rad"], rows["true_dir"])))
    return out


def score_bins(rows: dict, weight: float, threshold: float, dir_weight: float, d_index: int | None) -> dict:
    """score() over each true speed bin's objects alone: {bin: score}."""
    per_object = [k for k, v in rows.items() if isinstance(v, np.ndarray) and v.shape[:1] == rows["true"].shape]
    out = {}
    for b in np.unique(rows["bin"]).astype(int).tolist():
        keep = rows["bin"] == b
        out[b] = score({**rows, **{k: rows[k][keep] for k in per_object}}, weight, threshold, dir_weight, d_index)
    return out


def main(argv=None) -> int:
    ap = OneLineParser(prog="fit_plane_fit.py", description=__doc__.split("\n\n")[0])
    ap.add_argument("--ckpt", type=existing_dir, default=str(ROOT / "ckpt"))
    ap.add_argument("--data", type=Path, default=str(ROOT / "data" / "synth"))
    ap.add_argument("--split", default="train")
    ap.add_argument("--max-windows", type=positive_int, default=3)
    ap.add_argument("--limit", type=positive_int, default=None, help="first N sequences of each split only")
    ap.add_argument("--check", default="", help="comma-separated splits to report (never used to fit)")
    ap.add_argument("--write", action="store_true", help="set the fitted keys in CKPT/config.json")
    ap.add_argument("--json", type=json_output, default=None)
    ap.add_argument("--history", type=comma_list(positive_float), default=[],
                    help="comma-separated distances D (px) to try with plane_fit_history")
    ap.add_argument("--history-windows", type=comma_list(int_in(1, 1000)), default=[20],
                    help="comma-separated K_max (1-1000) of plane_fit_history to try with each D and refits")
    ap.add_argument("--history-margin", type=int_in(0, 64), default=3, help="box margin (px, 0-64) of plane_fit_history")
    ap.add_argument("--refits", type=comma_list(int_in(0, 4)), default=[0],
                    help="comma-separated plane_fit_refits (0-4) to try with each D")
    ap.add_argument("--per-bin", action="store_true", help="each candidate's errors per true speed bin too")
    ap.add_argument("--no-progress", dest="progress", action="store_false")
    a = ap.parse_args(argv)
    if a.refits != [0] and not a.history:
        ap.error("--refits tries plane_fit_refits with --history D,..; without it there is no history to refit over")
    return guarded("fit_plane_fit", run, a)


def run(a) -> int:
    from toffe_deploy.evaluate import split_files
    from toffe_deploy.fileio import atomic_path, check_outputs

    distances = a.history
    refit_list = a.refits
    windows = a.history_windows
    triples = [(d, r, k) for k in windows for d in distances for r in refit_list]
    candidates = [(d, r) for d, r, _k in triples]
    k_of = [k for _d, _r, k in triples]
    history = (candidates, k_of, a.history_margin) if candidates else ()
    ckpt = Path(a.ckpt)
    if not (ckpt / "config.json").is_file():
        raise InputError(ckpt, "no config.json here: not a checkpoint directory (--ckpt)")
    checks = [s for s in a.check.split(",") if s.strip()]
    for split in [a.split] + checks:            # every split exists before the work (InputError naming the splits)
        split_files(Path(a.data), split)
    check_outputs(files=[("--json", a.json)] + ([("--write", ckpt / "config.json")] if a.write else []))
    fit = collect(ckpt, Path(a.data), a.split, a.max_windows, a.limit, a.progress and sys.stderr.isatty(), history)
    if fit["true"].size == 0:
        raise ToffeError(f"no matched objects in {a.data}/{a.split}: nothing to fit")
    best = None
    for di in range(len(candidates)) if candidates else [None]:
        _err, w, t = min((score(fit, w, t, 0.0, di)["fused_err_px_ms"], float(w), float(t))
                         for w in WEIGHTS for t in THRESHOLDS)
        _err, wd = min((score(fit, w, t, d, di)["fused_dir_err_deg"], float(d)) for d in DIR_WEIGHTS)
        r = score(fit, w, t, wd, di)
        rel = r["fused_err_px_ms"] / r["ofpd_err_px_ms"] + r["fused_dir_err_deg"] / r["ofpd_dir_err_deg"]
        if di is not None:
            print(f"D {candidates[di][0]:g} px, K_max {k_of[di]}, {candidates[di][1]} refits: "
                  f"speed {r['fused_err_px_ms']:.3f} px/ms, direction {r['fused_dir_err_deg']:.2f} deg "
                  f"(weights {w}, {t}, {wd}; relative sum {rel:.4f})")
            if a.per_bin:
                print("    per bin (n: px/ms / deg): " + ", ".join(
                    f"{b} ({q['n']}: {q['fused_err_px_ms']:.3f} / {q['fused_dir_err_deg']:.2f})"
                    for b, q in score_bins(fit, w, t, wd, di).items()))
        if best is None or rel < best[0]:
            best = (rel, di, w, t, wd)
    _rel, di, w, t, wd = best
    keys = {"plane_fit_weight": w, "plane_fit_min_px_ms": t, "plane_fit_dir_weight": wd}
    if di is not None:
        keys["plane_fit_history"] = [candidates[di][0], k_of[di], a.history_margin]
        keys["plane_fit_refits"] = candidates[di][1]
    report = {"fit_split": a.split, **keys, "splits": {a.split: score(fit, w, t, wd, di)}}
    for split in checks:
        report["splits"][split] = score(collect(ckpt, Path(a.data), split, a.max_windows, a.limit,
                                                a.progress and sys.stderr.isatty(),
                                                ([candidates[di]], k_of[di], a.history_margin)
                                                if di is not None else ()), w, t, wd, 0 if di is not None else None)
    print(f"fitted on {a.split}: " + ", ".join(f"{k} {v}" for k, v in keys.items()))
    print("| split | objects | speed error px/ms: OFPD -> fused | bin accuracy: OFPD -> fused | direction error deg: OFPD -> fused |")
    print("|---|---|---|---|---|")
    for split, r in report["splits"].items():
        if r["n"]:
            print(f"| {split} | {r['n']} | {r['ofpd_err_px_ms']:.3f} -> {r['fused_err_px_ms']:.3f} | "
                  f"{r['ofpd_bin_acc']:.3f} -> {r['fused_bin_acc']:.3f} | "
                  f"{r['ofpd_dir_err_deg']:.2f} -> {r['fused_dir_err_deg']:.2f} |")
    if a.json:
        with atomic_path(a.json) as tmp:
            tmp.write_text(json_text(report, indent=2))
    if a.write:
        cfg_path = ckpt / "config.json"
        cfg = json.loads(cfg_path.read_text())
        cfg.setdefault("ofpd", {}).update(keys)
        with atomic_path(cfg_path) as tmp:
            tmp.write_text(json.dumps(cfg, indent=2) + "\n")
        print(f"wrote {cfg_path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
