"""Reference cascade inference (eq. 3-4) for training and evaluation, on numpy windows.

Two OFS stage back-ends plug into ``toffe_deploy.cascade.run_cascade``:
- ``fixed_stage_fn``: the Loihi 2 fixed-point arithmetic (fixed_point.run_ofs_fixed) of the
  quantized stages, i.e. what the deployment computes (default for evaluation);
- ``float_stage_fn``: the trained torch OFS in float (the paper's model before quantization).

Both run a stage only on the bounding box of the input's events grown by K // 2: with zero
state and zero input a LIF neuron never fires, and a pixel's input only reaches K // 2 pixels,
so the result is identical to the full-sensor run at a fraction of the cost.
"""
from __future__ import annotations

from typing import Callable

import numpy as np

from ..cascade import run_cascade
from ..config import ToffeConfig
from ..fixed_point import LoihiOFSParams, quantize_ofs, run_ofs_fixed
from ..metrics import Prediction
from .. import ofpd_io
from ..outline_centre import outline_positions, outline_settings
from ..plane_fit import PlaneFusion, dense_flow
from ..time_surface import dense_history_flow


def quantize_stages(ofs: list[dict], reset: str = "subtract") -> list[LoihiOFSParams]:
    """Checkpoint OFS stages (weight, threshold, leak) -> Loihi fixed-point parameters with the
    config's neuron ``reset``."""
    return [quantize_ofs(p["weight"], p["threshold"], p["leak"], reset) for p in ofs]


def on_event_bbox(run: Callable[[np.ndarray], np.ndarray], inp: np.ndarray, margin: int) -> np.ndarray:
    """Apply run((B, C, h, w) -> (B, h, w)) to the events' bounding box (+margin) of inp (B, C, H, W)."""
    b, _c, h, w = inp.shape
    out = np.zeros((b, h, w), dtype=bool)
    any_px = inp.any(axis=(0, 1))
    rows, cols = np.flatnonzero(any_px.any(axis=1)), np.flatnonzero(any_px.any(axis=0))
    if rows.size == 0:
        return out
    y0, y1 = max(rows[0] - margin, 0), min(rows[-1] + margin + 1, h)
    x0, x1 = max(cols[0] - margin, 0), min(cols[-1] + margin + 1, w)
    out[:, y0:y1, x0:x1] = run(inp[:, :, y0:y1, x0:x1])
    return out


def fixed_stage_fn(stages: list[LoihiOFSParams]):
    """run_stage(k, inp) for run_cascade with the fixed-point arithmetic."""

    def run_stage(k: int, inp: np.ndarray) -> np.ndarray:
        p = stages[k - 1]
        return on_event_bbox(lambda x: run_ofs_fixed(x, p), inp, p.kernel_size // 2)

    return run_stage


def float_stage_fn(models):
    """run_stage(k, inp) for run_cascade with torch OFS models (index k-1), float, no grad."""
    import torch

    def run_stage(k: int, inp: np.ndarray) -> np.ndarray:
        m = models[k - 1]
        margin = m.conv.kernel_size[0] // 2

        def run(x):
            with torch.no_grad():
                s = m(torch.from_numpy(x.astype(np.float32))[:, None])      # (B, 1, C, h, w)
            return s[:, 0, 0].numpy() > 0

        return on_event_bbox(run, inp, margin)

    return run_stage


def ofpd_torch_fn(model):
    """ofpd(x (N, C, h, w) float32) -> (pose, direction, speed) numpy, with a torch OFPD."""
    import torch

    def run(x: np.ndarray):
        with torch.no_grad():
            return tuple(t.numpy() for t in model(torch.from_numpy(x)))

    return run


def window_outputs(binned: np.ndarray, run_stage, ofpd, config: ToffeConfig, recent=None):
    """One window (B, 2, H, W) -> (stage_k (N,), merged frames (N, B, 2, H, W), OFPD pose,
    direction, speed as the network gives them, CascadeResult): predict_window before the
    plane-fit fusion and the decoding (benchmarks/fit_plane_fit.py fits the fusion on these).
    recent: the front end's SupportHistory after this window (ofpd.recent_events;
    events.support.sampled_window_recent gives it)."""
    res = run_cascade(binned, run_stage, config.n_speed_bins, config.mask_kernel, config.ofs_pool)
    ks, merged = ofpd_io.merge_frames(np.stack(res.frames), config, recent)
    if ks.size == 0:
        return ks, merged, None, None, None, res
    pose, direction, speed = ofpd(ofpd_io.prepare(merged, config))
    return ks, merged, pose, direction, speed, res


def predict_window(binned: np.ndarray, run_stage, ofpd, config: ToffeConfig, recent=None, history=None,
                   faint=None):
    """One window (B, 2, H, W) counts -> (list[Prediction], CascadeResult).

    Objects are the report groups of the stage frames (ofpd_io.merge_frames: speed bin = the
    fastest stage that fires, input = the union of the group's frames); one batched OFPD call;
    the plane fit blended into its speed and direction when config.ofpd says so
    (toffe_deploy/plane_fit.py), and slow objects' positions from their outlines over the
    windows before (ofpd.outline_centre; toffe_deploy/outline_centre.py). recent:
    window_outputs'. history: the plane fit's windows up to this one (ofpd.plane_fit_history;
    events.support.sampled_window_history gives both). faint: (faint_objects.FaintDensity, t0)
    for ofpd.faint_objects on consecutive windows (the density takes this window's event pixels,
    ``recent.latest_pixels``, and its objects' ones): the faint objects follow, position only
    (Prediction.measured False), as the Pipeline reports them.
    """
    ks, merged, pose, direction, speed, res = window_outputs(binned, run_stage, ofpd, config, recent)
    if ks.size == 0:
        return _with_faint([], faint, config, recent, (), [], [], []), res
    fusion = PlaneFusion(config)
    speed, direction = fusion.apply(speed, direction, lambda want, k: (
        dense_flow(merged) if k is None else dense_history_flow(merged, history, want, k, fusion.history[2])),
        None if history is None else history.available)
    d = ofpd_io.decode(pose, direction, speed, ks, config)
    outline = outline_settings(config)
    ones = ()
    if faint is not None or (outline is not None and history is not None):
        obj, _b, _c, ys, xs = np.nonzero(merged > 0)
        ones = (obj, xs, ys)
    if outline is not None and history is not None:           # slow objects' positions from their outlines
        d["x_px"], d["y_px"] = outline_positions(outline, history, ones, d["x_px"], d["y_px"],
                                                 d["speed_px_ms"], d["direction_rad"], config.dt_us)
    preds = [Prediction(int(k), float(d["x_px"][i]), float(d["y_px"][i]), float(d["direction_rad"][i]),
                        float(d["speed_mps"][i]), float(d["speed_bin_mps"][i]), float(d["speed_px_ms"][i]))
             for i, k in enumerate(d["speed_bin"].tolist())]
    return _with_faint(preds, faint, config, recent, ones, d["speed_bin"].tolist(), [p.x for p in preds],
                       [p.y for p in preds]), res


def _with_faint(preds: list, faint, config: ToffeConfig, recent, ones, bins, xs, ys) -> list:
    """``preds`` with this window's faint objects appended (``predict_window``'s ``faint``): bin 1
    at its representative speed, the density's drift as direction, measured False."""
    if faint is None:
        return preds
    density, t0 = faint
    fx = density.step(t0, recent.latest_pixels, ones, bins, xs, ys)
    mps = float(config.representative_speeds[0])              # px/ms left NaN: derived from it (Prediction)
    return preds + [Prediction(1, x, y, dr, mps, mps, measured=False)
                    for x, y, dr in zip(fx[0].tolist(), fx[1].tolist(), fx[2].tolist())]
