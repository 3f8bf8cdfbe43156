"""Synthetic high-speed object sequences: specs, event generation and ground truth.

A sequence is a static background (uniform grey, optionally lightly textured) seen by the
pinhole camera (camera.py), with one or more planar objects (shapes.py) facing the camera and
moving on closed trajectories (trajectories.py). The scene is sampled every ``sample_us``
(50 us = 20,000 samples/s, as the paper's simulated DAVIS) and fed to the DVS emulator (dvs.py).

Only the pixels that can change are rendered: for a chunk of samples, the box covering the
object at the sample before the chunk and at every sample in it, and within it only the band
around the object's edge that the edge can sweep during the chunk. The signed distances of
the shapes are 1-Lipschitz in the centre, so a pixel whose distance d0 at the sample before the
chunk has |d0| > 0.5 + (path of the centre during the chunk) + K |radius change| keeps its
coverage (0 or 1) all chunk; K bounds |d sdf / d radius| near the object (module code). Pixels
the refractory period holds pending are rendered too (DVSEmulator.pending). So the emulation is
exact (identical to rendering whole frames, tested) while the cost scales with the object's
perimeter, not the sensor or the object's area. Overlapping boxes are merged.

Ground truth per object per sample (the interface of events/fmt_toffe): t, object_id, x, y
(projected centre, px), direction = atan2(dv/dt, du/dt) (rad, y down), speed = |dP/dt| (m/s,
3-D), speed_bin, visible (centre inside the sensor and in front), speed_px_ms = hypot(du/dt,
dv/dt) / 1000 (image-plane speed of the projected centre, px/ms) and depth_m (object Z, m).
speed_bin is the bin of the image-plane speed under the *reference* configuration
(``ToffeConfig().speed_bin_of_px_ms``: bins stated in m/s at 5 m with 554.26 px): an event
camera sees image-plane motion only, so that is what the OFS can separate.
"""
from __future__ import annotations

import dataclasses
import hashlib
import json
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..config import ToffeConfig
from ..events.core import EVENT_DTYPE
from ..camera import PinholeCamera
from .dvs import DVSEmulator, DVSParams, hot_pixel_events, noise_events
from .shapes import SHAPES, coverage, sdf
from .trajectories import Trajectory

GENERATOR_NAME = "toffe-deploy synth"
GENERATOR_VERSION = 3
#: Intensity (linear, 0..1) of the background; objects are brighter or darker by a factor 2
#: (log contrast +-0.69, about three events per pixel per edge at C = 0.25).
BACKGROUND = 0.4
BRIGHT, DARK = 0.8, 0.2


@dataclass(frozen=True)
class ObjectSpec:
    """One moving object: its shape, physical size (m, full width) and linear intensity."""

    shape: str
    trajectory: Trajectory
    size_m: float = 0.4
    intensity: float = BRIGHT
    target_bin: int = 0  # the speed bin its lap time was chosen for (metadata; truth is per sample)

    def __post_init__(self):
        if self.shape not in SHAPES:
            raise ValueError(f"unknown shape {self.shape!r} (expected one of {', '.join(SHAPES)})")

    def to_dict(self) -> dict[str, Any]:
        d = dataclasses.asdict(self)
        d["trajectory"]["offset_m"] = list(self.trajectory.offset_m)
        d["trajectory"]["direction"] = "cw" if self.trajectory.clockwise else "ccw"
        return d


@dataclass(frozen=True)
class SequenceSpec:
    """Everything that defines a sequence except the seed (which draws thresholds and noise)."""

    name: str
    objects: tuple[ObjectSpec, ...]
    duration_s: float = 0.1
    split: str = "custom"
    camera: PinholeCamera = field(default_factory=PinholeCamera)
    dvs: DVSParams = field(default_factory=DVSParams)
    sample_us: int = 50
    background: float = BACKGROUND
    texture: float = 0.0  # relative amplitude of a smooth multiplicative background texture
    meta: dict = field(default_factory=dict)  # split labels (e.g. pair spacing), recorded as given

    @property
    def n_samples(self) -> int:
        return int(round(self.duration_s * 1e6 / self.sample_us))

    def to_dict(self) -> dict[str, Any]:
        return {
            "name": self.name, "split": self.split, "duration_s": self.duration_s,
            "sample_us": self.sample_us, "background": self.background, "texture": self.texture,
            "camera": dataclasses.asdict(self.camera), "dvs": dataclasses.asdict(self.dvs),
            "objects": [o.to_dict() for o in self.objects], "meta": dict(self.meta),
        }

    def digest(self, seed: int) -> str:
        """Identity of (generator version, spec, seed): files with equal digests are equal."""
        blob = json.dumps([GENERATOR_NAME, GENERATOR_VERSION, self.to_dict(), int(seed)], sort_keys=True)
        return hashlib.sha256(blob.encode()).hexdigest()[:16]


def _background(spec: SequenceSpec, rng: np.random.Generator) -> np.ndarray:
    """(H, W) float32 intensity: uniform, times 1 + texture * smooth noise in [-1, 1]."""
    w, h = spec.camera.sensor_size
    bg = np.full((h, w), spec.background, dtype=np.float32)
    if spec.texture > 0:
        import cv2

        coarse = rng.uniform(-1.0, 1.0, size=(max(2, h // 16), max(2, w // 16))).astype(np.float32)
        bg *= 1.0 + spec.texture * cv2.resize(coarse, (w, h), interpolation=cv2.INTER_CUBIC)
        np.clip(bg, 0.0, 1.0, out=bg)
    return bg


@dataclass
class _Track:
    """An object's projected centre u, v and radius r (px) at every sample."""

    obj: ObjectSpec
    u: np.ndarray
    v: np.ndarray
    r: np.ndarray
    z_mean: float


#: Ground-truth columns, in file order (module doc).
GT_COLUMNS = ("t", "object_id", "x", "y", "direction", "speed", "speed_bin", "visible", "speed_px_ms", "depth_m")


def object_tracks(spec: SequenceSpec, t_s: np.ndarray) -> tuple[list[_Track], dict[str, np.ndarray]]:
    """Projected tracks for rendering and the ground-truth columns (time-major rows)."""
    cam = spec.camera
    bin_of = np.vectorize(ToffeConfig().speed_bin_of_px_ms, otypes=[np.int8])  # reference bins
    tracks, cols = [], {k: [] for k in GT_COLUMNS[2:]}
    for obj in spec.objects:
        p = obj.trajectory.position(t_s)
        vel = obj.trajectory.velocity(t_s)
        u, v = cam.project(p)
        du, dv = cam.project_velocity(p, vel)
        speed_px_ms = np.hypot(du, dv) / 1000.0
        r = cam.f * (obj.size_m / 2.0) / p[:, 2]
        tracks.append(_Track(obj, u, v, r, float(p[:, 2].mean())))
        cols["x"].append(u)
        cols["y"].append(v)
        cols["direction"].append(np.arctan2(dv, du))
        cols["speed"].append(np.linalg.norm(vel, axis=-1))
        cols["speed_bin"].append(bin_of(speed_px_ms))
        cols["visible"].append((p[:, 2] > 0) & (u >= 0) & (u <= cam.width - 1) & (v >= 0) & (v <= cam.height - 1))
        cols["speed_px_ms"].append(speed_px_ms)
        cols["depth_m"].append(p[:, 2])
    n, j = t_s.shape[0], len(spec.objects)
    gt = {k: np.stack(v, axis=1).reshape(-1) for k, v in cols.items()}  # rows: sample-major
    gt["t"] = np.repeat(np.round(t_s * 1e6).astype(np.int64), j)
    gt["object_id"] = np.tile(np.arange(j, dtype=np.int32), n)
    return tracks, {k: gt[k] for k in GT_COLUMNS}


def appearance_summary(spec: SequenceSpec) -> dict[str, Any]:
    """The drawn appearance of a sequence in the units it was drawn in (recorded in the file's
    attrs and index.json): camera, sensor, background and per object size_px (apparent diameter
    at the trajectory's mean depth), log contrast log((I + eps) / (B + eps)) and events per edge
    |log contrast| / threshold (what the OFS reads speed from)."""
    cam, d = spec.camera, spec.dvs
    objs = []
    for o in spec.objects:
        z = o.trajectory.depth_m
        c = float(np.log((o.intensity + d.log_eps) / (spec.background + d.log_eps)))
        objs.append({"size_px": round(cam.f * o.size_m / z, 3), "size_m": o.size_m, "depth_m": z,
                     "log_contrast": round(c, 4), "events_per_edge": round(abs(c) / d.threshold, 3),
                     "polarity": "bright" if c > 0 else "dark"})
    return {"sensor_size": list(cam.sensor_size), "hfov_deg": cam.hfov_deg, "focal_px": round(cam.f, 3),
            "background": spec.background, "texture": spec.texture, "threshold": d.threshold,
            "threshold_sigma": d.threshold_sigma, "refractory_us": d.refractory_us,
            "noise_hz": d.noise_rate_hz, "hot_pixels": d.hot_pixel_fraction,
            "hot_pixel_rate_hz": d.hot_pixel_rate_hz, "objects": objs, **spec.meta}


def _box(tr: _Track, k0: int, k1: int, w: int, h: int) -> tuple[int, int, int, int] | None:
    """Pixel box (x0, y0, x1, y1), end exclusive, holding the object at samples k0..k1-1."""
    u, v, r = tr.u[k0:k1], tr.v[k0:k1], tr.r[k0:k1]
    x0 = max(0, int(math.floor((u - r).min())) - 2)
    x1 = min(w, int(math.ceil((u + r).max())) + 3)
    y0 = max(0, int(math.floor((v - r).min())) - 2)
    y1 = min(h, int(math.ceil((v + r).max())) + 3)
    return (x0, y0, x1, y1) if x0 < x1 and y0 < y1 else None


def _merge_boxes(boxes: list[tuple[tuple[int, int, int, int], list[int]]]):
    """Merge intersecting boxes (with the object indices they hold) until none intersect."""
    boxes = list(boxes)
    merged = True
    while merged:
        merged = False
        for i in range(len(boxes)):
            for j in range(i + 1, len(boxes)):
                (a, ia), (b, ib) = boxes[i], boxes[j]
                if a[0] < b[2] and b[0] < a[2] and a[1] < b[3] and b[1] < a[3]:
                    boxes[i] = ((min(a[0], b[0]), min(a[1], b[1]), max(a[2], b[2]), max(a[3], b[3])), ia + ib)
                    del boxes[j]
                    merged = True
                    break
            if merged:
                break
    return boxes


def _render_pixels(bg_px: np.ndarray, xs: np.ndarray, ys: np.ndarray, tracks: list[_Track],
                   ks: np.ndarray) -> np.ndarray:
    """(K, *xs.shape) intensity of pixels (xs, ys) with background bg_px at samples ks: the
    objects composited far to near."""
    extra = (None,) * xs.ndim
    img = np.broadcast_to(bg_px, (ks.shape[0],) + xs.shape).copy()
    for tr in sorted(tracks, key=lambda t: -t.z_mean):
        u = tr.u[ks].astype(np.float32)[(slice(None),) + extra]
        v = tr.v[ks].astype(np.float32)[(slice(None),) + extra]
        r = tr.r[ks].astype(np.float32)[(slice(None),) + extra]
        cov = coverage(tr.obj.shape, xs[None] - u, ys[None] - v, r)
        img += (np.float32(tr.obj.intensity) - img) * cov
    return img


def _render(bg: np.ndarray, box, tracks: list[_Track], ks: np.ndarray) -> np.ndarray:
    """(K, h, w) intensity of a box at samples ks (every pixel of it)."""
    x0, y0, x1, y1 = box
    ys, xs = np.mgrid[y0:y1, x0:x1].astype(np.float32)
    return _render_pixels(bg[y0:y1, x0:x1], xs, ys, tracks, ks)


def _band(box, tracks: list[_Track], kp: int, k1: int) -> np.ndarray:
    """(h, w) bool: the pixels of box whose coverage by some object can change over samples
    kp..k1-1 (module doc: distance at kp against path and radius change)."""
    x0, y0, x1, y1 = box
    xs = np.arange(x0, x1, dtype=np.float32)[None, :]
    ys = np.arange(y0, y1, dtype=np.float32)[:, None]
    band = np.zeros((y1 - y0, x1 - x0), dtype=bool)
    for tr in tracks:
        u, v, r = tr.u[kp:k1], tr.v[kp:k1], tr.r[kp:k1]
        path = float(np.hypot(np.diff(u), np.diff(v)).sum())
        dr = float(np.abs(r - r[0]).max())
        # |d sdf / d r| <= 2 |q| + 1.5 with q = offset / r (scaled shapes); offsets in the box
        # reach at most r + path + a few pixels
        k_r = 2.0 * (r.max() + path + 4.0) / max(float(r.min()), 1e-3) + 1.5
        d0 = sdf(tr.obj.shape, xs - np.float32(u[0]), ys - np.float32(v[0]), np.float32(r[0]))
        band |= np.abs(d0) <= 0.5 + path + k_r * dr + 1e-3
    return band


def _chunk_len(tracks: list[_Track]) -> int:
    """Samples per rendering chunk, between 4 and 256: per chunk the band costs ~ perimeter x
    (1 + 2 path) per sample and the box ~ area once, so the best path per chunk is about
    sqrt(r step / pi) px (r radius, step px per sample); the smallest over the objects."""
    best = 256
    for tr in tracks:
        step = float(np.hypot(np.diff(tr.u), np.diff(tr.v)).max(initial=0.0))
        if step > 0:
            best = min(best, int(math.sqrt(max(float(tr.r.min()), 1.0) / (math.pi * step))))
    return int(min(256, max(4, best)))


def generate_sequence(spec: SequenceSpec, seed: int, progress: bool = False
                      ) -> tuple[np.ndarray, dict[str, np.ndarray], tuple[int, int]]:
    """Events (EVENT_DTYPE, time-sorted), ground truth columns and sensor size of a sequence.

    Deterministic for (spec, seed): the seed draws the per-pixel thresholds, background texture
    and noise; the spec fixes the motion. Samples are at t = k * sample_us, k = 0..n-1; the first
    sample sets every pixel's reference, so events start at k = 1.
    """
    rng = np.random.default_rng(seed)
    w, h = spec.camera.sensor_size
    n = spec.n_samples
    if n < 1:
        raise ValueError(f"duration {spec.duration_s} s is shorter than one sample")
    t_s = np.arange(n, dtype=np.float64) * (spec.sample_us * 1e-6)
    t_us = np.arange(n, dtype=np.int64) * spec.sample_us
    tracks, gt = object_tracks(spec, t_s)
    bg = _background(spec, rng)
    frame0 = bg.copy()
    k_first = np.zeros(1, dtype=np.int64)
    for tr in tracks:
        box = _box(tr, 0, 1, w, h)
        if box is not None:
            frame0[box[1]:box[3], box[0]:box[2]] = _render(bg, box, tracks, k_first)[0]
    dvs = DVSEmulator(spec.dvs.log(frame0), spec.dvs, rng)
    chunk = _chunk_len(tracks)
    pieces = []
    starts = range(1, n, chunk)
    if progress:
        from tqdm import tqdm

        starts = tqdm(starts, desc=spec.name, unit="chunk", leave=False)
    for k0 in starts:
        k1 = min(n, k0 + chunk)
        ks = np.arange(k0, k1)
        boxes = []
        for i, tr in enumerate(tracks):
            box = _box(tr, k0 - 1, k1, w, h)
            if box is not None:
                boxes.append((box, [i]))
        groups = []
        left = dvs.pending   # pending pixels fire without a change of input: feed them too
        for box, idx in _merge_boxes(boxes):
            x0, y0, x1, y1 = box
            band = _band(box, [tracks[i] for i in idx], k0 - 1, k1)
            if left is not None and left.shape[0]:
                py, px = left // w, left % w
                inside = (px >= x0) & (px < x1) & (py >= y0) & (py < y1)
                band[py[inside] - y0, px[inside] - x0] = True
                left = left[~inside]
            by, bx = np.nonzero(band)
            groups.append((by + y0, bx + x0, [tracks[i] for i in idx]))
        if left is not None and left.shape[0]:   # pending outside every box: all objects
            groups.append((left // w, left % w, tracks))
        for by, bx, group in groups:
            if by.shape[0]:
                img = _render_pixels(bg[by, bx], bx.astype(np.float32), by.astype(np.float32), group, ks)
                pieces.append(dvs.process_pixels(by * w + bx, spec.dvs.log(img), t_us[ks]))
    pieces.append(noise_events(spec.dvs.noise_rate_hz, n, spec.sample_us, (w, h), rng))
    pieces.append(hot_pixel_events(spec.dvs.hot_pixel_fraction, spec.dvs.hot_pixel_rate_hz, n, spec.sample_us,
                                   (w, h), rng))
    events = np.concatenate(pieces) if pieces else np.empty(0, EVENT_DTYPE)
    events = events[np.argsort(events["t"], kind="stable")]
    return events, gt, (w, h)
