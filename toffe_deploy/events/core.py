"""The one in-memory form of events used everywhere (tonic-style structured arrays)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: x, y in pixels; t in microseconds; p polarity 1 = ON (brighter), 0 = OFF (darker).
EVENT_DTYPE = np.dtype([("x", "<u2"), ("y", "<u2"), ("t", "<i8"), ("p", "u1")])


@dataclass
class Events:
    """A time-sorted structured array of EVENT_DTYPE plus the sensor size (width, height)."""

    events: np.ndarray
    sensor_size: tuple[int, int]

    def __len__(self) -> int:
        return int(self.events.shape[0])

    @property
    def width(self) -> int:
        return int(self.sensor_size[0])

    @property
    def height(self) -> int:
        return int(self.sensor_size[1])

    @property
    def duration_us(self) -> int:
        if len(self) == 0:
            return 0
        return int(self.events["t"][-1] - self.events["t"][0])


def make_events(x, y, t, p) -> np.ndarray:
    """Build an EVENT_DTYPE array from columns (any integer-like arrays of equal length)."""
    x = np.asarray(x)
    out = np.empty(x.shape[0], dtype=EVENT_DTYPE)
    out["x"] = x
    out["y"] = y
    out["t"] = t
    out["p"] = p
    return out
