#!/usr/bin/env python
"""Tracking accuracy of the deployed pipeline on whole sequences of a data-set split.

    .venv/bin/python benchmarks/bench_tracking.py --bundle export/ --data data/synth --split multi,pairs
        [--max-windows 200] [--limit N] [--score-gate 20] [--gate 17] [--alpha A] [--beta B] [--confirm K] [--max-misses M] [--tentative-misses T]
        [--hysteresis H] [--gate-growth G] [--birth-gap PX] [--gate-speed K] [--report-misses R]
        [--max-occluded O] [--turn-beta B] [--max-turn RAD] [--merge PX] [--merge-move PX]
        [--no-shared-keeps-motion] [--shared-gate-grows] [--reid PX] [--reid-ratio R] [--coast-px PX] [--max-coast N]
        [--pos-beta B] [--pos-min PX] [--pos-max-rad RAD] [--blob-growth G] [--heading-cost PX] [--reid-growth G]
        [--no-reid-ratio-missed] [--hidden PX] [--handover PX] [--handover-reach K] [--handover-windows N]
        [--handover-speed-ratio R] [--no-confirm-at-start] [--no-parting] [--parting-heading PX] [--parting-events PX]
        [--truth-blobs [--truth-merge F]] [--save-detections DIR | --detections DIR] [--json FILE]

Each sequence runs from its start, window after window (dt of the bundle), through
``Pipeline(bundle, "cpu", track=TrackerConfig(...))``; its detections are scored like `run`
does (metrics.FlowErrors) and its confirmed tracks by tracking_metrics.TrackingErrors (CLEAR MOT,
IDF1 through motmetrics). Also counted: speed-bin changes between consecutive windows of one
ground-truth object, as the detections report them and as its track reports them (flicker),
and per ground-truth speed bin the mean direction error of the matched detections, as the
detection reports it (this window only; faint objects left out: their direction is a guess)
and as its confirmed track's heading does (tracked, causal: from past and current windows only;
tracks with no measured motion, speed 0, left out: a track started by faint objects). Prints one markdown row per split and
a direction table; the JSON holds every figure and the settings, and each sequence's detection
recall and false positives per window, MOTA, IDF1, ID switches, misses and false positives
(per_sequence), and each object's windows, detected windows (a detection within the score
gate, one to one) and tracked windows (as the tracking metrics score: a confirmed track's
object or a listed coasting track within the gate, tracking_metrics.reported) with its events
per passing edge where the generator recorded it (per_object; recall_by_events_per_edge: the recall of the
objects that fire at least 1 / 1.2 / 1.5 / 2 events per edge, also printed: the misses of
objects the sensor hardly sees told from the pipeline's own), and the tracking metrics again
over the sequences whose every object fires at least 1 (tracking_visible). ``--ofpd
KEY=VALUE`` / ``--config KEY=VALUE`` try a grouping or fusion setting on the bundle's trained
weights without exporting a new bundle (as detect_diagnose.py).

``--save-detections DIR``: also write each split's per-window detections (the pipeline's
objects, before tracking) to DIR/SPLIT.jsonl (JSON lines: a header {"split", "files", "fields",
"max_windows"}, then one {"seq", "t0_us", "objects": [[fields...]]} per window); ``--detections
DIR``: replay them into the tracker instead of running the OFS and OFPD (the same figures in
seconds; the sequences must be the ones saved: same --data, --split, --limit, and --max-windows
at most the one saved, else it is refused). A file saved before the header had "max_windows"
is replayed as it is, with a warning: its window count cannot be checked.

``--truth-blobs``: the tracker alone, on detections made from the ground truth (each object's
centre, direction and image-plane speed, every window), except that objects whose discs
overlap (centre distance below their mean diameter, ``appearance.objects[].size_px`` of the
generator's attrs) are reported as one blob at their mean centre with the first one's motion:
what a perfect detector that cannot split touching objects would give. Scores identities
through crossings apart from the detector's misses and false positives. ``--truth-merge F``
merges below F times the mean diameter instead (0.5: a detector that splits objects whose
centres are more than a radius apart; 0: one that splits every pair).

``--cost``: instead, the CPU time per window of the cpu pipeline with and without tracking on
the shipped sample (or --events; time.process_time, one pinned core, best of --repeats
passes, the two interleaved), i.e. what tracking adds to `run --target cpu`; wall time and the
load average beside it. The share is given twice: of the pipeline after binning (the volumes are
built before the timed loop) and of the whole window from its events (binning, timed apart the
same way, added: the per-window time `run` and bench_run.py measure).
"""
from __future__ import annotations

import argparse
import contextlib
import dataclasses
import json
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from _args import (OneLineParser, apply_overrides, existing_file, guarded, json_output,  # noqa: E402
                   key_value, nonneg_float, nonneg_int, positive_float, positive_int)


def bin_flicker(rows) -> int:
    """Bin changes between consecutive windows of each object: rows of (object id, window, bin)."""
    last: dict = {}
    n = 0
    for oid, w, b in rows:
        prev = last.get(oid)
        if prev is not None and prev[0] == w - 1 and prev[1] != b:
            n += 1
        last[oid] = (w, b)
    return n


def angle_err_deg(a: float, b: float) -> float:
    """|a - b| wrapped to [0, 180] degrees (a, b in rad)."""
    import math

    return abs(math.degrees((a - b + math.pi) % (2 * math.pi) - math.pi))


#: an ObjectFlow's fields in a detections file (``--save-detections``), in this order
DET_FIELDS = ("speed_bin", "ofs_bin", "speed_mps", "speed_bin_mps", "speed_px_s", "x", "y", "direction_rad",
              "n_events", "speed_clipped", "faint")


def save_detections(path: Path, split: str, files, windows: list, max_windows: int) -> None:
    """The pipeline's detections of a split, one JSON line per window ({"seq": file index, "t0_us",
    "objects": [[DET_FIELDS...], ...]}) after a header line ({"split", "files", "fields",
    "max_windows"}): what ``--detections`` replays into the tracker. windows: (file index, t0_us,
    objects) per window; max_windows: the --max-windows they were run with."""
    from toffe_deploy.fileio import atomic_path

    with atomic_path(path) as tmp, open(tmp, "w") as f:
        f.write(json.dumps({"split": split, "files": [str(p) for p in files], "fields": DET_FIELDS,
                            "max_windows": int(max_windows)}) + "\n")
        for fi, t0, objs in windows:
            f.write(json.dumps({"seq": fi, "t0_us": int(t0),
                                "objects": [[getattr(o, k) for k in DET_FIELDS] for o in objs]}) + "\n")


def load_detections(path: Path, files, max_windows: int | None = None) -> dict:
    """{file index: [(t0_us, [field tuples])]} from a ``save_detections`` file, which must be of
    the same sequences and, when its header says, saved with at least ``max_windows`` windows per
    sequence (InputError otherwise; a header without "max_windows": a warning, replayed as it is)."""
    from toffe_deploy.errors import InputError, warn

    try:
        with open(path) as f:
            head = json.loads(f.readline())
            if not isinstance(head, dict) or not {"files", "fields"} <= set(head):
                raise InputError(path, "not a --save-detections file (its first line is no header)")
            if head["files"] != [str(p) for p in files] or tuple(head["fields"]) != DET_FIELDS:
                raise InputError(path, "saved for other sequences or fields (--data, --split, --limit)")
            saved = head.get("max_windows")
            if saved is None:
                warn(f"{path}: saved without its --max-windows (an older file): replayed as it is, a sequence "
                     "may have fewer windows than --max-windows asks")
            elif max_windows is not None and max_windows > saved:
                raise InputError(path, f"saved with --max-windows {saved}, fewer than the {max_windows} asked: "
                                       f"replay with --max-windows {saved} or save again")
            out: dict = {i: [] for i in range(len(files))}
            for line in f:
                r = json.loads(line)
                out[r["seq"]].append((r["t0_us"], r["objects"]))
    except FileNotFoundError:
        raise InputError(path, "missing file (--detections DIR needs DIR/SPLIT.jsonl from --save-detections)") from None
    except (json.JSONDecodeError, UnicodeDecodeError, KeyError, TypeError, IndexError) as exc:
        raise InputError(path, f"not a --save-detections file ({type(exc).__name__}: {exc})") from None
    return out


def run_split(bundle, files, settings, max_windows, gate, saved=None, keep=None) -> dict:
    """One split through the pipeline (or, with ``saved`` from load_detections, its saved
    detections through the tracker alone); ``keep``: a list that gets (file index, t0_us,
    objects) of every window (for save_detections)."""
    import math

    import numpy as np

    from toffe_deploy.events.io import open_events
    from toffe_deploy.metrics import FlowErrors, match_gated, predictions_of
    from toffe_deploy.runtime.pipeline import ObjectFlow, Pipeline, WindowResult
    from toffe_deploy.runtime.spikes import SpikeVolume
    from toffe_deploy.runtime.truth import TruthIndex, sequence_focal_px
    from toffe_deploy.tracking import Tracker
    from toffe_deploy.tracking_metrics import TrackingErrors, reported

    def replay(fi):
        """The saved windows of sequence fi through a fresh Tracker (what Pipeline(track=) does)."""
        tracker = Tracker(cfg, cfg.dt_us, settings, cfg.speed_scale.px_ms_per_mps)
        for t0, rows in saved[fi][:max_windows]:
            objs = [ObjectFlow(**dict(zip(DET_FIELDS, r))) for r in rows]
            tracker.update(objs, t0)
            yield WindowResult(t0, t0 + cfg.dt_us, objs, coasting=tracker.coasting())

    cfg = bundle.config
    flow = FlowErrors(gate_px=gate, n_bins=cfg.n_speed_bins, pred_scale=cfg.speed_scale)
    track = TrackingErrors(gate)
    det_bins, trk_bins, t_track, n_win = [], [], 0.0, 0
    dir_det = {k: [] for k in range(1, cfg.n_speed_bins + 1)}
    dir_trk = {k: [] for k in range(1, cfg.n_speed_bins + 1)}
    per_sequence, per_object = [], []
    track_visible, n_visible = TrackingErrors(gate), 0
    for fi, path in enumerate(files):
        with open_events(path) as src:
            truth, focal = TruthIndex(src.ground_truth), sequence_focal_px(src.attrs)
            sensor = tuple(src.sensor_size)

            def windows():
                for i, (t0, ev) in enumerate(src.iter_windows(cfg.dt_us, t_start=src.t_start_us)):
                    if i >= max_windows:
                        return
                    yield t0, SpikeVolume.from_events(ev, t0, cfg.dt_us, cfg.n_bins, sensor)

            epe = events_per_edge(src.attrs)
            seen: dict = {}                                 # object id -> windows it is in, windows detected
            # a sequence whose every object fires >= VISIBLE_EDGE_EVENTS per passing edge is scored again apart
            n_objects = _object_count(src.attrs)
            visible = bool(epe) and len(epe) == n_objects and min(epe.values()) >= VISIBLE_EDGE_EVENTS
            if visible:
                track_visible.new_sequence()
                n_visible += 1
            track.new_sequence()
            own = TrackingErrors(gate)                      # this sequence alone (per_sequence)
            own.new_sequence()
            own_flow = FlowErrors(gate_px=gate, n_bins=cfg.n_speed_bins, pred_scale=cfg.speed_scale)
            with contextlib.ExitStack() as stack:
                if saved is None:
                    pipe = stack.enter_context(Pipeline(bundle, "cpu", sensor_size=sensor, track=settings,
                                                        speed_scale=cfg.speed_scale))   # as replay() and flow
                    results = pipe.process_stream(windows())
                else:
                    results = replay(fi)
                for w, res in enumerate(results):
                    if keep is not None:
                        keep.append((fi, res.t0_us, res.objects))
                    gt = truth.window(res.t0_us, cfg.dt_us)
                    preds = predictions_of(res.objects)
                    flow.add_window(preds, gt, focal)
                    own_flow.add_window(preds, gt, focal)
                    track.add_result(res, gt)
                    own.add_result(res, gt)
                    if visible:
                        track_visible.add_result(res, gt)
                    for t in gt:
                        seen.setdefault(int(t.object_id), [0, 0, 0])[0] += 1
                    for i, _ in match_gated([h[1:] for h in reported(res)], [(t.x, t.y) for t in gt], gate):
                        seen[int(gt[i].object_id)][2] += 1
                    for i, j in match_gated([(o.x, o.y) for o in res.objects], [(t.x, t.y) for t in gt], gate):
                        seen[int(gt[i].object_id)][1] += 1
                        key = (fi, gt[i].object_id)
                        o, b = res.objects[j], int(gt[i].speed_bin)
                        det_bins.append((key, w, o.speed_bin))
                        if b in dir_det and not o.faint:    # a faint object's direction is no measurement
                            dir_det[b].append(angle_err_deg(o.direction_rad, gt[i].direction))
                        if o.track is not None:
                            trk_bins.append((key, w, o.track["speed_bin"]))
                            if b in dir_trk and o.track.confirmed and o.track["speed_px_s"] > 0:   # 0: no measured motion
                                dir_trk[b].append(angle_err_deg(math.radians(o.track["direction_deg"]),
                                                                gt[i].direction))
                    n_win += 1
            per_object += [{"sequence": Path(path).stem, "object_id": k, "windows": n, "detected": hit,
                            "tracked": held, "events_per_edge": epe.get(k)}
                           for k, (n, hit, held) in sorted(seen.items())]
            m, d = own.summary(), own_flow.summary()
            per_sequence.append({"sequence": Path(path).stem, "recall": d["recall"],
                                 "fp_per_window": d["fp_per_window"], "mota": m["mota"], "idf1": m["idf1"],
                                 "id_switches": m["id_switches"], "misses": m["misses"],
                                 "false_positives": m["false_positives"]})
    e = flow.summary()
    return {"sequences": len(files), "windows": n_win, "recall": e["recall"], "fp_per_window": e["fp_per_window"],
            "bin_accuracy": e["bin_accuracy"], "tracking": track.summary(),
            "bin_changes_detections": bin_flicker(det_bins), "bin_changes_tracks": bin_flicker(trk_bins),
            "matched": len(det_bins), "per_sequence": per_sequence, "per_object": per_object,
            "recall_by_events_per_edge": recall_by_events_per_edge(per_object),
            "tracking_visible": {"sequences": n_visible, "min_events_per_edge": VISIBLE_EDGE_EVENTS,
                                 **(track_visible.summary() if n_visible else {})},
            "direction_error_deg": {str(k): {"detection": float(np.mean(dir_det[k])) if dir_det[k] else None,
                                             "tracked_causal": float(np.mean(dir_trk[k])) if dir_trk[k] else None,
                                             "n": len(dir_det[k]), "n_tracked": len(dir_trk[k])} for k in dir_det}}


def truth_blobs(truths, size_px, speed_bin_of, merge: float = 1.0) -> list:
    """One window's detections from its ground truth: overlapping objects merged into one blob
    (module doc). truths: ObjectTruth list; size_px: diameter per object id; merge: the centre
    distance that merges two, in mean diameters."""
    import math

    from toffe_deploy.runtime.pipeline import ObjectFlow

    out, used = [], set()
    for i, t in enumerate(truths):
        if i in used:
            continue
        grp = [i] + [j for j in range(i + 1, len(truths)) if j not in used and math.hypot(
            t.x - truths[j].x, t.y - truths[j].y) < merge * (size_px[t.object_id] + size_px[truths[j].object_id]) / 2.0]
        used.update(grp)
        v = 1000.0 * t.speed_px_ms
        b = max(1, speed_bin_of(t.speed_px_ms))
        out.append(ObjectFlow(b, b, t.speed, t.speed, v,
                              sum(truths[j].x for j in grp) / len(grp), sum(truths[j].y for j in grp) / len(grp),
                              t.direction, 0))
    return out


#: the thresholds of recall_by_events_per_edge: events per passing edge (the generator's |log contrast| / C)
EDGE_EVENTS = (1.0, 1.2, 1.5, 2.0)
#: tracking_visible: the tracking metrics again over the sequences whose every object fires at least this
#: many events per passing edge (at 1 and under, an object is seen only through the pixels' threshold
#: mismatch and noise: no tracker can follow what the sensor does not report)
VISIBLE_EDGE_EVENTS = 1.0


def _json_attr(attrs: dict, key: str):
    """attrs[key] as the generator wrote it (a JSON text or the value it decodes to), None if absent or not JSON."""
    v = attrs.get(key) if isinstance(attrs, dict) else None
    if isinstance(v, str):
        try:
            return json.loads(v)
        except json.JSONDecodeError:
            return None
    return v


def _object_count(attrs: dict) -> int:
    """How many objects a generated sequence holds (its ``objects`` attrs), 0 when not known."""
    objs = _json_attr(attrs, "objects")
    return len(objs) if isinstance(objs, list) else 0


def events_per_edge(attrs: dict) -> dict:
    """{object id: events per passing edge} that the generator recorded for a sequence (its
    ``appearance`` attrs: |log contrast| / contrast threshold, `dataset synth`'s randomized
    splits); {} for a recording without them."""
    app = _json_attr(attrs, "appearance")
    objs = app.get("objects") if isinstance(app, dict) else None
    if not isinstance(objs, list):
        return {}
    return {i: float(o["events_per_edge"]) for i, o in enumerate(objs)
            if isinstance(o, dict) and isinstance(o.get("events_per_edge"), (int, float))}


def recall_by_events_per_edge(per_object: list) -> dict:
    """Detection recall over the objects that fire at least E events per passing edge, for each
    E of EDGE_EVENTS (keys ">=E": objects, windows, recall), when every object's figure is known:
    an object at or under the sensor's contrast threshold (about 1 event per edge) is hardly in
    its events at all, and this tells those misses from the pipeline's own. {} otherwise."""
    if not per_object or any(r["events_per_edge"] is None for r in per_object):
        return {}
    out = {}
    for e in EDGE_EVENTS:
        sel = [r for r in per_object if r["events_per_edge"] >= e]
        n = sum(r["windows"] for r in sel)
        out[f">={e}"] = {"objects": len(sel), "windows": n,
                         "recall": sum(r["detected"] for r in sel) / n if n else None}
    return out


def run_split_truth_blobs(config, files, settings, max_windows, gate, merge: float = 1.0) -> dict:
    """CLEAR MOT / IDF1 of the tracker alone on truth_blobs detections (``--truth-blobs``)."""
    from toffe_deploy.errors import InputError
    from toffe_deploy.events.io import open_events
    from toffe_deploy.runtime.pipeline import WindowResult
    from toffe_deploy.runtime.truth import TruthIndex
    from toffe_deploy.tracking import Tracker
    from toffe_deploy.tracking_metrics import TrackingErrors

    track, n_win, n_blob = TrackingErrors(gate), 0, 0
    dt = config.dt_us
    for path in files:
        with open_events(path) as src:
            objs = (src.attrs.get("appearance") or {}).get("objects")
            if not objs:
                raise InputError(path, "no appearance.objects[].size_px in its attrs (generated by dataset synth?)")
            size_px = [float(o["size_px"]) for o in objs]
            truth, t_start = TruthIndex(src.ground_truth), int(src.t_start_us)
            n = min(max_windows, (int(src.t_end_us) - t_start) // dt)
        tracker = Tracker(config, dt, settings)
        track.new_sequence()
        for w in range(n):
            t0 = t_start + w * dt
            gt = truth.window(t0, dt)
            dets = truth_blobs(gt, size_px, config.speed_bin_of_px_ms, merge)
            n_blob += len(dets) < len(gt)
            tracker.update(dets, t0)
            track.add_result(WindowResult(t0, t0 + dt, dets, coasting=tracker.coasting()), gt)
            n_win += 1
    return {"sequences": len(files), "windows": n_win, "windows_with_a_blob": n_blob, "tracking": track.summary()}


def tracker_cost(bundle, events, settings, repeats: int) -> dict:
    """CPU time per window (time.process_time, one pinned core, each window's best of ``repeats``
    passes, the passes of the two pipelines interleaved, which one goes first alternating) of
    Pipeline(track=settings) and Pipeline(track=False) over the recording's windows; wall time
    (time.perf_counter) the same way beside it."""
    import os

    import numpy as np

    from toffe_deploy.events.io import open_events
    from toffe_deploy.runtime.pipeline import Pipeline
    from toffe_deploy.runtime.spikes import SpikeVolume

    os.sched_setaffinity(0, {min(1, os.cpu_count() - 1)})
    cfg = bundle.config
    with open_events(events) as src:
        sensor = tuple(src.sensor_size)
        raw = list(src.iter_windows(cfg.dt_us))
    if not raw:
        from toffe_deploy.errors import InputError

        raise InputError(events, f"no whole window of {cfg.dt_us} us: nothing to time")
    wins = [(t0, SpikeVolume.from_events(ev, t0, cfg.dt_us, cfg.n_bins, sensor)) for t0, ev in raw]
    pipes = {"track": Pipeline(bundle, "cpu", sensor_size=sensor, track=settings),
             "no_track": Pipeline(bundle, "cpu", sensor_size=sensor, track=False)}
    best = {k: np.full(len(wins), np.inf) for k in pipes}
    wall = {k: np.full(len(wins), np.inf) for k in pipes}
    binning = np.full(len(wins), np.inf)     # the window's events to its SpikeVolume, as run does first
    n_obj = 0
    for p in pipes.values():
        p.__enter__()
    try:
        for r in range(repeats):
            for k in (list(pipes) if r % 2 == 0 else list(pipes)[::-1]):
                p = pipes[k]
                p.reset_tracks()
                for i, w in enumerate(wins):
                    a, aw = time.process_time(), time.perf_counter()
                    (res,) = p.process_stream([w])
                    best[k][i] = min(best[k][i], time.process_time() - a)
                    wall[k][i] = min(wall[k][i], time.perf_counter() - aw)
                    n_obj += len(res.objects) if k == "track" else 0
            for i, (t0, ev) in enumerate(raw):
                a = time.process_time()
                SpikeVolume.from_events(ev, t0, cfg.dt_us, cfg.n_bins, sensor)
                binning[i] = min(binning[i], time.process_time() - a)
    finally:
        for p in pipes.values():
            p.close()
    t, n = float(best["track"].mean()), float(best["no_track"].mean())
    tw, nw = float(wall["track"].mean()), float(wall["no_track"].mean())
    b = float(binning.mean())
    return {"windows": len(wins), "objects_per_window": n_obj / repeats / len(wins),
            "tracker_us_per_window": (t - n) * 1e6, "cpu_ms_per_window_binning": b * 1e3,
            "tracker_share_of_window": (t - n) / (n + b),
            "cpu_ms_per_window_track": t * 1e3, "cpu_ms_per_window_no_track": n * 1e3, "tracker_share": t / n - 1.0,
            "wall_ms_per_window_track": tw * 1e3, "wall_ms_per_window_no_track": nw * 1e3,
            "tracker_share_wall": tw / nw - 1.0, "load_average": os.getloadavg()}


def _settings(a):
    """The TrackerConfig of the parsed arguments (ValueError for a bad value)."""
    from toffe_deploy.tracking import TrackerConfig

    return TrackerConfig(gate_px=a.gate, alpha=a.alpha, beta=a.beta, confirm_hits=a.confirm,
                         max_misses=a.max_misses, hysteresis=a.hysteresis, gate_growth=a.gate_growth,
                         birth_gap_px=a.birth_gap, tentative_misses=a.tentative_misses, gate_speed=a.gate_speed,
                         report_misses=a.report_misses, max_occluded=a.max_occluded,
                         shared_keeps_motion=a.shared_keeps_motion, turn_beta=a.turn_beta,
                         max_turn_rad=a.max_turn, merge_px=a.merge, merge_move_px=a.merge_move,
                         shared_gate_grows=a.shared_gate_grows, reid_px=a.reid, reid_ratio=a.reid_ratio,
                         coast_px=a.coast_px, max_coast=a.max_coast, pos_beta=a.pos_beta, pos_min_px=a.pos_min,
                         pos_max_rad=a.pos_max_rad, blob_growth=a.blob_growth, heading_cost_px=a.heading_cost,
                         reid_growth=a.reid_growth, reid_ratio_missed=a.reid_ratio_missed, hidden_px=a.hidden,
                         handover_px=a.handover, handover_reach=a.handover_reach,
                         handover_windows=a.handover_windows, handover_speed_ratio=a.handover_speed_ratio,
                         parting=a.parting, parting_heading_px=a.parting_heading,
                         parting_events_px=a.parting_events, parting_turn_rad=a.parting_turn,
                         coast_turn_rad=a.coast_turn, occluded_px=a.occluded, occluded_travel_px=a.occluded_travel,
                         occluded_min_hits=a.occluded_hits, confirm_at_start=a.confirm_at_start)


def main(argv=None) -> int:
    from toffe_deploy.metrics import GATE_PX
    from toffe_deploy.tracking import TrackerConfig

    d = TrackerConfig()
    ap = OneLineParser(prog="bench_tracking.py", description=__doc__.split("\n\n")[0],
                       formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    ap.add_argument("--bundle", default=str(ROOT / "export"), help="deploy bundle (toffe-deploy export ckpt/)")
    ap.add_argument("--data", type=Path, default=str(ROOT / "data" / "synth"),
                    help="data set directory (toffe-deploy dataset synth)")
    ap.add_argument("--split", default="multi,pairs", help="comma-separated splits")
    ap.add_argument("--max-windows", type=positive_int, default=200, help="windows per sequence from its start")
    ap.add_argument("--limit", type=nonneg_int, default=0, help="first N sequences per split (0: all)")
    ap.add_argument("--gate", type=float, default=d.gate_px, help="the tracker's association gate (px)")
    ap.add_argument("--score-gate", type=positive_float, default=GATE_PX,
                    help="the scoring gate: a hypothesis within it of an object matches (px; eval's, default 20)")
    ap.add_argument("--alpha", type=float, default=d.alpha)
    ap.add_argument("--beta", type=float, default=d.beta)
    ap.add_argument("--confirm", type=int, default=d.confirm_hits)
    ap.add_argument("--max-misses", type=int, default=d.max_misses)
    ap.add_argument("--tentative-misses", type=int, default=d.tentative_misses)
    ap.add_argument("--hysteresis", type=float, default=d.hysteresis)
    ap.add_argument("--gate-growth", type=float, default=d.gate_growth)
    ap.add_argument("--birth-gap", type=float, default=d.birth_gap_px)
    ap.add_argument("--gate-speed", type=float, default=d.gate_speed)
    ap.add_argument("--report-misses", type=int, default=d.report_misses)
    ap.add_argument("--max-occluded", type=int, default=d.max_occluded)
    ap.add_argument("--turn-beta", type=float, default=d.turn_beta, help="turn-rate gain (0: constant velocity)")
    ap.add_argument("--max-turn", type=float, default=d.max_turn_rad, help="largest turn per window (rad)")
    ap.add_argument("--merge", type=float, default=d.merge_px, help="merge_px: pairs of tracks this close may share a blob")
    ap.add_argument("--merge-move", type=float, default=d.merge_move_px,
                    help="merge_move_px: tracks slower than this (px per window) share no blob")
    ap.add_argument("--no-shared-keeps-motion", dest="shared_keeps_motion", action="store_false",
                    help="a blob inside two tracks' gates updates the assigned track's motion too")
    ap.add_argument("--shared-gate-grows", action="store_true",
                    help="a coasting track's grown gate also makes a detection shared (default: its base gate)")
    ap.add_argument("--reid", type=float, default=d.reid_px,
                    help="reid_px: a missed track takes a leftover detection this near (second association; 0: off)")
    ap.add_argument("--reid-ratio", type=float, default=d.reid_ratio,
                    help="reid_ratio: ... only if that many times nearer to it than to any other confirmed track")
    ap.add_argument("--coast-px", type=float, default=d.coast_px,
                    help="coast_px: a confirmed track lives past --max-misses while it has coasted at most this far")
    ap.add_argument("--max-coast", type=int, default=d.max_coast, help="max_coast: ... up to this many misses")
    ap.add_argument("--pos-beta", type=float, default=d.pos_beta,
                    help="pos_beta: gain of the velocity the track's detection positions give (0: coast on v_i)")
    ap.add_argument("--pos-min", type=float, default=d.pos_min_px,
                    help="pos_min_px: slowest track (px per window) that coasts on that velocity")
    ap.add_argument("--pos-max-rad", type=float, default=d.pos_max_rad,
                    help="pos_max_rad: ... if it is within this angle of v_i's direction")
    ap.add_argument("--blob-growth", type=float, default=d.blob_growth,
                    help="blob_growth: gate growth per window in a row a track's detection was a blob")
    ap.add_argument("--heading-cost", type=float, default=d.heading_cost_px,
                    help="heading_cost_px: association cost (px) per radian of direction difference")
    ap.add_argument("--reid-growth", type=float, default=d.reid_growth,
                    help="reid_growth: reid_px grows by this much of a coasting track's travel per miss")
    ap.add_argument("--no-reid-ratio-missed", dest="reid_ratio_missed", action="store_false",
                    help="the re-identification ratio test against every other confirmed track, not only missed ones")
    ap.add_argument("--hidden", type=float, default=d.hidden_px,
                    help="hidden_px: a detection this near a missed confirmed track converging on its taker is a blob "
                         "of both (0: off)")
    ap.add_argument("--handover", type=float, default=d.handover_px,
                    help="handover_px: a new track confirmed this near a lost track's last detection takes its id "
                         "(0: off)")
    ap.add_argument("--handover-reach", type=float, default=d.handover_reach,
                    help="handover_reach: the hand-over radius grows by this much of the lost track's travel per window")
    ap.add_argument("--handover-windows", type=int, default=d.handover_windows,
                    help="handover_windows: a lost track can hand its id over for this many windows since its detection")
    ap.add_argument("--handover-speed-ratio", type=float, default=d.handover_speed_ratio,
                    help="handover_speed_ratio: the most the two tracks' speeds may differ by (a factor)")
    ap.add_argument("--no-parting", dest="parting", action="store_false",
                    help="no parting re-decision (two tracks out of one blob keep the ids the association gave)")
    ap.add_argument("--parting-heading", type=float, default=d.parting_heading_px,
                    help="parting_heading_px: parting cost (px) per radian of direction difference")
    ap.add_argument("--parting-events", type=float, default=d.parting_events_px,
                    help="parting_events_px: parting cost (px) per unit of ln(event ones) difference (0: off)")
    ap.add_argument("--parting-turn", type=float, default=d.parting_turn_rad,
                    help="parting_turn_rad: the most a track's state from before its blob turns when carried to now (rad)")
    ap.add_argument("--no-confirm-at-start", dest="confirm_at_start", action="store_false",
                    help="confirm_at_start off: births in a stream's first --confirm - 1 windows wait for --confirm hits too")
    ap.add_argument("--coast-turn", type=float, default=d.coast_turn_rad,
                    help="coast_turn_rad: the most a track's prediction turns over a run of windows without its own detection (rad)")
    ap.add_argument("--occluded", type=float, default=d.occluded_px,
                    help="occluded_px: a missed track this near a detection another track took is occluded, while it "
                         "has travelled at most --occluded-travel since its last detection (0: off)")
    ap.add_argument("--occluded-travel", type=float, default=d.occluded_travel_px,
                    help="occluded_travel_px: the most a track may have travelled since its last detection for --occluded")
    ap.add_argument("--occluded-hits", type=int, default=d.occluded_min_hits,
                    help="occluded_min_hits: the fewest hits a track needs for --occluded")
    ap.add_argument("--truth-blobs", action="store_true",
                    help="the tracker alone, on the ground truth with touching objects merged (module doc)")
    ap.add_argument("--truth-merge", type=nonneg_float, default=1.0, metavar="F",
                    help="--truth-blobs: merge objects closer than F mean diameters (default 1: touching discs)")
    ap.add_argument("--save-detections", type=Path, metavar="DIR",
                    help="also write each split's per-window detections to DIR/SPLIT.jsonl")
    ap.add_argument("--detections", type=Path, metavar="DIR",
                    help="replay DIR/SPLIT.jsonl (--save-detections) into the tracker instead of running the pipeline")
    ap.add_argument("--json", type=json_output)
    ap.add_argument("--ofpd", action="append", default=[], metavar="KEY=VALUE",
                    help="override a config.ofpd key of the bundle (JSON value), e.g. edge_merge_frac=1.2: a grouping "
                         "or fusion setting tried without exporting a bundle")
    ap.add_argument("--config", action="append", default=[], metavar="KEY=VALUE",
                    help="override a top-level config key of the bundle (JSON value)")
    ap.add_argument("--cost", action="store_true", help="measure the tracker's CPU time per window instead")
    ap.add_argument("--events", type=existing_file, default=str(ROOT / "toffe_deploy" / "samples" / "sample_multi.h5"))
    ap.add_argument("--repeats", type=positive_int, default=5)
    a = ap.parse_args(argv)
    try:
        settings = _settings(a)
        a.ofpd = [key_value(kv, "--ofpd") for kv in a.ofpd]
        a.config = [key_value(kv, "--config") for kv in a.config]
    except ValueError as exc:
        ap.error(str(exc))
    if a.detections is not None and a.truth_blobs:
        ap.error("--detections replays the pipeline's detections; --truth-blobs makes its own: give one")
    if (a.ofpd or a.config) and (a.detections is not None or a.truth_blobs):
        ap.error("--ofpd and --config change the pipeline's detections; --detections and --truth-blobs do not "
                 "run it")
    return guarded("bench_tracking", run, a, settings)


def run(a, settings) -> int:
    """bench_tracking.py with parsed arguments: every input and output checked before any output."""
    from toffe_deploy.deploy.bundle import load_bundle
    from toffe_deploy.errors import InputError
    from toffe_deploy.evaluate import split_files
    from toffe_deploy.fileio import atomic_path, check_outputs, json_text

    def write_json(obj) -> None:
        with atomic_path(a.json) as tmp:
            tmp.write_text(json_text(obj, indent=1) + "\n")

    bundle = load_bundle(a.bundle)
    if a.ofpd or a.config:
        bundle = dataclasses.replace(bundle, config=apply_overrides(bundle.config, a.ofpd, a.config))
    check_outputs(files=[("--json", a.json)], dirs=[("--save-detections", a.save_detections)])
    if a.cost:
        c = tracker_cost(bundle, a.events, settings, a.repeats)
        print(f"{c['windows']} windows, {c['objects_per_window']:.2f} objects per window: CPU per window "
              f"{c['cpu_ms_per_window_track']:.3f} ms with tracking, {c['cpu_ms_per_window_no_track']:.3f} ms without "
              f"(+{100 * c['tracker_share']:.1f} %); wall {c['wall_ms_per_window_track']:.3f} / "
              f"{c['wall_ms_per_window_no_track']:.3f} ms (+{100 * c['tracker_share_wall']:.1f} %); load average "
              + " ".join(f"{v:.2f}" for v in c["load_average"]))
        print(f"tracker {c['tracker_us_per_window']:.1f} us per window: +{100 * c['tracker_share_of_window']:.1f} % of "
              f"the whole window from its events (binning {c['cpu_ms_per_window_binning']:.3f} ms included, as `run` "
              "and bench_run.py time it)")
        if a.json:
            write_json({"settings": dataclasses.asdict(settings), **c})
        return 0
    splits = [s.strip() for s in a.split.split(",") if s.strip()]
    if not splits:
        raise InputError(a.data, f"--split names no split: {a.split!r}")
    files_of = {}
    for split in splits:                                 # every split, and its saved detections, before any output
        files = split_files(Path(a.data), split)
        files_of[split] = files[:a.limit] if a.limit else files
        if a.detections is not None and not (a.detections / f"{split}.jsonl").is_file():
            raise InputError(a.detections / f"{split}.jsonl", "missing file (--detections DIR needs DIR/SPLIT.jsonl "
                                                              "from --save-detections)")
        if a.save_detections is not None:
            check_outputs(files=[("--save-detections", a.save_detections / f"{split}.jsonl")])
    out = {"bundle": a.bundle, "settings": dataclasses.asdict(settings), "max_windows": a.max_windows,
           "score_gate_px": a.score_gate, "overrides": {"ofpd": dict(a.ofpd), "config": dict(a.config)}, "splits": {}}
    if a.truth_blobs:
        out["detections"] = "truth_blobs"
        out["truth_merge"] = a.truth_merge
        print("| split | sequences | windows | windows with a blob | MOTA | IDF1 | ID switches | frag. | misses | FP |\n"
              "|---|---|---|---|---|---|---|---|---|---|")
        for split in splits:
            r = run_split_truth_blobs(bundle.config, files_of[split], settings,
                                      a.max_windows, a.score_gate, a.truth_merge)
            out["splits"][split] = r
            m = r["tracking"]
            print(f"| {split} | {r['sequences']} | {r['windows']} | {r['windows_with_a_blob']} | {m['mota']:.3f} "
                  f"| {m['idf1']:.3f} | {m['id_switches']} | {m['fragmentations']} | {m['misses']} "
                  f"| {m['false_positives']} |", flush=True)
        if a.json:
            write_json(out)
        return 0
    saved_of = {split: None if a.detections is None else
                load_detections(a.detections / f"{split}.jsonl", files_of[split], a.max_windows) for split in splits}
    print("(detection recall: the pipeline's detections per window, one to one within the score gate; MOTA, IDF1, "
          "misses and FP: the tracker's confirmed and listed coasting tracks, CLEAR MOT, so its first windows before "
          "a track is confirmed are misses even where the detection recall is 1)")
    print("| split | sequences | windows | detection recall | MOTA | IDF1 | MOTP (px) | ID switches | frag. | "
          "tracker misses | tracker FP | bin changes det. / track |\n|---|---|---|---|---|---|---|---|---|---|---|---|")
    for split in splits:
        files = files_of[split]
        t = time.perf_counter()
        keep = [] if a.save_detections else None
        r = run_split(bundle, files, settings, a.max_windows, a.score_gate, saved_of[split], keep)
        if keep is not None:
            a.save_detections.mkdir(parents=True, exist_ok=True)
            save_detections(a.save_detections / f"{split}.jsonl", split, files, keep, a.max_windows)
        r["wall_s"] = time.perf_counter() - t
        out["splits"][split] = r
        m = r["tracking"]
        print(f"| {split} | {r['sequences']} | {r['windows']} | {r['recall']:.3f} | {m['mota']:.3f} | {m['idf1']:.3f} "
              f"| {m['motp_px']:.2f} | {m['id_switches']} | {m['fragmentations']} | {m['misses']} "
              f"| {m['false_positives']} | {r['bin_changes_detections']} / {r['bin_changes_tracks']} |", flush=True)
    for split, r in out["splits"].items():
        v = r["tracking_visible"]
        if v["sequences"] and v["sequences"] < r["sequences"]:
            print(f"{split}: the {v['sequences']} of {r['sequences']} sequences whose every object fires >= "
                  f"{VISIBLE_EDGE_EVENTS:g} events per passing edge: MOTA {v['mota']:.3f}, IDF1 {v['idf1']:.3f}, "
                  f"{v['id_switches']} ID switches")
        if r["recall_by_events_per_edge"]:
            print(f"{split}: recall of the objects that fire at least E events per passing edge (the generator's "
                  "|log contrast| / threshold): " + ", ".join(
                      f"E {k[2:]}: {v['recall']:.3f} ({v['objects']} objects)" for k, v in
                      r["recall_by_events_per_edge"].items() if v["recall"] is not None))
    bins = sorted({k for r in out["splits"].values() for k in r["direction_error_deg"]})
    print("\nDirection error per ground-truth speed bin (deg, mean over detections matched to the truth, faint ones left out: their direction is a guess): "
          "the detection's own (this window) / its confirmed track's (tracked, causal: from past windows only; "
          "tracks with no measured motion, speed 0, left out)\n")
    print("| split | " + " | ".join(f"bin {k}" for k in bins) + " |\n|---|" + "---|" * len(bins))

    def cell(e):
        f = (lambda v: "-" if v is None else f"{v:.1f}")
        return f"{f(e['detection'])} / {f(e['tracked_causal'])}" if e else "-"
    for split, r in out["splits"].items():
        print(f"| {split} | " + " | ".join(cell(r["direction_error_deg"].get(k)) for k in bins) + " |")
    if a.json:
        write_json(out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
