"""Held-out windows for the export's parity checks, with their ground truth.

Source, in this order:
- ``data``: the held-out ('test') sequences of a data set directory (as written by
  ``toffe-deploy dataset``), windows spread evenly over the files and over time (seeded);
- otherwise: the synthetic generator's multi-object scenes (``dataset.splits`` 'multi', two to
  four objects at distinct speed bins at once, so every cascade stage has work), rendered at the
  checkpoint's sensor size, short, with a fixed seed. parity.json records which.

Windows without events are skipped (nothing to compare); each window is binned exactly as the
runtime bins it (``events.binning.bin_window``).
"""
from __future__ import annotations

import copy
import dataclasses
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..config import ToffeConfig
from ..errors import InputError
from ..events.binning import bin_window
from ..events.support import SupportHistory, front_end, history_before
from ..plane_fit import history_settings

GEN_SEQUENCES = 2          # multi-object scenes generated when no data set is given


@dataclass
class HeldOut:
    """windows[i] (B, 2, H, W) bool, the front end's output for the window starting at t0[i];
    truths[i] the visible objects (or None). With config.input_support, support[i] is (the raw
    window, the SupportHistory of the K windows before it): what a Pipeline needs to redo the
    front end (its temporal support is not idempotent); empty without. With
    ofpd.plane_fit_history, ones[i] is the plane fit's time_surface.OnesHistory before window i
    (the front end's ones of the windows before it); empty without."""

    windows: list[np.ndarray]
    t0: list[int]
    truths: list[list] = field(default_factory=list)
    source: dict = field(default_factory=dict)
    support: list = field(default_factory=list)
    ones: list = field(default_factory=list)
    focal_px: list = field(default_factory=list)    # per window: its camera's focal length (None: unknown)

    def __len__(self) -> int:
        return len(self.windows)

    def recent(self, i: int, config: ToffeConfig):
        """The front end's SupportHistory after window i (what ofpd.recent_events reads): its
        history before with the window's event pixels pushed; None when no grouping reads it."""
        from ..ofpd_io import ofpd_settings

        if not self.support or ofpd_settings(config)["recent_events"] is None:
            return None
        raw, before = self.support[i]
        hist = copy.deepcopy(before)
        front_end(raw, config, hist, self.t0[i])
        return hist

    def ones_after(self, i: int):
        """The plane fit's history after window i (its ones pushed), or None without."""
        if not self.ones:
            return None
        return self.ones[i].after(self.t0[i], self.windows[i])

    def add(self, t0: int, window: np.ndarray, truths, support, ones=None, focal_px: float | None = None) -> None:
        self.windows.append(window)
        self.t0.append(t0)
        self.truths.append(truths)
        self.focal_px.append(focal_px)
        if support is not None:
            self.support.append(support)
        if ones is not None:
            self.ones.append(ones)


def _pick(t_starts: np.ndarray, n: int) -> np.ndarray:
    if t_starts.size <= n:
        return t_starts
    return t_starts[np.linspace(0, t_starts.size - 1, n).round().astype(np.int64)]


def _windows_of(events: np.ndarray, gt: dict | None, config: ToffeConfig, t_lo: int, t_hi: int, n: int):
    """Up to n non-empty windows of [t_lo, t_hi), evenly spread; yields (t0, front end's window,
    truths, (raw window, SupportHistory before it) or None, the plane fit's OnesHistory before it
    or None), as a stream started at t_lo holds them."""
    from ..dataset.groundtruth import window_truth

    dt = config.dt_us
    starts = np.arange(t_lo, t_hi - dt + 1, dt, dtype=np.int64)
    if starts.size == 0:
        return []
    counts = np.diff(np.searchsorted(events["t"], np.append(starts, starts[-1] + dt)))
    starts = starts[counts > 0]
    out = []
    t = events["t"]
    def read(lo, hi):
        return events[np.searchsorted(t, lo):np.searchsorted(t, hi)]

    for t0 in _pick(starts, n):
        raw = bin_window(events, int(t0), dt, config.n_bins, config.sensor_size)
        hist = before = ones = None
        if history_settings(config) is not None:
            hist, ones = history_before(read, int(t0), dt, config, config.sensor_size, t_lo)
        elif config.input_support is not None:
            hist = SupportHistory.before(read, int(t0), dt, config.input_support[0], config.sensor_size)
        if hist is not None:
            before = (raw > 0, copy.deepcopy(hist))
        b = front_end(raw, config, hist, int(t0))
        out.append((int(t0), b, window_truth(gt, int(t0), dt) if gt is not None else None, before, ones))
    return out


def _from_generator(config: ToffeConfig, seed: int, n_windows: int, progress: bool) -> HeldOut:
    from ..camera import PinholeCamera
    from ..dataset.splits import split_specs
    from ..dataset.synth import generate_sequence

    per_seq = -(-n_windows // GEN_SEQUENCES)
    duration_s = (per_seq + 2) * config.dt_us * 1e-6
    specs = split_specs("multi", seed=seed, duration_s=duration_s, multi_count=GEN_SEQUENCES)
    # the generator's 60 deg view over the checkpoint's sensor (its focal length is recorded and
    # scored with: the model reads image-plane motion; a checkpoint's own focal_px may be the
    # 640 px reference's on a small test sensor, a view of a few degrees that held no object)
    cam = PinholeCamera(width=config.width, height=config.height)
    held = HeldOut([], [], [], {"kind": "generated", "generator": "toffe_deploy.dataset.synth (split 'multi')",
                               "seed": seed, "sequences": [s.name for s in specs], "duration_s": duration_s,
                               "sensor_size": list(config.sensor_size), "focal_px": cam.f, "dt_us": config.dt_us,
                               "held_out": "multi-object scenes on the test curves; training uses the "
                                           "'train' split only"})
    for i, spec in enumerate(specs):
        events, gt, _ = generate_sequence(dataclasses.replace(spec, camera=cam), seed + i)
        for t0, b, tr, sup, ones in _windows_of(events, gt, config, config.dt_us, int(duration_s * 1e6), per_seq):
            held.add(t0, b, tr, sup, ones, cam.f)
    return held


def _from_data(config: ToffeConfig, data: str | os.PathLike, seed: int, n_windows: int) -> HeldOut:
    from ..events.io import open_events
    from ..model.data import find_sequences
    from ..runtime.truth import sequence_focal_px

    files = find_sequences(data, "test")
    rng = np.random.default_rng(seed)
    chosen = sorted(rng.choice(len(files), size=min(len(files), n_windows), replace=False).tolist())
    per_file = -(-n_windows // len(chosen))
    held = HeldOut([], [], [], {"kind": "data set", "data": str(Path(data).resolve()), "split": "test",
                               "files": [files[i].name for i in chosen], "seed": seed, "dt_us": config.dt_us})
    for i in chosen:
        with open_events(files[i]) as src:
            if tuple(src.sensor_size) != tuple(config.sensor_size):
                raise InputError(files[i], f"sensor size {list(src.sensor_size)} differs from the checkpoint's "
                                           f"{list(config.sensor_size)}")
            events = src.read(src.t_start_us, src.t_end_us + 1)
            gt = src.ground_truth
            focal = sequence_focal_px(src.attrs)
            for t0, b, tr, sup, ones in _windows_of(events, gt, config, src.t_start_us, src.t_end_us + 1, per_file):
                held.add(t0, b, tr, sup, ones, focal)
    return held


def heldout_windows(config: ToffeConfig, data: str | os.PathLike | None = None, seed: int = 0,
                    n_windows: int = 16, progress: bool = False) -> HeldOut:
    """The parity windows (see module docstring); InputError when none has events."""
    held = _from_data(config, data, seed, n_windows) if data is not None else \
        _from_generator(config, seed, n_windows, progress)
    if not held.windows:
        raise InputError(data or "generator", "no held-out window with events for the parity checks")
    held.windows = held.windows[:n_windows]
    held.t0 = held.t0[:n_windows]
    held.truths = held.truths[:n_windows]
    held.focal_px = held.focal_px[:n_windows]
    held.support = held.support[:n_windows]
    held.source["n_windows"] = len(held.windows)
    return held
