"""The sequence lists of the splits (the paper's "TOFFE Dataset" protocol, plus randomized
appearance, held-out appearance and close pairs).

- train: 3 curves (ellipse, lemniscate, limacon) x orientations 0/45/90/145 deg x clockwise /
  anticlockwise x 4 shapes x 4 speed bins = 384 sequences, one object each;
- test: 2 other curves (trefoil, squircle) at orientation 0 x 2 senses x 4 shapes x 4 bins = 64;
- multi: sequences with 2-4 objects at distinct speed bins at once, one per image quadrant, on
  the test curves (what ``run`` sees);
- appearance: held-out appearance combinations (appearance.py: the region training skips), on
  the test curves: 2 curves x 4 shapes x 4 bins = 32 single-object sequences and
  APPEARANCE_MULTI_COUNT multi-object ones;
- pairs: PAIRS_PER_BIN x 4 bins sequences of two objects of one size on the same trajectory
  (same bin, parallel motion), their centres PAIR_SPACING_RADII = 3-8 object radii apart
  (meta: spacing_radii, spacing_px, gap_px, offset_angle_deg);
- crossing: CROSSING_COUNT sequences of 2-3 objects whose paths cross inside the view while the
  sequence runs (even-numbered: one bin for all, odd: distinct bins), for tracking through
  merges; object k's starting phase is set so that it meets object k - 1 at a point of their
  paths at a drawn time (meta: same_bin, bins, crossings [{objects, t_s, x_px, y_px, angle_deg}]),
  and every two objects lie apart at the start and at the end (_apart_at_ends; since 2026-11-24;
  in a sequence shorter than the default 0.1 s, where slow objects cannot part, the layout of
  200 whose objects lie farthest apart at the ends when none does).

Appearance ``paper`` (the geometry below, fixed in metres) or ``random`` (appearance.py ranges,
laid out in pixels then converted at each object's drawn depth and the drawn focal length: the
curve's on-screen excursion, object size and image-plane speed are what is drawn, so the
scene looks alike at any depth). With ``random`` each object's image-plane speed is drawn in
the target bin's px/ms range (PROGRAMMED_PX_MS: PROGRAMMED_SPEEDS at the reference 5 m and
554.26 px) and converted to m/s at its depth for the trajectory.

Each object's lap time is drawn so its speeds over the lap fall in the programmed range of its
target bin (PROGRAMMED_SPEEDS; bin 4 stops at the paper's maximum programmed speed, 144 m/s,
bin 1 starts at 2 m/s so the slowest objects still move a pixel in 5 ms). Starting phase,
and lap time come from the split seed, so a split is deterministic for a seed.

Contrast: objects are brighter than the background by default (``contrast="bright"``), as a lit
object against a darker scene. ``"mixed"`` draws bright or dark per object, ``"dark"`` makes all
dark. Why bright by default: within one window a bright object moving right and a dark object
moving left fire the same events (ON on the right edge, OFF on the left); only the motion
during the window tells them apart, and a bin-1 object moves 0.1-1 px in 500 us, so with mixed
contrast the direction of slow objects is ambiguous for any per-window model (measured: dirE of
bin 1 about 60 deg at dt = 500 us with mixed contrast).
"""
from __future__ import annotations

import dataclasses
import itertools
import math
import zlib

import numpy as np

from ..camera import REFERENCE_DEPTH_M, REFERENCE_FOCAL_PX, PinholeCamera, SpeedScale
from .appearance import AppearanceRanges, RANDOM, draw, is_held_out
from .dvs import DVSParams
from .shapes import SHAPES
from .synth import BRIGHT, DARK, ObjectSpec, SequenceSpec
from .trajectories import TAU, TEST_CURVES, TRAIN_CURVES, Trajectory, lap_time_for_speeds

SPLITS = ("train", "test", "multi", "appearance", "pairs", "crossing")
APPEARANCES = ("paper", "random")
ORIENTATIONS_DEG = (0.0, 45.0, 90.0, 145.0)
#: Programmed speed range (m/s) per target bin (the bins of ToffeConfig, bin 4 capped at 144).
PROGRAMMED_SPEEDS = {1: (2.0, 18.0), 2: (18.0, 42.0), 3: (42.0, 84.0), 4: (84.0, 144.0)}
#: Scene geometry (metres): depth of the trajectory plane, its depth swing, object size, and the
#: largest excursion of a single-object trajectory (fits the 5.77 x 4.33 m view at 5 m when rotated).
DEPTH_M, DEPTH_AMP_M, SIZE_M, SCALE_M = 5.0, 0.3, 0.4, 1.6
#: Multi-object scenes: smaller objects on smaller curves, one per quadrant centre.
MULTI_SIZE_M, MULTI_SCALE_M, MULTI_DEPTH_AMP_M = 0.35, 0.55, 0.2
MULTI_QUADRANTS_M = ((-1.35, -0.95), (1.35, -0.95), (-1.35, 0.95), (1.35, 0.95))
#: Longest generated sequence (s): the generator holds a whole sequence in memory (events of a
#: 640x480 scene run to ~70 MB per second), so a typo like 1e9 must not try to allocate it.
MAX_SYNTH_DURATION_S = 10.0
#: the sensor sides (px) the generator renders, `dataset synth --sensor-size` and `run --synthetic`
#: alike (`run` itself takes any W x H up to config.MAX_SENSOR_PIXELS)
SYNTH_SIDE_PX = (8, 4096)
DEFAULT_DURATION_S = {"train": 0.1, "test": 0.1, "multi": 0.25, "appearance": 0.1, "pairs": 0.1, "crossing": 0.1}
DEFAULT_MULTI_COUNT = 16
#: The programmed speed ranges as image-plane speeds (px/ms) at the reference camera and depth.
PROGRAMMED_PX_MS = {k: tuple(SpeedScale(REFERENCE_FOCAL_PX, REFERENCE_DEPTH_M).to_px_ms(v) for v in r)
                    for k, r in PROGRAMMED_SPEEDS.items()}
#: Random layouts, in pixels relative to the room an object has (half the smaller sensor side for
#: one object; the paper's 1.6 m excursion at 5 m is 0.74 of the 240 px half height): the curve's
#: excursion, the depth swing per metre of excursion (the paper's 0.3 m / 1.6 m) and the multi
#: quadrant centres (the paper's 1.35 m, 0.95 m at 5 m, as fractions of the half sensor).
EXCURSION_FRAC, MULTI_EXCURSION_FRAC, DEPTH_AMP_PER_SCALE = 0.74, 0.51, 0.1875
MULTI_QUADRANTS_FRAC = ((-0.47, -0.44), (0.47, -0.44), (-0.47, 0.44), (0.47, 0.44))
APPEARANCE_MULTI_COUNT, PAIRS_PER_BIN = 8, 8
PAIR_SPACING_RADII = (3.0, 8.0)
#: Crossing scenes: sequences; each crossing's time as fractions of the duration (the
#: tracks have windows before and after it); curve centres offset by this fraction of the room
#: from the view's centre (so that two paths cut each other rather than nest); smallest angle
#: (deg) between the two directions of motion at a crossing (no grazing).
CROSSING_COUNT, CROSSING_TIME_FRAC, CROSSING_OFFSET_FRAC, CROSSING_MIN_ANGLE_DEG = 16, (0.3, 0.7), 0.3, 20.0


def sequence_seed(seed: int, name: str) -> int:
    """A per-sequence seed from the split seed and the sequence name (stable across runs)."""
    return int(np.random.SeedSequence([int(seed), zlib.crc32(name.encode())]).generate_state(1)[0])


CONTRASTS = ("bright", "dark", "mixed")


def _intensity(rng, contrast: str) -> float:
    dark = rng.random() < 0.5          # drawn in every mode, so the other parameters do not move
    if contrast == "mixed":
        return DARK if dark else BRIGHT
    return DARK if contrast == "dark" else BRIGHT


def _object(rng, shape, curve, bin_k, orientation, clockwise, scale, size, depth_amp, offset=(0.0, 0.0),
            contrast="bright"):
    lo, hi = PROGRAMMED_SPEEDS[bin_k]
    lap = lap_time_for_speeds(curve, scale, depth_amp, lo, hi, rng)
    traj = Trajectory(curve, lap_time_s=round(lap, 9), scale_m=scale, depth_m=DEPTH_M, depth_amp_m=depth_amp,
                      orientation_deg=orientation, clockwise=clockwise,
                      phase0=round(float(rng.uniform(0.0, TAU)), 9), offset_m=tuple(offset))
    return ObjectSpec(shape, traj, size_m=size, intensity=_intensity(rng, contrast), target_bin=bin_k)


def _sensor(rng, ranges: AppearanceRanges) -> tuple[DVSParams, float]:
    """Per-sequence DVS parameters and background texture drawn from the sensor ranges."""
    thr, sig, refr, noise, hot, tex = (draw(rng, k, getattr(ranges, k)) for k in
                                       ("threshold", "threshold_sigma", "refractory_us", "noise_hz",
                                        "hot_pixels", "texture"))
    return DVSParams(threshold=thr, threshold_sigma=sig, noise_rate_hz=noise, refractory_us=refr,
                     hot_pixel_fraction=hot), tex


def _camera(rng, ranges: AppearanceRanges) -> PinholeCamera:
    w, h = ranges.sensor_size
    if ranges.focal_px is not None:
        hfov = math.degrees(2.0 * math.atan(w / 2.0 / draw(rng, "focal_px", ranges.focal_px)))
    else:
        hfov = draw(rng, "hfov_deg", ranges.hfov_deg)
    return PinholeCamera(int(w), int(h), round(hfov, 9))


@dataclasses.dataclass(frozen=True)
class _Look:
    """An object's drawn depth (m), size (m and apparent px diameter) and signed log contrast."""

    depth: float
    size_m: float
    size_px: float
    contrast: float


def _look(rng, ranges: AppearanceRanges, cam: PinholeCamera, size_cap_px: float) -> _Look:
    depth = draw(rng, "depth_m", ranges.depth_m)
    if ranges.size_m is not None:
        size_px = min(cam.f * draw(rng, "size_m", ranges.size_m) / depth, size_cap_px)
    else:
        lo, hi = ranges.size_px
        size_px = draw(rng, "size_px", (min(lo, size_cap_px), min(hi, size_cap_px)))
    c = draw(rng, "object_contrast", ranges.object_contrast)
    if rng.random() < ranges.dark_fraction:
        c = -c
    return _Look(round(depth, 9), round(size_px * depth / cam.f, 9), size_px, c)


def _random_object(rng, cam: PinholeCamera, look: _Look, background: float, eps: float, shape: str, curve: str,
                   bin_k: int, orientation: float, clockwise: bool, centre_px=(0.0, 0.0), room_px: float = 240.0,
                   excursion_frac: float = EXCURSION_FRAC, reach_px: float | None = None,
                   depth_swing: bool = True) -> ObjectSpec:
    """An object laid out in pixels (module doc): its curve's excursion keeps it (its edge
    ``reach_px`` from the trajectory centre, default its radius) inside ``room_px``."""
    reach = look.size_px / 2.0 if reach_px is None else reach_px
    exc = max(min(excursion_frac * room_px, room_px - reach - 2.0), 0.1 * room_px)
    m_per_px = look.depth / cam.f
    scale = exc * m_per_px
    amp = DEPTH_AMP_PER_SCALE * scale if depth_swing else 0.0
    to_mps = SpeedScale(cam.f, look.depth).to_mps
    lo, hi = PROGRAMMED_PX_MS[bin_k]
    lap = lap_time_for_speeds(curve, scale, amp, to_mps(lo), to_mps(hi), rng)
    traj = Trajectory(curve, lap_time_s=round(lap, 9), scale_m=round(scale, 9), depth_m=look.depth,
                      depth_amp_m=round(amp, 9), orientation_deg=orientation, clockwise=clockwise,
                      phase0=round(float(rng.uniform(0.0, TAU)), 9),
                      offset_m=(round(centre_px[0] * m_per_px, 9), round(centre_px[1] * m_per_px, 9)))
    intensity = max((background + eps) * math.exp(look.contrast) - eps, 0.0)
    return ObjectSpec(shape, traj, size_m=look.size_m, intensity=round(intensity, 9), target_bin=bin_k)


def _random_scene(rng, ranges: AppearanceRanges, holdout: str | None, place, n_looks: int, size_cap_frac: float):
    """Draw camera, sensor and background, then ``n_looks`` object looks that all lie outside
    (holdout "exclude") or inside ("only") the held-out region, redrawing as needed; then
    ``place(cam, dvs, background, looks)`` lays the objects out, or returns None when this
    scene has no room for the layout (crossing: no two paths that cut), and the whole scene is
    redrawn. Returns (cam, dvs, texture, background, objects)."""
    unplaced = 0
    for _ in range(100):
        cam = _camera(rng, ranges)
        dvs, texture = _sensor(rng, ranges)
        bg = draw(rng, "background", ranges.background)
        cap = size_cap_frac * min(cam.sensor_size)
        looks = []
        for _ in range(n_looks):
            for _ in range(100):
                lk = _look(rng, ranges, cam, cap)
                if holdout is None or is_held_out(abs(lk.contrast) / dvs.threshold, lk.size_px,
                                                  dvs.noise_rate_hz) == (holdout == "only"):
                    looks.append(lk)
                    break
            else:
                break
        if len(looks) == n_looks:
            objs = place(cam, dvs, bg, looks)
            if objs is not None:
                return cam, dvs, texture, bg, objs
            unplaced += 1
    if unplaced:
        raise ValueError(f"no layout of the objects found in {unplaced} scenes drawn (e.g. no crossing paths)")
    where = "inside" if holdout == "only" else "outside"
    raise ValueError(f"the appearance ranges leave no room {where} the held-out region "
                     "(events per edge x size x noise; data/README.md)")


def _random_single(rng, ranges, holdout, shape, curve, b, orient, cw):
    def place(cam, dvs, bg, looks):
        return [_random_object(rng, cam, looks[0], bg, dvs.log_eps, shape, curve, b, orient, cw,
                               room_px=min(cam.sensor_size) / 2.0)]
    return _random_scene(rng, ranges, holdout, place, 1, 1.0)


def _random_multi(rng, ranges, holdout):
    n_obj = int(rng.integers(2, 5))
    bins = rng.choice([1, 2, 3, 4], size=n_obj, replace=False)
    quads = rng.choice(len(MULTI_QUADRANTS_FRAC), size=n_obj, replace=False)

    def place(cam, dvs, bg, looks):
        w, h = cam.sensor_size
        room = 0.9 * min(0.47 * w / 2.0, 0.44 * h / 2.0)
        objs = []
        for lk, b, q in zip(looks, bins, quads):
            fx, fy = MULTI_QUADRANTS_FRAC[q]
            objs.append(_random_object(rng, cam, lk, bg, dvs.log_eps, str(rng.choice(SHAPES)),
                                       str(rng.choice(TEST_CURVES)), int(b), float(rng.choice(ORIENTATIONS_DEG)),
                                       bool(rng.random() < 0.5), (fx * w / 2.0, fy * h / 2.0), room,
                                       MULTI_EXCURSION_FRAC))
        return objs
    # a quadrant's room is ~0.2 of the smaller side: objects up to that size
    return _random_scene(rng, ranges, holdout, place, n_obj, 0.2)


def _random_pair(rng, ranges, b):
    """Two objects of one size and depth on one trajectory, offset by spacing_radii * radius."""
    spacing = draw(rng, "spacing_radii", PAIR_SPACING_RADII)
    angle = float(rng.uniform(0.0, 180.0))
    curve, orient, cw = str(rng.choice(TEST_CURVES)), float(rng.choice(ORIENTATIONS_DEG)), bool(rng.random() < 0.5)
    shapes = [str(rng.choice(SHAPES)) for _ in range(2)]
    meta = {}

    def place(cam, dvs, bg, looks):
        lk = looks[0]
        r = lk.size_px / 2.0
        half = spacing * r / 2.0
        dx, dy = half * math.cos(math.radians(angle)), half * math.sin(math.radians(angle))
        a = _random_object(rng, cam, lk, bg, dvs.log_eps, shapes[0], curve, b, orient, cw, (dx, dy),
                           room_px=min(cam.sensor_size) / 2.0, reach_px=half + r, depth_swing=False)
        c2 = draw(rng, "object_contrast", ranges.object_contrast)
        c2 = -c2 if rng.random() < ranges.dark_fraction else c2
        m_per_px = lk.depth / cam.f
        off = (round(-dx * m_per_px, 9), round(-dy * m_per_px, 9))
        second = ObjectSpec(shapes[1], dataclasses.replace(a.trajectory, offset_m=off), size_m=a.size_m,
                            intensity=round(max((bg + dvs.log_eps) * math.exp(c2) - dvs.log_eps, 0.0), 9),
                            target_bin=b)
        meta.update(spacing_radii=round(spacing, 4), spacing_px=round(2.0 * half, 3),
                    gap_px=round(2.0 * half - 2.0 * r, 3), offset_angle_deg=round(angle, 3))
        return [a, second]
    # (spacing / 2 + 1) r must leave room for the curve: diameters up to 0.12 of the smaller side
    scene = _random_scene(rng, ranges, None, place, 1, 0.12)
    return scene, meta


def _pixel_path(cam: PinholeCamera, traj: Trajectory, phi: np.ndarray) -> np.ndarray:
    """(n, 2) projected centres (px) of a trajectory at phases phi."""
    u, v = cam.project(traj.position_at_phase(phi))
    return np.stack([u, v], axis=-1)


def _meeting(cam, lead: Trajectory, other: Trajectory, t_lo: float, t_hi: float, t_want: float):
    """Where ``lead``'s path during [t_lo, t_hi] (s) cuts ``other``'s closed path: (time, phase of
    ``other`` there, (x, y) px, crossing angle deg) of the cut nearest t_want, None if there is
    none at CROSSING_MIN_ANGLE_DEG or more. Both paths as polylines (200 times, 1,024 phases: chords
    within 0.05 px of the curves); segments p + s r and q + u w cut where s = (q - p) x w / (r x w)
    and u = (q - p) x r / (r x w) lie in [0, 1]."""
    t = np.linspace(t_lo, t_hi, 200)
    phi = np.linspace(0.0, TAU, 1025)
    a, b = _pixel_path(cam, lead, lead.phase(t)), _pixel_path(cam, other, phi)
    r, w = np.diff(a, axis=0)[:, None, :], np.diff(b, axis=0)[None, :, :]
    qp = b[None, :-1, :] - a[:-1, None, :]

    def cross(x, y):
        return x[..., 0] * y[..., 1] - x[..., 1] * y[..., 0]

    den = cross(r, w)
    with np.errstate(divide="ignore", invalid="ignore"):
        s, u = cross(qp, w) / den, cross(qp, r) / den
    i, k = np.nonzero((den != 0) & (s >= 0) & (s <= 1) & (u >= 0) & (u <= 1))
    best = None
    for i, k in zip(i.tolist(), k.tolist()):
        ri, wk = r[i, 0], w[0, k]
        cos = abs(float(ri @ wk)) / float(np.linalg.norm(ri) * np.linalg.norm(wk))
        angle = math.degrees(math.acos(min(1.0, cos)))
        t_c = float(t[i] + s[i, k] * (t[i + 1] - t[i]))
        if angle >= CROSSING_MIN_ANGLE_DEG and (best is None or abs(t_c - t_want) < abs(best[0] - t_want)):
            x, y = a[i] + s[i, k] * ri
            best = (t_c, float(phi[k] + u[i, k] * (phi[k + 1] - phi[k])), (float(x), float(y)), angle)
    return best


def _apart_at_ends(cam, objs, sizes_px, duration_s: float) -> float:
    """How far apart every two of the objects lie at the sequence's start and at its end: the
    least centre distance over the sum of their radii (>= 1: apart). Two objects that cross
    come together and part inside the sequence. Why: without it 17 of 716 object pairs over 24
    crossing seeds overlapped from the first window to the last (slow objects meeting at a
    shallow angle, and objects 0 and 2, each timed to meet object 1, never checked against each
    other), which no detector sees as two objects and no tracker can follow as a crossing
    (2026-11-24)."""
    t = np.array([0.0, duration_s])
    pos = [_pixel_path(cam, o.trajectory, o.trajectory.phase(t)) for o in objs]
    least = math.inf
    for i in range(len(objs)):
        for j in range(i + 1, len(objs)):
            gap = np.hypot(*(pos[i] - pos[j]).T)
            least = min(least, float(gap.min()) / ((sizes_px[i] + sizes_px[j]) / 2.0))
    return least


def _random_crossing(rng, ranges, n_obj: int, same_bin: bool, duration_s: float):
    """2-3 objects on test curves around centres offset from the view's, object k timed to meet
    object k - 1 where their paths cut (module doc); redrawn until every meeting exists."""
    bins = [int(rng.integers(1, 5))] * n_obj if same_bin else [int(b) for b in rng.choice([1, 2, 3, 4], n_obj,
                                                                                          replace=False)]
    meta = {}

    def place(cam, dvs, bg, looks):
        room = min(cam.sensor_size) / 2.0
        best = None                       # the layout whose objects lie farthest apart at the ends
        for _ in range(200):
            objs, crossings = [], []
            for k, (lk, b) in enumerate(zip(looks, bins)):
                ang = rng.uniform(0.0, TAU)
                off = CROSSING_OFFSET_FRAC * room
                o = _random_object(rng, cam, lk, bg, dvs.log_eps, str(rng.choice(SHAPES)), str(rng.choice(TEST_CURVES)),
                                   b, float(rng.choice(ORIENTATIONS_DEG)), bool(rng.random() < 0.5),
                                   (off * math.cos(ang), off * math.sin(ang)), room - off)
                if k:
                    lo, hi = CROSSING_TIME_FRAC
                    hit = _meeting(cam, objs[-1].trajectory, o.trajectory, lo * duration_s, hi * duration_s,
                                   float(rng.uniform(lo, hi)) * duration_s)
                    if hit is None:
                        break
                    t_c, phi, (x, y), angle = hit
                    sense = 1.0 if o.trajectory.clockwise else -1.0
                    phase0 = round(float((phi - sense * TAU * t_c / o.trajectory.lap_time_s) % TAU), 9)
                    o = dataclasses.replace(o, trajectory=dataclasses.replace(o.trajectory, phase0=phase0))
                    crossings.append({"objects": [k - 1, k], "t_s": round(t_c, 6), "x_px": round(x, 2),
                                      "y_px": round(y, 2), "angle_deg": round(angle, 1)})
                objs.append(o)
            if len(objs) == n_obj:
                apart = _apart_at_ends(cam, objs, [lk.size_px for lk in looks], duration_s)
                if apart >= 1.0:
                    meta.update(same_bin=same_bin, bins=bins, crossings=crossings)
                    return objs
                if best is None or apart > best[0]:
                    best = (apart, objs, crossings)
        if best is not None and duration_s < DEFAULT_DURATION_S["crossing"]:
            # a sequence shorter than the split's 0.1 s, where slow objects cannot part (none of the
            # 100 scenes had a layout at 0.03 s, after 2 min): the layout that comes nearest
            meta.update(same_bin=same_bin, bins=bins, crossings=best[2])
            return best[1]
        return None                                          # this scene has none: _random_scene redraws it
    # like pairs: objects up to 0.12 of the smaller side leave room for the curves
    scene = _random_scene(rng, ranges, None, place, n_obj, 0.12)
    return scene, meta


def split_specs(split: str, seed: int = 0, duration_s: float | None = None, dvs: DVSParams | None = None,
                texture: float = 0.0, multi_count: int = DEFAULT_MULTI_COUNT,
                contrast: str = "bright", appearance: str = "paper",
                ranges: AppearanceRanges | None = None) -> list[SequenceSpec]:
    """The sequence specs of one split, in a fixed order (see module doc).

    appearance "paper": the paper's geometry and look; the sensor is ``dvs`` / ``texture`` or,
    when ``ranges`` is given, drawn per sequence from its sensor fields (and its sensor_size).
    appearance "random": everything drawn from ``ranges`` (default appearance.RANDOM); the train
    split skips the held-out region. The appearance split is always random, inside the region;
    pairs and crossing are always random.
    """
    if split not in SPLITS:
        raise ValueError(f"unknown split {split!r} (expected one of {', '.join(SPLITS)})")
    if contrast not in CONTRASTS:
        raise ValueError(f"unknown contrast {contrast!r} (expected one of {', '.join(CONTRASTS)})")
    if appearance not in APPEARANCES:
        raise ValueError(f"unknown appearance {appearance!r} (expected one of {', '.join(APPEARANCES)})")
    dur = float(duration_s if duration_s is not None else DEFAULT_DURATION_S[split])
    random_look = appearance == "random" or split in ("appearance", "pairs", "crossing")
    specs = []

    def add(name, objects, cam=None, seq_dvs=None, seq_texture=None, background=None, meta=None):
        if cam is None and ranges is not None:   # paper geometry, sensor from the ranges
            sensor_rng = np.random.default_rng(sequence_seed(seed, "sensor:" + name))
            seq_dvs, seq_texture = _sensor(sensor_rng, ranges)
            cam = PinholeCamera(*ranges.sensor_size)
        kw = {"background": background} if background is not None else {}
        specs.append(SequenceSpec(name, tuple(objects), duration_s=dur, split=split, camera=cam or PinholeCamera(),
                                  dvs=seq_dvs or dvs or DVSParams(), texture=texture if seq_texture is None
                                  else seq_texture, meta={"appearance": "random" if random_look else "paper",
                                                          **(meta or {})}, **kw))

    def add_random(name, scene, holdout, meta=None):
        cam, seq_dvs, tex, bg, objs = scene
        add(name, objs, cam, seq_dvs, round(tex, 9), round(bg, 9), {"holdout": holdout or "none", **(meta or {})})

    rr = ranges or RANDOM
    if split in ("train", "test"):
        curves = TRAIN_CURVES if split == "train" else TEST_CURVES
        orients = ORIENTATIONS_DEG if split == "train" else (0.0,)
        for curve, orient, cw, shape, b in itertools.product(curves, orients, (True, False), SHAPES, (1, 2, 3, 4)):
            name = f"{split}_{curve}_o{int(orient):03d}_{'cw' if cw else 'ccw'}_{shape}_b{b}"
            rng = np.random.default_rng(sequence_seed(seed, name))
            if random_look:
                hold = "exclude" if split == "train" else None
                add_random(name, _random_single(rng, rr, hold, shape, curve, b, orient, cw), hold)
            else:
                add(name, [_object(rng, shape, curve, b, orient, cw, SCALE_M, SIZE_M, DEPTH_AMP_M,
                                   contrast=contrast)])
    elif split == "multi":
        for i in range(multi_count):
            name = f"multi_{i:03d}"
            rng = np.random.default_rng(sequence_seed(seed, name))
            if random_look:
                add_random(name, _random_multi(rng, rr, None), None)
                continue
            n_obj = int(rng.integers(2, 5))
            bins = rng.choice([1, 2, 3, 4], size=n_obj, replace=False)
            quads = rng.choice(len(MULTI_QUADRANTS_M), size=n_obj, replace=False)
            objs = []
            for b, q in zip(bins, quads):
                objs.append(_object(rng, str(rng.choice(SHAPES)), str(rng.choice(TEST_CURVES)), int(b),
                                    float(rng.choice(ORIENTATIONS_DEG)), bool(rng.random() < 0.5),
                                    MULTI_SCALE_M, MULTI_SIZE_M, MULTI_DEPTH_AMP_M, MULTI_QUADRANTS_M[q],
                                    contrast=contrast))
            add(name, objs)
    elif split == "appearance":
        for curve, shape, b in itertools.product(TEST_CURVES, SHAPES, (1, 2, 3, 4)):
            name = f"appearance_{curve}_{shape}_b{b}"
            rng = np.random.default_rng(sequence_seed(seed, name))
            cw = bool(rng.random() < 0.5)
            add_random(name, _random_single(rng, rr, "only", shape, curve, b, 0.0, cw), "only")
        for i in range(APPEARANCE_MULTI_COUNT):
            name = f"appearance_multi_{i:03d}"
            rng = np.random.default_rng(sequence_seed(seed, name))
            add_random(name, _random_multi(rng, rr, "only"), "only")
    elif split == "pairs":
        for b, i in itertools.product((1, 2, 3, 4), range(PAIRS_PER_BIN)):
            name = f"pairs_b{b}_{i:03d}"
            rng = np.random.default_rng(sequence_seed(seed, name))
            scene, meta = _random_pair(rng, rr, b)
            add_random(name, scene, None, meta)
    else:
        for i in range(CROSSING_COUNT):
            name = f"crossing_{i:03d}"
            rng = np.random.default_rng(sequence_seed(seed, name))
            scene, meta = _random_crossing(rng, rr, int(rng.integers(2, 4)), i % 2 == 0, dur)
            add_random(name, scene, None, meta)
    return specs


def balanced_subset(specs: list[SequenceSpec], limit: int, seed: int = 0) -> list[SequenceSpec]:
    """At most ``limit`` specs, taken round-robin over the target speed bin of object 0 after a
    seeded shuffle within each bin, so a small subset still covers every bin (order kept)."""
    if limit >= len(specs):
        return list(specs)
    rng = np.random.default_rng(seed)
    groups: dict[int, list[int]] = {}
    for i, s in enumerate(specs):
        groups.setdefault(s.objects[0].target_bin, []).append(i)
    queues = [list(rng.permutation(g)) for _, g in sorted(groups.items())]
    picked: list[int] = []
    while len(picked) < limit:
        for q in queues:
            if q and len(picked) < limit:
                picked.append(int(q.pop(0)))
    return [specs[i] for i in sorted(picked)]
