"""Small HDF5 helpers shared by the HDF5 readers (ours, DSEC, MVSEC)."""
from __future__ import annotations

import h5py
import numpy as np

from ..errors import InputError

#: Filters real data sets use that plain h5py lacks (DSEC ships Blosc-compressed files).
_FILTER_NAMES = {32001: "Blosc", 32004: "LZ4", 32008: "bitshuffle", 32015: "Zstandard"}


def require_filters(path, ds: h5py.Dataset) -> None:
    """InputError naming the missing HDF5 compression filter, before a read fails obscurely."""
    try:
        import hdf5plugin  # noqa: F401  (registers Blosc & co. when installed)
    except ImportError:
        pass
    dcpl = ds.id.get_create_plist()
    for i in range(dcpl.get_nfilters()):
        fid = dcpl.get_filter(i)[0]
        if not h5py.h5z.filter_avail(fid):
            name = _FILTER_NAMES.get(fid, f"id {fid}")
            raise InputError(path, f"{ds.name} is compressed with the HDF5 {name} filter, which is not "
                                   "installed here (pip install hdf5plugin)")


def dataset(path, h5: h5py.File, name: str) -> h5py.Dataset:
    """``h5[name]`` as a readable dataset, or InputError('missing field ...')."""
    obj = h5.get(name)
    if obj is None:
        raise InputError(path, f"missing field /{name.lstrip('/')}")
    if not isinstance(obj, h5py.Dataset):
        raise InputError(path, f"/{name.lstrip('/')} is not a dataset")
    require_filters(path, obj)
    return obj


def read_slice(path, ds: h5py.Dataset, sl) -> np.ndarray:
    """``ds[sl]``, with a corrupt/truncated file turned into InputError."""
    try:
        return ds[sl]
    except (OSError, ValueError, RuntimeError) as exc:
        raise InputError(path, f"cannot read {ds.name} (truncated or corrupt file?): {exc}") from None


def index_via_ms(path, t: int, ms_to_idx: h5py.Dataset, index_t0_us: int, t_col: h5py.Dataset,
                 n: int, t_offset: int = 0) -> int:
    """First event index with time >= t, using a DSEC-style millisecond index.

    ms_to_idx[m] = first i with t_col[i] + t_offset >= index_t0_us + 1000 m. Two reads: the two
    index entries around t and the timestamps of that one millisecond.
    """
    m = (int(t) - index_t0_us) // 1000
    if m < 0:
        return 0
    if m >= ms_to_idx.shape[0]:
        return n
    bounds = read_slice(path, ms_to_idx, slice(m, m + 2)).astype(np.int64)
    lo = min(max(int(bounds[0]), 0), n)
    hi = min(max(int(bounds[1]), 0), n) if bounds.shape[0] > 1 else n
    if hi <= lo:
        return lo
    ts = read_slice(path, t_col, slice(lo, hi)).astype(np.int64) + t_offset
    return lo + int(np.searchsorted(ts, t, side="left"))
