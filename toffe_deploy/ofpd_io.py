"""OFPD input/output in numpy, shared by training, export and every runtime target (no torch).

Input (``prepare``): a speed-separated frame (B, 2, H, W) of one stage is cut to an
object-centric crop and pooled:

    c        = centroid of the frame's event pixels (two passes: whole frame, then within the
               crop around the first estimate, so stray events far away barely move it)
    crop     = frame[:, :, cy - S/2 : cy + S/2, cx - S/2 : cx + S/2]     (S = ofpd.crop_px, zero
               outside the sensor)
    x[2b+p]  = mean over each P x P cell of crop[b, p] > 0                (P = ofpd.pool)
    x[2B]    = (x_px of the cell centre) / COORD_SCALE,  x[2B+1] = (y_px of the cell centre) / COORD_SCALE

so C = 2B + 2 channels of (S/P) x (S/P). The two coordinate planes carry where the crop sits on
the sensor; the network reads the crop centre back as their mean and adds its own residual,
so its ``pose`` output is already in full-resolution pixels while all learned features stay
translation invariant (a crop learns far faster than a whole-sensor regression on a 2-core CPU).

Output (``decode``): pose (N, 2) px; direction (N, 2) = (cos, sin) -> atan2, image-plane angle
with y pointing down; speed (N, 1) = ln(speed in m/s), exponentiated and clipped into the
stage's speed bin [lo, min(hi, MAX_SPEED_MPS)] (the OFS cascade already decided the bin; the
head only refines within it). ``speed_bin_mps`` is the paper's bin-only estimate: the
representative speed of stage k.
"""
from __future__ import annotations

from typing import Any

import cv2
import numpy as np

from .config import ToffeConfig

COORD_SCALE = 1000.0       # coordinate planes hold px / 1000 (keeps inputs O(1))
MAX_SPEED_MPS = 150.0      # the data set's programmed speeds stay below 144 m/s

OFPD_DEFAULTS: dict[str, Any] = {
    "crop_px": 128,         # S: crop side in full-resolution pixels
    "pool": 2,              # P: cell side; the network sees (S/P) x (S/P)
    "conv_channels": [16, 32],
    "conv_kernels": [5, 3],
    "hidden": 64,           # FC width shared by the three heads
    "min_events": 12,       # has_object: fewer event pixels than this = no object in the frame
    "dedupe_px": 64,        # report_objects: box half-size (px) around a reported object
}


def ofpd_settings(config: ToffeConfig) -> dict[str, Any]:
    """config.ofpd over the defaults (a checkpoint written by an older version still loads)."""
    s = dict(OFPD_DEFAULTS)
    s.update(config.ofpd or {})
    if s["crop_px"] % s["pool"] != 0:
        raise ValueError(f"ofpd.crop_px {s['crop_px']} must be a multiple of ofpd.pool {s['pool']}")
    return s


def input_shape(config: ToffeConfig) -> tuple[int, int, int]:
    """(C, h, w) of the OFPD input for this config."""
    s = ofpd_settings(config)
    g = s["crop_px"] // s["pool"]
    return 2 * config.n_bins + 2, g, g


def ofpd_param_shapes(config: ToffeConfig) -> dict[str, tuple[int, ...]]:
    """Shapes of the OFPD state dict (the torch module in model/ofpd.py builds exactly these).

    conv1: 2B event planes -> c1, k1, stride 2;  conv2: c1 -> c2, k2, stride 2;  2x2 max pool;
    fc: c2 * (g/8)^2 -> hidden;  heads pose (2), direction (2), speed (1).
    """
    s = ofpd_settings(config)
    c_in, g, _ = input_shape(config)
    c1, c2 = s["conv_channels"]
    k1, k2 = s["conv_kernels"]
    g_out = g // 8
    h = s["hidden"]
    return {
        "conv1.weight": (c1, c_in - 2, k1, k1), "conv1.bias": (c1,),
        "conv2.weight": (c2, c1, k2, k2), "conv2.bias": (c2,),
        "fc.weight": (h, c2 * g_out * g_out), "fc.bias": (h,),
        "pose_head.weight": (2, h), "pose_head.bias": (2,),
        "direction_head.weight": (2, h), "direction_head.bias": (2,),
        "speed_head.weight": (1, h), "speed_head.bias": (1,),
    }


def event_pixels(frames: np.ndarray) -> np.ndarray:
    """(N, B, 2, H, W) -> (N, H, W) bool: pixels with any event in any bin or polarity."""
    return np.asarray(frames).reshape(frames.shape[0], -1, *frames.shape[-2:]).any(axis=1)


def centroid_of_pixels(xs: np.ndarray, ys: np.ndarray, half: int, width: int, height: int) -> tuple[float, float]:
    """Two-pass centroid (x, y) of event pixel coordinates: the mean, then the mean of the pixels
    within ``half`` of it (stray events far away barely move it); sensor centre when empty."""
    if xs.size == 0:
        return (width - 1) / 2.0, (height - 1) / 2.0
    cx, cy = xs.mean(), ys.mean()
    near = (np.abs(xs - cx) < half) & (np.abs(ys - cy) < half)
    if near.any():
        cx, cy = xs[near].mean(), ys[near].mean()
    return float(cx), float(cy)


def _centroid(mask: np.ndarray, half: int) -> tuple[float, float]:
    ys, xs = np.nonzero(mask)
    return centroid_of_pixels(xs, ys, half, mask.shape[1], mask.shape[0])


def _box(cx: float, cy: float, r: float, h: int, w: int) -> np.ndarray:
    ys, xs = np.ogrid[:h, :w]
    return (np.abs(xs - cx) < r) & (np.abs(ys - cy) < r)


def mode_centroid(mask: np.ndarray, r: int, half: int) -> tuple[float, float]:
    """Centroid of the densest cluster of a (H, W) bool mask: seed at the pixel whose
    (2r+1)^2 box holds the most event pixels (first in row-major order on ties), then twice the
    centroid of the pixels in the box |x - cx|, |y - cy| < r around the current estimate (falls
    back to centroid_of_pixels(half) when the box is empty). Box-kernel mean shift: with several
    objects in one frame it lands on one of them, not between them."""
    h, w = mask.shape
    dens = cv2.boxFilter(mask.astype(np.float32), -1, (2 * r + 1, 2 * r + 1), normalize=False,
                         borderType=cv2.BORDER_CONSTANT)
    sy, sx = np.unravel_index(int(np.argmax(dens)), dens.shape)
    ys, xs = np.nonzero(mask)
    cx, cy = float(sx), float(sy)
    for _ in range(2):
        near = (np.abs(xs - cx) < r) & (np.abs(ys - cy) < r)
        if not near.any():
            return centroid_of_pixels(xs, ys, half, w, h)
        cx, cy = float(xs[near].mean()), float(ys[near].mean())
    return cx, cy


def report_objects(pixels: np.ndarray, config: ToffeConfig) -> list[tuple[int, float, float]]:
    """The objects one window reports: [(stage index k-1, cx, cy)], fastest stage first.

    pixels (N, H, W) bool: event pixels of the N stage frames (index k-1 = stage k). Going from
    the fastest stage down, the pixels of frame k outside the boxes |x - cx|, |y - cy| < R
    (R = ofpd.dedupe_px) of the objects found so far are its candidates; while the box around
    their mode_centroid holds >= ofpd.min_events of them, that is an object of speed bin k and
    its box is claimed (several objects of one bin in one frame are reported separately).

    Why: OFS_k fires for speed bin >= k, so an object's bin is the fastest stage that fires on
    it. The cascade's closed mask rarely takes every event of the object; its leftover edges
    reach the slower stages, which would otherwise report the same object again at a wrong
    speed (measured on the test split: bin assignment 92 % with this rule, 57 % when every frame
    reports and the nearest report is matched).
    """
    s = ofpd_settings(config)
    r = int(s["dedupe_px"])
    n, h, w = pixels.shape
    claimed = np.zeros((h, w), dtype=bool)
    out = []
    for i in range(n - 1, -1, -1):                          # fastest stage first; N is tiny
        rem = pixels[i] & ~claimed
        while rem.sum() >= s["min_events"]:                 # one pass per object found
            cx, cy = mode_centroid(rem, r, s["crop_px"] // 2)
            box = _box(cx, cy, r, h, w)
            if (rem & box).sum() < s["min_events"]:
                break
            out.append((i, cx, cy))
            claimed |= box
            rem &= ~box
    return out


def has_object(frames: np.ndarray, config: ToffeConfig) -> np.ndarray:
    """(N,) bool for the N stage frames of ONE window (N, B, 2, H, W), frames[k-1] = stage k as
    in CascadeResult.frames: True for the stages that report an object (report_objects).
    Pass all stages of a window in one call (a single frame is judged on min_events alone)."""
    frames = np.asarray(frames)
    if frames.ndim == 4:
        frames = frames[None]
    keep = np.zeros(frames.shape[0], dtype=bool)
    for i, _cx, _cy in report_objects(event_pixels(frames), config):
        keep[i] = True
    return keep


def merge_frames(frames: np.ndarray, config: ToffeConfig) -> tuple[np.ndarray, np.ndarray]:
    """The objects of ONE window: (stage_k (G,) 1-based, OFPD frames (G, B, 2, H, W)).

    Object j's frame is the events of every stage inside its box (report_objects): all of the
    object's events, whichever stage the cascade's mask gave them to, and none of another
    object's. Feed these to prepare / decode.
    """
    frames = np.asarray(frames) > 0
    objs = report_objects(event_pixels(frames), config)
    r = ofpd_settings(config)["dedupe_px"]
    h, w = frames.shape[-2:]
    every = frames.any(axis=0)
    merged = np.zeros((len(objs),) + frames.shape[1:], dtype=bool)
    for j, (i, cx, cy) in enumerate(objs):
        merged[j] = every & _box(cx, cy, r, h, w)
    return np.array([i + 1 for i, _, _ in objs], dtype=np.int64), merged


def crop_origins(frames: np.ndarray, config: ToffeConfig) -> np.ndarray:
    """(N, 2) int top-left (x0, y0) of each frame's crop on the sensor."""
    s = ofpd_settings(config)
    size = s["crop_px"]
    px = event_pixels(np.asarray(frames))
    out = np.empty((px.shape[0], 2), dtype=np.int64)
    for i in range(px.shape[0]):          # one centroid per frame (N is small: stages x windows)
        cx, cy = _centroid(px[i], size // 2)
        # crop centre x0 + (S - 1) / 2 nearest to the centroid (within half a pixel)
        out[i] = int(np.floor(cx - (size - 1) / 2 + 0.5)), int(np.floor(cy - (size - 1) / 2 + 0.5))
    return out


def prepare(frames: np.ndarray, config: ToffeConfig) -> np.ndarray:
    """(N, B, 2, H, W) bool/uint8 speed-separated frames -> (N, 2B+2, S/P, S/P) float32 (see module doc)."""
    frames = np.asarray(frames)
    if frames.ndim == 4:
        frames = frames[None]
    n, b, c, h, w = frames.shape
    if c != 2 or b != config.n_bins:
        raise ValueError(f"frames must be (N, {config.n_bins}, 2, H, W), got {frames.shape}")
    s = ofpd_settings(config)
    size, pool = s["crop_px"], s["pool"]
    g = size // pool
    origins = crop_origins(frames, config)
    out = np.zeros((n, 2 * b + 2, g, g), dtype=np.float32)
    centres = (np.arange(g) + 0.5) * pool - 0.5          # cell centre in crop pixel units
    for i in range(n):
        x0, y0 = origins[i]
        sx0, sy0 = max(x0, 0), max(y0, 0)
        sx1, sy1 = min(x0 + size, w), min(y0 + size, h)
        crop = np.zeros((b * 2, size, size), dtype=np.float32)
        if sx1 > sx0 and sy1 > sy0:
            crop[:, sy0 - y0:sy1 - y0, sx0 - x0:sx1 - x0] = frames[i, :, :, sy0:sy1, sx0:sx1].reshape(b * 2, sy1 - sy0, sx1 - sx0) > 0
        out[i, :2 * b] = crop.reshape(2 * b, g, pool, g, pool).mean(axis=(2, 4))
        out[i, 2 * b] = ((x0 + centres) / COORD_SCALE)[None, :]
        out[i, 2 * b + 1] = ((y0 + centres) / COORD_SCALE)[:, None]
    return out


def speed_bounds(config: ToffeConfig) -> np.ndarray:
    """(N_bins, 2) [lo, hi] of each bin used to clip the regressed speed."""
    return np.array([[lo, min(hi, MAX_SPEED_MPS)] for lo, hi in config.speed_bins], dtype=np.float64)


def decode(pose: np.ndarray, direction: np.ndarray, speed: np.ndarray, stage_k: np.ndarray,
           config: ToffeConfig) -> dict[str, np.ndarray]:
    """OFPD outputs + 1-based stage per row -> x_px, y_px, direction_rad, speed_mps, speed_bin_mps."""
    pose = np.asarray(pose, dtype=np.float64).reshape(-1, 2)
    direction = np.asarray(direction, dtype=np.float64).reshape(-1, 2)
    speed = np.asarray(speed, dtype=np.float64).reshape(-1)
    k = np.asarray(stage_k, dtype=np.int64).reshape(-1)
    if not (pose.shape[0] == direction.shape[0] == speed.shape[0] == k.shape[0]):
        raise ValueError("pose, direction, speed and stage_k must have the same number of rows")
    if k.size and (k.min() < 1 or k.max() > config.n_speed_bins):
        raise ValueError(f"stage_k must be in 1..{config.n_speed_bins}")
    bounds = speed_bounds(config)[k - 1] if k.size else np.zeros((0, 2))
    reg = np.exp(np.clip(speed, -10.0, 10.0))
    return {
        "x_px": pose[:, 0],
        "y_px": pose[:, 1],
        "direction_rad": np.arctan2(direction[:, 1], direction[:, 0]),
        "speed_mps": np.clip(reg, bounds[:, 0], bounds[:, 1]),
        "speed_bin_mps": np.asarray(config.representative_speeds, dtype=np.float64)[k - 1] if k.size else np.zeros(0),
    }
