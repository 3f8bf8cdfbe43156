"""DSEC-style HDF5: /events/{x, y, t, p}, t in us relative to the scalar /t_offset, with the
optional /ms_to_idx seek index (ms_to_idx[m] = first i with t[i] >= 1000 m).

DSEC records no sensor size in the file: 640x480 (its Prophesee Gen3.1 cameras) unless a
``sensor_size`` is given. Real DSEC files are Blosc-compressed: reading them needs hdf5plugin,
and a missing filter is reported as such. Absolute times: t + t_offset.
"""
from __future__ import annotations

import numpy as np

from ..errors import InputError
from .convert import time_us, to_events
from .core import EVENT_DTYPE
from .h5util import dataset, index_via_ms, ms_index_dataset, read_slice
from .source import EventSource
from .validate import check_sensor_size

DSEC_SENSOR_SIZE = (640, 480)


class DsecSource(EventSource):
    format_name = "dsec"

    def __init__(self, path, h5, sensor_size=None):
        super().__init__(path, check_sensor_size(path, sensor_size or DSEC_SENSOR_SIZE))
        self._default_size = sensor_size is None       # the file records none: the layout's default
        self._h5 = h5
        self._cols = {n: dataset(path, h5, f"events/{n}") for n in EVENT_DTYPE.names}
        shapes = {n: d.shape for n, d in self._cols.items()}
        if any(len(s) != 1 for s in shapes.values()) or len({s[0] for s in shapes.values()}) != 1:
            raise InputError(path, f"event fields differ in shape: {shapes}")
        self._n = shapes["t"][0]
        if "t_offset" in h5:
            off = read_slice(path, dataset(path, h5, "t_offset"), ())
            if np.ndim(off) != 0 or not np.issubdtype(np.asarray(off).dtype, np.integer):
                raise InputError(path, f"/t_offset must be a scalar integer (us), got {off!r}")
            self._t_offset = int(off)
        else:
            self._t_offset = 0
        self._idx = ms_index_dataset(path, h5)

    @property
    def num_events(self):
        return self._n

    def _read_index(self, i0, i1):
        c = {n: read_slice(self.path, d, slice(i0, i1)) for n, d in self._cols.items()}
        t = time_us(self.path, c["t"], i0) + self._t_offset
        return to_events(self.path, c["x"], c["y"], t, c["p"], i0)

    def _t_at(self, i):
        return int(time_us(self.path, read_slice(self.path, self._cols["t"], slice(i, i + 1)), i)[0]) \
            + self._t_offset

    def _index_of_time(self, t):
        if self._idx is None or self._n == 0:
            return super()._index_of_time(t)
        return index_via_ms(self.path, t, self._idx, self._t_offset, self._cols["t"], self._n,
                            t_offset=self._t_offset)

    @property
    def attrs(self):
        return {"t_offset_us": self._t_offset, **({"sensor_size_default": "DSEC"} if self._default_size else {})}

    def close(self):
        try:
            self._h5.close()
        except Exception:   # closing an already-broken file must not mask the real error
            pass
