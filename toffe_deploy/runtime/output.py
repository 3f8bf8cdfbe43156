"""What ``run`` reports: one JSON line per window, and a summary (throughput, latency, errors).

JSON line per window (keys in this order)::

    {"t0_us": 1000, "t1_us": 1500, "objects": [{"speed_bin": 2, "ofs_bin": 2, "speed_mps": 27.1,
      "speed_bin_mps": 30.0, "speed_px_s": 3004.1, "x": 120.4, "y": 88.0, "direction_rad": -1.2,
      "n_events": 310, "direction_deg": -68.75}]}

speed_px_s is the image-plane speed the camera saw; speed_mps and speed_bin_mps are it (and the
bin's representative speed) in m/s for the run's camera (depth and focal length, see the summary).

Lines stream: each window's line is written, whole, as soon as the window is done, to stdout
(flushed per line, so a piped consumer sees it at once) or, with ``--out FILE.jsonl``, to that
file (truncated when the run starts streaming, then one ``os.write`` of one complete line per
window on an O_APPEND descriptor). A killed run (SIGKILL included) leaves valid JSONL of every
finished window and never a partial line; a write the system refuses half-way (a full disk) is
cut back to the last whole line before the error is reported. The other outputs
(``--summary-json``, ``--dump-spikes``) stay atomic.
"""
from __future__ import annotations

import contextlib
import fcntl
import math
import os
import sys
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterator

import numpy as np

from ..errors import InputError
from ..fileio import atomic_path, clear_killed, json_text, savez_compressed, special_file, temp_prefix
from .pipeline import WindowResult
from .traffic import Traffic


class LineFile:
    """A JSONL file written one whole line at a time: ``write(text)`` takes complete lines and
    puts each call on disk with one ``os.write`` on an O_APPEND descriptor, so the file always
    ends at a line boundary whatever kills the process; a short or refused write is cut back to
    the previous boundary (ftruncate) before the OSError propagates.

    The lines go to a temp file beside ``path`` (missing directories are made) that replaces
    ``path`` with the first line written, so a run that fails before it has a line to write (bad
    events in its first window, a live source that never sends) leaves an existing file as it
    was and no new one; ``close`` then removes the temp file. A ``path`` that names a device or
    a pipe (/dev/null, a FIFO, bash's ``>(...)``: fileio.special_file) is written into directly,
    as a shell redirection would (a rename would replace the device or pipe with a file); a pipe
    whose reader went away ends the run as a closed stdout does (BrokenPipeError: exit 0, quietly)."""

    def __init__(self, path: str | Path):
        self.path = Path(path)
        self.size = 0
        if special_file(self.path):
            try:                                   # a FIFO's open waits for its reader, as `> fifo` does
                self.fd, self.tmp, self.placed, self.regular = (os.open(self.path, os.O_WRONLY | os.O_APPEND), None,
                                                                True, False)
            except OSError as exc:
                raise InputError(path, f"cannot write: {exc.strerror or exc}") from None
            return
        self.regular = True
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            clear_killed(self.path)
            fd, tmp = tempfile.mkstemp(prefix=temp_prefix(self.path), suffix=".tmp", dir=self.path.parent)
        except OSError as exc:
            raise InputError(path, f"cannot write: {exc.strerror or exc}") from None
        self.fd, self.tmp, self.placed = fd, tmp, False
        fcntl.fcntl(fd, fcntl.F_SETFL, fcntl.fcntl(fd, fcntl.F_GETFL) | os.O_APPEND)
        mask = os.umask(0)
        os.umask(mask)
        os.fchmod(fd, 0o644 & ~mask)           # what open(path, "w") gives, not mkstemp's 0600

    def write(self, text: str) -> None:
        data = text.encode("utf-8")
        done = 0
        try:
            while done < len(data):
                done += os.write(self.fd, data[done:])
        except BrokenPipeError:
            raise                                  # a pipe's reader went away (a FIFO, >(head)): as stdout's, cli ends quietly
        except OSError as exc:
            if done and self.regular:
                os.ftruncate(self.fd, self.size)
            raise InputError(self.path, f"cannot write: {exc.strerror or exc}") from None
        self.size += done
        if not self.placed:
            try:
                os.replace(self.tmp, self.path)
            except OSError as exc:
                raise InputError(self.path, f"cannot write: {exc.strerror or exc}") from None
            self.placed = True

    def flush(self) -> None:
        """Every write is already in the kernel (no user-space buffer)."""

    def close(self) -> None:
        if self.fd >= 0:
            os.close(self.fd)
            self.fd = -1
            if not self.placed:
                with contextlib.suppress(OSError):
                    os.unlink(self.tmp)


class LineStdout:
    """stdout for JSON lines: each ``write`` (whole lines) is flushed at once, so a consumer on
    a pipe gets every window as it is done. A closed pipe (``| head``) raises BrokenPipeError,
    which the CLI ends on quietly (cli.main)."""

    def write(self, text: str) -> None:
        sys.stdout.write(text)
        sys.stdout.flush()

    def flush(self) -> None:
        sys.stdout.flush()

    def close(self) -> None:
        self.flush()


@contextlib.contextmanager
def jsonl_sink(path: str | Path | None) -> Iterator[LineFile | LineStdout]:
    """A whole-line JSON-lines writer: stdout (flushed per line) when ``path`` is None, else
    ``path`` streamed line by line (LineFile)."""
    sink = LineStdout() if path is None else LineFile(path)
    try:
        yield sink
    finally:
        sink.close()


def write_line(stream, obj: dict) -> None:
    """One dict as one compact JSON line, written whole (any line: a window, a header)."""
    stream.write(json_text(obj, separators=(",", ":")) + "\n")


def write_window(stream, result: WindowResult) -> None:
    write_line(stream, result.to_json())


def percentiles_ms(seconds: list[float]) -> dict[str, float]:
    """p50/p90/p99 of per-window latencies, in milliseconds."""
    if not seconds:
        return {"p50": math.nan, "p90": math.nan, "p99": math.nan}
    a = np.asarray(seconds) * 1e3
    return {f"p{q}": float(np.percentile(a, q)) for q in (50, 90, 99)}


@dataclass
class RunSummary:
    """Counts and timings of one run; ``errors`` holds metrics.FlowErrors.summary() (recall, false
    positives per window, bin accuracy and confusion, pixE/dirE/speedE) when truth was present;
    ``camera`` is the run camera's summary line (runtime.run_camera), ``camera_json`` its fields."""

    target: str
    tag: str | None = None          # the OFS arithmetic: the Lava process models (fixed_pt / floating_pt) on the
                                    # Lava targets; cpu and cuda run fixed_pt's, bit for bit (the header's tag)
    windows: int = 0
    objects: int = 0
    objects_per_bin: dict[int, int] = field(default_factory=dict)
    wall_s: float = 0.0
    latencies_s: list[float] = field(default_factory=list)
    errors: dict | None = None
    startup_s: float = 0.0
    camera: str | None = None
    camera_json: dict | None = None
    dt_us: int = 0                  # window length: the sensor time each window covers (realtime_factor)
    skipped_windows: int = 0
    skipped_gaps: int = 0
    longest_gap_us: int = 0
    #: a file's last us after its last whole window, not processed (run --include-incomplete processes them)
    incomplete_us: int = 0
    traffic: Traffic | None = None          # host <-> chip bridge traffic (Lava targets)
    #: live sources: per window, line written - host time of its newest event (events.live's clock)
    event_latencies_s: list[float] = field(default_factory=list)
    live: dict | None = None                # live sources: events.live.LiveStats (received, dropped, late)
    #: events.convert.TimeUnitCheck's hint on the first windows' timestamps (nanoseconds read as us?)
    time_unit_note: str | None = None

    def skip(self, n_windows: int, dt_us: int) -> None:
        """Record a stretch of ``n_windows`` empty windows the run jumped over (see --skip-empty-after)."""
        self.skipped_windows += n_windows
        self.skipped_gaps += 1
        self.longest_gap_us = max(self.longest_gap_us, n_windows * dt_us)

    def add(self, result: WindowResult, latency_s: float) -> None:
        self.windows += 1
        self.objects += len(result.objects)
        for o in result.objects:
            self.objects_per_bin[o.speed_bin] = self.objects_per_bin.get(o.speed_bin, 0) + 1
        self.latencies_s.append(latency_s)
        if result.cascade is not None:
            if self.traffic is None:
                self.traffic = Traffic()
            self.traffic.add(result.cascade.inputs, result.cascade.spikes)

    @property
    def windows_per_s(self) -> float:
        return self.windows / self.wall_s if self.wall_s > 0 else math.nan

    @property
    def realtime_factor(self) -> float:
        """Sensor time processed / wall time (> 1: faster than the sensor makes the windows).
        Windows skipped over gaps (--skip-empty-after) count as sensor time too; a live source's
        windows jumped over after its queue dropped their events do not (they are not skipped)."""
        if not (self.wall_s > 0 and self.dt_us > 0):
            return math.nan
        return (self.windows + self.skipped_windows) * self.dt_us * 1e-6 / self.wall_s

    def to_json(self) -> dict:
        return {"target": self.target, "windows": self.windows, "objects": self.objects,
                "objects_per_bin": {str(k): v for k, v in sorted(self.objects_per_bin.items())},
                "wall_s": self.wall_s, "startup_s": self.startup_s, "windows_per_s": self.windows_per_s,
                "realtime_factor": self.realtime_factor,
                "latency_ms": percentiles_ms(self.latencies_s), "latency_kind": self.latency_kind, "tag": self.tag,
                "errors": self.errors, "camera": self.camera_json,
                "skipped": {"windows": self.skipped_windows, "gaps": self.skipped_gaps,
                            "longest_gap_s": self.longest_gap_us / 1e6},
                "incomplete_tail_us": self.incomplete_us,
                "bridge_traffic": self.traffic.to_json() if self.traffic is not None else None,
                "live": None if self.live is None else
                {**self.live, "event_latency_ms": percentiles_ms(self.event_latencies_s)},
                "time_unit_note": self.time_unit_note}

    @property
    def latency_kind(self) -> str:
        """What ``latency_ms`` is: on the simulator, host wall time through a pipelined Lava run,
        not Loihi latency (said in the text, the JSON and the report alike)."""
        return ("simulator wall time per window (not Loihi 2 latency)" if self.target == "loihi-sim"
                else "latency per window")

    def lines(self) -> list[str]:
        lat = percentiles_ms(self.latencies_s)
        bins = ", ".join(f"bin {k}: {v}" for k, v in sorted(self.objects_per_bin.items())) or "none"
        what = self.latency_kind
        out = [f"target {self.target}: {self.windows} windows, {self.objects} objects ({bins})",
               f"{self.windows_per_s:.1f} windows/s over {self.wall_s:.2f} s"
               + (" (a live source's pace: its waits and --idle-timeout included" if self.live is not None else " (")
               + f"{'; ' if self.live is not None else ''}start-up {self.startup_s:.2f} s"
               + (f"; real-time factor {self.realtime_factor:.3g}" if math.isfinite(self.realtime_factor) else "")
               + "); "
               f"{what} p50 {_ms(lat['p50'])}, p90 {_ms(lat['p90'])}, p99 {_ms(lat['p99'])}"]
        if self.camera:
            out.append(self.camera)
        if self.traffic is not None:
            out.append(self.traffic.line())
        if self.live is not None:
            out.append(live_line(self.live, self.event_latencies_s))
            late, got = self.live.get("late_events", 0), self.live.get("received_events", 0)
            if late:
                out.append(f"warning: {late} of {got} events ({100 * late / max(got, 1):.1f} %) came after their "
                           "window had been closed and were dropped: their times went back (events out of order at "
                           "the source) or the producer stalled for longer than the grace (--window-grace-ms gives it "
                           "longer; a file gives every event)")
        if self.time_unit_note:
            out.append(f"warning: {self.time_unit_note}")
        if self.skipped_windows:
            out.append(f"skipped {self.skipped_windows} empty windows in {self.skipped_gaps} gap(s) without events "
                       f"(longest {self.longest_gap_us / 1e6:.3f} s); no JSON line for them")
        if self.incomplete_us:
            out.append(f"the recording's last {self.incomplete_us} us end inside a window: not processed (its "
                       "objects would come from part of a window; --include-incomplete processes it)")
        if self.errors is not None:
            out += truth_lines(self.errors)
        return out


def _ms(v: float) -> str:
    """A latency for the summary lines: '1.23 ms', or '-' when no window gave one."""
    return f"{v:.2f} ms" if math.isfinite(v) else "-"


def live_line(stats: dict, latencies_s: list[float]) -> str:
    """The summary's line for a live source: event-to-line latency, received and lost events."""
    lat = percentiles_ms(latencies_s)
    return (f"live: newest event -> JSON line p50 {_ms(lat['p50'])}, p99 {_ms(lat['p99'])}; "
            f"{stats['received_events']} events in {stats['received_chunks']} chunks received, "
            f"{stats['dropped_events']} dropped in {stats['dropped_chunks']} chunks (queue of "
            f"{stats['queue_events']} events, peak {stats['peak_queue_events']}), {stats['late_events']} late"
            + (f", {stats['reordered_events']} out of time order put back in order" if stats.get("reordered_events")
               else "")
            + (f"; {stats['dropped_windows']} windows whose events were dropped jumped over (no JSON line, "
               "not counted as sensor time done)" if stats.get("dropped_windows") else "")
            + (f", {stats['invalid_events']} invalid (outside the sensor, stray datagrams)" if stats.get("invalid_events") else "")
            + (f"; the stream ended inside its last window: its {stats['incomplete_events']} events not processed "
               "(--include-incomplete processes them)" if stats.get("incomplete_events") else "")
            + (f", {stats['socket_drops']} datagrams dropped by the kernel (socket buffer full)"
               if stats.get("socket_drops") else ""))


def truth_lines(e: dict) -> list[str]:
    """The summary's ground-truth lines from a FlowErrors.summary(): detection first (recall, false
    positives per window, bin accuracy and the non-zero confusion cells), then the errors."""
    c = e["confusion"]
    cells = ", ".join(f"{t}->{p}: {n}" for t, row in zip(c["labels"], c["matrix"])
                      for p, n in zip(c["labels"], row) if n) or "none"
    fp = (f"{e['fp_per_window']:.3f} false positives per window "
          f"({e['false_positives']} in {e['n_windows']} windows)")
    if not e["n_gt"]:
        return [f"vs ground truth: no object in the truth, {fp}"]
    acc = f"{e['bin_accuracy']:.3f}" if e["n_matched"] else "- (nothing matched)"
    out = [f"vs ground truth (one-to-one within {e['gate_px']:g} px): recall {100 * e['recall']:.1f}% "
           f"({e['n_matched']}/{e['n_gt']} objects), {fp}, bin accuracy {acc}"]
    if e["n_matched"]:
        px_ms = "" if math.isnan(e["speedE_px_ms"]) else f", {e['speedE_px_ms']:.3f} px/ms"
        out += [f"matched objects: pixE {e['pixE']:.3f} px, dirE {e['dirE']:.3f} deg, speedE {e['speedE']:.3f} m/s"
                f"{px_ms} (bin-only {e['speedE_bin_only']:.3f} m/s); bins true->predicted: {cells}"]
    if e.get("tracking"):
        from ..tracking_metrics import tracking_line

        out.append(tracking_line(e["tracking"]))
    return out


#: what --dump-spikes may hold in memory before it writes (dense bool arrays, one byte each)
DUMP_MAX_BYTES = 4 << 30


def dump_bytes_per_window(n_stages: int, n_bins: int, width: int, height: int) -> int:
    """Bytes of one window's stage_input (N, B, 2, H, W) and stage_output (N, B, H, W) bool."""
    return n_stages * n_bins * width * height * 3


class SpikeDump:
    """`run --dump-spikes FILE.npz`: every window's OFS stage inputs and outputs, written once at
    the end (atomically, compressed) as

        t0_us         (n,) int64           window starts
        stage_input   (n, N, B, 2, H, W)   bool: the masked input OFS_k received (index k - 1), on
                                           the OFS grid (H, W = the sensor pooled by ofs_pool)
        stage_output  (n, N, B, H, W)      bool: its output spikes

    the same arrays on every target (cpu, loihi-sim, loihi2): what a user compares with another
    runtime (netx, NIR, hardware) when a deployment disagrees."""

    def __init__(self, path: str | Path):
        self.path = Path(path)
        self.t0: list[int] = []
        self.inputs: list[np.ndarray] = []
        self.outputs: list[np.ndarray] = []

    def add(self, result: WindowResult) -> None:
        stage_input, stage_output = result.stages
        self.t0.append(int(result.t0_us))
        self.inputs.append(stage_input)
        self.outputs.append(stage_output)

    def write(self) -> None:
        """One compressed .npz, atomically (atomic_path reports a refused write naming the file)."""
        with atomic_path(self.path) as tmp, open(tmp, "wb") as f:
            savez_compressed(f, t0_us=np.asarray(self.t0, dtype=np.int64),
                                stage_input=np.asarray(self.inputs, dtype=bool),
                                stage_output=np.asarray(self.outputs, dtype=bool))
