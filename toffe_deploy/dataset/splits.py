"""The train / test / multi-object sequence lists (the paper's "TOFFE Dataset" protocol).

- train: 3 curves (ellipse, lemniscate, limacon) x orientations 0/45/90/145 deg x clockwise /
  anticlockwise x 4 shapes x 4 speed bins = 384 sequences, one object each;
- test: 2 other curves (trefoil, squircle) at orientation 0 x 2 senses x 4 shapes x 4 bins = 64;
- multi: sequences with 2-4 objects at distinct speed bins at once, one per image quadrant, on
  the test curves (what ``run`` sees).

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

import itertools
import zlib

import numpy as np

from .dvs import DVSParams
from .shapes import SHAPES
from .synth import BRIGHT, DARK, ObjectSpec, SequenceSpec
from .trajectories import TAU, TEST_CURVES, TRAIN_CURVES, Trajectory, lap_time_for_speeds

SPLITS = ("train", "test", "multi")
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
DEFAULT_DURATION_S = {"train": 0.1, "test": 0.1, "multi": 0.25}
DEFAULT_MULTI_COUNT = 16


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


def split_specs(split: str, seed: int = 0, duration_s: float | None = None, dvs: DVSParams | None = None,
                texture: float = 0.0, multi_count: int = DEFAULT_MULTI_COUNT,
                contrast: str = "bright") -> list[SequenceSpec]:
    """The sequence specs of one split, in a fixed order (see module doc)."""
    if split not in SPLITS:
        raise ValueError(f"unknown split {split!r} (expected one of {', '.join(SPLITS)})")
    if contrast not in CONTRASTS:
        raise ValueError(f"unknown contrast {contrast!r} (expected one of {', '.join(CONTRASTS)})")
    dur = float(duration_s if duration_s is not None else DEFAULT_DURATION_S[split])
    dvs = dvs or DVSParams()
    specs = []

    def add(name, objects):
        specs.append(SequenceSpec(name, tuple(objects), duration_s=dur, split=split, dvs=dvs, texture=texture))

    if split in ("train", "test"):
        curves = TRAIN_CURVES if split == "train" else TEST_CURVES
        orients = ORIENTATIONS_DEG if split == "train" else (0.0,)
        for curve, orient, cw, shape, b in itertools.product(curves, orients, (True, False), SHAPES, (1, 2, 3, 4)):
            name = f"{split}_{curve}_o{int(orient):03d}_{'cw' if cw else 'ccw'}_{shape}_b{b}"
            rng = np.random.default_rng(sequence_seed(seed, name))
            add(name, [_object(rng, shape, curve, b, orient, cw, SCALE_M, SIZE_M, DEPTH_AMP_M, contrast=contrast)])
    else:
        for i in range(multi_count):
            name = f"multi_{i:03d}"
            rng = np.random.default_rng(sequence_seed(seed, name))
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
