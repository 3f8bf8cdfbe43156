"""The OFS stages as a NIR graph (Neuromorphic Intermediate Representation, the ``nir`` package).

One graph: ``input`` (C_in, H, W) feeds every stage k as ``stage<k>_conv`` (nir.Conv2d) ->
``stage<k>_lif`` (nir.LIF) -> ``stage<k>_output``. Values are the floats the quantized integers
represent exactly (W = w / s, vth = vth_mant / s, lambda = 1 - dv / 4096), so a NIR consumer
runs what Loihi runs (up to its own arithmetic).

NIR's LIF is continuous time, tau dv/dt = (v_leak - v) + r I, tau in seconds. Integrated with
one forward-Euler step of dt = the time bin (dt_us / n_bins, in seconds; metadata
``time_step_s``), as NIR readers do, it is v[t] = (1 - dt/tau) v[t-1] + (dt/tau) r I[t]. So

    tau = dt / (1 - lambda),   r = 1,   conv weight = W * tau / dt = W / (1 - lambda)

give v[t] = lambda v[t-1] + conv(W, s[t]). The threshold is written half a Loihi state unit
above vth, v_threshold = vth + 1 / (128 s): the integer state is a multiple of 1 / (64 s) and
fires when it exceeds vth, i.e. from vth + 1 / (64 s) on, so the midpoint decides every tie the
same way despite the rounding of tau in seconds and of the float weights (readers differ on r: Norse ignores it, snnTorch
rescales its threshold by r dt / tau, so the gain lives in the weights and r = 1). NIR's LIF
resets to v_reset (0) in the step it fires: exactly the reset "zero" neuron, and readers
reproduce a reset-zero bundle's float OFS run one window at a time from rest. NIR has no reset
by subtraction: a "subtract" bundle's graph says so in its metadata (its readers run a
zero-reset network). The cascade's masking (closing, inversion) is no NIR node: the metadata
says it in words, with the integer parameters as JSON, so nothing is lost.
"""
from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Sequence

import numpy as np

from ..config import ToffeConfig
from ..fixed_point import LoihiOFSParams

MAX_TAU = 1e9   # in time steps: lambda = 1 (no leak) has tau = infinity; NIR needs a finite number


def lif_tau(leak: float, dt_s: float = 1.0) -> float:
    """tau (s) of NIR's LIF for a discrete leak lambda per step of dt_s seconds (module docstring)."""
    return dt_s * (MAX_TAU if leak >= 1.0 else min(1.0 / (1.0 - leak), MAX_TAU))


def time_step_s(config: ToffeConfig) -> float:
    """One time bin in seconds: NIR's dt for this graph."""
    return float(config.dt_us) / config.n_bins * 1e-6


NIR_RESET = {
    "zero": "zero: v = v_reset = 0 in the step a neuron fires (NIR's LIF), as the bundle's OFS: NIR readers "
            "reproduce it (float) run one window (n_bins steps) at a time from rest",
    "subtract": "subtraction: v[t] = lambda v[t-1] + I[t] - vth * o[t-1] (paper eq. 1, undecayed, at step t). "
                "NIR's LIF cannot express it: every NIR reader runs v_reset = 0 (a zero reset) and so does "
                "NOT reproduce this bundle; use ofs_loihi.json",
}


def ofs_nir_graph(config: ToffeConfig, ofs: Sequence[LoihiOFSParams]):
    """Build the nir.NIRGraph of all OFS stages (parallel branches from one input)."""
    import nir

    (w, h), c = config.ofs_grid(), config.ofs_in_channels     # the OFS grid (sensor pooled by ofs_pool)
    nodes = {"input": nir.Input(input_type=np.array([c, h, w]))}
    edges = []
    stage_meta = []
    dt = time_step_s(config)
    for k, p in enumerate(ofs, start=1):
        wf, vth, lam = p.float_equivalent()
        pad = p.kernel_size // 2
        tau = lif_tau(lam, dt)
        one = np.ones((1, h, w), dtype=np.float32)
        nodes[f"stage{k}_conv"] = nir.Conv2d(
            input_shape=(h, w), weight=(wf * (tau / dt)).astype(np.float32), stride=1, padding=pad, dilation=1,
            groups=1, bias=np.zeros(1, dtype=np.float32))
        nodes[f"stage{k}_lif"] = nir.LIF(tau=one * np.float32(tau), r=one,
                                         v_leak=one * 0.0,
                                         v_threshold=one * np.float32(vth + 0.5 / (64 * p.weight_scale)),
                                         v_reset=one * 0.0)
        nodes[f"stage{k}_output"] = nir.Output(output_type=np.array([1, h, w]))
        edges += [("input", f"stage{k}_conv"), (f"stage{k}_conv", f"stage{k}_lif"),
                  (f"stage{k}_lif", f"stage{k}_output")]
        stage_meta.append({"stage": k, "weight_int": p.weight.tolist(), "vth_mant": int(p.vth_mant), "dv": int(p.dv),
                           "du": int(p.du), "weight_scale": float(p.weight_scale), "leak": float(lam)})
    metadata = {
        "producer": "toffe-deploy export",
        "model": "TOFFE OFS cascade, one branch per speed bin k (stage<k>_*), k = 1 slowest",
        "reset": NIR_RESET[config.reset],
        "reset_mode": config.reset,
        "reproduces_bundle": config.reset == "zero",
        "discretisation": "forward Euler, one step of time_step_s per time bin: tau = dt / (1 - lambda) s, r = 1, "
                          "conv weights = W / (1 - lambda) (the gain tau / dt); state zero at every window start",
        "time_step_us": float(config.dt_us) / config.n_bins,
        "time_step_s": dt,
        "n_bins": int(config.n_bins),
        "input": "binary spikes per polarity channel (count > 0), shape (C_in, H, W) = (2, height, width) of the "
                 "OFS grid: the sensor OR-pooled over ofs_pool x ofs_pool pixel blocks",
        "ofs_pool": int(config.ofs_pool),
        "sensor_size": [int(config.width), int(config.height)],
        "conv_layout": "weight (C_out, C_in, kH, kW) cross-correlation, input_shape (H, W), zero padding K//2",
        "cascade": f"run stage N first; a stage's spikes OR-ed over the window, closed with a {config.mask_kernel}x"
                   f"{config.mask_kernel} square and inverted, mask the next slower stage's input (paper eq. 3-4); "
                   "each grid cell's mask covers its ofs_pool x ofs_pool sensor pixels",
        "loihi_fixed_point_json": json.dumps(stage_meta),
    }
    return nir.NIRGraph(nodes=nodes, edges=edges, metadata=metadata)


def write_ofs_nir(path: str | os.PathLike, config: ToffeConfig, ofs: Sequence[LoihiOFSParams]) -> Path:
    """nir.write the OFS graph to ``path`` and check that nir.read loads it back unchanged."""
    import nir

    graph = ofs_nir_graph(config, ofs)
    nir.write(str(path), graph)
    back = nir.read(str(path))
    for k, p in enumerate(ofs, start=1):
        got = np.asarray(back.nodes[f"stage{k}_conv"].weight)
        if not np.array_equal(got, graph.nodes[f"stage{k}_conv"].weight):
            raise RuntimeError(f"NIR round trip changed stage{k}'s weights")
    return Path(path)


def simulate_nir_stage(graph, stage: int, window: np.ndarray) -> np.ndarray:
    """What a NIR reader computes for branch ``stage`` of the graph on one window (B, C, H, W),
    from rest: NIR's Conv2d (cross-correlation, zero padding) then its LIF by forward Euler with
    the graph's ``time_step_s``, reset to v_reset in the step it fires. Returns spikes (B, H, W)
    bool. numpy only: the reference the readers (snnTorch, Norse) are checked against."""
    import cv2

    conv, lif = graph.nodes[f"stage{stage}_conv"], graph.nodes[f"stage{stage}_lif"]
    dt = float(graph.metadata["time_step_s"])
    weight = np.asarray(conv.weight, np.float64)
    pad = int(np.atleast_1d(conv.padding)[0])
    tau, r = np.asarray(lif.tau, np.float64)[0], np.asarray(lif.r, np.float64)[0]
    v_leak, v_th = np.asarray(lif.v_leak, np.float64)[0], np.asarray(lif.v_threshold, np.float64)[0]
    v_reset = np.asarray(lif.v_reset, np.float64)[0]
    x = np.asarray(window) > 0
    b, c, h, w = x.shape
    v = np.zeros((h, w))
    out = np.zeros((b, h, w), bool)
    for t in range(b):
        cur = np.zeros((h, w))
        for ch in range(c):
            padded = np.pad(x[t, ch].astype(np.float64), pad)
            cur += cv2.filter2D(padded, cv2.CV_64F, weight[0, ch], borderType=cv2.BORDER_CONSTANT)[pad:pad + h, pad:pad + w]
        v = v + dt / tau * (v_leak - v + r * cur)
        out[t] = v > v_th
        v = np.where(out[t], v_reset, v)
    return out
