"""Evaluation of a checkpoint on held-out sequences: the paper's Table 1 and more.

Per dt: windows [t0, t0 + dt) are sampled evenly from each sequence, binned at full sensor
resolution, run through the reference cascade (OFS stages in Loihi fixed point by default, the
arithmetic the deployment runs; ``ofs="float"`` uses the float weights) and OFPD on every stage
frame holding an object. Ground truth is the window's midpoint truth (window_truth). Windows
with no visible object are skipped; a visible object without a matching prediction is a miss.

Reported: pixE, dirE, speedE (regressed within the bin) and speedE of the paper's bin-only
estimate, all as means over matched objects; detection rate and false positives; the same per
ground-truth speed bin; and for single-object windows the speed separation of every OFS stage
run alone on the window: fires (its closed output keeps >= min_events event pixels) vs should
fire (object speed bin >= k), as precision / recall.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .cascade import close_binary
from .checkpoint import load_checkpoint
from .events.binning import bin_window
from .events.frontend import apply_dense
from .metrics import FlowErrors, SeparationCounts
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
    max_dist_px: float = 64.0
    progress: bool = True


def _sample_starts(t_start: int, t_end: int, dt: int, n: int) -> np.ndarray:
    starts = np.arange(t_start, t_end - dt + 1, dt)
    if starts.size > n:
        starts = starts[np.linspace(0, starts.size - 1, n).round().astype(int)]
    return starts


def evaluate(opts: EvalOptions) -> dict:
    """Run the evaluation; returns a JSON-able dict (see ``format_markdown``)."""
    import torch
    from tqdm import tqdm

    from .dataset.groundtruth import window_truth
    from .events.io import open_events
    from .model.data import find_sequences
    from .model.ofpd import OFPD
    from .model.ofs import OFS
    from .model.reference import fixed_stage_fn, float_stage_fn, ofpd_torch_fn, predict_window, quantize_stages

    ck = load_checkpoint(opts.ckpt)
    cfg = ck.config
    files = find_sequences(opts.data, opts.split)
    if opts.ofs == "fixed":
        run_stage = fixed_stage_fn(quantize_stages(ck.ofs))
    else:
        models = []
        for p in ck.ofs:
            m = OFS(cfg.ofs_in_channels, cfg.ofs_kernel, p["threshold"], p["leak"])
            with torch.no_grad():
                m.conv.weight.copy_(torch.from_numpy(p["weight"]))
            models.append(m.eval())
        run_stage = float_stage_fn(models)
    model = OFPD.from_config(cfg)
    model.load_state_dict({k: torch.from_numpy(v) for k, v in ck.ofpd_state.items()})
    ofpd = ofpd_torch_fn(model.eval())

    results = {"checkpoint": str(opts.ckpt), "trained_dt_us": cfg.dt_us, "split": opts.split, "ofs": opts.ofs,
               "sequences": len(files), "max_windows_per_sequence": opts.max_windows, "per_dt": []}
    for dt in opts.dts:
        errs = FlowErrors(max_dist_px=opts.max_dist_px)
        sep = [SeparationCounts() for _ in range(cfg.n_speed_bins)]
        for path in tqdm(files, desc=f"eval dt={dt}us", unit="seq", disable=not opts.progress):
            with open_events(path) as src:
                gt = src.ground_truth
                if gt is None:
                    from .errors import InputError
                    raise InputError(path, "has no ground truth (needed for evaluation)")
                sensor = src.sensor_size
                if tuple(sensor) != tuple(cfg.sensor_size):
                    from .errors import InputError
                    raise InputError(path, f"sensor size {list(sensor)} differs from the checkpoint's {list(cfg.sensor_size)}")
                for t0 in _sample_starts(src.t_start_us, src.t_end_us, dt, opts.max_windows):
                    truth = window_truth(gt, int(t0), dt)
                    if not truth:
                        continue
                    binned = apply_dense(bin_window(src.read(int(t0), int(t0) + dt), int(t0), dt, cfg.n_bins, sensor,
                                                    dtype=np.uint8), cfg.input_norm)
                    preds, res = predict_window(binned, run_stage, ofpd, cfg)
                    errs.add_window(preds, truth)
                    if len(truth) == 1:
                        inp = binned > 0
                        for k in range(1, cfg.n_speed_bins + 1):
                            spikes = res.spikes[k - 1] if k == cfg.n_speed_bins else run_stage(k, inp)
                            frame = inp & close_binary(spikes.any(axis=0), cfg.mask_kernel)[None, None]
                            sep[k - 1].add(ofpd_io.has_object(frame[None], cfg), truth[0].speed_bin >= k)
        row = {"dt_us": dt, "same_dt_as_training": dt == cfg.dt_us, "all": errs.summary(),
               "per_bin": {str(k): errs.summary(k) for k in range(1, cfg.n_speed_bins + 1)},
               "separation": {str(k): sep[k - 1].as_dict() for k in range(1, cfg.n_speed_bins + 1)}}
        results["per_dt"].append(row)
    return results


def _f(v: float, nd: int = 2) -> str:
    return "-" if v is None or (isinstance(v, float) and math.isnan(v)) else f"{v:.{nd}f}"


def format_markdown(r: dict) -> str:
    """Table 1 style markdown: ours beside the paper's, then per-bin rows and OFS separation."""
    lines = [f"Checkpoint `{r['checkpoint']}` (trained at dt = {r['trained_dt_us']} us), split `{r['split']}`, "
             f"{r['sequences']} sequences, <= {r['max_windows_per_sequence']} windows each, OFS {r['ofs']}.", "",
             "| dt (us) | pixE (px) | dirE (deg) | speedE (m/s) | speedE bin-only (m/s) | detected | false pos. | paper pixE | paper dirE | paper speedE |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for row in sorted(r["per_dt"], key=lambda x: -x["dt_us"]):
        a = row["all"]
        p = PAPER_TABLE1.get(row["dt_us"], (float("nan"),) * 3)
        star = "" if row["same_dt_as_training"] else "*"
        lines.append(f"| {row['dt_us']}{star} | {_f(a['pixE'], 3)} | {_f(a['dirE'], 3)} | {_f(a['speedE'], 3)} | "
                     f"{_f(a['speedE_bin_only'], 3)} | {a['n_matched']}/{a['n_gt']} ({_f(100 * a['detection_rate'], 1)}%) | "
                     f"{a['false_positives']} | {_f(p[0], 3)} | {_f(p[1], 3)} | {_f(p[2], 3)} |")
    if any(not row["same_dt_as_training"] for row in r["per_dt"]):
        lines.append(f"\n\\* evaluated with the weights trained at dt = {r['trained_dt_us']} us.")
    lines += ["", "Per ground-truth speed bin (matched objects; bin acc. = cascade put it in its true bin):", "",
              "| dt (us) | bin | matched | pixE (px) | dirE (deg) | speedE (m/s) | speedE bin-only (m/s) | bin acc. |",
              "|---|---|---|---|---|---|---|---|"]
    for row in sorted(r["per_dt"], key=lambda x: -x["dt_us"]):
        for k, b in row["per_bin"].items():
            lines.append(f"| {row['dt_us']} | {k} | {b['n_matched']} | {_f(b['pixE'])} | {_f(b['dirE'])} | {_f(b['speedE'])} | "
                         f"{_f(b['speedE_bin_only'])} | {_f(b['bin_accuracy'])} |")
    lines += ["", "OFS speed separation (single-object windows, each stage alone: fires vs object bin >= k):", "",
              "| dt (us) | " + " | ".join(f"OFS{k} P / R" for k in sorted(r["per_dt"][0]["separation"])) + " |",
              "|---|" + "---|" * len(r["per_dt"][0]["separation"])]
    for row in sorted(r["per_dt"], key=lambda x: -x["dt_us"]):
        cells = [f"{_f(s['precision'])} / {_f(s['recall'])}" for _k, s in sorted(row["separation"].items())]
        lines.append(f"| {row['dt_us']} | " + " | ".join(cells) + " |")
    return "\n".join(lines)
