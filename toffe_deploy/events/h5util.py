"""Small HDF5 helpers shared by the HDF5 readers (ours, DSEC, MVSEC)."""
from __future__ import annotations

import h5py
import numpy as np

from ..errors import InputError

#: Filters real data sets use that plain h5py lacks (DSEC ships Blosc-compressed files).
_FILTER_NAMES = {32001: "Blosc", 32004: "LZ4", 32008: "bitshuffle", 32015: "Zstandard",
                 36559: "ECF (Prophesee)"}
#: How to get a filter that hdf5plugin does not ship.
_FILTER_HINTS = {36559: "install Prophesee's hdf5_ecf plugin and point HDF5_PLUGIN_PATH at it, or export "
                        "the recording as RAW"}


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
            hint = _FILTER_HINTS.get(fid, "pip install hdf5plugin")
            raise InputError(path, f"{ds.name} is compressed with the HDF5 {name} filter, which is not "
                                   f"installed here ({hint})")


def dataset(path, h5: h5py.File, name: str) -> h5py.Dataset:
    """``h5[name]`` as a readable dataset, or InputError('missing field ...')."""
    obj = h5.get(name)
    if obj is None:
        raise InputError(path, f"missing field /{name.lstrip('/')}")
    if not isinstance(obj, h5py.Dataset):
        raise InputError(path, f"/{name.lstrip('/')} is not a dataset")
    require_filters(path, obj)
    return obj


def ms_index_dataset(path, group: h5py.Group, name: str = "ms_to_idx") -> h5py.Dataset | None:
    """The optional millisecond seek index of a group: None when absent, else a 1-D integer dataset."""
    if name not in group:
        return None
    ds = dataset(path, group, name)
    if ds.ndim != 1 or ds.dtype.kind not in "iu":
        raise InputError(path, f"{ds.name} must be a 1-D integer seek index, got {ds.dtype} {ds.shape}")
    return ds


def read_slice(path, ds: h5py.Dataset, sl) -> np.ndarray:
    """``ds[sl]``, with a corrupt/truncated file turned into InputError."""
    try:
        return ds[sl]
    except (OSError, ValueError, RuntimeError) as exc:
        raise InputError(path, f"cannot read {ds.name} (truncated or corrupt file?): {exc}") from None


def index_via_ms(path, t: int, ms_to_idx: h5py.Dataset, index_t0_us: int, t_col: h5py.Dataset,
                 n: int, t_offset: int = 0) -> int:
    """First event index with time >= t, using a DSEC-style millisecond index.

    ms_to_idx[m] = first i with t_col[i] + t_offset >= index_t0_us + 1000 m. Three small reads:
    the two index entries around t, the timestamps of that one millisecond, and the two
    timestamps around the answer, which prove it right. The index is never trusted: an entry out
    of range, decreasing, or an answer the timestamps contradict is an InputError (a corrupt or
    foreign index would otherwise silently drop or repeat events).
    """
    m = (int(t) - index_t0_us) // 1000
    if m < 0:
        i = 0
    elif m >= ms_to_idx.shape[0]:
        i = n
    else:
        bounds = read_slice(path, ms_to_idx, slice(m, m + 2)).astype(np.int64)
        lo = int(bounds[0])
        hi = int(bounds[1]) if bounds.shape[0] > 1 else n
        if not 0 <= lo <= hi <= n:
            raise InputError(path, f"{ms_to_idx.name}[{m}:{m + 2}] = {bounds.tolist()} is not a non-decreasing "
                                   f"index into the {n} events: {_CORRUPT}")
        ts = read_slice(path, t_col, slice(lo, hi)).astype(np.int64) + t_offset
        i = lo + int(np.searchsorted(ts, t, side="left"))
    _check_first_at(path, ms_to_idx, t, i, t_col, n, t_offset)
    return i


_CORRUPT = "corrupt seek index (delete it to read the file by binary search, or rewrite the file)"


def _check_first_at(path, ms_to_idx: h5py.Dataset, t: int, i: int, t_col: h5py.Dataset, n: int,
                    t_offset: int) -> None:
    """InputError unless i is the first event with time >= t (t_col[i-1] < t <= t_col[i])."""
    a, b = max(i - 1, 0), min(i + 1, n)
    if b <= a:
        return
    ts = read_slice(path, t_col, slice(a, b)).astype(np.int64) + t_offset
    before_ok = i == 0 or ts[0] < t
    after_ok = i == n or ts[-1] >= t
    if not (before_ok and after_ok):
        raise InputError(path, f"{ms_to_idx.name} disagrees with the timestamps (it puts the first event at "
                               f"t >= {t} us at index {i}): {_CORRUPT}")
