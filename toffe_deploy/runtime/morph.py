"""The cascade's closing (eq. 3) on a few spiking pixels, exact, without a full-frame image.

``toffe_deploy.cascade.close_binary`` on a 640x480 frame costs ~0.1 ms per stage although the
spikes of a window cover a few small objects. Here the frame is *compacted*: only the rows and
the columns within R = kernel of a spiking pixel are kept, and the closing runs on that
(rows x cols) image with the same ``close_binary``.

Why it is exact: closing with a k x k square reaches at most 2 * (k // 2) <= R pixels. Inside
one run of kept rows (or columns) offsets are preserved. Between two runs, the first spiking row
of a run lies R rows into it (its own dilation made the run), so a pixel of one run is more than
R compacted rows from any spike of another run: neighbourhoods up to R see the same spikes at
the same offsets as in the full frame. Rows and columns left out are farther than R from every
spike, hence outside the closing (closing is contained in the k//2 dilation), and at the edges of
the compacted image the kept pixels within k//2 of the edge are themselves more than k//2 from
any spike (or the edge is the sensor's own edge), so OpenCV's neutral border changes nothing.
"""
from __future__ import annotations

import cv2
import numpy as np

from ..cascade import close_binary


def _kept(pos: np.ndarray, n: int, radius: int) -> np.ndarray:
    """(n,) bool: positions within ``radius`` of any of ``pos`` (a 1-D dilation)."""
    mark = np.zeros((1, n), dtype=np.uint8)
    mark[0, pos] = 1
    return cv2.dilate(mark, np.ones((1, 2 * radius + 1), dtype=np.uint8))[0].view(bool)


class CompactClosing:
    """Close(S) for a set S of linear pixel ids on a (height, width) sensor.

    ``at(pix)`` gives Close(S) at given pixels, ``pixels()`` all pixels of Close(S) (row-major).
    """

    def __init__(self, spike_pix: np.ndarray, height: int, width: int, kernel: int):
        self.height, self.width = int(height), int(width)
        spike_pix = np.asarray(spike_pix, dtype=np.int64)
        self.empty = spike_pix.size == 0
        if self.empty:
            return
        rows, cols = np.divmod(spike_pix, self.width)
        radius = max(int(kernel), 1)
        self.keep_r = _kept(rows, self.height, radius)
        self.keep_c = _kept(cols, self.width, radius)
        self.map_r = np.cumsum(self.keep_r) - 1
        self.map_c = np.cumsum(self.keep_c) - 1
        img = np.zeros((int(self.map_r[-1]) + 1, int(self.map_c[-1]) + 1), dtype=np.uint8)
        img[self.map_r[rows], self.map_c[cols]] = 1
        self.closed = close_binary(img, kernel)

    @classmethod
    def _from_parts(cls, height: int, width: int, keep_r, keep_c, map_r, map_c, closed, empty: bool) -> "CompactClosing":
        """A closing already computed on a compaction (``WindowCompaction.close``)."""
        self = cls.__new__(cls)
        self.height, self.width, self.empty = int(height), int(width), bool(empty)
        if not self.empty:
            self.keep_r, self.keep_c, self.map_r, self.map_c, self.closed = keep_r, keep_c, map_r, map_c, closed
        return self

    def at(self, pix: np.ndarray) -> np.ndarray:
        """Close(S) at the given linear pixel ids: (n,) bool."""
        out = np.zeros(np.shape(pix), dtype=bool)
        if self.empty or out.size == 0:
            return out
        rows, cols = np.divmod(np.asarray(pix, dtype=np.int64), self.width)
        ok = self.keep_r[rows] & self.keep_c[cols]
        out[ok] = self.closed[self.map_r[rows[ok]], self.map_c[cols[ok]]]
        return out

    def pixels(self) -> np.ndarray:
        """Linear pixel ids of Close(S), sorted."""
        if self.empty:
            return np.zeros(0, dtype=np.int64)
        ys, xs = np.nonzero(self.closed)
        return np.flatnonzero(self.keep_r)[ys] * self.width + np.flatnonzero(self.keep_c)[xs]

    def dense(self) -> np.ndarray:
        """Close(S) as a (height, width) bool image."""
        out = np.zeros(self.height * self.width, dtype=bool)
        out[self.pixels()] = True
        return out.reshape(self.height, self.width)


class WindowCompaction:
    """One compaction per window, shared by the closings of all its stages.

    A stage's spikes lie in the window's active set (ofs_sparse), so the rows and columns kept
    around the *active* pixels (within R = kernel) are a superset of those CompactClosing keeps
    around the spikes, and the argument of the module doc holds unchanged for any kept set that
    contains every row/column within R of a spike: inside a run offsets are preserved, a spike
    is R kept rows from the end of its run, and the compacted image's edges (other than the
    sensor's own) are more than R from every spike. So Close(spikes) is computed on one image
    laid out once per window, and a stage costs one scatter, one cv2 closing and one gather.

    ``slots``: the active pixels (linear ids y * W + x); ``pixels``: pixels whose closing is
    read back (every one must lie in the kept rows and columns, e.g. the window's input pixels).
    """

    def __init__(self, slots: np.ndarray, pixels: np.ndarray, height: int, width: int, kernel: int):
        self.height, self.width, self.kernel = int(height), int(width), int(kernel)
        self.se = np.ones((self.kernel, self.kernel), dtype=np.uint8)
        slots = np.asarray(slots, dtype=np.int64)
        self.empty = slots.size == 0
        if self.empty:
            return
        rows, cols = np.divmod(slots, self.width)
        radius = max(self.kernel, 1)
        self.keep_r = _kept(rows, self.height, radius)
        self.keep_c = _kept(cols, self.width, radius)
        self.map_r = np.cumsum(self.keep_r) - 1
        self.map_c = np.cumsum(self.keep_c) - 1
        self.shape = (int(self.map_r[-1]) + 1, int(self.map_c[-1]) + 1)
        self.slot_at = self.map_r[rows] * self.shape[1] + self.map_c[cols]
        py, px = np.divmod(np.asarray(pixels, dtype=np.int64), self.width)
        self.pixel_at = self.map_r[py] * self.shape[1] + self.map_c[px]

    def close(self, spiking: np.ndarray) -> tuple[CompactClosing, np.ndarray]:
        """(Close(S), Close(S) at ``pixels``) for S = the slots selected by the bool mask
        ``spiking`` (over ``slots``); the same closing as ``CompactClosing(slots[spiking], ...)``."""
        at = self.slot_at[spiking] if not self.empty else spiking[:0]
        if at.size == 0:
            return (CompactClosing._from_parts(self.height, self.width, None, None, None, None, None, True),
                    None)
        img = np.zeros(self.shape, dtype=np.uint8)
        img.reshape(-1)[at] = 1
        closed = cv2.morphologyEx(img, cv2.MORPH_CLOSE, self.se).view(bool)   # 0/1: close_binary's result
        return (CompactClosing._from_parts(self.height, self.width, self.keep_r, self.keep_c, self.map_r,
                                           self.map_c, closed, False),
                closed.reshape(-1)[self.pixel_at])
