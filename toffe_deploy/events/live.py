"""Live event sources behind one interface: stdin, UDP AER (aestream / SPIF), DV network streams, DV cameras.

Why a reader thread and a bounded queue: a camera or a socket does not wait for us. Each source's
reader thread turns what arrives into EVENT_DTYPE chunks and puts them in a ``ChunkQueue`` that
holds at most ``max_events`` events; when a chunk does not fit, the oldest chunks are dropped (and
counted) until it does, so the reader never blocks and the run always works on the newest data.
The run's thread cuts windows [t0, t0 + dt) by event time, as ``EventSource.iter_windows`` does
for files, from the first event's timestamp on.

Clock: a source's timestamps are mapped to host time at the first event,

    host(t) = host_first + (t - t_first) * 1e-6 s

(``host_first``: ``time.perf_counter()`` when the chunk holding the first event arrived). A window
is closed when an event at or past its end arrives, or when host time passes close(t1) + the
grace (``grace_s``, default GRACE_S; ``run --window-grace-ms``) with nothing newer in the queue
and the producer quiet for QUIET_GAPS of its usual lag gaps (wall time between chunks less the
stream time between them: ~0 for a real-time source; a quiet stream still yields its windows on
time). close(t) is host(t) moved later whenever a chunk arrives later than its newest event
maps (close(t_newest) <= its arrival): a producer slower than real time (a pipe from a
converter, a driver that buffers, one that sends a chunk every 50 ms) has its windows closed
at its own pace, by its events, not by the clock before its events come. A
producer that stalls for much longer than its usual gaps and the grace has the windows of the
stall closed empty on time, as a quiet camera's; its events that then come are late.
An event older than the window being filled arrived too late: it is dropped and counted (the
run's summary says how many and how to give a stalling producer longer). After
the queue dropped chunks, the windows whose events were dropped are jumped over (no line: they
were not empty, their events are gone; counted in ``dropped_windows``), so a run that falls
behind works on the newest events instead of walking through the lost span. The
latency of a window is the time its line was written minus host(newest event in the window).

Formats: see README.md, "Live sources" (``-``: a 16-byte header then EVENT_DTYPE records on
stdin; ``udp://HOST:PORT``: aestream's SPIF-style 32-bit AER words, with or without 32-bit
timestamps; ``dv://HOST:PORT`` and ``dv-camera[:SERIAL]`` through dv-processing).
"""
from __future__ import annotations

import abc
import collections
import math
import os
import select
import socket
import struct
import sys
import threading
import time
from dataclasses import asdict, dataclass
from typing import Iterator

import numpy as np

from ..errors import InputError
from .core import EVENT_DTYPE, copy_events, count_before
from .validate import check_chunk, check_sensor_size

#: Default bound of the live queue, in events (about 1 s of a busy 1 Mev/s camera, 13 MB).
QUEUE_EVENTS = 1 << 20
#: How long past a window's end (host time) the run waits for late events before closing it.
GRACE_S = 0.005
#: stdin stream: magic, then u16 version, u16 width, u16 height, u16 reserved (little-endian).
STDIN_MAGIC = b"TOFFE-EV"
STDIN_HEADER = struct.Struct("<8sHHHH")
STDIN_VERSION = 1
#: the clock closes a window only once the producer has been quiet for QUIET_GAPS of its usual
#: lag gaps (wall time between chunks less their stream time; a decaying maximum, GAP_DECAY per
#: chunk): a pipe that delivers 0.5 ms of events every 50 ms is not a quiet stream between them
QUIET_GAPS, GAP_DECAY = 2.0, 0.95
#: the gap assumed over the first PACE_CHUNKS chunks, until they tell the pace (a slow pipe's first
#: windows wait for it; a producer that had to wait for the reader hands its backlog over at once)
FIRST_GAP_S, PACE_CHUNKS = 0.1, 10
_POLL_S = 0.1                   # how often a blocked reader or the run's thread checks for a stop
_END = object()


def is_live(spec: str | None) -> bool:
    """Whether an ``--events`` value names a live source rather than a file."""
    return spec is not None and (spec == "-" or spec.startswith(("udp://", "dv://"))
                                 or spec == "dv-camera" or spec.startswith("dv-camera:"))


def stdin_header(sensor_size: tuple[int, int]) -> bytes:
    """The 16 bytes a producer writes before EVENT_DTYPE records on our stdin."""
    return STDIN_HEADER.pack(STDIN_MAGIC, STDIN_VERSION, int(sensor_size[0]), int(sensor_size[1]), 0)


def aer_words(ev: np.ndarray, timestamps: bool = True) -> np.ndarray:
    """Events as aestream's UDP words (little-endian uint32): x << 16 | p << 15 | y, followed by
    the timestamp's low 32 bits (us) with ``timestamps``; without, bit 31 is set and no time is sent."""
    w = (ev["x"].astype(np.uint32) << 16) | (ev["p"].astype(np.uint32) << 15) | ev["y"].astype(np.uint32)
    if not timestamps:
        return (w | np.uint32(1 << 31)).astype("<u4")
    out = np.empty(2 * ev.shape[0], "<u4")
    out[0::2] = w
    out[1::2] = (ev["t"].astype(np.int64) & 0xFFFFFFFF).astype(np.uint32)
    return out


@dataclass
class LiveStats:
    """What a live source received and dropped; ``queue_events`` is the queue bound and
    ``peak_queue_events`` the most it held (close to the bound: the run falls behind)."""

    received_events: int = 0
    received_chunks: int = 0
    dropped_events: int = 0
    dropped_chunks: int = 0         # chunks dropped whole, or cut to the queue's size (one larger than it)
    dropped_windows: int = 0        # windows jumped over after a drop (their events are gone: no line)
    late_events: int = 0
    reordered_events: int = 0       # came after a later-stamped event but in time: sorted into their window
    invalid_events: int = 0         # UDP: addresses outside the sensor, stray datagrams (dropped, not fatal)
    socket_drops: int = 0           # UDP: datagrams the kernel dropped (socket buffer full; Linux)
    incomplete_events: int = 0      # the stream ended inside its last window: its events, not processed
    queue_events: int = 0
    peak_queue_events: int = 0


class ChunkQueue:
    """Bounded FIFO of event chunks, counted in events. ``put`` never blocks: it drops the oldest
    chunks until the new one fits (a chunk larger than the bound keeps its newest events); with
    ``block`` (a pipe, which can push back on its writer) it waits for room instead and drops
    nothing (a chunk larger than the bound goes in alone)."""

    def __init__(self, max_events: int, stats: LiveStats, block: bool = False):
        self.max_events = int(max_events)
        self.block = bool(block)
        self.stats = stats
        self._q: collections.deque = collections.deque()
        self._n = 0
        self._cv = threading.Condition()
        self._closed = False
        self._error: BaseException | None = None

    def put(self, chunk: np.ndarray) -> None:
        n = int(chunk.shape[0])
        with self._cv:
            s = self.stats
            s.received_events += n
            s.received_chunks += 1
            while self.block and self._q and self._n + n > self.max_events and not self._closed:
                self._cv.wait(_POLL_S)                   # the run takes chunks out (get notifies)
            if self.block and self._closed:
                return                                   # closed while it waited: nobody reads on, evict nothing
            if n > self.max_events and not self.block:   # cut: it lost its oldest events (a drop, too)
                s.dropped_events += n - self.max_events
                s.dropped_chunks += 1
                chunk, n = chunk[n - self.max_events:], self.max_events
            while self._q and self._n + n > self.max_events:
                old = self._q.popleft()
                self._n -= old.shape[0]
                s.dropped_events += int(old.shape[0])
                s.dropped_chunks += 1
            self._q.append(chunk)
            self._n += n
            s.peak_queue_events = max(s.peak_queue_events, self._n)
            self._cv.notify()

    def close(self, error: BaseException | None = None) -> None:
        """End of stream (``error``: why the reader stopped, raised to the consumer)."""
        with self._cv:
            self._closed = True
            self._error = error
            self._cv.notify()

    def get(self, timeout: float):
        """The oldest chunk, None when nothing came within ``timeout`` s, or _END after close."""
        with self._cv:
            if not self._q and not self._closed and timeout > 0:
                self._cv.wait(timeout)
            if self._q:
                chunk = self._q.popleft()
                self._n -= chunk.shape[0]
                self._cv.notify_all()                    # a blocked put has room now
                return chunk
            if self._closed:
                if self._error is not None:
                    raise self._error
                return _END
            return None


class LiveSource(abc.ABC):
    """A live stream of events (see module docstring). Subclasses open their device in
    ``__init__`` (so a wrong address fails before any work) and implement ``_produce``, which
    calls ``_push(chunk)`` until the stream ends or ``self._stop`` is set."""

    live = True
    format_name = "live"
    ground_truth = None
    blocking = False                      # the reader waits for room in the queue (a pipe) instead of dropping
    ended = False                         # the stream itself ended (a pipe's end of file), not --idle-timeout

    def __init__(self, name: str, sensor_size, max_events: int = QUEUE_EVENTS, idle_timeout_s: float = 0.0,
                 grace_s: float = GRACE_S):
        if max_events < 1:
            raise InputError(name, f"--queue-events must be >= 1, got {max_events}")
        self.path = name
        self.sensor_size = check_sensor_size(name, sensor_size)
        self.attrs: dict = {}
        self.idle_timeout_s = float(idle_timeout_s or 0.0)
        self.grace_s = float(grace_s)
        self.stats = LiveStats(queue_events=int(max_events))
        self.queue = ChunkQueue(max_events, self.stats, block=self.blocking)
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._t_first: int | None = None
        self._host_first = 0.0
        self._close_first = 0.0           # close(t)'s anchor: host_first, moved later by a slow producer
        self._last_arrival = 0.0
        self._gap = 0.0                   # the producer's usual lag gap between chunks (s)
        self._last_t = 0
        self._opened = time.perf_counter()
        self._offset = 0

    # ---- reader side --------------------------------------------------------------------
    @abc.abstractmethod
    def _produce(self) -> None:
        """Read until end of stream or ``self._stop``, passing each chunk to ``_push``."""

    def _push(self, ev: np.ndarray, arrival: float | None = None) -> None:
        """Queue a chunk that arrived at perf_counter() ``arrival`` (None: now). The clocks take
        its arrival, not the time it is pushed: `udp://` holds its first datagram up to
        FIRST_HOLD_S, and anchoring close_time there closed every later window as much later."""
        if not ev.shape[0]:
            return
        now = time.perf_counter() if arrival is None else arrival
        check_chunk(self.path, ev, self.sensor_size, offset=self._offset, check_order=False)
        self._offset += int(ev.shape[0])
        if self._t_first is None:
            self._t_first, self._host_first = int(ev["t"][0]), now
            self._close_first = now
        t_max = int(ev["t"].max())
        ahead = self.host_time(t_max) - now
        if ahead > 0:                           # no event arrives before it happened: the clock's anchor
            self._host_first -= ahead           # is the earliest arrival for its timestamp (latency >= 0)
        behind = now - (self._close_first + (t_max - self._t_first) * 1e-6)
        if behind > 0:                          # the producer is slower than real time: follow its pace
            self._close_first += behind
        if self._last_arrival:                  # its usual lag gap between chunks: a decaying maximum
            lag = (now - self._last_arrival) - (t_max - self._last_t) * 1e-6
            self._gap = max(lag, GAP_DECAY * self._gap)
        self._last_arrival, self._last_t = now, max(t_max, self._last_t)
        self.queue.put(ev)

    def _run(self) -> None:
        try:
            self._produce()
        except BaseException as exc:            # handed to the run's thread, which raises it
            self.queue.close(exc if isinstance(exc, InputError) else
                             InputError(self.path, f"live source failed: {exc}"))
        else:
            self.queue.close()

    def start(self) -> None:
        if self._thread is None:
            self._thread = threading.Thread(target=self._run, name=f"live {self.path}", daemon=True)
            self._thread.start()

    # ---- run side -----------------------------------------------------------------------
    def host_time(self, t_us: int) -> float:
        """perf_counter() seconds at which an event stamped ``t_us`` happened: the first event's
        arrival, moved earlier whenever a chunk arrives before its events map to (a producer
        ahead of real time: a file piped in, a sender that catches up)."""
        return self._host_first + (int(t_us) - (self._t_first or 0)) * 1e-6

    def close_time(self, t_us: int) -> float:
        """perf_counter() seconds by which the events stamped before ``t_us`` have come at the
        stream's own pace (host_time moved later by a producer slower than real time): a window
        ending at t_us is closed by the clock at close_time + grace."""
        return self._close_first + (int(t_us) - (self._t_first or 0)) * 1e-6

    def close_by(self, t1_us: int) -> float:
        """perf_counter() seconds at which the clock closes a window ending at ``t1_us`` when nothing
        newer has come: close_time + grace, and not before the producer has been quiet for
        QUIET_GAPS of its usual lag gaps (the wall time between two chunks less the stream time
        between them: about 0 for a real-time source, bursty or not, whose quiet windows close
        on time; 50 ms for a pipe that hands over 0.5 ms of events every 50 ms), nor, while its
        pace is not known (its first PACE_CHUNKS chunks), before FIRST_GAP_S."""
        at = max(self.close_time(t1_us) + self.grace_s, self._last_arrival + QUIET_GAPS * self._gap)
        if self.stats.received_chunks < PACE_CHUNKS:
            at = max(at, self._last_arrival + FIRST_GAP_S)
        return at

    def _next(self, timeout: float):
        """A chunk, None (nothing yet) or _END; ends the stream after ``idle_timeout_s`` of silence."""
        item = self.queue.get(timeout)
        if item is None and self.idle_timeout_s:
            since = self._opened if self._t_first is None else self._last_arrival
            if time.perf_counter() - since > self.idle_timeout_s:
                return _END
        return item

    def iter_windows(self, dt_us: int, t_start: int | None = None, skip_empty_after: int | None = None,
                     include_incomplete: bool = True) -> Iterator[tuple[int, np.ndarray]]:
        """(t0, events with t0 <= t < t0 + dt_us), from the first event's time (or ``t_start``)
        until the stream ends; after ``skip_empty_after`` empty windows it waits for the next
        event and jumps to its window, as the file path does. A window the stream ended inside
        (its last event + 1 us before the window's end) is partial: its objects would come from
        part of a window, so `run` passes ``include_incomplete=False`` to drop it (counted in
        ``stats.incomplete_events``), as it drops a file's last partial window."""
        dt_us = int(dt_us)
        self._opened = time.perf_counter()      # idle_timeout_s counts from here: the run is ready (its
        self.start()                            # start-up, after the "reading" line, does not count)
        buf = np.empty(0, EVENT_DTYPE)
        exhausted = False
        t0 = None if t_start is None else int(t_start)
        while not buf.shape[0]:                      # the first event fixes the window grid
            item = self._next(_POLL_S)
            if item is _END:
                return
            if item is not None and item.shape[0]:
                # the first event as it came, not the chunk's earliest: the grid must not depend on
                # how the producer's writes were cut into chunks; earlier events in it are late
                t0 = int(item["t"][0]) if t0 is None else t0
                buf = self._append(buf, item, t0)    # sorted, should the source's chunk not be
        n_empty, seen_drops, jump_to = 0, self.stats.dropped_chunks, None
        while True:
            if skip_empty_after is not None and n_empty >= skip_empty_after and buf.shape[0]:
                t0 += (int(buf["t"][0]) - t0) // dt_us * dt_us      # jump to the next event's window
                n_empty = 0
            t1 = t0 + dt_us
            waiting = skip_empty_after is not None and n_empty >= skip_empty_after and not buf.shape[0]
            while not exhausted and (not buf.shape[0] or buf["t"][-1] < t1):
                item = self._next(0.0)
                if item is None:
                    left = _POLL_S if waiting else self.close_by(t1) - time.perf_counter()
                    if left <= 0:
                        break                        # closed by the clock: nothing newer came
                    item = self._next(min(left, _POLL_S))
                    if item is None:
                        continue
                if item is _END:
                    exhausted = True
                    break
                if self.stats.dropped_chunks != seen_drops and item.shape[0]:
                    seen_drops = self.stats.dropped_chunks
                    if int(item["t"].min()) >= t1:       # the queue overflowed before this chunk: catch up
                        keep = buf["t"] < t1            # this window ends here; what followed it is cut
                        self.stats.dropped_events += int((~keep).sum())
                        buf, jump_to = self._append(buf[keep], item, t0), int(item["t"].min())
                        break
                buf = self._append(buf, item, t0)
                if waiting and buf.shape[0]:
                    t0 += (int(buf["t"][0]) - t0) // dt_us * dt_us
                    t1, waiting, n_empty = t0 + dt_us, False, 0
            if exhausted and not buf.shape[0]:
                return
            cut = count_before(buf, t1)
            if exhausted and cut == buf.shape[0] and cut and int(buf["t"][-1]) + 1 < t1 and not include_incomplete:
                self.stats.incomplete_events += cut          # the stream ended inside this window
                return
            yield t0, copy_events(buf[:cut])
            buf = buf[cut:]
            n_empty = 0 if cut else n_empty + 1
            t0 = t1
            if jump_to is not None:
                n = (jump_to - t0) // dt_us
                self.stats.dropped_windows += n
                t0, jump_to, n_empty = t0 + n * dt_us, None, 0

    def _append(self, buf: np.ndarray, chunk: np.ndarray, t0: int) -> np.ndarray:
        """buf + chunk in time order; events before t0 (the window being filled) are late: dropped."""
        late = chunk["t"] < t0
        if late.any():
            self.stats.late_events += int(late.sum())
            chunk = chunk[~late]
        out = np.concatenate([buf, chunk]) if buf.shape[0] else chunk
        if out.shape[0] > 1 and (np.diff(out["t"]) < 0).any():
            t = out["t"]                       # buf is sorted: the events behind the latest stamp before them
            self.stats.reordered_events += int((t[1:] < np.maximum.accumulate(t)[:-1]).sum())
            out = out[np.argsort(t, kind="stable")]
        return out

    def stats_json(self) -> dict:
        return asdict(self.stats)

    # ---- lifetime -----------------------------------------------------------------------
    def _close_device(self) -> None:
        """Release the socket / reader (subclasses)."""

    def close(self) -> None:
        self._stop.set()
        self.queue.close()                      # a reader waiting for room (a pipe's) stops waiting
        if self._thread is not None:
            self._thread.join(timeout=2.0)
        self._close_device()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def __repr__(self) -> str:
        return f"<{type(self).__name__} {self.path} {self.sensor_size[0]}x{self.sensor_size[1]}>"


class StdinSource(LiveSource):
    """``--events -``: the 16-byte header (STDIN_HEADER) then 13-byte EVENT_DTYPE records
    (x u16, y u16, t i64 us, p u8; little-endian, packed), time-sorted, until end of file."""

    format_name = "stdin"
    blocking = True                       # a pipe pushes back on its writer: nothing is dropped

    def __init__(self, sensor_size=None, fd: int | None = None, **kw):
        if fd is None and sys.stdin is None:             # `<&-`: Python gives no stdin at all
            raise InputError("-", "stdin is closed: pipe a binary event stream in (README: Live sources)")
        self.fd = sys.stdin.fileno() if fd is None else fd
        try:
            self._open(sensor_size, **kw)
        except OSError as exc:                           # e.g. opened write-only: EBADF
            raise InputError("-", f"cannot read stdin: {exc.strerror or exc}") from None

    def _open(self, sensor_size, **kw) -> None:
        """__init__'s checks and the header, read from ``self.fd``."""
        if os.isatty(self.fd):
            raise InputError("-", "stdin is a terminal: pipe a binary event stream in (README: Live sources)")
        wait = float(kw.get("idle_timeout_s") or 0.0)
        if wait and not select.select([self.fd], [], [], wait)[0]:   # a producer that never starts
            raise InputError("-", f"nothing arrived on stdin within --idle-timeout {wait:g} s "
                                  "(expected a binary event stream: README, Live sources)")
        head = self._read_exact(STDIN_HEADER.size)
        if not head:
            raise InputError("-", "stdin is empty: expected a binary event stream (README: Live sources)")
        if len(head) < STDIN_HEADER.size or not head.startswith(STDIN_MAGIC):
            raise InputError("-", f"stdin does not start with the {STDIN_MAGIC.decode()} header "
                                  "(16 bytes: magic, u16 version, width, height, reserved; README: Live sources)")
        _, version, w, h, reserved = STDIN_HEADER.unpack(head)
        if version != STDIN_VERSION:
            raise InputError("-", f"stdin stream version {version}; this toffe-deploy reads version {STDIN_VERSION}")
        if reserved:                    # kept for a later version's flags: not to be misread as none
            raise InputError("-", f"stdin header's reserved field is {reserved}; version {STDIN_VERSION} writes 0 "
                                  "(README: Live sources)")
        super().__init__("-", sensor_size or (w, h), **kw)

    def _read_exact(self, n: int) -> bytes:
        out = b""
        while len(out) < n:
            b = os.read(self.fd, n - len(out))
            if not b:
                break
            out += b
        return out

    def _produce(self) -> None:
        rec = EVENT_DTYPE.itemsize
        rest = b""
        while not self._stop.is_set():
            if not select.select([self.fd], [], [], _POLL_S)[0]:
                continue
            data = os.read(self.fd, 1 << 20)
            if not data:
                if rest:
                    raise InputError("-", f"stdin ended inside an event record ({len(rest)} of {rec} bytes)")
                self.ended = True
                return
            data = rest + data
            n = len(data) // rec
            rest = data[n * rec:]
            if n:
                self._push(np.frombuffer(bytearray(memoryview(data)[:n * rec]), EVENT_DTYPE))


def _host_port(spec: str, scheme: str) -> tuple[str, int]:
    host, sep, port = spec[len(scheme):].rpartition(":")
    try:
        port_n = int(port)
    except ValueError:
        port_n = -1
    if sep and host and port.isdigit() and port_n >= 65536:
        raise InputError(spec, f"port {port_n} is out of range (0..65535)")
    if not sep or not host or not 0 <= port_n < 65536:
        raise InputError(spec, f"expected {scheme}HOST:PORT, e.g. {scheme}127.0.0.1:3333")
    return host.strip("[]"), port_n


#: How long `udp://` holds its first datagram for the next one to confirm its form (UdpAerSource.receive).
FIRST_HOLD_S = 0.05


def _form(packet: bytes) -> bool:
    """Whether an AER datagram carries timestamps (bit 31 of its first word clear)."""
    return len(packet) >= 4 and not packet[3] >> 7


def _addresses(packet: bytes) -> int:
    """The number of event addresses in an AER datagram (pairs of words when timestamped)."""
    n = len(packet) // 4
    return n // 2 if _form(packet) else n


class UdpAerSource(LiveSource):
    """``--events udp://HOST:PORT``: listens on HOST:PORT for aestream's UDP AER packets
    (``aestream input ... output udp HOST PORT [--include-timestamp true]``; see ``aer_words``).
    With timestamps, the 32-bit microsecond times are unwrapped (they wrap every 71.6 min);
    without, each packet's events get its arrival time. Addresses outside the sensor are dropped
    and counted (``invalid_events``: a datagram socket takes packets from anyone, and aestream
    0.6.4 pads its last timestamped packet with stale words). The stream ends after
    ``idle_timeout_s`` without a packet, or on Ctrl-C."""

    format_name = "udp-aer"

    def __init__(self, spec: str, sensor_size, **kw):
        host, port = _host_port(spec, "udp://")
        if sensor_size is None:
            raise InputError(spec, "an AER stream does not carry its sensor size: give --sensor-size WxH")
        super().__init__(spec, sensor_size, **kw)
        try:
            self.sock = socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET, socket.SOCK_DGRAM)
            self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 8 << 20)
            self.sock.bind((host, port))
        except OSError as exc:
            raise InputError(spec, f"cannot listen: {exc.strerror or exc}") from None
        self.sock.settimeout(_POLL_S)
        self.port = self.sock.getsockname()[1]
        self._form_events = {True: 0, False: 0}   # events taken in datagrams with / without timestamps
        self._held: tuple[bytes, float] | None = None   # the first datagram, until the next (receive)
        self._last32: int | None = None        # the last word's raw 32-bit time, and unwrapped
        self._last_unwrapped = 0
        self._last_datagram = 0.0              # host time of the last timestamped datagram
        self._t0_host = time.perf_counter()

    def decode(self, packet: bytes, arrival: float) -> np.ndarray:
        """One packet's words as EVENT_DTYPE (a trailing partial word is ignored).

        A datagram socket takes packets from anyone, so what cannot be the stream's is dropped
        and counted as ``invalid_events``: addresses outside the sensor, a timestamped datagram's
        last word without its time, and a datagram of the stream's other form (bit 31 of its
        first word: 1 = no timestamps) unless it brings that form more events than the stream's
        form has had so far (the first datagrams decide, and a stray first one is outvoted by
        the stream's next one; one stray packet had ended the run, or moved the stream's clock so
        that every later event came late). A datagram of the stream's own form with a wrong time
        cannot be told from a real one. The times of the kept words are
        unwrapped step by step: each step from the previous kept word is taken as the one of its
        two readings, forward or back, under half the 32-bit range, so a datagram from before a
        wrap that comes after one is put back before it (taking every drop of more than 2**31 as
        a wrap had counted that wrap twice: every later window 71.6 min late); across a silence
        of more than half the range the host's arrival times decide (``arrival``, perf_counter
        seconds). Events that fall before 0 (a datagram from before a wrap the stream began
        after) are dropped as ``late_events``."""
        words = np.frombuffer(packet, "<u4", count=len(packet) // 4)
        if not words.size:
            return np.empty(0, EVENT_DTYPE)
        stamped = _form(packet)
        addr = words[0:words.size // 2 * 2:2] if stamped else words
        if stamped:
            self.stats.invalid_events += int(words.size % 2)   # an address without its time
            if not addr.size:
                return np.empty(0, EVENT_DTYPE)
        x, y = (addr >> 16) & 0x7FFF, addr & 0x7FFF
        ok = (x < self.sensor_size[0]) & (y < self.sensor_size[1])
        if not ok.all():
            self.stats.invalid_events += int((~ok).sum())
            if not ok.any():
                return np.empty(0, EVENT_DTYPE)     # neither the stream's form nor its clock comes from it
            addr, x, y = addr[ok], x[ok], y[ok]
        mine, other = self._form_events[stamped], self._form_events[not stamped]
        if other and mine + addr.size <= other:             # the other form's stream: a stray
            self.stats.invalid_events += int(addr.size)
            return np.empty(0, EVENT_DTYPE)
        self._form_events[stamped] = mine + int(addr.size)
        if not stamped:                                     # no timestamps: arrival time
            t = np.full(addr.size, round((arrival - self._t0_host) * 1e6), np.int64)
        else:
            t32 = words[1::2].astype(np.int64)       # one time per address, as ok
            if not ok.all():
                t32 = t32[ok]
            prev, base = (int(t32[0]), int(t32[0])) if self._last32 is None else (self._last32, self._last_unwrapped)
            step = (np.diff(t32, prepend=prev) + (1 << 31)) % (1 << 32) - (1 << 31)
            if self._last32 is not None:        # after a silence of over half the range (35.8 min) the
                silent_us = (arrival - self._last_datagram) * 1e6     # host clock says which way it went
                step[0] += round((silent_us - step[0]) / (1 << 32)) * (1 << 32)
            t = base + np.cumsum(step)
            self._last32, self._last_unwrapped, self._last_datagram = int(t32[-1]), int(t[-1]), arrival
            if t.min() < 0:                                 # from before a wrap that the stream began after:
                keep = t >= 0                               # before its first event, so late
                self.stats.late_events += int((~keep).sum())
                addr, x, y, t = addr[keep], x[keep], y[keep], t[keep]
        out = np.empty(addr.size, EVENT_DTYPE)
        out["x"], out["y"], out["p"], out["t"] = x, y, (addr >> 15) & 1, t
        return out

    def receive(self, packet: bytes | None, arrival: float) -> list[np.ndarray]:
        """The events to push for a datagram (``packet``; None: a poll with none). The stream's
        first datagram with an event is held until the next one, or FIRST_HOLD_S: if the next is
        of the other form and brings more events, the first was a stray and is dropped (it would
        have been the stream's first event, and every real one after it late or far off)."""
        return [ev for ev, _at in self._receive_timed(packet, arrival)]

    def _receive_timed(self, packet: bytes | None, arrival: float) -> list[tuple[np.ndarray, float]]:
        """receive's chunks, each with the time its datagram arrived (a held one's is earlier)."""
        if self._held is not None:
            held, at = self._held
            if packet is None and arrival - at < FIRST_HOLD_S:
                return []
            self._held = None
            if packet is not None and _form(packet) != _form(held) and _addresses(packet) > _addresses(held):
                self.stats.invalid_events += _addresses(held)      # outvoted before it was decoded
                return [(self.decode(packet, arrival), arrival)]
            return [(self.decode(held, at), at)] + ([] if packet is None else [(self.decode(packet, arrival), arrival)])
        if packet is None:
            return []
        if not any(self._form_events.values()) and _addresses(packet):
            self._held = (packet, arrival)
            return []
        return [(self.decode(packet, arrival), arrival)]

    def _produce(self) -> None:
        while not self._stop.is_set():
            wait = FIRST_HOLD_S / 5 if self._held is not None else _POLL_S   # a held first datagram goes
            if self.sock.gettimeout() != wait:                               # on within FIRST_HOLD_S
                self.sock.settimeout(wait)
            try:
                packet = self.sock.recv(1 << 16)
            except socket.timeout:
                packet = None
            except OSError:
                if self._stop.is_set():
                    return
                raise
            for ev, at in self._receive_timed(packet, time.perf_counter()):
                self._push(ev, at)
        for ev, at in self._receive_timed(None, math.inf):   # a held first datagram, at the end
            self._push(ev, at)

    def _socket_drops(self) -> int:
        """Datagrams the kernel dropped on our socket (/proc/net/udp's last column; 0 elsewhere)."""
        inode = str(os.fstat(self.sock.fileno()).st_ino)
        for table in ("/proc/net/udp", "/proc/net/udp6"):
            try:
                with open(table) as f:
                    for line in f:
                        cols = line.split()
                        if len(cols) > 12 and cols[9] == inode:
                            return int(cols[-1])
            except OSError:
                pass
        return 0

    def stats_json(self) -> dict:
        if self.sock.fileno() >= 0:
            self.stats.socket_drops = self._socket_drops()
        return super().stats_json()

    def _close_device(self) -> None:
        self.sock.close()


def _dv():
    try:
        import dv_processing as dv
    except ImportError:
        raise InputError("dv", "DV sources need dv-processing (pip install dv-processing)") from None
    return dv


def _from_dv(arr: np.ndarray) -> np.ndarray:
    out = np.empty(arr.shape[0], EVENT_DTYPE)
    out["t"], out["x"], out["y"], out["p"] = arr["timestamp"], arr["x"], arr["y"], arr["polarity"]
    return out


class DvSource(LiveSource):
    """``dv://HOST:PORT`` (a DV network event stream: dv.io.NetworkReader, e.g. DV's "Output to
    network" module or dv.io.NetworkWriter) or ``dv-camera[:SERIAL]`` (an iniVation camera on USB:
    dv.io.camera.open). Sensor size and timestamps come from the stream; it ends when the sender
    stops (or the camera is unplugged), or on Ctrl-C."""

    format_name = "dv"

    def __init__(self, spec: str, sensor_size=None, **kw):
        dv = _dv()
        if spec.startswith("dv://"):
            host, port = _host_port(spec, "dv://")
            try:
                self.reader = dv.io.NetworkReader(host, port)
            except Exception as exc:                 # Boost's message, less its source location
                raise InputError(spec, "cannot connect to a DV network stream: "
                                       f"{str(exc).split(' [', 1)[0].strip() or type(exc).__name__}") from None
        else:
            serial = spec.partition(":")[2]
            found = [str(d) for d in dv.io.camera.discover()]
            if not found:
                raise InputError(spec, "no DV camera attached (dv-processing found no iniVation device on USB)")
            try:
                self.reader = dv.io.camera.open(serial) if serial else dv.io.camera.open()
            except Exception as exc:
                raise InputError(spec, f"cannot open the camera (attached: {', '.join(found)}): {exc}") from None
        if not self.reader.isEventStreamAvailable():
            raise InputError(spec, "the DV stream carries no events")
        super().__init__(spec, sensor_size or tuple(self.reader.getEventResolution()), **kw)
        self.attrs = {"camera": self.reader.getCameraName()}

    def _produce(self) -> None:
        while not self._stop.is_set() and self.reader.isRunning():
            batch = self.reader.getNextEventBatch()
            if batch is None or not len(batch):
                time.sleep(0.0005)
                continue
            self._push(_from_dv(batch.numpy()))


def open_live(spec: str, sensor_size: tuple[int, int] | None = None, queue_events: int = QUEUE_EVENTS,
              idle_timeout_s: float = 0.0, grace_s: float = GRACE_S) -> LiveSource:
    """The live source an ``--events`` value names (see is_live); InputError when it cannot open."""
    kw = {"max_events": queue_events, "idle_timeout_s": idle_timeout_s, "grace_s": grace_s}
    if spec == "-":
        return StdinSource(sensor_size, **kw)
    if spec.startswith("udp://"):
        return UdpAerSource(spec, sensor_size, **kw)
    return DvSource(spec, sensor_size, **kw)
