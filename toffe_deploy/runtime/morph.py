"""The cascade's closing (eq. 3) on a few spiking pixels, exact, without a full-frame image.

``toffe_deploy.cascade.close_binary`` on a 640x480 frame costs ~0.1 ms per stage although the
spikes of a window cover a few small objects. Here the frame is *compacted*: only the rows and
the columns within R = kernel of a spiking pixel are kept, and the closing runs on that
(rows x cols) image: ``compiled.close_square``, equal to the OpenCV call of ``close_binary``
(tested), compiled into the compaction so a stage's closing is one call.

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

import numpy as np

from .. import compiled


class CompactClosing:
    """Close(S) for a set S of linear pixel ids on a (height, width) sensor.

    ``at(pix)`` gives Close(S) at given pixels, ``pixels()`` all pixels of Close(S) (row-major).
    The compaction (kept rows and columns, the image of S on them) is one compiled pass over S
    and the closing of that image (``compiled.compact_closed``).
    """

    def __init__(self, spike_pix: np.ndarray, height: int, width: int, kernel: int):
        self.height, self.width = int(height), int(width)
        spike_pix = np.asarray(spike_pix, dtype=np.int64)
        self.empty = spike_pix.size == 0
        if self.empty:
            return
        self.keep_r, self.keep_c, self.map_r, self.map_c, closed = compiled.compact_closed(
            spike_pix, self.height, self.width, max(int(kernel), 1), int(kernel))
        self.closed = closed.view(bool)                  # 0/1: close_binary's result

    def at(self, pix: np.ndarray) -> np.ndarray:
        """Close(S) at the given linear pixel ids: (n,) bool."""
        pix = np.asarray(pix, dtype=np.int64)
        if self.empty or pix.size == 0:
            return np.zeros(pix.shape, dtype=bool)
        return compiled.compact_lookup(pix.reshape(-1), self.width, self.keep_r, self.keep_c, self.map_r,
                                       self.map_c, self.closed).reshape(pix.shape)

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
