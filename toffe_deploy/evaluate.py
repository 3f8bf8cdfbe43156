"""Evaluation of a checkpoint on held-out sequences: the paper's Table 1 and more.

Per dt: windows [t0, t0 + dt) are sampled evenly from each sequence, binned at full sensor
resolution, run through the reference cascade (OFS stages in Loihi fixed point by default, the
arithmetic the deployment runs; ``ofs="float"`` uses the float weights) and OFPD on every stage
frame holding an object. Ground truth is the window's midpoint truth (window_truth). Every
sampled window counts, those with no visible object too (a prediction there is a false
positive); predictions and objects are matched one-to-one within a 20 px gate (metrics).

Reported: recall, false positives per window, bin accuracy with the confusion matrix (true x
predicted bin); pixE, dirE, speedE (regressed within the bin; also in px/ms) and speedE of the
paper's bin-only estimate, as means over matched objects; the same per ground-truth speed bin;
optionally the same per bucket of a per-sequence attribute (``by``: breakdown.py); and for
single-object windows the speed separation of every OFS stage run alone on the window: fires
(its closed output keeps >= min_events event pixels) vs should fire (object speed bin >= k), as
precision / recall.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .breakdown import Breakdown, attr_value, bucket_labels, bucket_order, numeric_keys
from .cascade import stage_frame
from .checkpoint import load_checkpoint
from .errors import InputError, ToffeError, warn
from .events.support import WindowHistories
from .metrics import GATE_PX, FlowErrors, SeparationCounts
from .tracking_metrics import TrackingErrors
from . import ofpd_io

PAPER_TABLE1 = {5000: (14.135, 25.842, 19.948), 2000: (8.406, 14.345, 16.677), 1000: (6.626, 13.817, 11.867),
                500: (5.355, 10.769, 10.649), 200: (5.404, 24.411, 15.632)}


@dataclass
class EvalOptions:
    ckpt: Path
    data: Path
    dts: tuple[int, ...] = (200, 500, 1000, 2000, 5000)
    split: str = "test"
    max_windows: int = 20
    ofs: str = "fixed"
    gate_px: float = GATE_PX
    by: tuple[Breakdown, ...] = ()
    progress: bool = True
    track_windows: int = 0          # > 0: tracking metrics over this many consecutive windows per sequence
    skip_stream_start: bool = False  # leave out each sequence's first window (no windows before it)


def _sample_starts(t_start: int, t_end: int, dt: int, n: int) -> np.ndarray:
    starts = np.arange(t_start, t_end - dt + 1, dt)
    if starts.size > n:
        starts = starts[np.linspace(0, starts.size - 1, n).round().astype(int)]
    return starts


def track_sequence(src, gt, dt: int, n_windows: int, predict, config, errors, focal=None) -> None:
    """Tracking metrics of one sequence: its first ``n_windows`` consecutive windows of ``dt``
    through ``predict(t0) -> list[Prediction]`` and a tracking.Tracker, each window's confirmed
    and coasting tracks scored against window_truth (tracking_metrics.TrackingErrors ``errors``,
    a new sequence in it)."""
    from .dataset.groundtruth import window_truth
    from .runtime.pipeline import ObjectFlow, WindowResult
    from .tracking import Tracker

    tracker = Tracker(config, dt)
    errors.new_sequence()
    k_mps = config.speed_scale.px_ms_per_mps
    for t0 in range(int(src.t_start_us), min(int(src.t_end_us) - dt + 1, int(src.t_start_us) + n_windows * dt), dt):
        objs = [ObjectFlow(p.stage, p.stage, p.speed_mps, p.speed_bin_mps,
                           1000.0 * (p.speed_px_ms if math.isfinite(p.speed_px_ms) else p.speed_mps * k_mps),
                           p.x, p.y, p.direction_rad, 0, faint=not p.measured) for p in predict(t0)]
        tracker.update(objs, t0)
        errors.add_result(WindowResult(t0, t0 + dt, objs, coasting=tracker.coasting()), window_truth(gt, t0, dt))


def split_files(data: Path, split: str) -> list[Path]:
    """The sequence files of a split: those index.json lists, else DIR/SPLIT/*.h5 (a split
    directory the index does not list); InputError naming the splits there otherwise."""
    from .dataset.build import iter_split_files
    from .model.data import find_sequences

    root = Path(data)
    if not root.is_dir():
        raise InputError(root, "is a file, not a data-set directory (give the directory that holds index.json "
                               "or split folders of .h5 files)" if root.exists() else "data directory does not exist")
    if (root / "index.json").exists() and any(True for _ in iter_split_files(root, split)):
        return find_sequences(root, split)
    files = sorted((root / split).glob("*.h5"))
    if not files:
        have = sorted(d.name for d in root.iterdir() if d.is_dir() and any(d.glob("*.h5")))
        raise InputError(root, f"no sequences in split '{split}' (splits here: {', '.join(have) or 'none'})")
    return files


def reference_models(ckpt: Path, ofs: str = "fixed"):
    """(config, run_stage, ofpd) of a checkpoint as eval runs it: the OFS stages in Loihi fixed
    point (ofs "fixed") or float, the OFPD in torch (model/reference.py's functions)."""
    import torch

    from .model.ofpd import OFPD
    from .model.ofs import OFS
    from .model.reference import fixed_stage_fn, float_stage_fn, ofpd_torch_fn, quantize_stages

    ck = load_checkpoint(ckpt)
    cfg = ck.config
    if ofs == "fixed":
        run_stage = fixed_stage_fn(quantize_stages(ck.ofs, cfg.reset))
    else:
        models = []
        for p in ck.ofs:
            m = OFS(cfg.ofs_in_channels, cfg.ofs_kernel, p["threshold"], p["leak"], reset=cfg.reset)
            with torch.no_grad():
                m.conv.weight.copy_(torch.from_numpy(p["weight"]))
            models.append(m.eval())
        run_stage = float_stage_fn(models)
    model = OFPD.from_config(cfg)
    model.load_state_dict({k: torch.from_numpy(v) for k, v in ck.ofpd_state.items()})
    return cfg, run_stage, ofpd_torch_fn(model.eval())


def evaluate(opts: EvalOptions) -> dict:
    """Run the evaluation; returns a JSON-able dict (see ``format_markdown``)."""
    from tqdm import tqdm

    from .dataset.groundtruth import window_truth
    from .events.io import open_events
    from .model.reference import predict_window
    from .runtime.truth import sequence_focal_px

    cfg, run_stage, ofpd = reference_models(opts.ckpt, opts.ofs)
    short = [dt for dt in opts.dts if dt < cfg.n_bins]
    if short:
        raise ToffeError(f"--dt {short[0]}: a window of {cfg.n_bins} time bins needs at least {cfg.n_bins} us")
    files = split_files(opts.data, opts.split)

    attrs, spans, sensors = [], [], set()
    for path in files:
        with open_events(path) as src:
            attrs.append(src.attrs)
            spans.append(int(src.t_end_us - src.t_start_us))
            sensors.add(tuple(int(v) for v in src.sensor_size))
    need = 2 if opts.skip_stream_start else 1          # windows a sequence must hold to give one
    long = [dt for dt in opts.dts if files and need * dt > max(spans)]
    if long:                    # before the work: a table of nothing, exit 0, was the answer
        raise ToffeError(f"--dt {long[0]}: no sequence of {opts.data}/{opts.split} holds a whole window of "
                         f"{long[0]} us{' after its first' if need == 2 else ''} (the longest spans {max(spans)} us)")
    groups = []                                           # per --by: (found paths, bucket of each file, order)
    for b in opts.by:
        found = [attr_value(a, b.name) for a in attrs]
        if files and not any(found):        # before the work, not after it: an eval can take minutes
            keys = sorted({k for a in attrs for k in numeric_keys(a)})
            raise ToffeError(f"--by {b.name}: no sequence of {opts.data}/{opts.split} has a numeric attribute of "
                             f"that name (they have: {', '.join(keys)})")
        values = [f[1] if f else None for f in found]
        labels = bucket_labels(values, b.edges)
        groups.append((sorted({f[0] for f in found if f}), labels, bucket_order(labels, values)))

    from .faint_objects import FaintDensity, faint_settings

    faint = faint_settings(cfg)
    if faint is not None:
        why = "(the rule needs the windows before and their reported objects)"
        warn(f"{opts.ckpt}: ofpd.faint_objects is applied in the tracking pass over consecutive windows only, not to "
             f"the sampled windows {why}" if opts.track_windows > 0 else
             f"{opts.ckpt}: ofpd.faint_objects is not applied to the sampled windows {why}; --track-windows applies it "
             "over consecutive windows, and benchmarks/bench_tracking.py scores the deployed pipeline with it")
    from .runtime.truth import sequence_focal_px

    focals = {None if f is None else round(f, 3) for f in map(sequence_focal_px, attrs)}
    # what was evaluated on: the data and its camera beside the checkpoint's (a 346x260 checkpoint on
    # 1280x720 data ran without a word of it)
    camera = {"data": str(opts.data), "data_sensor_size": [list(v) for v in sorted(sensors)],
              "data_focal_px": next(iter(focals)) if len(focals) == 1 else None,
              "checkpoint_sensor_size": list(cfg.sensor_size), "checkpoint_focal_px": round(cfg.focal_px, 3)}
    results = {**camera, "checkpoint": str(opts.ckpt), "trained_dt_us": cfg.dt_us, "split": opts.split, "ofs": opts.ofs,
               "faint_objects_applied": False,
               "faint_objects_in_tracking": faint is not None and opts.track_windows > 0, "sequences": len(files),
               "max_windows_per_sequence": opts.max_windows, "gate_px": opts.gate_px,
               "track_windows": opts.track_windows, "skip_stream_start": opts.skip_stream_start, "per_dt": []}

    def new_errors():
        return FlowErrors(gate_px=opts.gate_px, n_bins=cfg.n_speed_bins, pred_scale=cfg.speed_scale)

    for dt in opts.dts:
        # the window's own length: the plane fit, the OFPD decode and the outline's lag convert
        # per-bin and per-window motion to px/ms with config.dt_us (the training dt otherwise:
        # off by the ratio of the two at every other --dt)
        wcfg = dataclasses.replace(cfg, dt_us=int(dt))
        errs = new_errors()
        track_errs = TrackingErrors(opts.gate_px) if opts.track_windows > 0 else None
        by_errs = [{lab: new_errors() for lab in order} for _paths, _labels, order in groups]
        sep = [SeparationCounts() for _ in range(cfg.n_speed_bins)]
        for fi, path in enumerate(tqdm(files, desc=f"eval dt={dt}us", unit="seq", disable=not opts.progress)):
            with open_events(path) as src:
                gt = src.ground_truth
                if gt is None:
                    raise InputError(path, "has no ground truth (needed for evaluation)")
                sensor = src.sensor_size
                focal = sequence_focal_px(attrs[fi])
                starts = _sample_starts(src.t_start_us, src.t_end_us, dt, opts.max_windows)
                if opts.skip_stream_start:         # the same sample less a stream's first window
                    starts = starts[starts > src.t_start_us]
                windows = WindowHistories(src.read, dt, wcfg, sensor, src.t_start_us)
                for t0 in starts:
                    truth = window_truth(gt, int(t0), dt)
                    binned, recent, history = windows(t0)
                    preds, res = predict_window(binned, run_stage, ofpd, wcfg, recent, history)
                    errs.add_window(preds, truth, focal)
                    for g, (_paths, labels, _order) in enumerate(groups):
                        by_errs[g][labels[fi]].add_window(preds, truth, focal)
                    if len(truth) == 1:
                        inp = res.inputs[cfg.n_speed_bins - 1]        # the whole window on the OFS grid
                        for k in range(1, cfg.n_speed_bins + 1):
                            spikes = res.spikes[k - 1] if k == cfg.n_speed_bins else run_stage(k, inp)
                            frame = stage_frame(binned, spikes, cfg.mask_kernel, cfg.ofs_pool)
                            sep[k - 1].add(ofpd_io.has_object(frame[None], wcfg, recent), truth[0].speed_bin >= k)
                if track_errs is not None:
                    stream = WindowHistories(src.read, dt, wcfg, sensor, src.t_start_us)
                    density = None if faint is None else FaintDensity(faint, sensor, dt)

                    def predict(t0, stream=stream, density=density):
                        binned, recent, history = stream(t0)
                        return predict_window(binned, run_stage, ofpd, wcfg, recent, history,
                                              None if density is None else (density, int(t0)))[0]

                    track_sequence(src, gt, dt, opts.track_windows, predict, wcfg, track_errs)
        row = {"dt_us": dt, "same_dt_as_training": dt == cfg.dt_us, "all": errs.summary(),
               "per_bin": {str(k): errs.summary(k) for k in range(1, cfg.n_speed_bins + 1)},
               "separation": {str(k): sep[k - 1].as_dict() for k in range(1, cfg.n_speed_bins + 1)},
               "by": [{"name": b.name, "attribute": paths,
                       "buckets": [{"bucket": lab, "sequences": labels.count(lab), **by_errs[g][lab].summary()}
                                   for lab in order]}
                      for g, (b, (paths, labels, order)) in enumerate(zip(opts.by, groups))]}
        if track_errs is not None:
            row["tracking"] = track_errs.summary()
        results["per_dt"].append(row)
    return results


def _f(v: float, nd: int = 2) -> str:
    return "-" if v is None or (isinstance(v, float) and math.isnan(v)) else f"{v:.{nd}f}"


def _camera_text(r: dict) -> str:
    """``; data D: WxH, focal F px (the checkpoint's: ...)`` for the header; empty for results
    written before eval recorded the data's camera."""
    if "data_sensor_size" not in r:
        return ""
    sizes = " and ".join(f"{w}x{h}" for w, h in r["data_sensor_size"]) or "no sequences"
    f = r.get("data_focal_px")
    ck = r["checkpoint_sensor_size"]
    return (f"; data `{r['data']}`: {sizes}, focal {'mixed' if f is None else f'{f:g} px'}; the checkpoint's "
            f"{ck[0]}x{ck[1]}, {r['checkpoint_focal_px']:g} px")


def format_markdown(r: dict) -> str:
    """Table 1 style markdown: detection (recall, FP per window, bin accuracy) and errors beside the
    paper's, then per-bin rows, the bin confusion matrix, the breakdowns and the OFS separation."""
    rows = sorted(r["per_dt"], key=lambda x: -x["dt_us"])
    lines = [f"Checkpoint `{r['checkpoint']}` (trained at dt = {r['trained_dt_us']} us{_camera_text(r)}), split "
             f"`{r['split']}`, {r['sequences']} sequences, <= {r['max_windows_per_sequence']} windows each"
             f"{' less its first' if r.get('skip_stream_start') else ''}, OFS {r['ofs']}; "
             f"one-to-one matching within {r['gate_px']:g} px.", "",
             "| dt (us) | recall | FP / window | bin acc. | pixE (px) | dirE (deg) | speedE (m/s) | speedE (px/ms) "
             "| speedE bin-only (m/s) | paper pixE | paper dirE | paper speedE |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for row in rows:
        a = row["all"]
        p = PAPER_TABLE1.get(row["dt_us"], (float("nan"),) * 3)
        star = "" if row["same_dt_as_training"] else "*"
        lines.append(f"| {row['dt_us']}{star} | {a['n_matched']}/{a['n_gt']} ({_f(100 * a['recall'], 1)}%) | "
                     f"{_f(a['fp_per_window'], 3)} ({a['false_positives']}/{a['n_windows']}) | {_f(a['bin_accuracy'], 3)} | "
                     f"{_f(a['pixE'], 3)} | {_f(a['dirE'], 3)} | {_f(a['speedE'], 3)} | {_f(a['speedE_px_ms'], 3)} | "
                     f"{_f(a['speedE_bin_only'], 3)} | {_f(p[0], 3)} | {_f(p[1], 3)} | {_f(p[2], 3)} |")
    lines.append("\nspeedE bin-only: the paper's speed estimate, each object at its speed bin's representative "
                 "speed (the OFS stage that fired), not the OFPD's regressed speed of the speedE columns.")
    if any(not row["same_dt_as_training"] for row in rows):
        lines.append(f"\n\\* evaluated with the weights trained at dt = {r['trained_dt_us']} us.")
    lines += ["", "Per ground-truth speed bin (errors over matched objects; bin acc. = cascade put it in its true bin; "
              "FP = unmatched predictions reported in that bin):", "",
              "| dt (us) | bin | objects | recall | FP | pixE (px) | dirE (deg) | speedE (m/s) | speedE (px/ms) "
              "| speedE bin-only (m/s) | bin acc. |",
              "|---|---|---|---|---|---|---|---|---|---|---|"]
    for row in rows:
        for k, b in row["per_bin"].items():
            lines.append(f"| {row['dt_us']} | {k} | {b['n_gt']} | {_f(b['recall'])} | {b['false_positives']} | "
                         f"{_f(b['pixE'])} | {_f(b['dirE'])} | {_f(b['speedE'])} | {_f(b.get('speedE_px_ms'), 3)} | "
                         f"{_f(b['speedE_bin_only'])} | {_f(b['bin_accuracy'])} |")
    lines += ["", "Bin confusion over matched objects (rows: true bin, columns: predicted bin):"]
    for row in rows:
        c = row["all"]["confusion"]
        lines += ["", f"| dt = {row['dt_us']} us | " + " | ".join(f"pred {k}" for k in c["labels"]) + " |",
                  "|---|" + "---|" * len(c["labels"])]
        lines += [f"| true {k} | " + " | ".join(str(v) for v in m) + " |" for k, m in zip(c["labels"], c["matrix"])]
    for g, by in enumerate(rows[0]["by"] if rows else []):
        found = ", ".join(by["attribute"]) or "not found in any sequence"
        lines += ["", f"By `{by['name']}` (sequence attribute: {found}):", "",
                  f"| dt (us) | {by['name']} | sequences | objects | recall | FP / window | bin acc. | pixE (px) "
                  "| dirE (deg) | speedE (m/s) | speedE (px/ms) |",
                  "|---|---|---|---|---|---|---|---|---|---|---|"]
        for row in rows:
            for b in row["by"][g]["buckets"]:
                lines.append(f"| {row['dt_us']} | {b['bucket']} | {b['sequences']} | {b['n_gt']} | {_f(b['recall'])} | "
                             f"{_f(b['fp_per_window'], 3)} | {_f(b['bin_accuracy'])} | {_f(b['pixE'])} | "
                             f"{_f(b['dirE'])} | {_f(b['speedE'])} | {_f(b.get('speedE_px_ms'), 3)} |")
    if any("tracking" in row for row in rows):
        lines += ["", f"Tracking (tracking.Tracker, default settings) over the first {r['track_windows']} consecutive "
                  "windows of each sequence, confirmed and coasting tracks vs the truth within the gate (motmetrics)"
                  f"{', ofpd.faint_objects applied' if r.get('faint_objects_in_tracking') else ''}:", "",
                  "| dt (us) | MOTA | IDF1 | MOTP (px) | ID switches | fragmentations | misses | false positives "
                  "| objects | true tracks | mostly tracked |", "|---|---|---|---|---|---|---|---|---|---|---|"]
        for row in rows:
            t = row.get("tracking")
            if t:
                lines.append(f"| {row['dt_us']} | {_f(t['mota'], 3)} | {_f(t['idf1'], 3)} | {_f(t['motp_px'])} | "
                             f"{t['id_switches']} | {t['fragmentations']} | {t['misses']} | {t['false_positives']} | "
                             f"{t['gt_objects']} | {t['gt_tracks']} | {t['mostly_tracked']} |")
    lines += ["", "OFS speed separation (single-object windows, each stage alone: fires vs object bin >= k):", "",
              "| dt (us) | " + " | ".join(f"OFS{k} P / R" for k in sorted(r["per_dt"][0]["separation"])) + " |",
              "|---|" + "---|" * len(r["per_dt"][0]["separation"])]
    for row in rows:
        cells = [f"{_f(s['precision'])} / {_f(s['recall'])}" for _k, s in sorted(row["separation"].items())]
        lines.append(f"| {row['dt_us']} | " + " | ".join(cells) + " |")
    return "\n".join(lines)
