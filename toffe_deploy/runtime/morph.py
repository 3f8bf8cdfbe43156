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
