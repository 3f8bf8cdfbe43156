"""TOFFE inference cascade (paper eq. 3-4), independent of how each OFS stage is computed.

Stages run from the fastest (k = N) down to k = 1. Stage k sees inp_k; its output spikes,
OR-ed over the B time steps, are closed (dilate then erode, square kernel) and inverted:

    mask_k  = Invert(Close(out_k))            (eq. 3)
    inp_k-1 = inp_k * mask_k                  (eq. 4)

The speed-separated frame handed to OFPD for bin k is inp_k restricted to Close(out_k): the
events of objects at speed bin k (faster ones were masked out upstream).
Morphology borders are neutral (OpenCV's default), so objects at the image edge are not eroded.

With ``pool`` p > 1 (ToffeConfig.ofs_pool) the stages run on a coarser grid, and the sensor-grid
window x only meets them through two maps:

    inp_N      = Pool_p(x)        cell (Y, X) fires where any pixel of its p x p block fires
    frame_k    = x_k & Up_p(closed_k),   x_k-1 = x_k & ~Up_p(closed_k)   (x_N = x)

Up_p repeats a cell over its block. Since Up_p(closed_k) is constant on each block,
Pool_p(x_k) = inp_k: the stages see exactly the masked cascade of eq. 3-4 on the pooled window,
while the frames (what OFPD sees) keep every sensor pixel. p = 2 quarters the neurons, which puts
the four 640x480 stages on one Loihi 2 chip.
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

    inputs: list[np.ndarray]     # (B, C, H', W') bool, on the OFS grid (H' = ceil(H / pool))
    spikes: list[np.ndarray]     # (B, H', W') bool
    closed: list[np.ndarray]     # (H', W') bool
    frames: list[np.ndarray]     # (B, C, H, W) bool, on the sensor grid: x_k & Up(closed[k])


StageFn = Callable[[int, np.ndarray], np.ndarray]
"""run_stage(k, inp_k) -> spikes (B, H, W) bool, for 1-based stage k and input (B, C, H, W)."""


def pool_any(x: np.ndarray, pool: int) -> np.ndarray:
    """(..., H, W) -> (..., ceil(H / p), ceil(W / p)) bool: a cell fires where any pixel of its
    p x p block does (the last row / column of blocks may be partial)."""
    x = np.asarray(x) > 0
    if pool == 1:
        return x
    h, w = x.shape[-2:]
    hp, wp = -(-h // pool), -(-w // pool)
    if (hp * pool, wp * pool) != (h, w):
        pad = [(0, 0)] * (x.ndim - 2) + [(0, hp * pool - h), (0, wp * pool - w)]
        x = np.pad(x, pad)
    return x.reshape(*x.shape[:-2], hp, pool, wp, pool).any(axis=(-3, -1))


def unpool(mask: np.ndarray, pool: int, hw: tuple[int, int]) -> np.ndarray:
    """(..., H', W') -> (..., H, W): each cell repeated over its p x p block, cropped to (H, W)."""
    if pool == 1:
        return np.asarray(mask)
    up = np.repeat(np.repeat(np.asarray(mask), pool, axis=-2), pool, axis=-1)
    return up[..., :hw[0], :hw[1]]


def run_cascade(x: np.ndarray, run_stage: StageFn, n_stages: int, mask_kernel: int = 5,
                pool: int = 1) -> CascadeResult:
    """Run the OFS cascade on one window x (B, C, H, W) (nonzero = event), its stages on the grid
    pooled by ``pool`` (module docstring)."""
    xk = np.asarray(x) > 0
    hw = xk.shape[-2:]
    inp = pool_any(xk, pool)
    res = CascadeResult([None] * n_stages, [None] * n_stages, [None] * n_stages, [None] * n_stages)
    for k in range(n_stages, 0, -1):
        spikes = np.asarray(run_stage(k, inp), dtype=bool)
        closed = close_binary(spikes.any(axis=0), mask_kernel)
        res.inputs[k - 1] = inp
        res.spikes[k - 1] = spikes
        res.closed[k - 1] = closed
        up = unpool(closed, pool, hw)[None, None]
        res.frames[k - 1] = xk & up
        xk = xk & ~up
        inp = inp & ~closed[None, None]
    return res


def stage_frame(x: np.ndarray, spikes: np.ndarray, mask_kernel: int, pool: int = 1) -> np.ndarray:
    """The frame a stage alone would hand OFPD: x (B, C, H, W) & Up(Close(any_t spikes))."""
    x = np.asarray(x) > 0
    closed = close_binary(np.asarray(spikes).any(axis=0), mask_kernel)
    return x & unpool(closed, pool, x.shape[-2:])[None, None]
