"""Randomized appearance: the ranges a sequence's camera, scene, object and sensor are drawn from,
and the held-out region of appearance combinations that training never sees.

Every parameter is a range (lo, hi), drawn once per sequence (per object for depth, size and
contrast) from the sequence's own seed: uniform, or log-uniform for scales (LOG_SCALED) when
lo > 0; lo == hi fixes the value. One random number is consumed per draw whatever the range,
so fixing one parameter does not move the others.

Held-out region (the "appearance" split): three appearance axes are cut into three cells each,

    events per edge E = |log contrast| / threshold:  < 2 | 2-5 | >= 5
    object size (apparent diameter, px):             < 35 | 35-80 | >= 80
    background noise (Hz per pixel):                 < 10 | 10-25 | >= 25

and an object is held out when its cell indices (i_E + i_size + i_noise) % 3 == 1: nine of the
27 cells, a diagonal pattern so every value of every axis is in training, only these
*combinations* are not. ``train`` redraws objects inside the region, ``appearance`` draws only
inside it.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

Range = tuple[float, float]

#: Parameters drawn log-uniformly (scales) when their range starts above zero.
LOG_SCALED = frozenset({"focal_px", "depth_m", "size_px", "size_m", "background", "noise_hz", "hot_pixels"})
#: Cell edges of the held-out partition (module doc).
HOLDOUT_EDGES = {"events_per_edge": (2.0, 5.0), "size_px": (35.0, 80.0), "noise_hz": (10.0, 25.0)}


@dataclass(frozen=True)
class AppearanceRanges:
    """Draw ranges, each (lo, hi). focal_px, when set, replaces hfov_deg; size_m, when set,
    replaces size_px (then size_px = f size_m / depth). An object's log contrast is drawn from
    object_contrast and its sign flipped with probability dark_fraction; its intensity is
    (B + eps) exp(c) - eps on a background of linear intensity B (so the sensor sees exactly c)."""

    sensor_size: tuple[int, int] = (640, 480)
    hfov_deg: Range = (40.0, 90.0)
    focal_px: Range | None = None
    depth_m: Range = (2.0, 12.0)
    size_px: Range = (15.0, 200.0)
    size_m: Range | None = None
    object_contrast: Range = (0.3, 2.0)
    dark_fraction: float = 0.3
    background: Range = (0.1, 0.6)
    threshold: Range = (0.1, 0.5)
    threshold_sigma: Range = (0.0, 0.06)
    refractory_us: Range = (0.0, 500.0)
    noise_hz: Range = (0.1, 50.0)
    hot_pixels: Range = (0.0, 1e-4)
    texture: Range = (0.0, 0.3)

    def replace(self, **kw) -> "AppearanceRanges":
        return dataclasses.replace(self, **{k: v for k, v in kw.items() if v is not None})

    def to_dict(self) -> dict:
        return {k: (list(v) if isinstance(v, tuple) else v) for k, v in dataclasses.asdict(self).items()}


#: The paper protocol's fixed appearance (640x480, 60 deg, 5 m, 0.4 m, object 0.8 on 0.4, C = 0.25
#: +- 0.03, no refractory period, noise, hot pixels or texture). Only its sensor fields are used
#: by the paper splits, whose geometry is fixed in metres (splits.py).
PAPER = AppearanceRanges(hfov_deg=(60.0, 60.0), depth_m=(5.0, 5.0), size_px=(44.34, 44.34), size_m=(0.4, 0.4),
                         object_contrast=(0.6907, 0.6907), dark_fraction=0.0, background=(0.4, 0.4),
                         threshold=(0.25, 0.25), threshold_sigma=(0.03, 0.03), refractory_us=(0.0, 0.0),
                         noise_hz=(0.0, 0.0), hot_pixels=(0.0, 0.0), texture=(0.0, 0.0))
#: The randomized default of the train split (data/README.md says why these ranges).
RANDOM = AppearanceRanges()
#: The sensor fields (the ones the paper geometry also honours).
SENSOR_FIELDS = ("threshold", "threshold_sigma", "refractory_us", "noise_hz", "hot_pixels", "texture")


def draw(rng: np.random.Generator, name: str, rng_range: Range) -> float:
    """One value of parameter ``name`` from its range (module doc); always one random number."""
    lo, hi = float(rng_range[0]), float(rng_range[1])
    u = rng.random()
    if lo == hi:
        return lo
    if name in LOG_SCALED and lo > 0:
        return float(math.exp(math.log(lo) + u * (math.log(hi) - math.log(lo))))
    return lo + u * (hi - lo)


def holdout_cell(events_per_edge: float, size_px: float, noise_hz: float) -> tuple[int, int, int]:
    """Cell indices of the held-out partition (module doc)."""
    vals = (events_per_edge, size_px, noise_hz)
    return tuple(int(np.searchsorted(HOLDOUT_EDGES[k], v, side="right")) for k, v in zip(HOLDOUT_EDGES, vals))


def is_held_out(events_per_edge: float, size_px: float, noise_hz: float) -> bool:
    """True inside the region the appearance split draws from and training skips."""
    return sum(holdout_cell(events_per_edge, size_px, noise_hz)) % 3 == 1
