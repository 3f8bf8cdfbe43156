"""EventSource: one streaming interface over every event file format.

Why a class per format with one base: callers (dataset, train, run) want windows
[t0, t0 + dt) out of recordings far larger than memory. The base class does the generic part
once: find the first event of a time (an index like DSEC's ms_to_idx when the file has one,
otherwise a binary search on the file's t column, ~log2(N) single reads), read events in
bounded chunks, validate each chunk as it passes (coordinates, negative or decreasing
timestamps), and cut the chunk stream into windows. A format only says how many events it has,
how to read events [i0, i1) and how to read one timestamp.

Time convention: ``t_start_us`` is the first time covered (the first event, or earlier when the
file says so), ``t_end_us`` is exclusive (last event + 1 us, or later when the file says so),
so ``iter_windows`` over [t_start_us, t_end_us) sees every event exactly once.
"""
from __future__ import annotations

import abc
import os
from pathlib import Path
from typing import Iterator

import numpy as np

from .core import EVENT_DTYPE, Events, copy_events, count_before
from .validate import check_chunk

#: Events read per chunk while streaming: 1 Mi events = 15 MiB in EVENT_DTYPE.
CHUNK_EVENTS = 1 << 20


class EventSource(abc.ABC):
    """Random access and streaming over one event file (see module docstring).

    Subclasses implement ``num_events``, ``_read_index(i0, i1)`` (converted to EVENT_DTYPE,
    unvalidated) and ``_t_at(i)``; they may override ``_index_of_time`` with a faster index.
    Use as a context manager or call ``close()``.
    """

    format_name = "events"

    def __init__(self, path: str | os.PathLike, sensor_size: tuple[int, int]):
        self.path = Path(path)
        self.sensor_size = (int(sensor_size[0]), int(sensor_size[1]))
        self.chunk_events = CHUNK_EVENTS

    # ---- to implement ------------------------------------------------------------------
    @property
    @abc.abstractmethod
    def num_events(self) -> int:
        """Number of events in the file."""

    @abc.abstractmethod
    def _read_index(self, i0: int, i1: int) -> np.ndarray:
        """Events i0..i1 (unvalidated) as EVENT_DTYPE."""

    @abc.abstractmethod
    def _t_at(self, i: int) -> int:
        """Timestamp of event i."""

    # ---- metadata ----------------------------------------------------------------------
    @property
    def t_start_us(self) -> int:
        """First time covered: the first event's timestamp (0 for an empty file)."""
        return self._t_at(0) if self.num_events else 0

    @property
    def t_end_us(self) -> int:
        """Exclusive end: the last event's timestamp + 1 (t_start_us for an empty file)."""
        return self._t_at(self.num_events - 1) + 1 if self.num_events else self.t_start_us

    @property
    def duration_us(self) -> int:
        return self.t_end_us - self.t_start_us

    @property
    def ground_truth(self) -> dict[str, np.ndarray] | None:
        """Per-object ground truth columns, or None when the file carries none."""
        return None

    @property
    def attrs(self) -> dict:
        """Free-form metadata stored with the events (JSON-decoded); {} when none."""
        return {}

    # ---- access ------------------------------------------------------------------------
    def _index_of_time(self, t: int) -> int:
        """First event index whose timestamp is >= t (binary search on the t column)."""
        lo, hi = 0, self.num_events
        while lo < hi:
            mid = (lo + hi) // 2
            if self._t_at(mid) < t:
                lo = mid + 1
            else:
                hi = mid
        return lo

    def read_index(self, i0: int, i1: int, prev_t: int | None = None) -> np.ndarray:
        """Events i0..i1-1, validated (``prev_t``: last timestamp before i0, if known)."""
        i0, i1 = max(0, int(i0)), min(self.num_events, int(i1))
        if i1 <= i0:
            return np.empty(0, EVENT_DTYPE)
        ev = self._read_index(i0, i1)
        check_chunk(self.path, ev, self.sensor_size, offset=i0, prev_t=prev_t)
        return ev

    def read(self, t0: int, t1: int) -> np.ndarray:
        """All events with t0 <= t < t1 (memory: just those events)."""
        if t1 <= t0:
            return np.empty(0, EVENT_DTYPE)
        i0 = self._index_of_time(int(t0))
        i1 = self._index_of_time(int(t1))
        return self.read_index(i0, i1)

    def iter_chunks(self, t_start: int | None = None, t_end: int | None = None) -> Iterator[np.ndarray]:
        """Validated, time-ordered chunks of at most ``chunk_events`` events in [t_start, t_end).

        A range from the file's first event or to its last one reads from index 0 or to the end
        instead of searching: the search assumes sorted times, and on a file whose time goes
        back near either end it skipped events that then never reached the order check (a
        converted copy silently lacked them)."""
        t_start = self.t_start_us if t_start is None else int(t_start)
        t_end = self.t_end_us if t_end is None else int(t_end)
        i, i_end = self._index_of_time(t_start), self._index_of_time(t_end)   # (a seek index is checked here)
        i = 0 if t_start <= self.t_start_us else i
        i_end = self.num_events if t_end >= self.t_end_us else i_end
        prev_t = None
        while i < i_end:
            j = min(i + self.chunk_events, i_end)
            ev = self.read_index(i, j, prev_t)
            prev_t = int(ev["t"][-1])
            yield ev
            i = j

    def iter_windows(self, dt_us: int, t_start: int | None = None, t_end: int | None = None,
                     skip_empty_after: int | None = None) -> Iterator[tuple[int, np.ndarray]]:
        """Yield (t0, events with t0 <= t < t0 + dt_us) for t0 = t_start, t_start + dt, ...

        Windows up to and including the one holding t_end - 1; an empty window is an empty array,
        not an error. Reads the file chunk by chunk: memory is one chunk plus one window.
        ``skip_empty_after`` = N: after N consecutive empty windows, jump straight to the window
        holding the next event (or past the end), so an hours-long gap costs N windows, not
        millions; callers see the jump as a t0 step larger than dt_us.
        """
        dt_us = int(dt_us)
        if dt_us <= 0:
            raise ValueError(f"window length must be positive, got {dt_us} us")
        t_start = self.t_start_us if t_start is None else int(t_start)
        t_end = self.t_end_us if t_end is None else int(t_end)
        if t_end <= t_start:
            return
        n_windows = -(-(t_end - t_start) // dt_us)
        chunks = self.iter_chunks(t_start, t_start + n_windows * dt_us)
        buf = np.empty(0, EVENT_DTYPE)
        exhausted = False
        w = n_empty = 0
        while w < n_windows:
            t0 = t_start + w * dt_us
            t1 = t0 + dt_us
            while not exhausted and (buf.shape[0] == 0 or buf["t"][-1] < t1):
                nxt = next(chunks, None)
                if nxt is None:
                    exhausted = True
                else:
                    buf = np.concatenate([buf, nxt]) if buf.shape[0] else nxt
            cut = count_before(buf, t1)
            yield t0, copy_events(buf[:cut])
            buf = buf[cut:]
            w += 1
            n_empty = 0 if cut else n_empty + 1
            if skip_empty_after is not None and n_empty >= skip_empty_after:
                # the fill loop above left the next event (if any) at buf[0]
                w = max(w, (int(buf["t"][0]) - t_start) // dt_us) if buf.shape[0] else n_windows
                n_empty = 0

    def read_unordered(self) -> np.ndarray:
        """Every event, checked for coordinates and negative times but not for order (sorting)."""
        ev = self._read_index(0, self.num_events) if self.num_events else np.empty(0, EVENT_DTYPE)
        check_chunk(self.path, ev, self.sensor_size, check_order=False)
        return ev

    def read_all(self) -> Events:
        """The whole file in memory, validated."""
        parts = list(self.iter_chunks())
        ev = np.concatenate(parts) if parts else np.empty(0, EVENT_DTYPE)
        return Events(ev, self.sensor_size)

    # ---- lifetime ----------------------------------------------------------------------
    def close(self) -> None:
        pass

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def __repr__(self) -> str:
        w, h = self.sensor_size
        return (f"<{type(self).__name__} {self.path} {self.num_events} events {w}x{h} "
                f"t=[{self.t_start_us}, {self.t_end_us}) us>")


class ArraySource(EventSource):
    """An EventSource over events already in memory (npz files, sorted loads, tests)."""

    format_name = "array"

    def __init__(self, path, events: np.ndarray, sensor_size, ground_truth=None, attrs=None,
                 t_range: tuple[int, int] | None = None, validated: bool = False):
        super().__init__(path, sensor_size)
        self._ev = events
        self._gt = ground_truth
        self._attrs = dict(attrs or {})
        self._t_range = t_range
        self._checked = validated

    def _check_once(self) -> None:
        """Validate the whole array on first access (not at construction, so sort=True can
        take an unsorted array first)."""
        if not self._checked:
            check_chunk(self.path, self._ev, self.sensor_size)
            self._checked = True

    @property
    def num_events(self) -> int:
        return int(self._ev.shape[0])

    def _read_index(self, i0, i1):
        return self._ev[i0:i1]

    def _t_at(self, i):
        return int(self._ev["t"][i])

    def _index_of_time(self, t):
        return int(np.searchsorted(self._ev["t"], t, side="left"))

    def read_index(self, i0, i1, prev_t=None):
        self._check_once()
        return self._ev[max(0, i0):max(0, i1)]

    @property
    def t_start_us(self):
        return self._t_range[0] if self._t_range else super().t_start_us

    @property
    def t_end_us(self):
        return self._t_range[1] if self._t_range else super().t_end_us

    @property
    def ground_truth(self):
        return self._gt

    @property
    def attrs(self):
        return self._attrs
