"""OFPD input/output in numpy (inner loops compiled: toffe_deploy/compiled.py), shared by
training, export and every runtime target (no torch).

Input (``prepare``): a speed-separated frame (B, 2, H, W) of one object is cut to an
object-centric crop and pooled to g x g cells (g = ofpd.crop_px / ofpd.pool):

    S        = crop side: ofpd.crop_px (crop "fixed") or g * P with P = clip(2^ceil(log2(1.5 *
               extent / g)), pool_min, pool_max) (crop "scaled", extent = the object's
               bounding-box side): the object fills about 2/3 of the crop whatever its size
    c        = centroid of the frame's event pixels (two passes: whole frame, then within the
               crop around the first estimate, so stray events far away barely move it)
    crop     = frame[:, :, cy - S/2 : cy + S/2, cx - S/2 : cx + S/2]     (zero outside the sensor)
    x[2b+p]  = mean over each P x P cell of crop[b, p] > 0                (P = S / g)
    x[2B]    = (x_px of the cell centre) / COORD_SCALE,  x[2B+1] = (y_px of the cell centre) / COORD_SCALE

    x[2B + 0], x[2B + 1] (ofpd.motion "time_cov", the motion planes; absent for "none"):
               per cell, 12 n cov(t, u) / P^2 and 12 n cov(t, v) / P^2 over its n ones, t = b / (B-1) - 1/2
               the time bin, u, v = the position inside the cell in cells (-1/2 .. 1/2)

so C = 2B + 2 (+ 2) channels of g x g. The motion planes say which way time runs inside a
cell: the direction of motion, whatever the contrast sign (a dark object's leading edge is
OFF, a bright one's ON; the time order of an edge's first spikes is the same for both). An
object moves 1-6 px in a 500 us window, inside one cell of P = 4-16 px, so the binned event
planes alone hide it (measured before them: dark objects read 143 deg off, backwards). Every
sum is an integer and the result one float division, so it does not depend on the order of
the ones. The two coordinate planes carry where the crop sits on the
sensor and its cell size: the network reads the crop centre back as their mean and P from
their spacing, and adds its own residual in cells (times P), so its ``pose`` output is already
in full-resolution pixels while all learned features stay translation and scale invariant.

Which objects a window reports (``group_objects_xy``: fastest stage first, each object claims
its pixels, several objects per stage possible; ofpd.grouping "blobs" follows the event blobs,
"boxes" is the fixed +-dedupe_px box of older checkpoints) and each object's frame
(``merge_frames``) are decided here too. All of it is implemented once, on pixel coordinates
(``group_objects_xy``, ``object_masks_xy``, ``crop_origin_xy``, ``prepare_xy``); the dense
functions only extract coordinates (np.nonzero) and call that core, and the cpu runtime
(runtime/ofpd_input.py) calls it on the window's event coordinates without building dense frames.

Output (``decode``): pose (N, 2) px; direction (N, 2) = (cos, sin) -> atan2, image-plane angle
with y pointing down; speed (N, 1) = ln(image-plane speed in px/ms) (speed_unit "px_ms"; the
module regresses ln(cells/ms) and adds ln P) or ln(m/s) ("mps", older checkpoints),
exponentiated; m/s and px/ms convert with config.speed_scale. The reported speed bin
(ofpd.bin_from): "ofs", the cascade's (the fastest stage that fired; the speed is clipped into
it, the paper's rule and that of checkpoints before the motion planes), or "ofpd", the bin of
the regressed speed (clipped only to the bins' overall range). Why "ofpd": one 5x5 LIF layer
reads speed from how many pixels an edge sweeps in its field, which thins at low contrast and
grows with texture; the OFPD sees the whole object and the time order inside each cell (the
motion planes), a measurement of the speed rather than of its footprint. The cascade still
finds and separates the objects; the stage each came from stays in the output as ``ofs_bin``.
``speed_bin_mps`` is the paper's bin-only estimate: the representative speed of stage k.
Before decoding, ofpd.plane_fit_weight > 0 blends the speed of the fast objects with the
velocity of planes fitted to their ones' time surface (toffe_deploy/plane_fit.py).
"""
from __future__ import annotations

import bisect
from dataclasses import dataclass
from typing import Any, Sequence

import cv2
import numpy as np

from .compiled import (blob_objects, box_mean, cell_centres, claimed_by, component_stats, crop_origin, crop_pool,
                       density_groups, fill_input, fill_motion, in_rects, link_components, merge_blobs, two_pass_centroid,
                       union_objects)
from .compiled import in_boxes as in_boxes_compiled
from .config import ToffeConfig

COORD_SCALE = 1000.0       # coordinate planes hold px / 1000 (keeps inputs O(1))
_NO_SCRATCH = np.zeros(0, np.int32)   # compiled.claimed_by without a scratch array
MAX_SPEED_MPS = 150.0      # the data set's programmed speeds stay below 144 m/s
MAX_SPEED_PX_MS = 16.0     # the same cap in px/ms (150 m/s at 5 m seen with 554 px: 16.6 px/ms)

# The OFPD input/output layout. A config.ofpd written before these keys existed (a non-empty
# dict without "grouping") keeps the layout its OFPD was trained on (LEGACY_LAYOUT); a config
# without any OFPD settings, and every OFPD trained from now on, get CURRENT_LAYOUT.
# "stages" (grouping "blobs"): "join", each stage's blobs apart, a slower stage's joining the
# objects reported so far (checkpoints before "union": it keeps their outputs as they were), or
# "union", blobs of all stages' pixels together (blob_objects_xy).
LEGACY_LAYOUT: dict[str, str] = {"grouping": "boxes", "crop": "fixed", "speed_unit": "mps", "motion": "none",
                                 "bin_from": "ofs", "stages": "join"}
CURRENT_LAYOUT: dict[str, str] = {"grouping": "blobs", "crop": "scaled", "speed_unit": "px_ms", "motion": "time_cov",
                                  "bin_from": "ofpd", "stages": "union"}
LAYOUT_CHOICES = {"grouping": ("boxes", "blobs"), "crop": ("fixed", "scaled"), "speed_unit": ("mps", "px_ms"),
                  "motion": ("none", "time_cov"), "bin_from": ("ofs", "ofpd"), "stages": ("join", "union")}
MOTION_PLANES = {"none": 0, "time_cov": 2}     # extra input planes of each ofpd.motion choice

OFPD_DEFAULTS: dict[str, Any] = {
    "crop_px": 128,         # S: crop side in full-resolution pixels (crop "fixed"); S/P = the grid g
    "pool": 4,              # P: cell side; the network sees g x g = (crop_px/pool)^2 cells
    "conv_channels": [16, 32],
    "conv_kernels": [3, 3],
    "hidden": 64,           # FC width shared by the three heads
    "min_events": 12,       # has_object: fewer event pixels than this = no object in the frame
    "dedupe_px": 64,        # grouping "boxes": box half-size (px) around a reported object
    **CURRENT_LAYOUT,
    "link_px": 4,           # grouping "blobs": pixels <= 4 px apart (Chebyshev) are one blob (what a 5x5 closing bridges)
    "merge_frac": 0.2,      # blobs within merge_frac * the larger extent of each other are one object ...
    "edge_merge_frac": 1.5,  # ... or within edge_merge_frac when both are open edges (not surrounding their centroid)
    "split_frac": 0.0,      # stages "union": a group cut at its narrowest into two closed outlines is two objects when
    "split_waist": 0.65,    # >= split_frac * extent apart, cut <= split_waist * width (compiled.split_two); 0 = never
    "split_polarity": 0.0,  # split_frac > 0: a half that does not surround its centroid is an object too when >= this
                            # share of its pixels fired each polarity only, apart (compiled.two_sided); 0 = never
    "closed_apart": False,  # stages "union": two groups that each surround their centroid and hold >= min_events
                            # pixels stay two objects (merge_frac joins them no more: compiled.merge_blobs)
    "recent_events": None,  # stages "union": [r, m, c], a group short of min_events is an object when the event pixels
                            # of the latest K windows (input_support's) in its box grown by r px reach
                            # m + floor(c * box area * their density) (compiled.recent_reaches); None = never
    "faint_objects": None,  # [L, z]: faint slow objects from the event density of the last L windows, z noise
                            # standard deviations above it (toffe_deploy/faint_objects.py); None = never
    "pool_min": 2,          # crop "scaled": P = clip(2^ceil(log2(1.5 * extent / g)), pool_min, pool_max)
    "pool_max": 16,
}


_SETTINGS: dict[int, tuple[ToffeConfig, dict, dict]] = {}   # id(config) -> (config, its ofpd then, settings)


def ofpd_settings(config: ToffeConfig) -> dict[str, Any]:
    """config.ofpd over the defaults (a checkpoint written by an older version still loads, with
    the layout it was trained on: each layout key a non-empty config.ofpd lacks takes its
    LEGACY_LAYOUT value, e.g. "motion": "none" for OFPDs trained before the motion planes).

    Remembered per config object while its ofpd dict stays equal (the cpu runtime asks several
    times per window); a copy is returned, so callers may change it."""
    hit = _SETTINGS.get(id(config))
    if hit is not None and hit[0] is config and hit[1] == (config.ofpd or {}):
        return dict(hit[2])
    s = _ofpd_settings(config)
    if len(_SETTINGS) >= 64:
        _SETTINGS.clear()
    _SETTINGS[id(config)] = (config, dict(config.ofpd or {}), s)
    return dict(s)


def _ofpd_settings(config: ToffeConfig) -> dict[str, Any]:
    given = dict(config.ofpd or {})
    s = dict(OFPD_DEFAULTS)
    if given:
        s.update({k: v for k, v in LEGACY_LAYOUT.items() if k not in given})
    s.update(given)
    from .config import MAX_SENSOR_PIXELS
    # whole numbers (int() downstream took 4.5, true or "12" silently, and 0 or less too): sizes
    # and distances in px within the largest sensor side (4096), min_events a count of one frame's pixels
    for key, hi in (("crop_px", 4096), ("pool", 4096), ("link_px", 4096), ("dedupe_px", 4096), ("pool_min", 4096),
                    ("pool_max", 4096), ("min_events", MAX_SENSOR_PIXELS)):
        if not (isinstance(s[key], int) and not isinstance(s[key], bool) and 1 <= s[key] <= hi):
            raise ValueError(f"ofpd.{key} must be a whole number 1..{hi}, got {s[key]!r}")
    if s["crop_px"] % s["pool"] != 0:
        raise ValueError(f"ofpd.crop_px {s['crop_px']} must be a multiple of ofpd.pool {s['pool']}")
    if s["pool_min"] > s["pool_max"]:
        raise ValueError(f"ofpd.pool_min {s['pool_min']} must not exceed ofpd.pool_max {s['pool_max']}")
    # fractions of an object's extent or width (compiled.merge_blobs, split_two): finite (abs < 1e300
    # fails NaN, inf and a whole number too large for a float alike), not negative; split_waist > 0
    # (split_frac 0 is what turns splitting off)
    for key, strict in (("merge_frac", False), ("edge_merge_frac", False), ("split_frac", False),
                        ("split_waist", True)):
        v = s[key]
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not abs(v) < 1e300 or (v <= 0 if strict else v < 0):
            raise ValueError(f"ofpd.{key} must be a finite number {'>' if strict else '>='} 0, got {v!r}")
    for key, choices in LAYOUT_CHOICES.items():
        if s[key] not in choices:
            raise ValueError(f"ofpd.{key} must be one of {', '.join(choices)}, got {s[key]!r}")
    if float(s["split_frac"]) > 0 and s["stages"] != "union":
        raise ValueError('ofpd.split_frac > 0 needs ofpd.stages "union"')
    pol = s["split_polarity"]
    if isinstance(pol, bool) or not isinstance(pol, (int, float)) or not 0.0 <= pol <= 0.5:
        raise ValueError(f"ofpd.split_polarity must be a number in [0, 0.5], got {pol!r}")
    if float(pol) > 0 and float(s["split_frac"]) <= 0:
        raise ValueError("ofpd.split_polarity > 0 needs ofpd.split_frac > 0 (it relaxes that split's test)")
    if not isinstance(s["closed_apart"], bool):
        raise ValueError(f"ofpd.closed_apart must be true or false, got {s['closed_apart']!r}")
    if s["closed_apart"] and s["stages"] != "union":
        raise ValueError('ofpd.closed_apart needs ofpd.stages "union"')
    if s["recent_events"] is not None:
        check_recent_events(s, config)
    if s["faint_objects"] is not None:
        from .faint_objects import check_faint_objects

        check_faint_objects(s["faint_objects"], config)
    if s["bin_from"] == "ofpd" and s["speed_unit"] != "px_ms":
        raise ValueError('ofpd.bin_from "ofpd" needs ofpd.speed_unit "px_ms"')
    return s


def check_recent_events(s: dict, config: ToffeConfig) -> None:
    """ofpd.recent_events must be three integers r, m, c >= 0 on a "union" grouping whose front
    end keeps the windows before (input_support)."""
    v = s["recent_events"]
    if (not isinstance(v, (list, tuple)) or len(v) != 3
            or not all(isinstance(a, int) and not isinstance(a, bool) and a >= 0 for a in v)):
        raise ValueError(f"ofpd.recent_events must be [r, m, c], three integers >= 0, got {v!r}")
    if s["grouping"] != "blobs" or s["stages"] != "union":
        raise ValueError('ofpd.recent_events needs ofpd.grouping "blobs" and ofpd.stages "union"')
    if getattr(config, "input_support", None) is None:
        raise ValueError("ofpd.recent_events needs input_support (the front end's windows before)")


def recent_args(s: dict, recent) -> tuple[np.ndarray | None, np.ndarray | None]:
    """(counts, rule) as compiled.union_objects takes them for ofpd settings ``s`` and ``recent``
    (an events.support.SupportHistory after this window's front end, or anything with its
    ``counts`` (H * W,) uint8 and ``total``): (None, None) when ofpd.recent_events is off or no
    windows are given (then min_events alone decides, as for a single frame)."""
    rule = s["recent_events"]
    if rule is None or recent is None:
        return None, None
    counts = np.ascontiguousarray(recent.counts, np.uint8).reshape(-1)
    return counts, np.array([*rule, int(recent.total)], np.int64)


def input_shape(config: ToffeConfig) -> tuple[int, int, int]:
    """(C, h, w) of the OFPD input for this config: 2B event planes, the motion planes
    (ofpd.motion), 2 coordinate planes."""
    s = ofpd_settings(config)
    g = s["crop_px"] // s["pool"]
    return 2 * config.n_bins + MOTION_PLANES[s["motion"]] + 2, g, g


def ofpd_param_shapes(config: ToffeConfig) -> dict[str, tuple[int, ...]]:
    """Shapes of the OFPD state dict (the torch module in model/ofpd.py builds exactly these).

    conv1: 2B event planes and the motion planes -> c1, k1, stride 2;  conv2: c1 -> c2, k2, stride 2;  2x2 max pool;
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
    frames = np.asarray(frames)
    return frames.reshape(frames.shape[0], int(np.prod(frames.shape[1:-2])), *frames.shape[-2:]).any(axis=1)


def pixel_polarity(frames: np.ndarray) -> np.ndarray:
    """(N, B, 2, H, W) -> (H, W) int8: the polarities a pixel fired in any frame and bin, bit 1
    for channel 0 and bit 2 for channel 1 (0: none, 3: both), as compiled.frame_pixels gives them."""
    frames = np.asarray(frames) > 0
    per_channel = frames.any(axis=(0, 1))                 # (2, H, W)
    return (per_channel[0].astype(np.int8) | (per_channel[1].astype(np.int8) << 1)).astype(np.int8)


def stage_pixels_of(frames: np.ndarray, config: ToffeConfig) -> list[tuple[np.ndarray, ...]]:
    """The stage pixels group_objects_xy takes, from the N stage frames (N, B, 2, H, W) of one
    window: [(xs, ys)] per stage, with each pixel's polarities as a third array when the
    grouping reads them (ofpd.split_polarity > 0)."""
    pixels = event_pixels(frames)
    xy = [np.nonzero(p)[::-1] for p in pixels]
    if not uses_polarity(ofpd_settings(config)):
        return xy
    pol = pixel_polarity(frames)
    return [(xs, ys, pol[ys, xs]) for xs, ys in xy]


# ---------------------------------------------------------------------------------------------
# The core, on pixel coordinates. The dense API below and the cpu runtime
# (runtime/ofpd_input.py, which keeps a window as event coordinates) both call these, so the
# objects a window reports and each object's OFPD input are defined exactly once.
# Coordinates are integer arrays (int64); every mean below is a float64 sum of integers (exact),
# so results do not depend on the order of the pixels.
# ---------------------------------------------------------------------------------------------

def _box_mean(xs: np.ndarray, ys: np.ndarray, cx: float, cy: float, r: float) -> tuple[int, float, float]:
    """(count, mean x, mean y) of the pixels with |x - cx| < r and |y - cy| < r (``in_boxes``), in
    one compiled pass (compiled.box_mean). Each mean is the exact integer sum divided once by
    the count, bit for bit np.mean's result on these integer coordinates (r = inf: all pixels)."""
    return box_mean(_int64(xs), _int64(ys), float(cx), float(cy), float(r))


def centroid_of_pixels(xs: np.ndarray, ys: np.ndarray, half: int, width: int, height: int) -> tuple[float, float]:
    """Two-pass centroid (x, y) of event pixel coordinates: the mean, then the mean of the pixels
    within ``half`` of it (stray events far away barely move it); sensor centre when empty."""
    return two_pass_centroid(_int64(xs), _int64(ys), float(half), int(width), int(height))


def in_boxes(xs: np.ndarray, ys: np.ndarray, centres, r: float) -> np.ndarray:
    """(G, n) bool: the pixels (xs, ys) inside the box |x - cx| < r and |y - cy| < r of each of
    G objects at centres (G, 2) = (cx, cy), in one compiled pass (compiled.in_boxes)."""
    return in_boxes_compiled(_int64(xs), _int64(ys), np.ascontiguousarray(centres, dtype=np.float64).reshape(-1, 2),
                             float(r))


def _int64(a: np.ndarray) -> np.ndarray:
    """A contiguous int64 view or copy of a coordinate array (what the compiled kernels take)."""
    return np.ascontiguousarray(a, dtype=np.int64)


def _box_count_seed(xs: np.ndarray, ys: np.ndarray, r: int, width: int, height: int) -> tuple[int, int, int]:
    """(max box count, y, x of its first row-major position) over the pixels' bounding box grown
    by r (clipped to the sensor), by a box filter on that rectangle."""
    x0, y0 = max(int(xs.min()) - r, 0), max(int(ys.min()) - r, 0)
    x1, y1 = min(int(xs.max()) + r + 1, width), min(int(ys.max()) + r + 1, height)
    grid = np.zeros((y1 - y0, x1 - x0), dtype=np.float32)
    grid[ys - y0, xs - x0] = 1.0
    # integer counts <= (2r+1)^2 < 2^24: exact in float32, whatever order OpenCV sums in
    dens = cv2.boxFilter(grid, -1, (2 * r + 1, 2 * r + 1), normalize=False, borderType=cv2.BORDER_CONSTANT)
    at = int(np.argmax(dens))
    sy, sx = divmod(at, x1 - x0)
    return int(dens.reshape(-1)[at]), y0 + sy, x0 + sx


def density_seed(xs: np.ndarray, ys: np.ndarray, r: int, width: int, height: int) -> tuple[int, int]:
    """(x, y) of the sensor pixel whose (2r+1)^2 box holds the most of the given unique pixels,
    the first in row-major order on ties ((0, 0) when there are none): the argmax of the dense
    cv2.boxFilter(mask, (2r+1, 2r+1), BORDER_CONSTANT) over the whole sensor, without it.

    The pixels are split into groups separated by gaps > 2r along x, then y, then x... (no box
    holds pixels of two groups, and the groups' bounding boxes grown by r are disjoint), so the
    count at any position is that of at most one group and zero outside the grown boxes:
    - a group whose extent is <= 2r on both axes fits in one box: its best count is all of its
      n pixels, first reached (row-major) at (max(xmax - r, 0), max(ymax - r, 0));
    - any other group is box-filtered on its grown bounding box (row-major order within that
      rectangle is the sensor's), unless its n is below the best count found (it cannot win).
    The answer is the best count, the smallest (y, x) on ties. The argmax may be a pixel
    without an event (between events). Cost follows the pixels, not the sensor, in the usual
    case of compact objects.
    """
    if xs.size == 0:
        return 0, 0
    xs, ys = _int64(xs), _int64(ys)
    best_n, best_key, order, hard = density_groups(xs, ys, int(r), int(width))   # most pixels, smallest y * W + x
    for start, end in sorted(hard.tolist(), key=lambda se: se[0] - se[1]):        # biggest group first
        if end - start < best_n:
            break
        sel = order[start:end]
        n, y, x = _box_count_seed(xs[sel], ys[sel], r, width, height)
        if n > best_n or (n == best_n and y * width + x < best_key):
            best_n, best_key = n, y * width + x
    y, x = divmod(best_key, width)
    return x, y


def mode_centroid_xy(xs: np.ndarray, ys: np.ndarray, r: int, half: int, width: int,
                     height: int) -> tuple[float, float]:
    """Centroid of the densest cluster of unique event pixels (xs, ys) on a (width, height)
    sensor: seed at density_seed, then twice the centroid of the pixels in the box
    |x - cx|, |y - cy| < r around the current estimate (falls back to centroid_of_pixels(half)
    when the box is empty). Box-kernel mean shift: with several objects in one frame it lands on
    one of them, not between them."""
    sx, sy = density_seed(xs, ys, r, width, height)
    cx, cy = float(sx), float(sy)
    for _ in range(2):
        n, nx, ny = _box_mean(xs, ys, cx, cy, r)
        if not n:
            return centroid_of_pixels(xs, ys, half, width, height)
        cx, cy = nx, ny
    return cx, cy


Objects = list[tuple[int, float, float]]


def report_objects_xy(stage_pixels: Sequence[tuple[np.ndarray, np.ndarray]], sensor_size: tuple[int, int],
                      config: ToffeConfig, recent=None) -> Objects:
    """The objects one window reports: [(stage index k-1, cx, cy)], fastest stage first
    (group_objects_xy without the claims)."""
    return group_objects_xy(stage_pixels, sensor_size, config, recent)[0]


def group_objects_xy(stage_pixels: Sequence[tuple[np.ndarray, np.ndarray]], sensor_size: tuple[int, int],
                     config: ToffeConfig, recent=None) -> tuple[Objects, "Claims"]:
    """(objects [(stage index k-1, cx, cy)], claims): the objects one window reports, fastest
    stage first, and which pixels each one claims (its OFPD frame is the events of every stage
    at them: object_masks_xy).

    stage_pixels[k-1] = (xs, ys): the unique event pixels of stage k's frame (any order) on a
    sensor (width, height), or (xs, ys, pol) with each pixel's polarities (``stage_pixels_of``;
    read by ofpd.split_polarity only, which without them splits as if it were 0). Why fastest
    first: OFS_k fires for speed bin >= k, so an object's bin is the fastest stage that fires on
    it. The cascade's closed mask rarely takes every event of the object; its leftover edges
    reach the slower stages, which would otherwise report the same object again at a wrong
    speed (measured on the test split: bin assignment 92 % with this rule, 57 % when every
    frame reports and the nearest report is matched).

    ofpd.grouping "blobs" (blob_objects_xy): objects follow the event blobs, any size, any
    spacing above what the closing bridges. "boxes" (box_objects_xy, checkpoints before it):
    a fixed +-dedupe_px box per object.

    recent: the front end's SupportHistory after this window (ofpd.recent_events: a group short
    of min_events counts the event pixels of the latest windows around it; recent_args).
    """
    w = int(sensor_size[0])
    if ofpd_settings(config)["grouping"] == "blobs":
        return blob_objects_xy(stage_pixels, sensor_size, config, recent)
    return _with_regions(box_objects_xy(stage_pixels, sensor_size, config), w, config)


def group_objects_flat(xs: np.ndarray, ys: np.ndarray, starts: np.ndarray, sensor_size: tuple[int, int],
                       config: ToffeConfig, recent=None, pol=None) -> tuple[Objects, "Claims"]:
    """group_objects_xy of stage pixels given as flat int64 arrays: stage i's are
    xs, ys[starts[i]:starts[i + 1]] (the cpu runtime's form: no per-stage arrays to join);
    pol: their polarities as stage_pixels_of gives them (ofpd.split_polarity), or None."""
    if ofpd_settings(config)["grouping"] == "blobs":
        return _blob_objects_flat(xs, ys, starts, int(sensor_size[0]), config, recent, pol)
    stage_pixels = [(xs[a:b], ys[a:b]) for a, b in zip(starts[:-1].tolist(), starts[1:].tolist())]
    return _with_regions(box_objects_xy(stage_pixels, sensor_size, config), int(sensor_size[0]), config)


def _with_regions(objs: Objects, w: int, config: ToffeConfig) -> tuple[Objects, "Claims"]:
    """Grouping "boxes": the objects and the rectangles they claim."""
    r = float(ofpd_settings(config)["dedupe_px"])
    # |x - c| < r over integers x is floor(c - r) + 1 <= x <= ceil(c + r) - 1
    regions = np.array([[np.floor(cx - r) + 1, np.floor(cy - r) + 1, np.ceil(cx + r) - 1, np.ceil(cy + r) - 1]
                        for _i, cx, cy in objs], dtype=np.int64).reshape(-1, 4)
    return objs, Claims(regions=regions, width=w)


@dataclass(frozen=True)
class Claims:
    """Which pixels each reported object claims: rectangles regions (G, 4) = x_min, y_min,
    x_max, y_max inclusive (grouping "boxes"), or pixel sets: keys (M,) sorted linear pixel ids
    y * width + x and owner (M,) their object (grouping "blobs")."""

    width: int
    regions: np.ndarray | None = None
    keys: np.ndarray | None = None
    owner: np.ndarray | None = None

    def masks(self, xs: np.ndarray, ys: np.ndarray, n_objects: int) -> list[np.ndarray]:
        """(n,) bool per object: the pixels (xs, ys) it claims."""
        return list(self.matrix(xs, ys, n_objects))

    def matrix(self, xs: np.ndarray, ys: np.ndarray, n_objects: int, scratch: np.ndarray | None = None) -> np.ndarray:
        """(G, n) bool: pixel i is claimed by object g (``masks`` as one array, one compiled pass;
        O(n) with an all -1 ``scratch`` of the sensor's size, compiled.new_scratch)."""
        xs, ys = _int64(xs), _int64(ys)
        if self.regions is not None:
            return in_rects(xs, ys, np.ascontiguousarray(self.regions, dtype=np.int64).reshape(-1, 4))
        return claimed_by(self.keys, self.owner, ys * self.width + xs, int(n_objects),
                          _NO_SCRATCH if scratch is None else scratch)


def box_objects_xy(stage_pixels: Sequence[tuple[np.ndarray, np.ndarray]], sensor_size: tuple[int, int],
                   config: ToffeConfig) -> Objects:
    """Grouping "boxes": going from the fastest stage down, the pixels of frame k outside the
    boxes |x - cx|, |y - cy| < R (R = ofpd.dedupe_px) of the objects found so far are its
    candidates; while the box around their mode_centroid_xy holds >= ofpd.min_events of them,
    that is an object of speed bin k and its box is claimed. Objects wider than R are split or
    missed, two closer than R merge: kept for the OFPDs trained on it."""
    s = ofpd_settings(config)
    r, need, half = int(s["dedupe_px"]), s["min_events"], s["crop_px"] // 2
    w, h = int(sensor_size[0]), int(sensor_size[1])
    out: list[tuple[int, float, float]] = []
    for i in range(len(stage_pixels) - 1, -1, -1):          # fastest stage first; N is tiny
        xs, ys = (np.asarray(a, dtype=np.int64) for a in stage_pixels[i])
        if out and xs.size:                                 # drop the claimed boxes, all at once
            free = ~in_boxes(xs, ys, [o[1:] for o in out], r).any(axis=0)
            xs, ys = xs[free], ys[free]
        while xs.size >= need:                              # one pass per object found
            cx, cy = mode_centroid_xy(xs, ys, r, half, w, h)
            box = in_boxes(xs, ys, (cx, cy), r)[0]
            if np.count_nonzero(box) < need:
                break
            out.append((i, cx, cy))
            xs, ys = xs[~box], ys[~box]
    return out


def blobs_xy(xs: np.ndarray, ys: np.ndarray, width: int, config: ToffeConfig
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The candidate objects of one frame's unique pixels: (group (n,) per pixel, -1 for none;
    count (G,) pixels per group; bbox (G, 4) inclusive; closed (G,) whether a group surrounds
    its centroid), groups numbered by their first pixel in row-major order.

    Blobs are the connected components of the pixels linked within ofpd.link_px (the 5x5
    closing of the cascade bridges 4 px gaps: a component is a blob of the closed mask).
    Components with >= ceil(min_events / 4) pixels are joined, closest pairs first
    (compiled.merge_blobs), while they come within edge_merge_frac * the larger extent of each
    other and neither surrounds its centroid yet (open edges, compiled.surrounds: the leading
    and trailing edges of an object, measured on the shipped sample up to 1.0-1.4 of an edge's
    extent apart), else within merge_frac (a whole object joins only pieces close to it, not a
    neighbour's edges); smaller components are specks that join a group they come close to,
    or isolated noise. Two objects of radius r at centre distance 3r whose events close
    around them are r apart > 0.2 * 2r: two groups. Groups below min_events are returned too:
    they may be a reported object's leftovers.
    """
    s = ofpd_settings(config)
    xs, ys = _int64(xs), _int64(ys)
    if xs.size == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 4), np.int64), np.zeros(0, bool)
    labels, n_comp = link_components(xs, ys, int(s["link_px"]), int(width))
    count, _sx, _sy, bbox = component_stats(labels, n_comp, xs, ys)
    need = int(s["min_events"])
    group, gc, gb, gclosed = merge_blobs(labels, count, bbox, xs, ys, float(s["merge_frac"]),
                                         float(s["edge_merge_frac"]), max(1, -(-need // 4)))
    return group[labels], gc, gb, gclosed


def blob_objects_xy(stage_pixels: Sequence[tuple[np.ndarray, np.ndarray]], sensor_size: tuple[int, int],
                    config: ToffeConfig, recent=None) -> tuple[Objects, Claims]:
    """Grouping "blobs" (see group_objects_xy), two ways (ofpd.stages):

    "union" (compiled.union_objects): the pixels of all stage frames form blobs together
    (blobs_xy's rule on their union, then once more on the groups it gives, so that the open
    pieces of one sparse object join as its components did); each group with >= min_events
    pixels is an object of the fastest stage holding >= min_events of them, at its centroid.
    The cascade hands one object's edges to several stages (a disc's sides to stage 4, its
    diagonals to stage 2, what the closed masks missed to stage 1): each stage alone sees open
    pieces, which "join" groups generously (edge_merge_frac), also with a neighbour's; together
    they close around the object, and a neighbour then joins only within merge_frac.
    Measured (benchmarks/detect_diagnose.py, dt 500, appearance split): 29 of 47 false
    positives were pieces of one object reported apart (the four corners of a 140 px square
    on stage 2, its outline on stage 1), and pairs of objects 3-5 radii apart were merged into
    one report between them; see ckpt/README.md for the tables.

    "join" (compiled.blob_objects, checkpoints before "union"): from the fastest stage down,
    each frame's pixels form candidate groups (blobs_xy). A group within merge_frac
    (edge_merge_frac if neither surrounds its centroid) * the larger extent of an object
    already reported (some pixel pair that close: the object's leftover edges on a slower
    stage, or a piece of it) joins that object's pixels. Any other with >= min_events pixels
    is an object of bin k at its centroid.

    An object claims exactly its pixels, of every stage. Objects of radius r at centre distance
    >= 3r stay two when their events close around them (they are r apart, minus their motion,
    > 0.2 * 2r); closer than the closing bridges (<= 4 px) they are one blob, unless
    ofpd.split_frac > 0 ("union" only): then a group cut across its principal axis where it is
    narrowest into two halves that each surround their own centroid, lie >= split_frac * the
    larger half's extent apart and meet in a waist <= split_waist * the narrower one's width
    (compiled.split_two) is two objects, each at its own centroid; with ofpd.split_polarity > 0
    (stage pixels given with their polarities, stage_pixels_of) a half that holds a leading and
    a trailing edge passes for a closed outline (two objects in a row along their motion,
    compiled.two_sided). Measured on the crossing sequences (objects whose paths cross):
    touching outlines are split, while one
    object's separated leading and trailing edges (open halves), a ring's two halves (open) and
    a fast object's smear (as wide at the cut as elsewhere) stay one."""
    pix = [tuple(_int64(a) for a in p[:2]) for p in stage_pixels]
    starts = np.cumsum([0] + [p[0].shape[0] for p in pix]).astype(np.int64)
    xs = np.concatenate([p[0] for p in pix]) if pix else np.zeros(0, np.int64)
    ys = np.concatenate([p[1] for p in pix]) if pix else np.zeros(0, np.int64)
    pol = (np.concatenate([np.asarray(p[2], np.int8) for p in stage_pixels])
           if pix and all(len(p) > 2 for p in stage_pixels) else None)
    return _blob_objects_flat(xs, ys, starts, int(sensor_size[0]), config, recent, pol)


def blob_settings(s: dict) -> tuple[bool, int, float, float, int, int, float, float, float, bool]:
    """(stages "union"?, then link, frac_closed, frac_open, need, min_count as compiled.union_objects /
    blob_objects take them, then split_frac, split_waist, split_polarity, closed_apart, union_objects'
    only) from ofpd_settings ``s``."""
    need = int(s["min_events"])
    return (s["stages"] == "union", int(s["link_px"]), float(s["merge_frac"]), float(s["edge_merge_frac"]), need,
            max(1, -(-need // 4)), float(s["split_frac"]), float(s["split_waist"]), float(s["split_polarity"]),
            bool(s["closed_apart"]))


def uses_polarity(s: dict) -> bool:
    """Whether the grouping of ofpd_settings ``s`` reads each pixel's polarities (split_polarity)."""
    return s["stages"] == "union" and float(s["split_frac"]) > 0 and float(s["split_polarity"]) > 0


def _blob_objects_flat(xs: np.ndarray, ys: np.ndarray, starts: np.ndarray, w: int, config: ToffeConfig,
                       recent=None, pol=None) -> tuple[Objects, Claims]:
    """blob_objects_xy on flat stage pixels (group_objects_flat), in one compiled pass."""
    s = ofpd_settings(config)
    union, *args = blob_settings(s)
    if union:
        if pol is not None and uses_polarity(s):
            pol = np.ascontiguousarray(pol, np.int8)
            if pol.shape != xs.shape:
                raise ValueError(f"pixel polarities {pol.shape} do not match the stage pixels {xs.shape}")
        else:
            pol = None
        stage, cx, cy, _owner, keys, owner = union_objects(xs, ys, starts, w, *args, *recent_args(s, recent), pol)
    else:
        stage, cx, cy, _owner, keys, owner = blob_objects(xs, ys, starts, w, *args[:5])
    objs = list(zip(stage.tolist(), cx.tolist(), cy.tolist()))       # (int, float, float) rows
    return objs, Claims(width=w, keys=keys, owner=owner)


def object_masks_xy(xs: np.ndarray, ys: np.ndarray, objects: Objects, claims: Claims) -> list[np.ndarray]:
    """merge_frames on coordinates: for each reported object, the bool mask of the given pixels
    (a window's ones of every stage frame) it claims (group_objects_xy): all of the object's
    events, whichever stage the cascade's mask gave them to."""
    if not objects:
        return []
    return claims.masks(xs, ys, len(objects))


def crop_size_xy(xs: np.ndarray, ys: np.ndarray, config: ToffeConfig) -> int:
    """Crop side S of an object with unique pixels (xs, ys): crop "fixed": ofpd.crop_px;
    "scaled": g * P with P = clip(2^ceil(log2(1.5 * extent / g)), pool_min, pool_max), extent =
    max(width, height) of the pixels' bounding box, g = crop_px / pool: the object fills about
    two thirds of the crop whatever its size, and the network still sees g x g cells."""
    s = ofpd_settings(config)
    if s["crop"] == "fixed":
        return int(s["crop_px"])
    g = s["crop_px"] // s["pool"]
    extent = 0 if xs.size == 0 else max(int(xs.max()) - int(xs.min()), int(ys.max()) - int(ys.min())) + 1
    return int(g * crop_pool(extent, g, int(s["pool_min"]), int(s["pool_max"])))


def crop_origin_xy(xs: np.ndarray, ys: np.ndarray, sensor_size: tuple[int, int], config: ToffeConfig
                   ) -> tuple[int, int, int]:
    """(x0, y0, S): the crop of one frame with unique event pixels (xs, ys): side S
    (crop_size_xy), top-left with the crop centre x0 + (S - 1) / 2 nearest to the two-pass
    centroid (within half a pixel)."""
    size = crop_size_xy(xs, ys, config)
    x0, y0 = crop_origin(_int64(xs), _int64(ys), size, int(sensor_size[0]), int(sensor_size[1]))
    return x0, y0, size


def coordinate_planes(origins: np.ndarray, g: int) -> tuple[np.ndarray, np.ndarray]:
    """(x (N, g), y (N, g)) cell-centre coordinates / COORD_SCALE of crops at origins (N, 3) =
    (x0, y0, S): x0 + (i + 0.5) P - 0.5 with P = S / g. The network reads the crop centre as
    their mean and the cell size P from their spacing."""
    return cell_centres(np.ascontiguousarray(origins, dtype=np.float64).reshape(-1, 3), int(g), COORD_SCALE)


def prepare_xy(ones: Sequence[tuple[np.ndarray, np.ndarray, np.ndarray]], origins: np.ndarray,
               config: ToffeConfig) -> np.ndarray:
    """The OFPD input (N, C, g, g) float32 (input_shape) of N frames given as their ones.

    ones[i] = (xs, ys, ch): the (unique) ones of frame i, ch = 2 b + polarity; origins[i] =
    crop_origin_xy of its event pixels (x0, y0, S). x[2b+p, cell] = #ones of channel 2b+p in
    the crop cell / P^2 (P = S / g: the mean of P x P binary pixels, one float32 division of an
    exact count), zero elsewhere; the coordinate planes as in coordinate_planes. The counts are
    one compiled pass over the ones (compiled.fill_input).
    """
    n = len(ones)
    obj = np.repeat(np.arange(n, dtype=np.int64), [len(o[0]) for o in ones])
    xs, ys, ch = (np.concatenate([o[i] for o in ones]).astype(np.int64, copy=False) if n else np.zeros(0, np.int64)
                  for i in range(3))
    return prepare_flat(obj, xs, ys, ch, origins, n, config)


def prepare_flat(obj: np.ndarray, xs: np.ndarray, ys: np.ndarray, ch: np.ndarray, origins: np.ndarray, n: int,
                 config: ToffeConfig) -> np.ndarray:
    """prepare_xy of n frames whose ones are given as flat arrays: one (xs, ys, ch) of frame obj
    each (int64, any order)."""
    c, g, _ = input_shape(config)
    b = config.n_bins
    out = np.zeros((n, c, g, g), dtype=np.float32)
    if n == 0:
        return out
    origins = np.ascontiguousarray(np.asarray(origins, dtype=np.int64).reshape(n, 3))
    obj, xs, ys, ch = (np.ascontiguousarray(a, dtype=np.int64) for a in (obj, xs, ys, ch))
    fill_input(out, obj, xs, ys, ch, origins, c - 2, COORD_SCALE)      # event planes (ch < 2B) and coordinates
    if c - 2 > 2 * b:
        fill_motion(out, obj, xs, ys, ch, origins, b, 2 * b)
    return out


# ---------------------------------------------------------------------------------------------
# The dense API (N, B, 2, H, W): coordinates out of the frames (np.nonzero), then the core.
# ---------------------------------------------------------------------------------------------

def mode_centroid(mask: np.ndarray, r: int, half: int) -> tuple[float, float]:
    """mode_centroid_xy of the event pixels of a (H, W) bool mask."""
    ys, xs = np.nonzero(mask)
    return mode_centroid_xy(xs, ys, r, half, mask.shape[1], mask.shape[0])


def report_objects(pixels: np.ndarray, config: ToffeConfig, recent=None) -> list[tuple[int, float, float]]:
    """report_objects_xy of pixels (N, H, W) bool, the event pixels of the N stage frames of one
    window (index k-1 = stage k): [(stage index k-1, cx, cy)], fastest stage first."""
    n, h, w = pixels.shape
    return report_objects_xy([np.nonzero(p)[::-1] for p in pixels], (w, h), config, recent)


def has_object(frames: np.ndarray, config: ToffeConfig, recent=None) -> np.ndarray:
    """(N,) bool for the N stage frames of ONE window (N, B, 2, H, W), frames[k-1] = stage k as
    in CascadeResult.frames: True for the stages that report an object (report_objects).
    Pass all stages of a window in one call (a single frame is judged on min_events alone)."""
    frames = np.asarray(frames)
    if frames.ndim == 4:
        frames = frames[None]
    keep = np.zeros(frames.shape[0], dtype=bool)
    h, w = frames.shape[-2:]
    for i, _cx, _cy in report_objects_xy(stage_pixels_of(frames, config), (w, h), config, recent):
        keep[i] = True
    return keep


def merge_frames(frames: np.ndarray, config: ToffeConfig, recent=None) -> tuple[np.ndarray, np.ndarray]:
    """The objects of ONE window: (stage_k (G,) 1-based, OFPD frames (G, B, 2, H, W)).

    Object j's frame is the events of every stage inside its box (report_objects,
    object_masks_xy): all of the object's events, whichever stage the cascade's mask gave them
    to, and none of another object's. Feed these to prepare / decode. recent: group_objects_xy's.
    """
    frames = np.asarray(frames) > 0
    h, w = frames.shape[-2:]
    objs, claims = group_objects_xy(stage_pixels_of(frames, config), (w, h), config, recent)
    every = np.flatnonzero(frames.any(axis=0))             # the window's ones, (b, c, y, x) linear
    ys, xs = np.divmod(every % (h * w), w)
    merged = np.zeros((len(objs), int(np.prod(frames.shape[1:]))), dtype=bool)
    for j, m in enumerate(object_masks_xy(xs, ys, objs, claims)):
        merged[j, every[m]] = True
    return (np.array([i + 1 for i, _, _ in objs], dtype=np.int64),
            merged.reshape((len(objs),) + frames.shape[1:]))


def crop_origins(frames: np.ndarray, config: ToffeConfig) -> np.ndarray:
    """(N, 3) int (x0, y0, S): top-left and side of each frame's crop on the sensor (crop_origin_xy)."""
    px = event_pixels(np.asarray(frames))
    out = np.empty((px.shape[0], 3), dtype=np.int64)
    for i in range(px.shape[0]):          # one centroid per frame (N is small: stages x windows)
        ys, xs = np.nonzero(px[i])
        out[i] = crop_origin_xy(xs, ys, (px.shape[2], px.shape[1]), config)
    return out


def prepare(frames: np.ndarray, config: ToffeConfig) -> np.ndarray:
    """(N, B, 2, H, W) bool/uint8 speed-separated frames -> (N, C, g, g) float32 (see module doc)."""
    frames = np.asarray(frames)
    if frames.ndim == 4:
        frames = frames[None]
    n, b, c, h, w = frames.shape
    if c != 2 or b != config.n_bins:
        raise ValueError(f"frames must be (N, {config.n_bins}, 2, H, W), got {frames.shape}")
    ones = []
    for i in range(n):
        bb, cc, ys, xs = np.nonzero(frames[i] > 0)
        ones.append((xs, ys, bb * 2 + cc))
    return prepare_xy(ones, crop_origins(frames, config), config)


def speed_bounds(config: ToffeConfig) -> np.ndarray:
    """(N_bins, 2) [lo, hi] m/s of each bin used to clip a speed regressed in m/s (speed_unit "mps")."""
    return np.array([[lo, min(hi, MAX_SPEED_MPS)] for lo, hi in config.speed_bins], dtype=np.float64)


def speed_bounds_px_ms(config: ToffeConfig) -> np.ndarray:
    """(N_bins, 2) [lo, hi] px/ms of each bin (config.speed_bins_px_ms, the top one capped at
    MAX_SPEED_PX_MS) used to clip a speed regressed in px/ms (speed_unit "px_ms")."""
    return np.array([[lo, min(hi, MAX_SPEED_PX_MS)] for lo, hi in config.speed_bins_px_ms], dtype=np.float64)


def speed_target(speed_px_ms: np.ndarray, config: ToffeConfig, speed_mps: np.ndarray | None = None) -> np.ndarray:
    """The OFPD speed output a training sample should give: ln(px/ms) (speed_unit "px_ms"; the
    module adds ln P to its head, which so regresses ln(cells/ms)) or ln(m/s) ("mps"), floored
    at the slowest bin's lower edge / 2."""
    if ofpd_settings(config)["speed_unit"] == "px_ms":
        return np.log(np.maximum(np.asarray(speed_px_ms, dtype=np.float64), config.speed_bins_px_ms[0][0] / 2))
    v = config.speed_scale.to_mps(np.asarray(speed_px_ms, dtype=np.float64)) if speed_mps is None else speed_mps
    return np.log(np.maximum(np.asarray(v, dtype=np.float64), 0.5))


def decode(pose: np.ndarray, direction: np.ndarray, speed: np.ndarray, stage_k: np.ndarray,
           config: ToffeConfig) -> dict[str, np.ndarray]:
    """OFPD outputs + 1-based stage per row -> x_px, y_px, direction_rad, speed_px_ms, speed_mps,
    speed_bin (the reported 1-based bin), speed_bin_mps (its representative speed), speed_clipped
    (bool: the regressed speed lay outside the clip range below, so the speed sits at its edge).

    speed_unit "px_ms": speed = ln(image-plane px/ms), exponentiated and clipped into the
    stage's bin in px/ms (speed_bounds_px_ms); speed_mps = config.speed_scale.to_mps of it.
    "mps": speed = ln(m/s), clipped into the bin in m/s; speed_px_ms = speed_scale.to_px_ms.
    bin_from "ofpd" (px_ms only): speed_bin = the bin of the regressed px/ms, the speed clipped
    to [lower edge of bin 1, upper edge of bin N] instead of the stage's bin.
    """
    return Decoder(config)(pose, direction, speed, stage_k)


class Decoder:
    """``decode`` with the config's settings, bin edges and camera worked out once: the cpu
    runtime decodes every window, and building them (ofpd_settings, speed_bounds_px_ms) cost
    more than the arithmetic. ``Decoder(config)(pose, direction, speed, stage_k)`` is decode;
    ``columns`` gives the same values as Python lists (the runtime's per-window form).

    Only exp and atan2 run in numpy (its float64 kernels are the reference; libm's may differ
    in the last bit); the clipping, the bin search and the unit factors are IEEE scalar
    operations, the same in Python as in numpy, done per row: a window has a handful of
    objects, where one numpy call costs more than the row's arithmetic."""

    def __init__(self, config: ToffeConfig):
        s = ofpd_settings(config)
        self.n_speed_bins = config.n_speed_bins
        self.mode = ("ofpd" if s["bin_from"] == "ofpd" else "px_ms") if s["speed_unit"] == "px_ms" else "mps"
        self.bounds = speed_bounds(config) if self.mode == "mps" else speed_bounds_px_ms(config)
        self.lower = np.ascontiguousarray(self.bounds[1:, 0])
        self.scale = config.speed_scale
        self.px_ms_per_mps = self.scale.px_ms_per_mps           # speed_scale.to_mps / to_px_ms's factor
        self.representative = np.asarray(config.representative_speeds, dtype=np.float64)
        self._bounds = [tuple(b) for b in self.bounds.tolist()]
        self._lower = self.lower.tolist()
        self._representative = self.representative.tolist()

    def __call__(self, pose: np.ndarray, direction: np.ndarray, speed: np.ndarray, stage_k: np.ndarray
                 ) -> dict[str, np.ndarray]:
        c = self.columns(pose, direction, speed, stage_k)
        return {name: np.array(c[name], dtype=dtype) for name, dtype in _DECODED}

    def columns(self, pose: np.ndarray, direction: np.ndarray, speed: np.ndarray, stage_k: np.ndarray
                ) -> dict[str, list]:
        """decode's result as one list per key (float, int, bool)."""
        # float32 rows as they are: tolist gives the same Python floats as a float64 copy would
        pose = np.asarray(pose)
        xy = (pose if pose.dtype in _FLOAT_DTYPES else pose.astype(np.float64)).reshape(-1, 2).T.tolist()   # [xs, ys]
        direction = np.asarray(direction, dtype=np.float64).reshape(-1, 2)
        speed = np.asarray(speed, dtype=np.float64).reshape(-1)
        ks = np.asarray(stage_k, dtype=np.int64).reshape(-1).tolist()
        if not (len(xy[0]) == direction.shape[0] == speed.shape[0] == len(ks)):
            raise ValueError("pose, direction, speed and stage_k must have the same number of rows")
        if ks and (min(ks) < 1 or max(ks) > self.n_speed_bins):
            raise ValueError(f"stage_k must be in 1..{self.n_speed_bins}")
        # np.minimum(np.maximum(...)) is np.clip (NaN kept) in two ufunc calls; numpy's exp on the
        # contiguous float64 array (its kernel, not libm's: the reference)
        reg = np.exp(np.minimum(np.maximum(speed, -10.0), 10.0)).tolist()
        f = self.px_ms_per_mps
        v_px, v_mps, clipped, bins = [], [], [], []
        if self.mode == "ofpd":
            lo, hi = self._bounds[0][0], self._bounds[-1][1]
            for r in reg:
                v = _clip(r, lo, hi)
                v_px.append(v)
                v_mps.append(v / f)                              # speed_scale.to_mps
                clipped.append(v != r)
                # searchsorted(lower, v, "right") + 1, in 1..N (a NaN sorts after every edge: bin N)
                bins.append(bisect.bisect_right(self._lower, v) + 1)
        else:
            bins = ks
            for r, k in zip(reg, ks):
                lo, hi = self._bounds[k - 1]
                v = _clip(r, lo, hi)
                clipped.append(v != r)
                if self.mode == "px_ms":
                    v_px.append(v)
                    v_mps.append(v / f)                          # speed_scale.to_mps
                else:
                    v_mps.append(v)
                    v_px.append(v * f)                           # speed_scale.to_px_ms
        rep = self._representative
        return {"x_px": xy[0], "y_px": xy[1],
                "direction_rad": np.arctan2(direction[:, 1], direction[:, 0]).tolist(),
                "speed_px_ms": v_px, "speed_mps": v_mps, "speed_bin": bins, "speed_clipped": clipped,
                "speed_bin_mps": [rep[k - 1] for k in bins]}


_FLOAT_DTYPES = (np.dtype(np.float32), np.dtype(np.float64))

#: decode's keys and the dtypes of its arrays
_DECODED = (("x_px", np.float64), ("y_px", np.float64), ("direction_rad", np.float64), ("speed_px_ms", np.float64),
            ("speed_mps", np.float64), ("speed_bin", np.int64), ("speed_clipped", bool), ("speed_bin_mps", np.float64))


def _clip(v: float, lo: float, hi: float) -> float:
    """np.minimum(np.maximum(v, lo), hi) (np.clip) of one float, NaN kept: no comparison with a NaN is true."""
    m = lo if v < lo else v
    return hi if m > hi else m
