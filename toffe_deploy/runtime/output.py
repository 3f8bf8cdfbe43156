"""What ``run`` reports: one JSON line per window, and a summary (throughput, latency, errors).

JSON line per window (keys in this order)::

    {"t0_us": 1000, "t1_us": 1500, "objects": [{"speed_bin": 2, "speed_mps": 27.1,
      "speed_bin_mps": 30.0, "x": 120.4, "y": 88.0, "direction_rad": -1.2, "n_events": 310,
      "direction_deg": -68.75}]}

Lines go to stdout or, with ``--out FILE.jsonl``, to a file written atomically (a temp file
renamed into place when the run finishes; an interrupted run leaves nothing half-written).
"""
from __future__ import annotations

import contextlib
import json
import math
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Iterator

import numpy as np

from ..errors import InputError
from ..fileio import atomic_path
from .pipeline import WindowResult


@contextlib.contextmanager
def jsonl_sink(path: str | Path | None) -> Iterator[IO[str]]:
    """A text stream for JSON lines: stdout when ``path`` is None, else an atomic file."""
    if path is None:
        yield sys.stdout
        sys.stdout.flush()
        return
    try:
        ctx = atomic_path(path)
        tmp = ctx.__enter__()
    except OSError as exc:
        raise InputError(path, f"cannot write: {exc.strerror or exc}") from None
    try:
        with open(tmp, "w", encoding="utf-8") as f:
            yield f
    except BaseException:
        if not ctx.__exit__(*sys.exc_info()):
            raise
    else:
        ctx.__exit__(None, None, None)


def write_window(stream: IO[str], result: WindowResult) -> None:
    stream.write(json.dumps(result.to_json(), separators=(",", ":")) + "\n")


def percentiles_ms(seconds: list[float]) -> dict[str, float]:
    """p50/p90/p99 of per-window latencies, in milliseconds."""
    if not seconds:
        return {"p50": math.nan, "p90": math.nan, "p99": math.nan}
    a = np.asarray(seconds) * 1e3
    return {f"p{q}": float(np.percentile(a, q)) for q in (50, 90, 99)}


@dataclass
class RunSummary:
    """Counts and timings of one run; ``errors`` holds pixE/dirE/speedE when truth was present."""

    target: str
    windows: int = 0
    objects: int = 0
    objects_per_bin: dict[int, int] = field(default_factory=dict)
    wall_s: float = 0.0
    latencies_s: list[float] = field(default_factory=list)
    errors: dict | None = None
    startup_s: float = 0.0
    skipped_windows: int = 0
    skipped_gaps: int = 0
    longest_gap_us: int = 0

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

    @property
    def windows_per_s(self) -> float:
        return self.windows / self.wall_s if self.wall_s > 0 else math.nan

    def to_json(self) -> dict:
        return {"target": self.target, "windows": self.windows, "objects": self.objects,
                "objects_per_bin": {str(k): v for k, v in sorted(self.objects_per_bin.items())},
                "wall_s": self.wall_s, "startup_s": self.startup_s, "windows_per_s": self.windows_per_s,
                "latency_ms": percentiles_ms(self.latencies_s), "errors": self.errors,
                "skipped": {"windows": self.skipped_windows, "gaps": self.skipped_gaps,
                            "longest_gap_s": self.longest_gap_us / 1e6}}

    def lines(self) -> list[str]:
        lat = percentiles_ms(self.latencies_s)
        bins = ", ".join(f"bin {k}: {v}" for k, v in sorted(self.objects_per_bin.items())) or "none"
        # on the simulator this is host wall time through a pipelined Lava run, not Loihi latency
        what = ("simulator wall time per window (not Loihi 2 latency)" if self.target == "loihi-sim"
                else "latency per window")
        out = [f"target {self.target}: {self.windows} windows, {self.objects} objects ({bins})",
               f"{self.windows_per_s:.1f} windows/s over {self.wall_s:.2f} s (start-up {self.startup_s:.2f} s); "
               f"{what} p50 {lat['p50']:.2f} ms, p90 {lat['p90']:.2f} ms, p99 {lat['p99']:.2f} ms"]
        if self.skipped_windows:
            out.append(f"skipped {self.skipped_windows} empty windows in {self.skipped_gaps} gap(s) without events "
                       f"(longest {self.longest_gap_us / 1e6:.3f} s); no JSON line for them")
        if self.errors is not None:
            e = self.errors
            if e.get("n_matched"):
                out.append(f"vs ground truth: pixE {e['pixE']:.3f} px, dirE {e['dirE']:.3f} deg, "
                           f"speedE {e['speedE']:.3f} m/s (bin-only {e['speedE_bin_only']:.3f} m/s); "
                           f"{e['n_matched']}/{e['n_gt']} objects detected, {e['false_positives']} false positives")
            else:
                out.append(f"vs ground truth: no object matched ({e.get('n_gt', 0)} in the truth)")
        return out
