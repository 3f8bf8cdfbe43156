"""AEDAT4 (iniVation DV) through the ``aedat`` package (MIT/Apache, Rust decoder).

AEDAT4 is a stream of compressed packets with no seek index, so this reader is sequential:
windows stream packet by packet (memory: one packet plus one window), and metadata (event
count, time span) costs one decoding pass, done lazily and cached. The sensor size comes from
the file's event stream description; the first event stream is used. Polarity ``on`` -> p = 1.
"""
from __future__ import annotations

from typing import Iterator

import numpy as np

from ..errors import InputError
from .convert import to_events
from .core import EVENT_DTYPE
from .source import EventSource
from .validate import check_chunk, check_sensor_size


def _decoder(path):
    try:
        import aedat
    except ImportError:
        raise InputError(path, "reading AEDAT4 needs the aedat package (pip install aedat)") from None

    try:
        return aedat.Decoder(str(path))
    except Exception as exc:  # the Rust decoder raises plain RuntimeError/OSError variants
        raise InputError(path, f"cannot read AEDAT4 file (truncated or corrupt?): {exc}") from None


class AedatSource(EventSource):
    format_name = "aedat4"

    def __init__(self, path, sensor_size=None):
        dec = _decoder(path)
        streams = {k: v for k, v in dec.id_to_stream().items() if v.get("type") == "events"}
        if not streams:
            raise InputError(path, "AEDAT4 file has no event stream")
        self._stream = min(streams)
        info = streams[self._stream]
        own = (int(info.get("width", 0)), int(info.get("height", 0)))
        super().__init__(path, check_sensor_size(path, sensor_size or own))
        self._meta = None

    def _packets(self) -> Iterator[np.ndarray]:
        """Converted events of each packet of our stream, in file order (unvalidated)."""
        dec = _decoder(self.path)
        while True:
            try:
                packet = next(dec)
            except StopIteration:
                return
            except Exception as exc:
                raise InputError(self.path, f"cannot decode AEDAT4 packet (truncated or corrupt?): "
                                            f"{exc}") from None
            if packet.get("stream_id") != self._stream or "events" not in packet:
                continue
            e = packet["events"]
            yield to_events(self.path, e["x"], e["y"], e["t"].astype(np.int64), e["on"])

    def _scan(self):
        if self._meta is None:
            n, first, last = 0, None, None
            for ev in self._packets():
                if ev.shape[0]:
                    first = int(ev["t"][0]) if first is None else first
                    last = int(ev["t"][-1])
                    n += int(ev.shape[0])
            self._meta = (n, first if first is not None else 0, last + 1 if last is not None else 0)
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
        t_start = self.t_start_us if t_start is None else int(t_start)
        t_end = self.t_end_us if t_end is None else int(t_end)
        offset, prev_t = 0, None
        for ev in self._packets():
            check_chunk(self.path, ev, self.sensor_size, offset=offset, prev_t=prev_t)
            offset += int(ev.shape[0])
            if ev.shape[0] == 0:
                continue
            prev_t = int(ev["t"][-1])
            if prev_t < t_start:
                continue
            if int(ev["t"][0]) >= t_end:
                return
            i0, i1 = np.searchsorted(ev["t"], [t_start, t_end], side="left")
            if i1 > i0:
                yield ev[i0:i1]

    def read(self, t0, t1):
        parts = list(self.iter_chunks(t0, t1)) if t1 > t0 else []
        return np.concatenate(parts) if parts else np.empty(0, EVENT_DTYPE)

    def _read_index(self, i0, i1):
        # No seek index in AEDAT4: decode the packets and slice (the base class validates).
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
