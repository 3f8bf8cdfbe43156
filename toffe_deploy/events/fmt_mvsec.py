"""MVSEC-style HDF5: /davis/left/events (or right), N x 4 float64 rows (x, y, t, p) with t in
seconds (ROS time) and p in {-1, +1}.

Mapping: t -> round(t * 1e6) int64 us (float64 seconds near 1.5e9 keep ~0.25 us resolution),
p -> 1 if p > 0 else 0. MVSEC records no sensor size: 346x260 (DAVIS 346) unless given.
"""
from __future__ import annotations

from ..errors import InputError
from .convert import time_us, to_events
from .h5util import dataset, read_slice
from .source import EventSource
from .validate import check_sensor_size

MVSEC_SENSOR_SIZE = (346, 260)


class MvsecSource(EventSource):
    format_name = "mvsec"

    def __init__(self, path, h5, sensor_size=None, camera: str | None = None):
        super().__init__(path, check_sensor_size(path, sensor_size or MVSEC_SENSOR_SIZE))
        self._default_size = sensor_size is None       # the file records none: the layout's default
        self._h5 = h5
        cams = [camera] if camera else [c for c in ("left", "right") if f"davis/{c}/events" in h5]
        if not cams:
            raise InputError(path, "missing field /davis/left/events (MVSEC layout)")
        self.camera = cams[0]
        self._ds = dataset(path, h5, f"davis/{self.camera}/events")
        if self._ds.ndim != 2 or self._ds.shape[1] < 4:
            raise InputError(path, f"/davis/{self.camera}/events must be N x 4 (x, y, t, p), "
                                   f"got shape {self._ds.shape}")

    @property
    def num_events(self):
        return int(self._ds.shape[0])

    def _read_index(self, i0, i1):
        a = read_slice(self.path, self._ds, slice(i0, i1))
        return to_events(self.path, a[:, 0], a[:, 1], time_us(self.path, a[:, 2], i0, scale=1e6), a[:, 3], i0)

    def _t_at(self, i):
        a = read_slice(self.path, self._ds, (slice(i, i + 1), 2))
        return int(time_us(self.path, a, i, scale=1e6)[0])

    @property
    def attrs(self):
        return {"camera": self.camera, **({"sensor_size_default": "MVSEC"} if self._default_size else {})}

    def close(self):
        try:
            self._h5.close()
        except Exception:   # closing an already-broken file must not mask the real error
            pass
