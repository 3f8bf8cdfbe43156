"""Our HDF5 event layout ("toffe-events", version 1): what the generator writes and every
command reads fastest.

Layout (why: column datasets like DSEC's so any HDF5 tool reads them; chunked + compressed so
a window reads only the chunks it touches; a millisecond index so seeking is two small reads)::

    /                      attrs: format = "toffe-events", format_version = 1,
                                  sensor_width, sensor_height (px), num_events,
                                  t_start_us, t_end_us (covered span, end exclusive),
                                  plus user attrs, each stored as JSON text under its own name
    /events/x, y           uint16  (N,)  pixel column / row, 0 <= x < width, 0 <= y < height
    /events/t              int64   (N,)  microseconds, non-decreasing, 0 .. 2**53
    /events/p              uint8   (N,)  1 = ON, 0 = OFF (any other value is refused)
    /events/ms_to_idx      int64   (M,)  ms_to_idx[m] = first i with t[i] >= index_t0_us + 1000 m
                                         (attr index_t0_us), M = ceil((t[-1]+1 - index_t0_us)/1000);
                                         a hint only: every lookup is checked against /events/t
    /ground_truth/<col>    1-D columns of one length, one row per object per sample (optional):
                           t i8 (us), object_id i4, x f4, y f4 (px, image-plane centre),
                           direction f4 (rad, atan2(dy, dx), y down), speed f4 (m/s, 3-D),
                           speed_bin i1 (1..4, 0 below bin 1), visible bool,
                           speed_px_ms f4 (image-plane speed of the centre, px/ms),
                           depth_m f4 (object Z, m); other columns kept as given.

speed_bin: files from generator version 3 on hold the bin of the image-plane speed speed_px_ms
under the reference configuration (ToffeConfig(): m/s bins at 5 m, 554.26 px); older files hold
the bin of the 3-D speed. Files written before speed_px_ms and depth_m existed read without
them in the file: speed_px_ms is derived on reading from the x, y track (central differences
per object, ``derive_speed_px_ms``), depth_m stays absent (it cannot be recovered).
"""
from __future__ import annotations

import io
import json
import os

import h5py
import numpy as np

from ..errors import InputError
from ..fileio import write_bytes_atomic
from .convert import time_us, to_events
from .core import EVENT_DTYPE
from .h5util import dataset, index_via_ms, ms_index_dataset
from .source import EventSource
from .validate import check_chunk, check_ground_truth, check_sensor_size

FORMAT_NAME = "toffe-events"
FORMAT_VERSION = 1
#: HDF5 chunk length (events) for the event columns: 64 Ki events ~ 1 MiB per column chunk.
H5_CHUNK = 1 << 16
RESERVED_ATTRS = ("format", "format_version", "sensor_width", "sensor_height", "num_events",
                  "t_start_us", "t_end_us")
#: Ground-truth columns we know and the dtype they are stored as.
GT_DTYPES = {"t": "<i8", "object_id": "<i4", "x": "<f4", "y": "<f4", "direction": "<f4",
             "speed": "<f4", "speed_bin": "i1", "visible": "?", "speed_px_ms": "<f4", "depth_m": "<f4"}
#: Columns every ground truth has; speed_px_ms is derived for files from before it, depth_m optional.
GT_REQUIRED = ("t", "object_id", "x", "y", "direction", "speed", "speed_bin", "visible")
GT_OPTIONAL = ("speed_px_ms", "depth_m")


def derive_speed_px_ms(gt: dict[str, np.ndarray]) -> np.ndarray:
    """Image-plane speed (px/ms) of each ground-truth row from its object's x, y over t (us):
    hypot(dx/dt, dy/dt) * 1000 by central differences (one-sided at the ends); NaN for an
    object with a single row. For files older than the speed_px_ms column."""
    t = np.asarray(gt["t"], dtype=np.float64)
    x, y = np.asarray(gt["x"], dtype=np.float64), np.asarray(gt["y"], dtype=np.float64)
    ids = np.asarray(gt["object_id"])
    out = np.full(t.shape[0], np.nan, dtype=np.float32)
    for oid in np.unique(ids):
        sel = np.flatnonzero(ids == oid)
        sel = sel[np.argsort(t[sel], kind="stable")]
        if sel.shape[0] < 2 or np.any(np.diff(t[sel]) <= 0):
            continue
        out[sel] = np.hypot(np.gradient(x[sel], t[sel]), np.gradient(y[sel], t[sel])) * 1000.0
    return out


def ms_index(t: np.ndarray, index_t0_us: int) -> np.ndarray:
    """ms_to_idx[m] = first i with t[i] >= index_t0_us + 1000 m (t sorted); one searchsorted."""
    if t.shape[0] == 0:
        return np.zeros(0, np.int64)
    n_ms = -(-(int(t[-1]) + 1 - index_t0_us) // 1000)
    edges = index_t0_us + 1000 * np.arange(n_ms + 1, dtype=np.int64)
    return np.searchsorted(t, edges, side="left").astype(np.int64)


def _column(f: h5py.Group, name: str, data: np.ndarray, dtype) -> None:
    data = np.ascontiguousarray(data, dtype=dtype)
    chunks = (min(H5_CHUNK, max(1, data.shape[0])),)
    f.create_dataset(name, data=data, chunks=chunks, maxshape=(None,), compression="gzip",
                     compression_opts=1, shuffle=True)


def write_events_h5(path: str | os.PathLike, events: np.ndarray, sensor_size: tuple[int, int],
                    ground_truth: dict | None = None, attrs: dict | None = None, *,
                    t_range: tuple[int, int] | None = None) -> None:
    """Write events (EVENT_DTYPE, time-sorted) and optional ground truth to ``path`` atomically.

    ``attrs`` values must be JSON-serializable (stored as JSON text, read back decoded).
    ``t_range`` = (t_start_us, t_end_us) records the span the file covers when it is wider than
    its events (e.g. a generated sequence whose last microseconds had no event); by default the
    span of the events and the ground truth. Raises ValueError on bad arguments (a caller bug).
    """
    events = np.asarray(events)
    missing = [n for n in EVENT_DTYPE.names if events.dtype.names is None or n not in events.dtype.names]
    if missing:
        raise ValueError(f"events lack fields {missing}; build them with make_events()")
    w, h = check_sensor_size(path, sensor_size)
    try:
        check_chunk(path, events, (w, h))
    except InputError as exc:
        raise ValueError(f"refusing to write bad events: {exc.problem}") from None
    attrs = dict(attrs or {})
    clash = [k for k in attrs if k in RESERVED_ATTRS]
    if clash:
        raise ValueError(f"attrs {clash} are reserved by the file format")
    attrs_json = {k: json.dumps(v) for k, v in attrs.items()}   # fail before touching the disk
    gt = None
    if ground_truth is not None:
        gt = {k: np.asarray(v) for k, v in ground_truth.items()}
        lengths = {k: v.shape for k, v in gt.items()}
        if any(len(s) != 1 for s in lengths.values()) or len({s[0] for s in lengths.values()}) > 1:
            raise ValueError(f"ground truth columns must be 1-D of one length, got {lengths}")
        if "t" not in gt:
            raise ValueError("ground truth needs a 't' column")
    t = np.ascontiguousarray(events["t"], dtype=np.int64)
    n = int(t.shape[0])
    if t_range is None:
        starts = [int(t[0])] if n else []
        ends = [int(t[-1]) + 1] if n else []
        if gt is not None and gt["t"].shape[0]:
            starts.append(int(gt["t"].min()))
            ends.append(int(gt["t"].max()) + 1)
        t_range = (min(starts), max(ends)) if starts else (0, 0)
    t_start, t_end = int(t_range[0]), int(t_range[1])
    if n and (t_start > t[0] or t_end <= t[-1]):
        raise ValueError(f"t_range {t_range} does not cover the events [{int(t[0])}, {int(t[-1])}]")
    buf = io.BytesIO()     # built in memory: HDF5's own writes crash the interpreter on a full disk
    with h5py.File(buf, "w") as f:
        f.attrs["format"] = FORMAT_NAME
        f.attrs["format_version"] = FORMAT_VERSION
        f.attrs["sensor_width"] = w
        f.attrs["sensor_height"] = h
        f.attrs["num_events"] = n
        f.attrs["t_start_us"] = t_start
        f.attrs["t_end_us"] = t_end
        for k, v in attrs_json.items():
            f.attrs[k] = v
        g = f.create_group("events")
        for name in EVENT_DTYPE.names:
            _column(g, name, events[name], EVENT_DTYPE[name])
        index_t0 = int(t[0]) if n else 0
        idx = g.create_dataset("ms_to_idx", data=ms_index(t, index_t0))
        idx.attrs["index_t0_us"] = index_t0
        if gt is not None:
            gg = f.create_group("ground_truth")
            for k, v in gt.items():
                _column(gg, k, v, GT_DTYPES.get(k, v.dtype))
    write_bytes_atomic(path, buf.getbuffer(), suffix=".h5")


class ToffeH5Source(EventSource):
    """Reader of our HDF5 layout: chunked column reads, ms index for seeking."""

    format_name = FORMAT_NAME

    def __init__(self, path, h5: h5py.File, sensor_size=None):
        a = h5.attrs
        version = int(a.get("format_version", 0))
        if version > FORMAT_VERSION:
            raise InputError(path, f"{FORMAT_NAME} format version {version} is newer than this "
                                   f"toffe-deploy reads ({FORMAT_VERSION}); upgrade toffe-deploy")
        missing = [k for k in ("sensor_width", "sensor_height") if k not in a]
        if missing:                                             # h5py's KeyError text is its C library's
            raise InputError(path, f"missing root attribute{'s' if len(missing) > 1 else ''} {', '.join(missing)}")
        own = (a["sensor_width"], a["sensor_height"])          # check_sensor_size: whole numbers only
        super().__init__(path, check_sensor_size(path, sensor_size or own))
        self._h5 = h5
        if "events" not in h5 or not isinstance(h5["events"], h5py.Group):
            raise InputError(path, "missing the /events group")
        g = h5["events"]
        missing = [n for n in EVENT_DTYPE.names if n not in g]
        if missing:
            raise InputError(path, f"missing event fields {', '.join('/events/' + m for m in missing)}")
        self._cols = {n: dataset(path, g, n) for n in EVENT_DTYPE.names}
        shapes = {n: d.shape for n, d in self._cols.items()}
        if any(len(s) != 1 for s in shapes.values()) or len({s[0] for s in shapes.values()}) != 1:
            raise InputError(path, f"event fields differ in shape: {shapes}")
        self._n = shapes["t"][0]
        self._idx = ms_index_dataset(path, g)
        self._idx_t0 = int(self._idx.attrs.get("index_t0_us", 0)) if self._idx is not None else 0
        self._span = (int(a.get("t_start_us", 0)), int(a.get("t_end_us", 0))) \
            if "t_start_us" in a and "t_end_us" in a else None
        self._gt_cache = None

    @property
    def num_events(self):
        return self._n

    def _read_index(self, i0, i1):
        try:
            c = {name: ds[i0:i1] for name, ds in self._cols.items()}
        except (OSError, ValueError) as exc:
            raise InputError(self.path, f"cannot read events {i0}..{i1 - 1} (truncated or corrupt "
                                        f"file?): {exc}") from None
        if all(c[n].dtype == EVENT_DTYPE[n] for n in EVENT_DTYPE.names):   # as we write it: no cast hides anything
            out = np.empty(i1 - i0, EVENT_DTYPE)
            for name in EVENT_DTYPE.names:
                out[name] = c[name]
            bad = np.flatnonzero(out["p"] > 1)
            if bad.size:
                i = int(bad[0])
                raise InputError(self.path, f"polarity p = {int(out['p'][i])} at event {i0 + i} is not 0 or 1")
            return out
        # other column types (float x, int8 p, ...): checked conversion, never a silent cast
        return to_events(self.path, c["x"], c["y"], time_us(self.path, c["t"], i0), c["p"], i0)

    def _t_at(self, i):
        try:
            return int(time_us(self.path, self._cols["t"][i:i + 1], i)[0])
        except (OSError, ValueError) as exc:
            raise InputError(self.path, f"cannot read timestamp {i} (truncated or corrupt file?): "
                                        f"{exc}") from None

    def _index_of_time(self, t):
        if self._idx is None or self._n == 0:
            return super()._index_of_time(t)
        return index_via_ms(self.path, t, self._idx, self._idx_t0, self._cols["t"], self._n)

    @property
    def t_start_us(self):
        return self._span[0] if self._span else super().t_start_us

    @property
    def t_end_us(self):
        return self._span[1] if self._span else super().t_end_us

    @property
    def ground_truth(self):
        if "ground_truth" not in self._h5:
            return None
        if self._gt_cache is None:
            g = self._h5["ground_truth"]
            try:
                gt = {k: g[k][()] for k in g if isinstance(g[k], h5py.Dataset)}
            except (OSError, ValueError) as exc:
                raise InputError(self.path, f"cannot read /ground_truth (corrupt file?): {exc}") from None
            if "speed_px_ms" not in gt and all(k in gt for k in ("t", "object_id", "x", "y")) \
                    and len({gt[k].shape for k in ("t", "object_id", "x", "y")}) == 1:
                gt["speed_px_ms"] = derive_speed_px_ms(gt)   # a file from before the column
            self._gt_cache = check_ground_truth(self.path, gt, required=GT_REQUIRED)
        return self._gt_cache

    @property
    def attrs(self):
        out = {}
        for k, v in self._h5.attrs.items():
            if k in RESERVED_ATTRS:
                continue
            if isinstance(v, bytes):
                v = v.decode("utf-8", "replace")
            try:
                out[k] = json.loads(v) if isinstance(v, str) else v.tolist() if hasattr(v, "tolist") else v
            except json.JSONDecodeError:
                out[k] = v                      # a plain string, not JSON
            except RecursionError:              # JSON nested deeper than the parser's stack
                raise InputError(self.path, f"root attribute {k}: JSON nested too deeply") from None
        return out

    def close(self):
        try:
            self._h5.close()
        except Exception:   # closing an already-broken file must not mask the real error
            pass
