"""Render accumulated event frames with the ground truth drawn on them (the paper's Fig. 5b),
so a person can check a sequence by eye.

Each panel shows one window's events and, for every visible object at the window's midpoint
(groundtruth.window_truth), its dashed outline (shape and size from the file's attrs), motion
direction (thin arrow, hue = direction) and a label "#id b<bin> <speed> m/s" beside it: the
drawing style of ``run --render`` (render.draw), dark or light theme. Panels are tiled into one
PNG.
"""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..fileio import atomic_path
from .groundtruth import window_truth


def window_starts(t_start: int, t_end: int, dt_us: int, n_frames: int, t0_us: int | None,
                  stride_us: int | None) -> list[int]:
    """Window starts: from t0 (default t_start) every stride (default: spread over the span)."""
    first = t_start if t0_us is None else int(t0_us)
    if stride_us is None:
        span = max(0, t_end - dt_us - first)
        stride_us = span // (n_frames - 1) if n_frames > 1 else 0
    return [first + i * int(stride_us) for i in range(n_frames)]


def show_file(path: str | os.PathLike, out: str | os.PathLike, t0_us: int | None = None, dt_us: int = 5000,
              n_frames: int = 4, stride_us: int | None = None, cols: int = 2, theme: str = "dark") -> str:
    """Write a PNG of ``n_frames`` windows of an events file; returns a one-line summary."""
    import cv2

    from ..events.io import open_events
    from ..render import draw
    from ..render.truth import TruthShapes

    th = draw.theme_of(theme)
    out = Path(out)
    if out.suffix.lower() != ".png":
        raise InputError(out, "output must be a .png file")
    with open_events(path) as src:
        gt = src.ground_truth
        shapes = TruthShapes(src.attrs)
        w, h = src.sensor_size
        scale, unit = draw.frame_scale((w, h)), draw.unit_px((w, h))
        if t0_us is not None and not src.t_start_us <= t0_us < src.t_end_us:    # it drew blank frames, exit 0
            raise InputError(path, f"--t0-us {t0_us} is outside the recording: it spans "
                                   f"[{src.t_start_us}, {src.t_end_us}) us")
        starts = window_starts(src.t_start_us, src.t_end_us, dt_us, n_frames, t0_us, stride_us)
        panels, n_obj = [], 0
        for t0 in starts:
            ev = src.read(t0, t0 + dt_us)
            img = draw.event_image(ev["y"].astype(np.int64) * w + ev["x"], ev["p"] == 1, (w, h), th, scale)
            truths = shapes.marks(window_truth(gt, t0, dt_us)) if gt is not None else []
            n_obj += len(truths)
            label = f"t = {t0 / 1000:.1f}-{(t0 + dt_us) / 1000:.1f} ms, {ev.shape[0]} events"
            if gt is None:
                label += ", no ground truth"
            draw.compose(img, (), truths, scale=scale, unit=unit, theme=th, header=label, truth_labels=True)
            cv2.rectangle(img, (0, 0), (img.shape[1] - 1, img.shape[0] - 1), (128, 128, 128), 1)
            panels.append(img)
    cols = max(1, min(cols, len(panels)))
    rows = -(-len(panels) // cols)
    blank = np.empty_like(panels[0])
    blank[:] = th.bg
    panels += [blank] * (rows * cols - len(panels))
    grid = np.vstack([np.hstack(panels[r * cols:(r + 1) * cols]) for r in range(rows)])
    with atomic_path(out, suffix=".png") as tmp:
        if not cv2.imwrite(str(tmp), grid):
            raise InputError(out, "could not write the PNG")
    return f"{len(starts)} windows of {dt_us} us, {n_obj} object truths drawn, {grid.shape[1]}x{grid.shape[0]} px"
