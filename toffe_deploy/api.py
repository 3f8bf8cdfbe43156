"""The Python API: load a bundle, open a pipeline for a target, feed events, get object flow and tracks.

    from toffe_deploy import api

    bundle = api.load_bundle("export/")                       # hash-verified deploy bundle
    with api.FlowStream(bundle, target="cpu") as flow:        # torch- and Lava-free on cpu / cuda
        for packet in camera:                                 # events as they arrive, time-sorted
            for win in flow.feed(packet["x"], packet["y"], packet["t"], packet["p"]):
                for obj in win.objects:                       # this window's detections
                    obj.x, obj.y, obj.direction_deg, obj.speed_px_s, obj.speed_mps, obj.track_id
                for t in flow.tracks():                       # every confirmed track, seen or coasting
                    t["track_id"], t["track"]["x"], t["track"]["speed_bin"]
        for win in flow.flush():                              # the windows still buffered (not a
            ...                                               # partial last one: flush(partial=True))

Windows: [t0, t0 + dt) on a grid from ``t_start_us`` (default: the first event's time, as
`run` on a live source); a window is processed once an event at or after its end arrives
(``flush`` ends the last one). Empty windows in between are processed too (the tracks coast
through them), up to ``skip_empty_after`` in a row (0 or None: always); a longer gap is jumped
over, as `run --skip-empty-after N` does. ``feed_window(t0_us, window)`` takes a ready window
instead: a dense (B, 2, H, W) array or a runtime.spikes.SpikeVolume; windows fed either way go
in time order, and ``feed`` after ``feed_window`` goes on from the end of that window. Results
are pipeline.WindowResult (``objects``: ObjectFlow; ``coasting``: tracks not seen in the window;
``to_json()``: the JSON line of `run` as a dict, schema.py).

Conventions (as the JSON lines, README "JSON lines"): x, y in sensor pixels from the top-left
pixel (0, 0), y down; direction atan2(dy, dx) in the image plane (0 = moving right, +90 deg =
moving down); times in the recording's microseconds; speed_px_s the image-plane speed, speed_mps
it at the camera's depth and focal length (``speed_scale``, default the bundle's camera).
"""
from __future__ import annotations

import functools
import threading

import numpy as np

from .camera import SpeedScale
from .deploy.bundle import Bundle, load_bundle
from .errors import InputError
from .events.convert import time_us, to_events
from .events.core import EVENT_DTYPE, count_before
from .events.validate import check_chunk, whole_number
from .runtime.pipeline import TARGETS, ObjectFlow, Pipeline, WindowResult
from .runtime.spikes import SpikeVolume
from .schema import header, load_schema
from .tracking import TrackerConfig

__all__ = ["load_bundle", "Bundle", "FlowStream", "Pipeline", "ObjectFlow", "WindowResult", "TrackerConfig",
           "SpeedScale", "TARGETS", "load_schema", "header"]

FEED = "FlowStream.feed"

#: Consecutive empty windows processed before a gap in the events is jumped over (as `run`'s default).
SKIP_EMPTY_AFTER = 1000


def _serialized(method):
    """One call at a time on a FlowStream (its lock): two threads inside ``feed`` at once cut the
    same buffered events into windows twice (measured: 370 windows returned for a recording of
    200). Events must still arrive in time order; the lock only keeps each call whole."""

    @functools.wraps(method)
    def call(self, *args, **kwargs):
        with self._lock:
            return method(self, *args, **kwargs)
    return call


class FlowStream:
    """Incremental object flow and tracking over events that arrive in packets (module doc).

    bundle: a Bundle or its directory; target: cpu, cuda, loihi-sim or loihi2; sensor_size
    (width, height): the camera's (default: the bundle's); speed_scale: the camera for speeds in
    m/s, ``SpeedScale(focal_px, depth_m)`` (default: the bundle's); track: True, a TrackerConfig,
    or False; t_start_us: the first window's start, the origin of the window grid (default: the
    first event's time, as `run` on a live source; a file's own start, as `run` on a file, is
    ``t_start_us=src.t_start_us``); skip_empty_after: empty windows in a row processed before
    a gap is jumped over (0 or None: never jump, as `run --skip-empty-after 0`); ofpd_variant:
    the bundle's OFPD file (fp32, fp16, int8). speed_scale's default and every other setting
    are `run`'s (Pipeline), so the same events give `run`'s lines."""

    def __init__(self, bundle: Bundle | str, target: str = "cpu", *, sensor_size: tuple[int, int] | None = None,
                 speed_scale: SpeedScale | None = None, track: bool | TrackerConfig = True,
                 t_start_us: int | None = None, skip_empty_after: int | None = SKIP_EMPTY_AFTER,
                 ofpd_variant: str = "fp32"):
        if skip_empty_after is not None and (isinstance(skip_empty_after, bool) or int(skip_empty_after) != skip_empty_after
                                             or skip_empty_after < 0):
            raise ValueError(f"skip_empty_after must be a whole number >= 0 (0 or None: never skip), got {skip_empty_after!r}")
        if t_start_us is not None and whole_number("t_start_us", t_start_us) < 0:
            raise ValueError(f"t_start_us must be >= 0, got {t_start_us}")
        self.bundle = load_bundle(bundle) if not isinstance(bundle, Bundle) else bundle
        self.pipeline = Pipeline(self.bundle, target, ofpd_variant=ofpd_variant, sensor_size=sensor_size,
                                 speed_scale=speed_scale, track=track)
        cfg = self.bundle.config
        self.dt_us, self.n_bins = int(cfg.dt_us), int(cfg.n_bins)
        self.sensor_size = self.pipeline.sensor_size
        self.t_start_us = None if t_start_us is None else int(t_start_us)
        self.skip_empty_after = int(skip_empty_after) if skip_empty_after else None    # None: never skip
        self._lock = threading.RLock()
        self._closed = False
        self.reset()

    @_serialized
    def reset(self) -> None:
        """Start a new recording: no buffered events, no tracks, the window grid from
        ``t_start_us`` (or the next first event) again. Events older than those fed so far are
        refused without it (they would fall in windows already processed)."""
        self._refuse_closed()
        self.t0 = self.t_start_us                  # the next window's start
        self._origin = self.t_start_us             # the window grid's origin
        self._buf = np.empty(0, EVENT_DTYPE)
        self._empty = 0
        self._t_last: int | None = None            # the last event fed
        self._done_until: int | None = None        # the end of the last window processed
        self._n_fed = 0
        self._last: WindowResult | None = None
        self.pipeline.reset_tracks()

    @_serialized
    def __enter__(self) -> "FlowStream":
        self._open()
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    @_serialized
    def close(self) -> None:
        """Stop the pipeline (a Lava target's runtime); the FlowStream takes no more calls."""
        self._closed = True
        self.pipeline.close()

    @property
    def closed(self) -> bool:
        return self._closed

    def _refuse_closed(self) -> None:
        if self._closed:
            raise ValueError("FlowStream is closed: make a new one to go on")

    def _open(self) -> None:
        """The pipeline, opened once (ValueError once closed)."""
        self._refuse_closed()
        if not self.pipeline._entered:
            self.pipeline.__enter__()

    def _run(self, t0: int, window) -> WindowResult:
        self._open()
        (res,) = self.pipeline.process_stream([(int(t0), window)])
        self._last = res
        return res

    @_serialized
    def feed_window(self, t0_us: int, window) -> WindowResult:
        """Object flow of one ready window [t0_us, t0_us + dt): a (B, 2, H, W) array (nonzero =
        event) or a SpikeVolume. Windows come in time order: t0_us >= 0, on the window grid (a
        whole number of dt from ``t_start_us``, or from the first window fed) and at or after the
        end of the last window processed (ValueError otherwise); a later ``feed`` goes on from its end."""
        self._open()
        t0 = int(t0_us)
        if t0 != t0_us or t0 < 0:
            raise ValueError(f"FlowStream.feed_window: t0_us must be a whole number of us >= 0, got {t0_us!r}")
        if self._origin is not None and (t0 - self._origin) % self.dt_us:
            raise ValueError(f"FlowStream.feed_window: t0 = {t0} us is off the window grid, which starts at "
                             f"{self._origin} us in steps of dt = {self.dt_us} us")
        if self._done_until is not None and t0 < self._done_until:
            raise ValueError(f"FlowStream.feed_window: the window at t0 = {t0} us starts before the end of the last "
                             f"window processed ({self._done_until} us): windows go in time order (reset() starts again)")
        if self._buf.shape[0]:
            raise ValueError("FlowStream.feed_window: events fed with feed() wait in the buffer; flush() them first")
        res = self._run(t0, window)
        self.t0 = self._done_until = t0 + self.dt_us
        if self._origin is None:
            self._origin = t0
        self._empty = 0
        return res

    @_serialized
    def feed(self, x, y, t, p) -> list[WindowResult]:
        """Add a packet of time-sorted events (columns of one length: x, y whole px, t whole us,
        p 0/1, -1/+1 or bool) and process every window it completes; -> their results, in time
        order. Columns the file readers would refuse (a fractional or negative coordinate, a
        NaN time, a polarity 7) are a ValueError here too, not silently cast."""
        self._open()
        ev = _checked_events(x, y, t, p)
        if ev.shape[0]:
            try:                                   # sensor, negative times, time order (the readers' check)
                check_chunk(FEED, ev, self.sensor_size, self._n_fed, self._t_last)
            except InputError as exc:
                raise ValueError(str(exc)) from None
            if self._origin is not None and int(ev["t"][0]) < self._origin:
                raise ValueError(f"{FEED}: an event at t = {int(ev['t'][0])} us is before the first window, which starts "
                                 f"at t_start_us = {self._origin} us (a later t_start_us, or drop the events before it)")
            if self._done_until is not None and int(ev["t"][0]) < self._done_until:
                raise ValueError(f"{FEED}: an event at t = {int(ev['t'][0])} us falls in a window already processed "
                                 f"(up to {self._done_until} us): a new recording needs reset() or a new FlowStream")
            if self.t0 is None:
                self.t0 = self._origin = int(ev["t"][0])
            self._t_last = int(ev["t"][-1])
            self._n_fed += ev.shape[0]
            self._buf = np.concatenate([self._buf, ev]) if self._buf.shape[0] else ev
        return self._drain(final=False)

    @_serialized
    def flush(self, partial: bool = False, t_end_us: int | None = None) -> list[WindowResult]:
        """Process the windows still buffered. The last one is partial when the stream ended inside
        it, so its objects would be found from part of a window (a slow one's position and speed
        from a fraction of its edges): dropped, as `run` and `eval` drop it, or processed with
        ``partial=True`` (`run --include-incomplete`). The stream ends at ``t_end_us`` (exclusive;
        a recording's end, or where a loop stopped reading) or, by default, at its last event + 1 us."""
        self._open()
        if t_end_us is not None:
            t_end_us = whole_number("t_end_us", t_end_us)
            if self._t_last is not None and t_end_us <= self._t_last:
                raise ValueError(f"FlowStream.flush: t_end_us must be a whole number of us after the last event fed "
                                 f"({self._t_last} us), got {t_end_us}")
        out = self._drain(final=True, partial=partial, t_end=t_end_us)
        self._buf = self._buf[:0]
        return out

    def _drain(self, final: bool, partial: bool = True, t_end: int | None = None) -> list[WindowResult]:
        """Process the buffered windows: those an event past their end has closed, or (``final``)
        every window before the stream's end (``t_end``, else the last event + 1 us), empty ones
        included as `run` processes a file's, the last partial one only with ``partial``."""
        out = []
        end = t_end if t_end is not None else int(self._buf["t"][-1]) + 1 if self._buf.shape[0] else None
        while self.t0 is not None:
            t1 = self.t0 + self.dt_us
            if not final and not (self._buf.shape[0] and int(self._buf["t"][-1]) >= t1):
                break                                      # not closed yet: wait for more events
            if final and (end is None or self.t0 >= end or (t1 > end and not partial)):
                break                                      # the stream's end (a last partial window: dropped)
            cut = count_before(self._buf, t1)
            win, self._buf = self._buf[:cut], self._buf[cut:]
            self._empty = 0 if cut else self._empty + 1
            if cut or self.skip_empty_after is None or self._empty <= self.skip_empty_after:
                vol = SpikeVolume.from_events(win, self.t0, self.dt_us, self.n_bins, self.sensor_size)
                out.append(self._run(self.t0, vol))
                self.t0 = self._done_until = t1
            else:                                          # a long gap: jump to the next event's window
                self.t0 = (self._origin + (int(self._buf["t"][0]) - self._origin) // self.dt_us * self.dt_us
                           if self._buf.shape[0] else t1)  # on the grid from the origin, as `run`
                self._empty = 0
                if not self._buf.shape[0]:
                    break                                  # nothing left: the rest is the gap (`run` jumps past it)
        return out

    @_serialized
    def tracks(self) -> list[dict]:
        """Every live confirmed track after the last window ([{"track_id", "track"}]: seen in it,
        ``track["misses"]`` 0, or coasting, > 0, also past the report_misses windows for which
        the JSON lines list a coasting track); [] without tracking. Also after close(): the
        tracks as the last window left them."""
        if self._last is None or self.pipeline.tracker is None:
            return []
        return self.pipeline.tracker.confirmed()


def _checked_events(x, y, t, p) -> np.ndarray:
    """FlowStream.feed's columns as an event array, with the file readers' checks
    (events.convert): ValueError on columns of different lengths or values a cast would hide."""
    cols = [np.asarray(c) for c in (x, y, t, p)]
    if any(c.ndim != 1 for c in cols) or len({c.shape[0] for c in cols}) != 1:
        raise ValueError(f"x, y, t, p must be 1-D columns of one length, got shapes {[c.shape for c in cols]}")
    try:
        return to_events(FEED, cols[0], cols[1], time_us(FEED, cols[2]), cols[3])
    except InputError as exc:
        raise ValueError(str(exc)) from None
