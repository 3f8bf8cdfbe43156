"""Metavision HDF5 (what Prophesee's Metavision SDK and OpenEB write as .hdf5): /CD/events, a
compound dataset of (x u2, y u2, p i2, t i8) records, t in microseconds, p in {0, 1}; /CD/indexes
(id, ts) every 2 ms and /EXT_TRIGGER/... beside it; root attributes as strings (``geometry`` =
"1280x720", ``version``, camera metadata).

Prophesee compresses /CD/events with its ECF HDF5 filter (id 0x8ECF = 36559). h5py reads it
only where Prophesee's hdf5_ecf plugin is installed (HDF5_PLUGIN_PATH); without it the file is
refused with one line naming the filter. Uncompressed and gzip files read as they are.
Seeking is a binary search on the t field (the 2 ms index is not needed).
"""
from __future__ import annotations

import numpy as np

from ..errors import InputError
from .convert import time_us, to_events
from .fmt_prophesee import header_geometry
from .h5util import dataset, read_slice
from .source import EventSource
from .validate import check_sensor_size


def _text(v) -> str:
    return v.decode("utf-8", "replace") if isinstance(v, bytes) else str(v)


class MetavisionH5Source(EventSource):
    format_name = "metavision"

    def __init__(self, path, h5, sensor_size=None):
        self._h5 = h5
        self._meta = {k: _text(v) for k, v in h5.attrs.items() if np.ndim(v) == 0}
        own = header_geometry({k.lower(): v for k, v in self._meta.items()})
        if sensor_size is None and own is None:
            raise InputError(path, "Metavision HDF5 without a 'geometry' root attribute (WxH); "
                                   "pass --sensor-size W H")
        super().__init__(path, check_sensor_size(path, sensor_size or own))
        self._ds = dataset(path, h5, "CD/events")
        names = self._ds.dtype.names or ()
        missing = [n for n in "xypt" if n not in names]
        if missing or self._ds.ndim != 1:
            raise InputError(path, f"/CD/events must be a 1-D compound dataset with fields x, y, p, t; "
                                   f"got {self._ds.dtype} {self._ds.shape}")

    @property
    def num_events(self):
        return int(self._ds.shape[0])

    def _read_index(self, i0, i1):
        a = read_slice(self.path, self._ds, slice(i0, i1))
        return to_events(self.path, a["x"], a["y"], time_us(self.path, a["t"], i0), a["p"], i0)

    def _t_at(self, i):
        a = read_slice(self.path, self._ds, slice(i, i + 1))
        return int(time_us(self.path, a["t"], i)[0])

    @property
    def attrs(self):
        return {"metadata": dict(self._meta)}     # nested: 'format', 'version' name our own file attrs

    def close(self):
        try:
            self._h5.close()
        except Exception:   # closing an already-broken file must not mask the real error
            pass
