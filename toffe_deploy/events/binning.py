"""TOFFE's discretized event volume: a window [t0, t0+dt) split into B bins x 2 polarities.

Bin of an event: b = floor((t - t0) * B / dt). Channel: the polarity (0 = OFF, 1 = ON).
O(events): one bincount over a linear index, no Python loop over events.
"""
from __future__ import annotations

import numpy as np


def window_slice(events: np.ndarray, t0: int, dt_us: int) -> np.ndarray:
    """The events of a time-sorted array that fall in [t0, t0 + dt_us) (a view, no copy)."""
    t = events["t"]
    i0, i1 = np.searchsorted(t, [t0, t0 + dt_us], side="left")
    return events[i0:i1]


_compiled = None


def _kernels():
    """toffe_deploy.compiled, imported on first use and kept: this module stays importable without
    numba (the CLI's light commands), and the cpu path's per-window call skips the import
    statement (~2.4 us a window as a function-level relative import, measured)."""
    global _compiled
    if _compiled is None:
        from .. import compiled

        _compiled = compiled
    return _compiled


def _kernel_args(events: np.ndarray, t0: int, dt_us: int, n_bins: int, sensor_size: tuple[int, int]) -> tuple:
    """The arguments compiled.bin_index and binned_ones take: the event fields, then the window."""
    width, height = int(sensor_size[0]), int(sensor_size[1])
    return (np.asarray(events["t"], dtype=np.int64), events["x"], events["y"], events["p"], int(t0), int(dt_us),
            int(n_bins), height, width)


def event_bin_index(events: np.ndarray, t0: int, dt_us: int, n_bins: int,
                    sensor_size: tuple[int, int]) -> np.ndarray:
    """Linear index ((b * 2 + p) * H + y) * W + x into the (n_bins, 2, H, W) volume of each event
    in [t0, t0 + dt_us), b = (t - t0) * B // dt, p = polarity (events outside are dropped).

    The one definition of an event's bin and channel: bin_window counts these indices and the
    runtime's SpikeVolume.from_events keeps their unique values.
    """
    return _kernels().bin_index(*_kernel_args(events, t0, dt_us, n_bins, sensor_size))   # one compiled pass


def event_ones(events: np.ndarray, t0: int, dt_us: int, n_bins: int, sensor_size: tuple[int, int]) -> np.ndarray:
    """np.unique(event_bin_index(...)): the sorted linear indices of the window's ones, in one
    compiled call (compiled.binned_ones; the cpu hot path: SpikeVolume.from_events)."""
    return _kernels().binned_ones(*_kernel_args(events, t0, dt_us, n_bins, sensor_size))


def bin_window(events: np.ndarray, t0: int, dt_us: int, n_bins: int, sensor_size: tuple[int, int],
               dtype=np.uint16) -> np.ndarray:
    """Counts per (bin, polarity, y, x) for the events in [t0, t0 + dt_us).

    Events outside the window are ignored, so a caller may pass a superset. Counts saturate at
    the dtype's maximum. Returns an array of shape (n_bins, 2, height, width).
    """
    width, height = int(sensor_size[0]), int(sensor_size[1])
    idx = event_bin_index(events, t0, dt_us, n_bins, sensor_size)
    size = n_bins * 2 * height * width
    info = np.iinfo(dtype) if np.issubdtype(dtype, np.integer) else None
    if idx.size * 64 < size:
        # Sparse window (the usual case at full resolution): count the touched bins only, so
        # the cost follows the events, not the 3 M bins of a 640x480 volume.
        out = np.zeros(size, dtype=dtype)
        uniq, cnt = np.unique(idx, return_counts=True)
        if info is not None:
            np.minimum(cnt, info.max, out=cnt)
        out[uniq] = cnt
        return out.reshape(n_bins, 2, height, width)
    counts = np.bincount(idx, minlength=size)
    if info is not None and counts.max(initial=0) > info.max:
        np.minimum(counts, info.max, out=counts)
    return counts.astype(dtype, copy=False).reshape(n_bins, 2, height, width)
