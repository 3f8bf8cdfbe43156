"""Checks on event data, done chunk by chunk while reading so that streaming stays bounded.

Every problem becomes an InputError naming the file, the event index and what is wrong, so a
user sees one line (``FILE: x = 700 outside the 640x480 sensor at event 12``), never a traceback.
"""
from __future__ import annotations

import os

import numpy as np

from ..errors import InputError
from .core import EVENT_DTYPE

#: Fields every event array must carry (EVENT_DTYPE's names).
REQUIRED_FIELDS = tuple(EVENT_DTYPE.names)


def check_sensor_size(path: str | os.PathLike, sensor_size) -> tuple[int, int]:
    """A (width, height) pair of positive ints that fit EVENT_DTYPE's uint16 coordinates."""
    try:
        w, h = (int(v) for v in sensor_size)
    except (TypeError, ValueError):
        raise InputError(path, f"sensor size must be (width, height), got {sensor_size!r}") from None
    if not (0 < w <= 65535 and 0 < h <= 65535):
        raise InputError(path, f"sensor size {w}x{h} is not in 1..65535 x 1..65535")
    return w, h


def check_chunk(path: str | os.PathLike, ev: np.ndarray, sensor_size: tuple[int, int], offset: int = 0,
                prev_t: int | None = None, check_order: bool = True) -> None:
    """Raise InputError for the first bad event of ``ev`` (events ``offset``.. of the file).

    Checks: coordinates inside the sensor, no negative timestamps and (``check_order``) no
    timestamp smaller than the one before it, ``prev_t`` being the last of the previous chunk.
    Vectorized: one pass of numpy comparisons per check.
    """
    if ev.shape[0] == 0:
        return
    w, h = sensor_size
    for name, limit in (("x", w), ("y", h)):
        bad = np.flatnonzero(ev[name] >= limit)
        if bad.size:
            i = int(bad[0])
            raise InputError(path, f"{name} = {int(ev[name][i])} outside the {w}x{h} sensor at event "
                                   f"{offset + i} (give the right sensor size?)")
    t = ev["t"]
    bad = np.flatnonzero(t < 0)
    if bad.size:
        i = int(bad[0])
        raise InputError(path, f"negative timestamp t = {int(t[i])} us at event {offset + i}")
    if not check_order:
        return
    if prev_t is not None and t[0] < prev_t:
        raise InputError(path, f"timestamps decrease at event {offset}: t = {int(t[0])} us after "
                               f"{int(prev_t)} us (events must be time-sorted; sort them with --sort "
                               "/ sort=True, which loads the whole file)")
    bad = np.flatnonzero(np.diff(t) < 0)
    if bad.size:
        i = int(bad[0]) + 1
        raise InputError(path, f"timestamps decrease at event {offset + i}: t = {int(t[i])} us after "
                               f"{int(t[i - 1])} us (events must be time-sorted; sort them with --sort "
                               "/ sort=True, which loads the whole file)")


def coordinates_in_range(path, name: str, values: np.ndarray, offset: int = 0) -> None:
    """Raw coordinates must be whole numbers in 0..65535 before they become uint16."""
    if values.size == 0:
        return
    v = np.asarray(values)
    bad = (v < 0) | (v > 65535)
    if np.issubdtype(v.dtype, np.floating):
        bad |= ~np.isfinite(v) | (v != np.round(v))
    idx = np.flatnonzero(bad)
    if idx.size:
        i = int(idx[0])
        raise InputError(path, f"{name} = {v[i]!r} at event {offset + i} is not a pixel coordinate")
