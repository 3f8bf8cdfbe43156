"""Render accumulated event frames with the ground truth drawn on them (the paper's Fig. 5b),
so a person can check a sequence by eye.

Each panel accumulates one window's events: white background, pixels with more ON than OFF
events red, more OFF blue (saturating at 3 net events). For every visible object at the window's
midpoint (groundtruth.window_truth) it draws the centre (green circle), the motion direction
(arrow, 40 px) and a label "#id b<bin> <speed> m/s". Panels are tiled into one PNG.
"""
from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..fileio import atomic_path
from .groundtruth import window_truth

ARROW_PX = 40


def event_image(events: np.ndarray, sensor_size: tuple[int, int]) -> np.ndarray:
    """(H, W, 3) uint8 BGR image of net event counts per pixel (see module doc)."""
    w, h = sensor_size
    sign = events["p"].astype(np.int64) * 2 - 1
    net = np.bincount(events["y"].astype(np.int64) * w + events["x"], weights=sign, minlength=w * h)
    net = np.clip(net.reshape(h, w) / 3.0, -1.0, 1.0)
    img = np.full((h, w, 3), 255.0)
    on, off = np.maximum(net, 0.0), np.maximum(-net, 0.0)
    img[..., 0] -= 255.0 * on          # ON -> red (B, G down)
    img[..., 1] -= 255.0 * (on + off)
    img[..., 2] -= 255.0 * off         # OFF -> blue (G, R down)
    return img.clip(0, 255).astype(np.uint8)


def draw_truth(img: np.ndarray, truths) -> None:
    """Draw each ObjectTruth (centre, direction arrow, label) onto a BGR image in place."""
    import cv2

    for o in truths:
        c = (int(round(o.x)), int(round(o.y)))
        tip = (int(round(o.x + ARROW_PX * math.cos(o.direction))), int(round(o.y + ARROW_PX * math.sin(o.direction))))
        cv2.circle(img, c, 4, (0, 160, 0), -1, cv2.LINE_AA)
        cv2.arrowedLine(img, c, tip, (0, 160, 0), 2, cv2.LINE_AA, tipLength=0.25)
        cv2.putText(img, f"#{o.object_id} b{o.speed_bin} {o.speed:.1f} m/s", (c[0] + 8, c[1] - 8),
                    cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 1, cv2.LINE_AA)


def window_starts(t_start: int, t_end: int, dt_us: int, n_frames: int, t0_us: int | None,
                  stride_us: int | None) -> list[int]:
    """Window starts: from t0 (default t_start) every stride (default: spread over the span)."""
    first = t_start if t0_us is None else int(t0_us)
    if stride_us is None:
        span = max(0, t_end - dt_us - first)
        stride_us = span // (n_frames - 1) if n_frames > 1 else 0
    return [first + i * int(stride_us) for i in range(n_frames)]


def show_file(path: str | os.PathLike, out: str | os.PathLike, t0_us: int | None = None, dt_us: int = 5000,
              n_frames: int = 4, stride_us: int | None = None, cols: int = 2) -> str:
    """Write a PNG of ``n_frames`` windows of an events file; returns a one-line summary."""
    import cv2

    from ..events.io import open_events

    out = Path(out)
    if out.suffix.lower() != ".png":
        raise InputError(out, "output must be a .png file")
    with open_events(path) as src:
        gt = src.ground_truth
        starts = window_starts(src.t_start_us, src.t_end_us, dt_us, n_frames, t0_us, stride_us)
        panels, n_obj = [], 0
        for t0 in starts:
            ev = src.read(t0, t0 + dt_us)
            img = event_image(ev, src.sensor_size)
            truths = window_truth(gt, t0, dt_us) if gt is not None else []
            n_obj += len(truths)
            draw_truth(img, truths)
            label = f"t = {t0 / 1000:.1f}-{(t0 + dt_us) / 1000:.1f} ms, {ev.shape[0]} events"
            if gt is None:
                label += ", no ground truth"
            cv2.putText(img, label, (8, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.55, (0, 0, 0), 1, cv2.LINE_AA)
            cv2.rectangle(img, (0, 0), (img.shape[1] - 1, img.shape[0] - 1), (128, 128, 128), 1)
            panels.append(img)
    cols = max(1, min(cols, len(panels)))
    rows = -(-len(panels) // cols)
    blank = np.full_like(panels[0], 255)
    panels += [blank] * (rows * cols - len(panels))
    grid = np.vstack([np.hstack(panels[r * cols:(r + 1) * cols]) for r in range(rows)])
    with atomic_path(out, suffix=".png") as tmp:
        if not cv2.imwrite(str(tmp), grid):
            raise InputError(out, "could not write the PNG")
    return f"{len(starts)} windows of {dt_us} us, {n_obj} object truths drawn, {grid.shape[1]}x{grid.shape[0]} px"
