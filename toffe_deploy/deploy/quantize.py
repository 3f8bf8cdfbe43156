"""Checkpoint OFS stages -> Loihi 2 integers, with the errors the quantization introduces.

The arithmetic and the scale choice are ``toffe_deploy.fixed_point.quantize_ofs``; this module
turns its ValueErrors into one-line InputErrors naming the stage and parameter, refuses values
that quantize to nothing (a threshold whose mantissa would round to 0), and measures

    weight error     max |W - w / s|, and that over max |W| (relative)
    threshold error  |vth - vth_mant / s| / vth
    leak error       |lambda - (1 - dv / 4096)|
"""
from __future__ import annotations

import os
from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np

from ..errors import InputError
from ..fixed_point import LoihiOFSParams, quantize_ofs


@dataclass
class QuantizedOFS:
    """Integer stages (index k-1), a per-stage error report and the clamps as warnings."""

    params: list[LoihiOFSParams]
    report: list[dict[str, Any]]
    warnings: list[str]


def quantize_stages(stages: Sequence[dict[str, Any]], source: str | os.PathLike = "ofs.safetensors",
                    reset: str = "subtract") -> QuantizedOFS:
    """Quantize every stage dict(weight, threshold, leak) with the neuron ``reset`` (config.RESETS);
    InputError(source, ...) if impossible."""
    params, report, warnings = [], [], []
    for k, st in enumerate(stages, start=1):
        w = np.asarray(st["weight"], dtype=np.float64)
        th, leak = float(st["threshold"]), float(st["leak"])
        try:
            p = quantize_ofs(w, th, leak, reset)
        except ValueError as exc:
            raise InputError(source, f"stage{k}: cannot be represented on Loihi 2: {exc}") from None
        wmax = float(np.max(np.abs(w)))
        if th * p.weight_scale < 0.5:
            raise InputError(source, f"stage{k}.threshold {th:.3g} is too small for max |weight| {wmax:.3g}: "
                                     f"its 17-bit mantissa would round to 0 (needs threshold >= {0.5 / p.weight_scale:.3g})")
        if not np.any(p.weight):
            raise InputError(source, f"stage{k}.weight: every weight rounds to 0 at weight scale "
                                     f"{p.weight_scale:.4g} (threshold/weight ratio too large for 17 bits)")
        w_q, th_q, lam_q = p.float_equivalent()
        err_w = float(np.max(np.abs(w - w_q)))
        rep = {
            "stage": k,
            "float": {"threshold": th, "leak": leak, "max_abs_weight": wmax},
            "weight_max_abs_error": err_w,
            "weight_rel_error": err_w / wmax,
            "threshold_rel_error": abs(th - th_q) / th,
            "leak_abs_error": abs(leak - lam_q),
            "clamps": list(p.notes),
        }
        params.append(p)
        report.append(rep)
        warnings.extend(f"stage{k}: {n}" for n in p.notes)
    return QuantizedOFS(params, report, warnings)
