"""Bit-packed spike planes: the wire format of every port in lava_procs.

A binary plane s (..., H, W) travels as ``np.packbits(s, axis=-1)``, shape (..., H, ceil(W / 8))
uint8, most significant bit first; the padding bits of the last byte are zero. Bitwise AND, OR
and NOT-AND on packed planes equal the same operations on the unpacked planes (padding stays
zero as long as a NOT is always combined with an AND against a plane whose padding is zero).
"""
from __future__ import annotations

import numpy as np


def packed_width(width: int) -> int:
    """Bytes per packed row of a plane ``width`` pixels wide."""
    return (int(width) + 7) // 8


def pack(planes: np.ndarray) -> np.ndarray:
    """Pack (..., H, W) nonzero-is-spike planes to (..., H, ceil(W / 8)) uint8."""
    return np.packbits(np.asarray(planes).astype(bool, copy=False), axis=-1)


def unpack(packed: np.ndarray, width: int) -> np.ndarray:
    """Inverse of ``pack``: (..., H, ceil(W / 8)) uint8 to (..., H, W) bool."""
    return np.unpackbits(np.asarray(packed, dtype=np.uint8), axis=-1, count=int(width)).view(bool)


def pack_indices(idx: np.ndarray, shape: tuple[int, ...]) -> np.ndarray:
    """Pack the ones of a binary array given by its unique flat indices (row-major over ``shape``).

    Costs O(events), not O(pixels): the bits of one byte are distinct powers of two, so their
    sum (one bincount) is their OR. Indices must be unique (as ``np.flatnonzero`` gives them).
    """
    *lead, h, w = (int(s) for s in shape)
    wb = packed_width(w)
    n_bytes = int(np.prod(lead, dtype=np.int64)) * h * wb
    idx = np.asarray(idx, dtype=np.int64)
    row, x = np.divmod(idx, w)
    bits = np.left_shift(1, 7 - (x & 7))
    out = np.bincount(row * wb + (x >> 3), weights=bits, minlength=n_bytes).astype(np.uint8)
    return out.reshape(*lead, h, wb)
