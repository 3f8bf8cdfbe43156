"""TOFFE inference cascade (paper eq. 3-4), independent of how each OFS stage is computed.

Stages run from the fastest (k = N) down to k = 1. Stage k sees inp_k; its output spikes,
OR-ed over the B time steps, are closed (dilate then erode, square kernel) and inverted:

    mask_k  = Invert(Close(out_k))            (eq. 3)
    inp_k-1 = inp_k * mask_k                  (eq. 4)

The speed-separated frame handed to OFPD for bin k is inp_k restricted to Close(out_k): the
events of objects at speed bin k (faster ones were masked out upstream).
Morphology borders are neutral (OpenCV's default), so objects at the image edge are not eroded.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import cv2
import numpy as np


def close_binary(img: np.ndarray, kernel: int) -> np.ndarray:
    """Morphological closing of a (H, W) binary image with a kernel x kernel square."""
    se = np.ones((kernel, kernel), dtype=np.uint8)
    return cv2.morphologyEx(img.astype(np.uint8), cv2.MORPH_CLOSE, se).astype(bool)


@dataclass
class CascadeResult:
    """Per stage k = 1..N at index k - 1: its input, output spikes, closed output and frame."""

    inputs: list[np.ndarray]     # (B, C, H, W) bool
    spikes: list[np.ndarray]     # (B, H, W) bool
    closed: list[np.ndarray]     # (H, W) bool
    frames: list[np.ndarray]     # (B, C, H, W) bool: inputs[k] & closed[k]


StageFn = Callable[[int, np.ndarray], np.ndarray]
"""run_stage(k, inp_k) -> spikes (B, H, W) bool, for 1-based stage k and input (B, C, H, W)."""


def run_cascade(x: np.ndarray, run_stage: StageFn, n_stages: int, mask_kernel: int = 5) -> CascadeResult:
    """Run the OFS cascade on one window x (B, C, H, W) (nonzero = event)."""
    inp = x > 0
    res = CascadeResult([None] * n_stages, [None] * n_stages, [None] * n_stages, [None] * n_stages)
    for k in range(n_stages, 0, -1):
        spikes = np.asarray(run_stage(k, inp), dtype=bool)
        closed = close_binary(spikes.any(axis=0), mask_kernel)
        res.inputs[k - 1] = inp
        res.spikes[k - 1] = spikes
        res.closed[k - 1] = closed
        res.frames[k - 1] = inp & closed[None, None]
        inp = inp & ~closed[None, None]
    return res
