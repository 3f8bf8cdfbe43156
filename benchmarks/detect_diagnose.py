#!/usr/bin/env python
"""Why detections are missed and where false positives come from (issue 11), per object.

    python benchmarks/detect_diagnose.py --split appearance            # ckpt/, dt 500, 6 windows
    python benchmarks/detect_diagnose.py --split pairs --ofpd merge_frac=0.3 --json /tmp/d.json
    python benchmarks/detect_diagnose.py --render /tmp/d.json         # its tables again

The windows, the cascade, the grouping and the matching are those of ``eval`` (evaluate.py:
the same sampled windows, front end, fixed-point OFS stages, ofpd_io.group_objects_xy and
metrics.match_gated within the 20 px gate); ``--ofpd KEY=VALUE`` overrides config.ofpd keys to
measure a grouping rule without writing a checkpoint (``--config KEY=VALUE`` a top-level key,
e.g. the front end's input_min_cluster: an experiment, the OFS was trained with its own). Each ground-truth object the matching
leaves unmatched (a miss) and each prediction it leaves unmatched (a false positive) becomes
one row:

miss: true bin, speed (m/s, px/ms, px per window), size now (size_m * focal / depth, px), log
    contrast and events per edge (the generator's), input events within R = size / 2 + 8 px
    of its centre (raw events, their unique pixels, and the pixels the front end keeps), spike cells of each OFS stage and
    frame pixels of each stage within R, the candidate groups near it (stage, pixels vs
    ofpd.min_events, reported or joined or dropped), and a cause, the first that holds:
      few_events    < min_events input pixels near it (the sensor gave too little: raw px
                    near < min_events, or the front end's cluster filter dropped them);
      no_stage      no stage frame keeps >= min_events of them (the OFS stages did not fire);
      dropped       its pixels form groups that no object claims (each < min_events);
      merged        its pixels are claimed by an object matched to another true object, or
                    by one whose pixels reach two or more true objects (within R of each);
      mislocated    claimed by another unmatched object (reported > gate away: also a FP);
      other         none of these (e.g. the matching gave the prediction to a neighbour).
fp: reported stage and bin, pixels it claims, extent, whether they surround their centroid,
    distance to the nearest true object (in its radii) and to the nearest other prediction,
    and for a duplicate the gap between its pixels and those of the object that was matched to
    that truth, over the larger extent (the ratio blob grouping compares with merge_frac /
    edge_merge_frac). Cause:
      merged        its pixels lie near two or more true objects (R of each): several
                    objects reported as one, between them;
      mislocated    nearest truth within its radius + 10 px is unmatched: the object was
                    found but reported > gate from its centre;
      slower_edge   nearest truth (within 1.5 radii + 10 px) is matched by a faster stage's
                    object: leftover edges reported again by a slower stage;
      split_same    ... matched by an object of the same stage: the object split in two;
      faster_part   ... matched by a slower stage's object (a part reached a faster stage);
      noise         no truth that close.
Prints the tables as markdown; ``--json`` writes the rows and the tables.
"""
from __future__ import annotations

import json
import math
import sys
from collections import Counter, defaultdict
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from toffe_deploy import ofpd_io  # noqa: E402
from toffe_deploy.compiled import min_gap, surrounds  # noqa: E402
from toffe_deploy.errors import InputError  # noqa: E402
from toffe_deploy.metrics import GATE_PX, match_gated  # noqa: E402
from _args import (OneLineParser, apply_overrides, existing_dir, existing_file, guarded, json_output,  # noqa: E402
                   key_value, positive_int)

NEAR_PAD = 8.0        # R = size / 2 + NEAR_PAD around a true object
FP_PAD = 10.0


def parse_args(argv=None):
    ap = OneLineParser(prog="detect_diagnose.py", description=__doc__.split("\n\n")[0])
    ap.add_argument("--ckpt", type=existing_dir, default=str(ROOT / "ckpt"))
    ap.add_argument("--data", type=Path, default=str(ROOT / "data" / "synth"))
    ap.add_argument("--split", default="appearance")
    ap.add_argument("--dt", type=positive_int, default=500, help="window length, us (default 500)")
    ap.add_argument("--max-windows", type=positive_int, default=6)
    ap.add_argument("--ofpd", action="append", default=[], metavar="KEY=VALUE",
                    help="override a config.ofpd key (JSON value), e.g. merge_frac=0.3")
    ap.add_argument("--config", action="append", default=[], metavar="KEY=VALUE",
                    help="override a top-level config key (JSON value), e.g. input_min_cluster=2")
    ap.add_argument("--json", type=json_output, help="write rows and tables here")
    ap.add_argument("--render", type=existing_file, metavar="JSON",
                    help="only print the tables of a --json file written earlier")
    a = ap.parse_args(argv)
    try:
        a.ofpd = [key_value(kv, "--ofpd") for kv in a.ofpd]
        a.config = [key_value(kv, "--config") for kv in a.config]
    except ValueError as exc:
        ap.error(str(exc))
    return a


def _sorted_x(xs, ys):
    o = np.argsort(xs, kind="stable")
    return np.ascontiguousarray(xs[o], np.int64), np.ascontiguousarray(ys[o], np.int64)


def pixel_gap(a, b) -> float:
    """Smallest Euclidean distance between a pixel of set a and one of set b (compiled.min_gap)."""
    if a[0].size == 0 or b[0].size == 0:
        return math.inf
    bx, by = _sorted_x(*b)
    return float(min_gap(np.ascontiguousarray(a[0], np.int64), np.ascontiguousarray(a[1], np.int64), bx, by, 1e9))


def extent(xs, ys) -> int:
    return 0 if xs.size == 0 else int(max(xs.max() - xs.min(), ys.max() - ys.min()) + 1)


def object_size_px(attrs: dict, oid: int, depth, focal) -> tuple[float, float, float]:
    """(size px now, log contrast, events per edge) of object oid from the generator's attrs."""
    objs = (attrs.get("appearance") or {}).get("objects") or []
    spec = (((attrs.get("generator") or {}).get("spec") or {}).get("objects")) or attrs.get("objects") or []
    a = objs[oid] if oid < len(objs) else {}
    size = float(a.get("size_px", math.nan))
    size_m = spec[oid].get("size_m") if oid < len(spec) else None
    if size_m and depth and focal:
        size = float(size_m) * float(focal) / float(depth)
    return size, float(a.get("log_contrast", math.nan)), float(a.get("events_per_edge", math.nan))


def diagnose_window(binned, raw, run_stage, ofpd, cfg, truth, attrs, focal, dt, recent=None, history=None):
    """(miss rows, fp rows, number of predictions) of one window (module doc); recent: the front
    end's SupportHistory after it (ofpd.recent_events); history: the plane fit's windows up to it
    (ofpd.plane_fit_history; events.support.sampled_window_history)."""
    from toffe_deploy.model.reference import predict_window

    preds, res = predict_window(binned, run_stage, ofpd, cfg, recent, history)
    need = int(ofpd_io.ofpd_settings(cfg)["min_events"])
    h, w = binned.shape[-2:]
    pool = int(cfg.ofs_pool)
    stage_px = ofpd_io.stage_pixels_of(np.stack(res.frames), cfg)       # [(xs, ys(, pol))] per stage
    objs, claims = ofpd_io.group_objects_xy(stage_px, (w, h), cfg, recent)
    assert len(objs) == len(preds)
    # every stage pixel: stage, candidate group of its stage, owner object
    sx = np.concatenate([p[0] for p in stage_px]).astype(np.int64)
    sy = np.concatenate([p[1] for p in stage_px]).astype(np.int64)
    sst = np.concatenate([np.full(p[0].size, i, np.int64) for i, p in enumerate(stage_px)])
    sgrp = np.full(sx.size, -1, np.int64)
    gcount = []
    off = 0
    for i, p in enumerate(stage_px):
        grp, cnt, _box, _closed = ofpd_io.blobs_xy(p[0], p[1], w, cfg)
        sgrp[off:off + grp.size] = np.where(grp >= 0, grp, -1)
        gcount.append(cnt)
        off += grp.size
    own_m = claims.matrix(sx, sy, len(objs)) if objs else np.zeros((0, sx.size), bool)
    sown = np.where(own_m.any(axis=0), own_m.argmax(axis=0), -1) if objs else np.full(sx.size, -1)
    in_y, in_x = np.nonzero(ofpd_io.event_pixels(binned[None])[0])
    sp_cells = [np.nonzero(s.any(axis=0)) for s in res.spikes]           # (ys, xs) on the OFS grid

    pairs = match_gated([(p.x, p.y) for p in preds], [(t.x, t.y) for t in truth], GATE_PX)
    t_of_p = {j: i for i, j in pairs}
    p_of_t = {i: j for i, j in pairs}
    sizes = [object_size_px(attrs, t.object_id, t.depth_m, focal) for t in truth]
    reach = [(s[0] / 2 if math.isfinite(s[0]) else 20.0) + NEAR_PAD for s in sizes]
    spans = [sum(bool(np.any((sx[own_m[j]] - t.x) ** 2 + (sy[own_m[j]] - t.y) ** 2 <= rr * rr))
                 for t, rr in zip(truth, reach)) for j in range(len(objs))]     # true objects each one's pixels reach
    misses, fps = [], []
    for i, t in enumerate(truth):
        if i in p_of_t:
            continue
        size, contrast, epe = sizes[i]
        r = reach[i]

        def near(xs, ys, cx=t.x, cy=t.y, r=r):
            return (np.asarray(xs) - cx) ** 2 + (np.asarray(ys) - cy) ** 2 <= r * r

        rx, ry = raw["x"].astype(np.int64), raw["y"].astype(np.int64)
        at = near(rx, ry)
        n_raw = int(at.sum())
        n_raw_px = int(np.unique(ry[at] * w + rx[at]).size)
        n_in = int(near(in_x, in_y).sum())
        sel = near(sx, sy)
        frame_k = [int((sel & (sst == k)).sum()) for k in range(len(stage_px))]
        spikes_k = [int(near(c[1] * pool + (pool - 1) / 2, c[0] * pool + (pool - 1) / 2).sum()) for c in sp_cells]
        groups = sorted({(int(sst[q]), int(sgrp[q])) for q in np.flatnonzero(sel) if sgrp[q] >= 0})
        gdesc = []
        for k, g in groups:
            members = (sst == k) & (sgrp == g)
            owners = set(sown[members].tolist()) - {-1}
            gdesc.append({"stage": k + 1, "pixels": int(gcount[k][g]), "near": int((members & sel).sum()),
                          "owner": sorted(owners)})
        owners_near = Counter(int(o) for o in sown[sel] if o >= 0)
        if n_in < need:
            cause = "few_events"
        elif sum(frame_k) < need:
            cause = "no_stage"
        elif not owners_near:
            cause = "dropped"
        else:
            o = owners_near.most_common(1)[0][0]          # i is unmatched: o is matched elsewhere or not at all
            cause = "merged" if o in t_of_p or spans[o] >= 2 else "mislocated"
        v_px = float(t.speed_px_ms) if t.speed_px_ms is not None else math.nan
        misses.append({"bin": int(t.speed_bin), "speed_mps": float(t.speed), "speed_px_ms": v_px,
                       "px_per_window": v_px * dt / 1000.0, "size_px": size, "log_contrast": contrast,
                       "events_per_edge": epe, "raw_events": n_raw, "raw_px": n_raw_px, "input_px": n_in, "spike_cells": spikes_k,
                       "frame_px": frame_k, "groups": gdesc, "cause": cause,
                       "nearest_pred_px": min((float(np.hypot(p.x - t.x, p.y - t.y)) for p in preds), default=math.inf)})
    for j, p in enumerate(preds):
        if j in t_of_p:
            continue
        mine = own_m[j]
        fx, fy = sx[mine], sy[mine]
        d_t = [float(np.hypot(p.x - t.x, p.y - t.y)) for t in truth]
        d_p = [float(np.hypot(p.x - q.x, p.y - q.y)) for m, q in enumerate(preds) if m != j]
        row = {"stage": objs[j][0] + 1, "bin": int(p.stage), "pixels": int(mine.sum()), "extent": extent(fx, fy),
               "closed": bool(surrounds(fx, fy)) if fx.size else False,
               "nearest_truth_px": min(d_t, default=math.inf), "nearest_pred_px": min(d_p, default=math.inf),
               "truth_radii": math.nan, "gap_ratio": math.nan, "host_stage": None, "cause": "noise"}
        row["truths_spanned"] = spans[j]
        if spans[j] >= 2:
            row["cause"] = "merged"
        elif truth:
            i = int(np.argmin(d_t))
            size = sizes[i][0]
            rad = size / 2 if math.isfinite(size) else 20.0
            row["truth_radii"] = d_t[i] / rad
            row["truth_size_px"] = size
            if i not in p_of_t and d_t[i] <= rad + FP_PAD:
                row["cause"] = "mislocated"
            elif i in p_of_t and d_t[i] <= 1.5 * rad + FP_PAD:
                m = p_of_t[i]
                hx, hy = sx[own_m[m]], sy[own_m[m]]
                row["host_stage"] = objs[m][0] + 1
                row["gap_ratio"] = pixel_gap((fx, fy), (hx, hy)) / max(extent(fx, fy), extent(hx, hy), 1)
                row["cause"] = ("slower_edge" if objs[j][0] < objs[m][0] else
                                "split_same" if objs[j][0] == objs[m][0] else "faster_part")
        fps.append(row)
    return misses, fps, len(preds)


def _q(v, qs=(0.1, 0.5, 0.9)):
    a = np.asarray([x for x in v if x is not None and math.isfinite(x)], dtype=float)
    return "/".join(f"{np.quantile(a, q):.3g}" for q in qs) if a.size else "-"


def tables(misses, fps, n_windows, n_gt) -> str:
    """Markdown: misses by bin and cause with the physical numbers; FPs by cause and stage."""
    lines = [f"{n_windows} windows, {n_gt} true objects, {len(misses)} missed, {len(fps)} false positives "
             f"({len(fps) / max(n_windows, 1):.3f} / window).", "",
             "Misses by true bin (quantiles 10/50/90 %):", "",
             "| bin | missed | causes | px / window | size px | raw events near | raw px near | input px near "
             "| frame px near (all stages) |", "|---|---|---|---|---|---|---|---|---|"]
    by_bin = defaultdict(list)
    for m in misses:
        by_bin[m["bin"]].append(m)
    for b in sorted(by_bin):
        ms = by_bin[b]
        causes = ", ".join(f"{c} {n}" for c, n in Counter(m["cause"] for m in ms).most_common())
        lines.append(f"| {b} | {len(ms)} | {causes} | {_q([m['px_per_window'] for m in ms])} | "
                     f"{_q([m['size_px'] for m in ms])} | {_q([m['raw_events'] for m in ms])} | "
                     f"{_q([m.get('raw_px', math.nan) for m in ms])} | "
                     f"{_q([m['input_px'] for m in ms])} | "
                     f"{_q([sum(m['frame_px']) for m in ms])} |")
    lines += ["", "False positives by cause and reported stage (quantiles 10/50/90 %):", "",
              "| cause | FPs | by stage | pixels | dist. to truth (radii) | gap / extent to the matched object "
              "| truth size px |", "|---|---|---|---|---|---|---|"]
    by_cause = defaultdict(list)
    for f in fps:
        by_cause[f["cause"]].append(f)
    for c, fs in sorted(by_cause.items(), key=lambda kv: -len(kv[1])):
        st = ", ".join(f"{k}: {n}" for k, n in sorted(Counter(f["stage"] for f in fs).items()))
        lines.append(f"| {c} | {len(fs)} | {st} | {_q([f['pixels'] for f in fs])} | "
                     f"{_q([f['truth_radii'] for f in fs])} | {_q([f['gap_ratio'] for f in fs])} | "
                     f"{_q([f.get('truth_size_px', math.nan) for f in fs])} |")
    return "\n".join(lines)


def rerender(path: str) -> str:
    """The tables of a --json file written earlier (InputError for a missing or foreign file)."""
    from toffe_deploy.fileio import read_json

    d = read_json(path)
    if not (isinstance(d, dict) and isinstance(d.get("misses"), list) and isinstance(d.get("fps"), list)
            and isinstance(d.get("n_windows"), int) and isinstance(d.get("n_gt"), int)):
        raise InputError(path, "not a detect_diagnose.py --json file (no misses, fps, n_windows, n_gt)")
    try:
        return tables(d["misses"], d["fps"], d["n_windows"], d["n_gt"])
    except (KeyError, TypeError, ValueError) as exc:
        raise InputError(path, f"not a detect_diagnose.py --json file ({type(exc).__name__}: {exc})") from None


def main(argv=None) -> int:
    a = parse_args(argv)
    if a.render:
        return guarded("detect_diagnose", lambda: print(rerender(a.render)))
    return guarded("detect_diagnose", run, a)


def run(a) -> int:
    from toffe_deploy.dataset.groundtruth import window_truth
    from toffe_deploy.evaluate import _sample_starts, reference_models, split_files
    from toffe_deploy.events.io import open_events
    from toffe_deploy.events.support import sampled_window_history
    from toffe_deploy.fileio import atomic_path, check_outputs, json_text
    from toffe_deploy.runtime.truth import sequence_focal_px

    files = split_files(Path(a.data), a.split)
    check_outputs(files=[("--json", a.json)])
    cfg, run_stage, ofpd = reference_models(Path(a.ckpt), "fixed")
    cfg = apply_overrides(cfg, a.ofpd, a.config)
    misses, fps = [], []
    n_windows = n_gt = n_pred = 0
    for path in files:
        with open_events(path) as src:
            gt, attrs = src.ground_truth, src.attrs
            focal = sequence_focal_px(attrs)
            for t0 in _sample_starts(src.t_start_us, src.t_end_us, a.dt, a.max_windows):
                truth = window_truth(gt, int(t0), a.dt)
                raw = src.read(int(t0), int(t0) + a.dt)
                binned, recent, history = sampled_window_history(src.read, int(t0), a.dt, cfg, src.sensor_size,
                                                                 src.t_start_us)
                ms, fs, n = diagnose_window(binned, raw, run_stage, ofpd, cfg, truth, attrs, focal, a.dt, recent,
                                            history)
                for r in ms + fs:
                    r["sequence"], r["t0"] = Path(path).stem, int(t0)
                misses += ms
                fps += fs
                n_windows += 1
                n_gt += len(truth)
                n_pred += n
    if n_windows == 0:
        raise InputError(Path(a.data) / a.split, f"no window of --dt {a.dt} us in its recordings: nothing to "
                                                 "diagnose (a --dt longer than the recordings?)")
    md = tables(misses, fps, n_windows, n_gt)
    overrides = [f"{k}={json.dumps(v)}" for k, v in a.ofpd + a.config]
    if a.json:
        with atomic_path(a.json) as tmp:
            tmp.write_text(json_text({"split": a.split, "overrides": overrides, "n_windows": n_windows,
                                      "n_gt": n_gt, "n_pred": n_pred, "misses": misses, "fps": fps,
                                      "markdown": md}, indent=1, default=float))
    print(f"split {a.split}, recall {1 - len(misses) / max(n_gt, 1):.3f}, FP / window {len(fps) / max(n_windows, 1):.3f}"
          + (f", overrides {overrides}" if overrides else ""))
    print(md)
    return 0


if __name__ == "__main__":
    sys.exit(main())
