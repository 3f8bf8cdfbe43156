"""numpy event files: ``.npy`` (memory-mapped, so windows stream) and ``.npz`` (loaded whole).

Accepted content: a structured array with fields x, y, t, p (the tonic convention; other fields
ignored) or a plain N x 4 array with columns x, y, t, p; in an .npz, arrays named x, y, t, p
(or one structured array named ``events``) plus an optional ``sensor_size`` (width, height).
t in microseconds (whole numbers), p as bool, 0/1 or -1/+1. Without a sensor size (argument or
file) it is inferred as max coordinate + 1 and ``attrs["sensor_size_inferred"]`` says so.
Never unpickles (allow_pickle=False): an object array is reported, not executed.
"""
from __future__ import annotations

import io
import zipfile

import numpy as np

from ..errors import InputError
from ..fileio import savez_compressed, write_bytes_atomic
from .convert import time_us, to_events
from .core import EVENT_DTYPE
from .source import ArraySource, EventSource
from .validate import check_chunk, check_sensor_size


def _columns(path, arr: np.ndarray) -> dict[str, np.ndarray]:
    """Column views x, y, t, p of a structured or N x 4 array (no copy for a memmap)."""
    if arr.dtype.names:
        missing = [n for n in EVENT_DTYPE.names if n not in arr.dtype.names]
        if missing:
            raise InputError(path, f"structured array lacks fields {', '.join(missing)} "
                                   f"(has {', '.join(arr.dtype.names)})")
        if arr.ndim != 1:
            raise InputError(path, f"expected a 1-D structured array, got shape {arr.shape}")
        return {n: arr[n] for n in EVENT_DTYPE.names}
    if arr.ndim == 2 and arr.shape[1] == 4 and arr.dtype.kind in "iuf":
        return {n: arr[:, k] for k, n in enumerate(EVENT_DTYPE.names)}
    raise InputError(path, f"expected a structured array with fields x, y, t, p or an N x 4 "
                           f"array (x, y, t, p), got dtype {arr.dtype} shape {arr.shape}")


def _infer_size(path, cols, plain: bool) -> tuple[int, int]:
    """Max coordinate + 1, checked; a plain N x 4 array whose size is off the scale says its
    column order (a (t, x, y, p) array read as x, y, t, p made "sensor size 99951x346")."""
    if cols["x"].shape[0] == 0:
        return (1, 1)
    w, h = int(np.max(cols["x"])) + 1, int(np.max(cols["y"])) + 1
    try:
        return check_sensor_size(path, (w, h))
    except InputError:
        raise InputError(path, f"no sensor size given, and the largest coordinates make {w}x{h} px, over 65535"
                         + (": a plain N x 4 array holds the columns x, y, t, p in that order (t in us)" if plain
                            else "") + " (--sensor-size WxH gives the size)") from None


class NpySource(EventSource):
    """A memory-mapped .npy: only the touched pages are read."""

    format_name = "npy"

    def __init__(self, path, cols: dict, sensor_size, inferred: bool):
        super().__init__(path, sensor_size)
        self._c = cols
        self._inferred = inferred

    @property
    def num_events(self):
        return int(self._c["t"].shape[0])

    def _read_index(self, i0, i1):
        c = {k: np.asarray(v[i0:i1]) for k, v in self._c.items()}
        return to_events(self.path, c["x"], c["y"], time_us(self.path, c["t"], i0), c["p"], i0)

    def _t_at(self, i):
        return int(time_us(self.path, np.asarray(self._c["t"][i:i + 1]), i)[0])

    def _index_of_time(self, t):
        return int(np.searchsorted(self._c["t"], t, side="left"))

    @property
    def attrs(self):
        return {"sensor_size_inferred": True} if self._inferred else {}


def open_numpy(path, kind: str, sensor_size=None) -> EventSource:
    """An EventSource over an .npy (streaming) or .npz (in memory) file."""
    try:
        if kind == "npy":
            arr = np.load(path, mmap_mode="r", allow_pickle=False)
            cols = _columns(path, arr)
            inferred = sensor_size is None
            size = check_sensor_size(path, sensor_size) if sensor_size else _infer_size(path, cols, not arr.dtype.names)
            return NpySource(path, cols, size, inferred)
        with np.load(path, allow_pickle=False) as z:
            names = set(z.files)
            plain = False
            if "events" in names:
                arr = z["events"]
                cols, plain = _columns(path, arr), not arr.dtype.names
            else:
                missing = [n for n in EVENT_DTYPE.names if n not in names]
                if missing:
                    raise InputError(path, f"npz lacks arrays {', '.join(missing)} "
                                           f"(has {', '.join(sorted(names)) or 'none'})")
                cols = {n: z[n] for n in EVENT_DTYPE.names}
                lengths = {n: c.shape for n, c in cols.items()}
                if any(len(s) != 1 for s in lengths.values()) or len({s[0] for s in lengths.values()}) != 1:
                    raise InputError(path, f"arrays x, y, t, p differ in shape: {lengths}")
            own = tuple(z["sensor_size"].tolist()) if "sensor_size" in names else None   # check_sensor_size
    except InputError:
        raise
    except (ValueError, OSError, EOFError, zipfile.BadZipFile, KeyError) as exc:
        raise InputError(path, f"cannot read {kind} file (truncated or corrupt?): {exc}") from None
    inferred = sensor_size is None and own is None
    size = check_sensor_size(path, sensor_size or own) if (sensor_size or own) else _infer_size(path, cols, plain)
    ev = to_events(path, cols["x"], cols["y"], time_us(path, cols["t"]), cols["p"])
    src = ArraySource(path, ev, size, attrs={"sensor_size_inferred": True} if inferred else None)
    src.format_name = "npz"
    return src


def write_npz(path, events: np.ndarray, sensor_size) -> None:
    """Columns x, y, t, p and sensor_size, compressed, written atomically (never pickled)."""
    w, h = check_sensor_size(path, sensor_size)
    try:
        check_chunk(path, events, (w, h))
    except InputError as exc:
        raise ValueError(f"refusing to write bad events: {exc.problem}") from None
    buf = io.BytesIO()     # built in memory so a full disk is one OSError, not a broken zip writer
    savez_compressed(buf, sensor_size=np.array([w, h], np.int64),
                        **{n: np.ascontiguousarray(events[n]) for n in EVENT_DTYPE.names})
    write_bytes_atomic(path, buf.getbuffer(), suffix=".npz")
