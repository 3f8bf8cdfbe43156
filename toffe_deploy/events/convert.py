"""Raw columns from any format -> EVENT_DTYPE, with the checks the cast would otherwise hide.

Why a separate step: a negative or fractional coordinate would silently wrap or truncate in a
uint16 cast, and a time in seconds would silently become 0 us; each reader converts through
here so the user hears about it instead.
"""
from __future__ import annotations

import numpy as np

from ..errors import InputError
from .core import EVENT_DTYPE
from .validate import BEYOND_HINT, coordinates_in_range


def polarity01(path, p: np.ndarray, offset: int = 0) -> np.ndarray:
    """Polarity as 1 = ON, 0 = OFF from any common encoding: bool, 0/1, -1/+1 (p > 0 is ON).

    Any other value (7, -3, NaN, 0.5) is an InputError: it means a wrong column or a corrupt
    file, which ``p > 0`` would silently turn into ON/OFF events. So is a column holding both -1
    and 0 (in the events read together, a reader's chunk): neither encoding, and both would read
    as OFF.
    """
    p = np.asarray(p)
    if p.dtype != np.bool_ and p.size:
        zero, minus = p == 0, p == -1
        bad = np.flatnonzero(~(zero | (p == 1) | minus))
        if bad.size:
            i = int(bad[0])
            raise InputError(path, f"polarity p = {p[i]!r} at event {offset + i} is not 0/1, -1/+1 or a bool")
        if minus.any() and zero.any():
            i, j = int(np.argmax(minus)), int(np.argmax(zero))
            raise InputError(path, f"polarity holds both -1 (event {offset + i}) and 0 (event {offset + j}): "
                                   "neither the 0/1 nor the -1/+1 encoding")
    return (p > 0).astype(np.uint8)


def time_us(path, t: np.ndarray, offset: int = 0, scale: float = 1.0, what: str = "t") -> np.ndarray:
    """Timestamps as int64 microseconds: t * scale (rounded when scaled from float seconds).

    With scale 1 a float column must hold whole numbers (microseconds), else InputError: the
    likely cause is a time in seconds, which would silently collapse to a few microseconds.
    """
    t = np.asarray(t)
    if np.issubdtype(t.dtype, np.floating):
        if not np.isfinite(t).all():
            i = int(np.flatnonzero(~np.isfinite(t))[0])
            raise InputError(path, f"{what} = {t[i]!r} at event {offset + i} is not a finite time")
        big = np.flatnonzero(np.abs(t) * scale > 2.0 ** 53)      # int64's cast wrapped these to -2**63
        if big.size:
            i = int(big[0])
            raise InputError(path, f"{what} = {t[i]!r} at event {offset + i} is beyond 2**53 us ({BEYOND_HINT})")
        if scale == 1.0:
            frac = np.flatnonzero(t != np.round(t))
            if frac.size:
                i = int(frac[0])
                raise InputError(path, f"{what} = {t[i]!r} at event {offset + i} is not a whole number of "
                                       "microseconds (a time in seconds? times must be in us)")
            return t.astype(np.int64)
        return np.round(t * scale).astype(np.int64)
    if not (np.issubdtype(t.dtype, np.integer) or t.dtype == np.bool_):
        raise InputError(path, f"{what} has dtype {t.dtype}, expected integer or float times")
    if t.dtype == np.uint64 and t.size and int(t.max()) > 2 ** 53:     # read as int64 it went negative
        i = int(np.argmax(t > 2 ** 53))
        raise InputError(path, f"{what} = {int(t[i])} at event {offset + i} is beyond 2**53 us ({BEYOND_HINT})")
    t = t.astype(np.int64)
    return t * int(scale) if scale != 1.0 else t


def to_events(path, x, y, t_us: np.ndarray, p, offset: int = 0) -> np.ndarray:
    """An EVENT_DTYPE array from columns; coordinates must be whole numbers in 0..65535."""
    n = np.asarray(t_us).shape[0]
    for name, col in (("x", x), ("y", y), ("p", p)):
        a = np.asarray(col)
        if a.shape != (n,):
            raise InputError(path, f"column {name} has shape {a.shape}, expected ({n},): one number per event")
        if a.dtype.kind not in "biuf":               # complex numbers too: a cast drops the imaginary part
            raise InputError(path, f"column {name} has dtype {a.dtype}, expected real numbers")
    coordinates_in_range(path, "x", x, offset)
    coordinates_in_range(path, "y", y, offset)
    out = np.empty(np.asarray(t_us).shape[0], EVENT_DTYPE)
    out["x"] = x
    out["y"] = y
    out["t"] = t_us
    out["p"] = polarity01(path, p, offset)
    return out


class TimeUnitCheck:
    """Whether a recording's timestamps look like nanoseconds read as microseconds, which no
    reader can refuse (both are integers): ``feed`` it timestamps (int64 us, any chunks), then
    ``hint()`` is one sentence or None.

    The sign: every timestamp a multiple of 1000 over at least ``min_events`` events spanning
    more than 1000 us (a us-resolution camera stored in ns, as ROS messages and many loggers
    write it; a camera's microseconds sit on every value, and 100 of them all on multiples of
    1000 by chance is a 1e-300 event). A recording quantized to whole milliseconds gets the hint
    too, which is why it says "if". Unix-epoch nanoseconds (~1.7e18) never get here: they lie
    beyond validate.MAX_TIME_US, refused with BEYOND_HINT."""

    def __init__(self, min_events: int = 100):
        self.min_events = int(min_events)
        self.events = 0
        self.chunks = 0                  # non-empty feeds (a run's windows with events)
        self.all_kilo = True
        self.t_min: int | None = None
        self.t_max: int | None = None

    def feed(self, t: np.ndarray) -> None:
        if t.size == 0:
            return
        self.chunks += 1
        self.events += int(t.size)
        lo, hi = int(t.min()), int(t.max())
        self.t_min = lo if self.t_min is None else min(self.t_min, lo)
        self.t_max = hi if self.t_max is None else max(self.t_max, hi)
        if self.all_kilo:
            self.all_kilo = not (t % 1000).any()

    @property
    def decided(self) -> bool:
        """Whether more timestamps can no longer change ``hint()`` (a caller may stop feeding)."""
        return self.t_max is not None and (not self.all_kilo or (
            self.events >= self.min_events and self.t_max - self.t_min > 1000))

    def hint(self) -> str | None:
        if self.t_max is None:
            return None
        if self.all_kilo and self.events >= self.min_events and self.t_max - self.t_min > 1000:
            return (f"every timestamp of {self.events:,} events is a multiple of 1000 us: if they are nanoseconds, "
                    "divide t by 1000 (times must be in microseconds)")
        return None
