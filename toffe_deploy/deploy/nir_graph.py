"""The OFS stages as a NIR graph (Neuromorphic Intermediate Representation, the ``nir`` package).

One graph: ``input`` (C_in, H, W) feeds every stage k as ``stage<k>_conv`` (nir.Conv2d) ->
``stage<k>_lif`` (nir.LIF) -> ``stage<k>_output``. Values are the floats the quantized integers
represent exactly (W = w / s, vth = vth_mant / s, lambda = 1 - dv / 4096), so a NIR consumer
runs what Loihi runs (up to its own arithmetic).

NIR's LIF is continuous time, tau dv/dt = (v_leak - v) + r I. Integrated with one forward-Euler
step of dt = 1 (the usual discretisation of NIR importers) it is
v[t] = (1 - 1/tau) v[t-1] + (r / tau) I[t], so tau = 1 / (1 - lambda) and r = tau give the
paper's v[t] = lambda v[t-1] + I[t]. NIR resets to v_reset and has no reset-by-subtraction
field, and the cascade's masking (closing, inversion) is no NIR node: the graph metadata says
both in words, with the integer parameters as JSON, so nothing is lost.
"""
from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Sequence

import numpy as np

from ..config import ToffeConfig
from ..fixed_point import LoihiOFSParams

MAX_TAU = 1e9   # lambda = 1 (no leak) has tau = infinity; NIR needs a finite number


def lif_tau(leak: float) -> float:
    """tau of NIR's LIF for a discrete leak lambda (see module docstring)."""
    return MAX_TAU if leak >= 1.0 else min(1.0 / (1.0 - leak), MAX_TAU)


def ofs_nir_graph(config: ToffeConfig, ofs: Sequence[LoihiOFSParams]):
    """Build the nir.NIRGraph of all OFS stages (parallel branches from one input)."""
    import nir

    c, h, w = config.ofs_in_channels, config.height, config.width
    nodes = {"input": nir.Input(input_type=np.array([c, h, w]))}
    edges = []
    stage_meta = []
    for k, p in enumerate(ofs, start=1):
        wf, vth, lam = p.float_equivalent()
        pad = p.kernel_size // 2
        tau = lif_tau(lam)
        one = np.ones((1, h, w), dtype=np.float32)
        nodes[f"stage{k}_conv"] = nir.Conv2d(
            input_shape=(h, w), weight=wf.astype(np.float32), stride=1, padding=pad, dilation=1, groups=1,
            bias=np.zeros(1, dtype=np.float32))
        nodes[f"stage{k}_lif"] = nir.LIF(tau=one * np.float32(tau), r=one * np.float32(tau),
                                         v_leak=one * 0.0, v_threshold=one * np.float32(vth),
                                         v_reset=one * 0.0)
        nodes[f"stage{k}_output"] = nir.Output(output_type=np.array([1, h, w]))
        edges += [("input", f"stage{k}_conv"), (f"stage{k}_conv", f"stage{k}_lif"),
                  (f"stage{k}_lif", f"stage{k}_output")]
        stage_meta.append({"stage": k, "weight_int": p.weight.tolist(), "vth_mant": int(p.vth_mant), "dv": int(p.dv),
                           "du": int(p.du), "weight_scale": float(p.weight_scale), "leak": float(lam)})
    metadata = {
        "producer": "toffe-deploy export",
        "model": "TOFFE OFS cascade, one branch per speed bin k (stage<k>_*), k = 1 slowest",
        "reset": "subtraction: v[t] = lambda v[t-1] + I[t] - vth * o[t-1] (paper eq. 1, undecayed, at step t); "
                 "NIR's v_reset field cannot express this, v_reset = 0 is a placeholder",
        "discretisation": "forward Euler, one step dt = 1 per time bin: tau = 1/(1-lambda), r = tau",
        "time_step_us": float(config.dt_us) / config.n_bins,
        "n_bins": int(config.n_bins),
        "input": "binary spikes per polarity channel (count > 0), shape (C_in, H, W) = (2, height, width)",
        "conv_layout": "weight (C_out, C_in, kH, kW) cross-correlation, input_shape (H, W), zero padding K//2",
        "cascade": f"run stage N first; a stage's spikes OR-ed over the window, closed with a {config.mask_kernel}x"
                   f"{config.mask_kernel} square and inverted, mask the next slower stage's input (paper eq. 3-4)",
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
