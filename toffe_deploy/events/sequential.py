"""SequentialSource: the EventSource of formats without a seek index (AEDAT4, Prophesee RAW and
DAT, ROS bags), which can only be decoded from the start.

Windows stream packet by packet (memory: one decoded packet plus one window); metadata (event
count, time span) costs one decoding pass, done lazily and cached; random access by index
decodes from the start. A format says only how to decode its packets, in file order.

Seeking by time: a format that can restart decoding at a packet (RAW, DAT: a byte position and
the decoder state) sets ``_cursor`` to that restart point before decoding each packet and
accepts it back as ``_packets(resume=...)``. The metadata pass then keeps one restart point per
packet (a few numbers per 4 MiB), and a window or ``read`` starting at time t decodes from the
first packet that reaches t instead of from the start.
"""
from __future__ import annotations

import bisect

import abc
from typing import Iterator

import numpy as np

from ..errors import InputError
from .core import EVENT_DTYPE
from .source import EventSource
from .validate import check_chunk


class SequentialSource(EventSource):
    """An EventSource over ``_packets()``: converted, unvalidated EVENT_DTYPE arrays in file order."""

    _meta = None
    #: restart point of the packet being decoded (formats that can seek set it; see module docstring)
    _cursor = None
    #: per packet with events: (restart point, events before it, last time before it, its last time)
    _points = None
    #: whether the metadata pass found the events in time order (None: no pass yet)
    _ordered = None
    #: the metadata pass's InputError naming the first decrease of time, or None
    disorder = None

    @abc.abstractmethod
    def _packets(self, resume=None) -> Iterator[np.ndarray]:
        """Decoded events of each packet, in file order (unvalidated), from the start or from
        a restart point ``resume`` (only formats that set ``_cursor`` get one)."""

    def _scan(self):
        if self._meta is None:
            for _ in self._iter_all(check=False):
                pass
        return self._meta

    @property
    def num_events(self):
        return self._scan()[0]

    @property
    def t_start_us(self):
        return self._scan()[1]

    @property
    def t_end_us(self):
        return self._scan()[2]

    def iter_chunks(self, t_start=None, t_end=None):
        if t_start is None and t_end is None and self._meta is None:
            yield from self._iter_all()       # the whole file: no scan pass first, the metadata after
            return
        t_start = self.t_start_us if t_start is None else int(t_start)
        t_end = self.t_end_us if t_end is None else int(t_end)
        offset, prev_t, packets = 0, None, None
        if self._points:
            k = bisect.bisect_left([pt[3] for pt in self._points], t_start)
            if k == len(self._points):
                return
            resume, offset, prev_t, _ = self._points[k]
            packets = self._packets(resume=resume)
        for ev in packets if packets is not None else self._packets():
            check_chunk(self.path, ev, self.sensor_size, offset=offset, prev_t=prev_t)
            offset += int(ev.shape[0])
            if ev.shape[0] == 0:
                continue
            prev_t = int(ev["t"][-1])
            if prev_t < t_start:
                continue
            if int(ev["t"][0]) >= t_end and self._ordered is not False:
                return          # out of order (found unchecked by the metadata pass): read on, so the
                                # check above names the disorder instead of the span ending early
            i0, i1 = np.searchsorted(ev["t"], [t_start, t_end], side="left")
            if i1 > i0:
                yield ev[i0:i1]

    def _iter_all(self, check: bool = True):
        """Every packet (validated when ``check``); records the metadata and restart points."""
        offset, first, prev_t, points, ordered = 0, None, None, [], True
        for ev in self._packets():
            # the values always (the metadata pass reads the whole file before a run writes a line),
            # the order only when ``check``: open_events(sort=True) sorts what this pass finds
            check_chunk(self.path, ev, self.sensor_size, offset=offset, prev_t=prev_t, check_order=check)
            if ev.shape[0]:
                # seeking needs time order (unchecked here for sort=True): a disorder disables it
                was = ordered
                ordered = ordered and (prev_t is None or int(ev["t"][0]) >= prev_t) \
                    and bool(np.all(ev["t"][1:] >= ev["t"][:-1]))
                if was and not ordered:           # the error a reading would raise, for open_events
                    try:
                        check_chunk(self.path, ev, self.sensor_size, offset=offset, prev_t=prev_t)
                    except InputError as exc:
                        self.disorder = exc
                points.append((self._cursor, offset, prev_t, int(ev["t"][-1])))
                first = int(ev["t"][0]) if first is None else first
                prev_t = int(ev["t"][-1])
                offset += int(ev.shape[0])
                yield ev
        self._meta = (offset, first if first is not None else 0, prev_t + 1 if prev_t is not None else 0)
        self._ordered = ordered
        self._points = points if ordered and points and all(pt[0] is not None for pt in points) else None

    def read(self, t0, t1):
        parts = list(self.iter_chunks(t0, t1)) if t1 > t0 else []
        return np.concatenate(parts) if parts else np.empty(0, EVENT_DTYPE)

    def _read_index(self, i0, i1):
        # No seek index: decode the packets and slice (the base class validates).
        return self.read_unordered()[max(0, i0):max(0, i1)]

    def _t_at(self, i):
        return int(self.read_unordered()["t"][i])

    def read_unordered(self):
        parts = list(self._packets())
        ev = np.concatenate(parts) if parts else np.empty(0, EVENT_DTYPE)
        check_chunk(self.path, ev, self.sensor_size, check_order=False)
        return ev

    def _index_of_time(self, t):
        # No seek index: a full decode, then a search (read() and iter_chunks() stream instead).
        return int(np.searchsorted(self.read_unordered()["t"], t, side="left"))
