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
#: Largest timestamp accepted (us): 2**53, ~285 years, covers Unix-epoch microseconds and stays
#: exact in float64; larger values are corrupt (int64 max would make every window loop overflow).
MAX_TIME_US = 2 ** 53
#: what a time beyond MAX_TIME_US likely is: Unix-epoch nanoseconds (~1.7e18) pass it, microseconds never
BEYOND_HINT = "nanoseconds? times must be in microseconds: divide t by 1000; else corrupt"
#: Longest recording accepted (us): one week. Longer spans are a corrupt timestamp, not a recording.
MAX_DURATION_US = 7 * 24 * 3600 * 10 ** 6


def check_time_span(path: str | os.PathLike, t_start_us: int, t_end_us: int) -> None:
    """The span a file covers ends by MAX_TIME_US and lasts at most MAX_DURATION_US.

    (Negative or decreasing timestamps are reported by check_chunk, with the event index.)
    """
    if max(t_start_us, t_end_us) > MAX_TIME_US:
        raise InputError(path, f"time span [{t_start_us}, {t_end_us}) us goes beyond 2**53 us "
                               f"({BEYOND_HINT})")
    if t_end_us - t_start_us > MAX_DURATION_US:
        raise InputError(path, f"spans {(t_end_us - t_start_us) / 86400e6:,.1f} days, more than the 7 days "
                               "toffe-deploy accepts (a corrupt timestamp?)")


def check_event_ends(path: str | os.PathLike, src) -> None:
    """For a source with random access (``src._t_at``): its last event is not before its first,
    and the span it reports covers both. Why: a reader reads the windows of [t_start_us,
    t_end_us), and time order is otherwise checked as the chunks are read; a last event before
    the first made that span empty (a .npy read as 0 windows, exit 0), and a span recorded in
    the file's attrs shorter than its events dropped the rest silently."""
    n = int(src.num_events)
    if n == 0:
        return
    first, last = int(src._t_at(0)), int(src._t_at(n - 1))
    if last < first:
        raise InputError(path, f"timestamps decrease: the last event (t = {last} us) is before the first "
                               f"(t = {first} us) {SORT_HINT}")
    t0, t1 = int(src.t_start_us), int(src.t_end_us)
    if not (t0 <= first and last < t1):
        raise InputError(path, f"its recorded time span [{t0}, {t1}) us does not hold its events "
                               f"(t = {first} .. {last} us): t_start_us / t_end_us are wrong")


def whole_number(name: str, v) -> int:
    """``v`` as an int when it is a whole number (a Python or numpy int, or a float like 640.0);
    ValueError for 640.7, true or "640", which int() turned silently into 640, 1 or 640
    (sensor sizes in files, integers in config.json)."""
    if isinstance(v, np.ndarray) and v.ndim == 0:
        v = v[()]                                # a 0-d array, as int() takes it
    if isinstance(v, (bool, np.bool_)) or not isinstance(v, (int, float, np.integer, np.floating)) \
            or not float(v).is_integer():
        raise ValueError(f"{name} must be a whole number, got {v!r}")
    return int(v)


def check_sensor_size(path: str | os.PathLike, sensor_size) -> tuple[int, int]:
    """A (width, height) pair of positive ints that fit EVENT_DTYPE's uint16 coordinates."""
    try:
        w, h = (whole_number("sensor size", v) for v in sensor_size)
    except (TypeError, ValueError):
        raise InputError(path, f"sensor size must be (width, height) in whole pixels, got {sensor_size!r}") from None
    if not (0 < w <= 65535 and 0 < h <= 65535):
        raise InputError(path, f"sensor size {w}x{h} is not in 1..65535 x 1..65535")
    return w, h


SORT_HINT = ("(events must be time-sorted: 'toffe-deploy events convert --sort IN OUT.h5' writes a sorted copy; "
             "open_events(sort=True) in Python)")


def check_chunk(path: str | os.PathLike, ev: np.ndarray, sensor_size: tuple[int, int], offset: int = 0,
                prev_t: int | None = None, check_order: bool = True) -> None:
    """Raise InputError for the first bad event of ``ev`` (events ``offset``.. of the file).

    Checks: coordinates inside the sensor, polarities 0/1, no negative timestamps and (``check_order``) no
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
    bad = np.flatnonzero(ev["p"] > 1)
    if bad.size:
        i = int(bad[0])
        raise InputError(path, f"polarity p = {int(ev['p'][i])} at event {offset + i} is not 0/1")
    t = ev["t"]
    bad = np.flatnonzero((t < 0) | (t > MAX_TIME_US))
    if bad.size:
        i = int(bad[0])
        what = "negative timestamp" if t[i] < 0 else f"timestamp beyond 2**53 us ({BEYOND_HINT})"
        raise InputError(path, f"{what} t = {int(t[i])} us at event {offset + i}")
    if not check_order:
        return
    if prev_t is not None and t[0] < prev_t:
        raise InputError(path, f"timestamps decrease at event {offset}: t = {int(t[0])} us after "
                               f"{int(prev_t)} us {SORT_HINT}")
    bad = np.flatnonzero(np.diff(t) < 0)
    if bad.size:
        i = int(bad[0]) + 1
        raise InputError(path, f"timestamps decrease at event {offset + i}: t = {int(t[i])} us after "
                               f"{int(t[i - 1])} us {SORT_HINT}")


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


def check_ground_truth(path, gt: dict, required=()) -> dict:
    """Ground-truth columns: the ``required`` names present, every column 1-D and of one length.

    A short or missing column would otherwise surface as an IndexError / KeyError deep in the
    per-window truth lookup.
    """
    missing = [k for k in required if k not in gt]
    if missing:
        raise InputError(path, f"/ground_truth lacks columns {', '.join(missing)}")
    shapes = {k: np.shape(v) for k, v in gt.items()}
    if any(len(s) != 1 for s in shapes.values()) or len({s[0] for s in shapes.values()}) > 1:
        desc = ", ".join(f"{k} {list(s)}" for k, s in shapes.items())
        raise InputError(path, f"/ground_truth columns must be 1-D and of one length, got {desc}")
    for k, v in gt.items():                     # numbers, finite where they are set (a NaN or inf direction
        a = np.asarray(v)                       # gave dirE nan with exit 0, and dataset show an IndexError)
        if not (np.issubdtype(a.dtype, np.number) or a.dtype == np.bool_):
            raise InputError(path, f"/ground_truth/{k} has dtype {a.dtype}, expected numbers")
        if k in _GT_FINITE and np.issubdtype(a.dtype, np.floating) and not np.isfinite(a).all():
            i = int(np.flatnonzero(~np.isfinite(a))[0])
            raise InputError(path, f"/ground_truth/{k} = {a[i]!r} at row {i} is not a finite number")
    for k, lo, hi in (("speed_bin", 0, 127), ("visible", 0, 1)):
        a = np.asarray(gt.get(k, []))
        if a.size and (a.min() < lo or a.max() > hi or (np.issubdtype(a.dtype, np.floating) and (a != np.round(a)).any())):
            bad = a[(a < lo) | (a > hi) | (a != np.round(a))][0]
            raise InputError(path, f"/ground_truth/{k} holds {bad!r}: expected whole numbers {lo}..{hi}")
    d = np.asarray(gt.get("depth_m", []))
    if d.size and (np.isfinite(d) & (d <= 0)).any():
        raise InputError(path, f"/ground_truth/depth_m holds {d[np.isfinite(d) & (d <= 0)][0]!r}: a depth is > 0")
    _check_truth_order(path, gt)
    return gt


def _check_truth_order(path, gt: dict) -> None:
    """Each object's samples in time order: the per-window lookup interpolates between the two
    samples around a window's midpoint found by bisection, and on a ``t`` that runs backwards it
    took the wrong two (wrong scores, exit 0). Rows in time order (the writer's) pass in one
    comparison; rows grouped by object are fine too."""
    t = np.asarray(gt.get("t", []))
    if t.shape[0] < 2 or not (t[1:] < t[:-1]).any():     # compared, not np.diff: unsigned t wraps
        return
    ids = np.asarray(gt["object_id"]) if "object_id" in gt else np.zeros(t.shape[0], np.int8)
    order = np.argsort(ids, kind="stable")
    ts, os_ = t[order], ids[order]
    back = np.flatnonzero((ts[1:] < ts[:-1]) & (os_[1:] == os_[:-1]))
    if back.size:
        j = int(back[0])
        raise InputError(path, f"/ground_truth/t runs backwards at row {int(order[j + 1])}: {ts[j + 1].item()} us after "
                               f"{ts[j].item()} us of object {os_[j].item()} (each object's rows must be in time order)")


#: ground-truth columns that must be finite (speed_px_ms and depth_m may be NaN: not known)
_GT_FINITE = ("t", "object_id", "x", "y", "direction", "speed")
