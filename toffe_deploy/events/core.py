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


def copy_events(events: np.ndarray) -> np.ndarray:
    """A writable copy of a contiguous EVENT_DTYPE array (a window cut off a reader's buffer).
    Why not ``events.copy()``: numpy copies an unaligned structured array field by field,
    ~19 us for a window of 2,200 events against ~2 us for its bytes (measured 2026-11-24)."""
    if not events.flags.c_contiguous:
        return events.copy()
    return events.view(np.uint8).copy().view(EVENT_DTYPE)


def count_before(events: np.ndarray, t: int) -> int:
    """How many of the time-sorted ``events`` come before time t: np.searchsorted on
    events["t"], left side. Why not that call itself: the field is a strided, unaligned view
    (13-byte records), which searchsorted copies whole before searching; cutting the next
    window off a 0.4 M-event buffer cost ~0.2 ms a window. Here it searches a prefix that grows
    4x until it holds t, so a window's cut copies a few windows' times at most."""
    times = events["t"]
    n = times.shape[0]
    hi = min(n, 4096)
    while hi < n and times[hi - 1] < t:
        hi = min(n, hi * 4)
    return int(np.searchsorted(np.ascontiguousarray(times[:hi]), t, side="left"))
