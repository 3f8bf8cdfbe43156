"""A binary event volume stored as the coordinates of its ones (the cpu target's window form).

A window of a few thousand events fills well under 1% of a 640x480x5x2 volume, so the fast host
path never builds the dense array: it keeps the sorted, unique linear indices

    idx = ((b * C + c) * H + y) * W + x        with s[b, c, y, x] = 1 exactly where idx is stored,

and derives (b, c, y, x) from them. ``from_events`` gives the same ones as
``toffe_deploy.events.binning.bin_window(...) > 0`` (bin b = (t - t0) * B // dt, channel = polarity)
without touching the empty pixels.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from ..compiled import dedupe, pool_index     # at import: a call-time import costs ~1 us per window
from ..events.binning import event_ones
from ..events.frontend import apply_index


@dataclass(frozen=True)
class SpikeVolume:
    """s[b, c, y, x] = 1 at each stored linear index ``idx`` (int64, sorted, unique), 0 elsewhere.

    shape = (B, C, H, W). Order of ``idx`` is row-major, so pixels come out in the same order as
    ``np.nonzero`` on the dense array would give them.
    """

    idx: np.ndarray
    shape: tuple[int, int, int, int]

    @property
    def n_pixels(self) -> int:
        return int(self.shape[2] * self.shape[3])

    # Coordinates are derived once per volume (cached; a subset takes its parent's slices).
    # One divmod gives the plane b * C + c and the pixel of every one; b and c come from it.
    @cached_property
    def bc(self) -> np.ndarray:
        """Plane index b * C + c of each one (= the OFPD channel 2 b + polarity when C = 2)."""
        self.__dict__["bc"], self.__dict__["pix"] = np.divmod(self.idx, self.n_pixels)
        return self.__dict__["bc"]

    @cached_property
    def b(self) -> np.ndarray:
        if self.shape[1] == 2:                    # shifts: cheaper than integer division
            return np.right_shift(self.bc, 1)
        return self.bc // self.shape[1]

    @cached_property
    def c(self) -> np.ndarray:
        if self.shape[1] == 2:
            return np.bitwise_and(self.bc, 1)
        return self.bc % self.shape[1]

    @cached_property
    def pix(self) -> np.ndarray:
        """Linear pixel index y * W + x of each one."""
        _ = self.bc
        return self.__dict__["pix"]

    def pixel_index(self, scratch: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(unique pixels, inverse) of ``pix``: pix = unique[inverse]. Computed once per volume
        (the OFS window and the OFPD grouping share it); with an all -1 ``scratch`` of >= H * W
        entries (``compiled.new_scratch``) in O(n), in order of first appearance, else sorted."""
        got = self.__dict__.get("_pixel_index")
        if got is None:
            if scratch is None:
                u, inv = np.unique(self.pix, return_inverse=True)
                got = (u, inv.reshape(-1))
            else:
                got = dedupe(self.pix, scratch)
            self.__dict__["_pixel_index"] = got
        return got

    def __len__(self) -> int:
        return int(self.idx.shape[0])

    @classmethod
    def from_dense(cls, volume: np.ndarray) -> "SpikeVolume":
        """From a dense (B, C, H, W) array; nonzero = spike."""
        volume = np.asarray(volume)
        if volume.ndim != 4:
            raise ValueError(f"expected a (B, C, H, W) volume, got shape {volume.shape}")
        return cls(np.flatnonzero(volume).astype(np.int64, copy=False), tuple(int(s) for s in volume.shape))

    @classmethod
    def from_events(cls, events: np.ndarray, t0: int, dt_us: int, n_bins: int,
                    sensor_size: tuple[int, int]) -> "SpikeVolume":
        """The binary volume of ``bin_window(events, t0, dt_us, n_bins, sensor_size) > 0``.

        Events outside [t0, t0 + dt_us) are ignored. O(n): the indices' np.unique by a radix
        sort (compiled.sorted_unique), one compiled call (events.binning.event_ones).
        """
        width, height = int(sensor_size[0]), int(sensor_size[1])
        return cls(event_ones(events, t0, dt_us, n_bins, sensor_size), (int(n_bins), 2, height, width))

    def front_end(self, norm: str, min_cluster: int = 1) -> "SpikeVolume":
        """The ones the network sees through the input front end (events/frontend.py); self
        when it keeps them all. Idempotent, so a caller may apply it again."""
        if norm == "none" and min_cluster <= 1:
            return self
        return SpikeVolume(apply_index(self.idx, self.shape, norm, min_cluster), self.shape)

    def pool(self, p: int) -> tuple["SpikeVolume", np.ndarray | None]:
        """(the volume OR-pooled over p x p pixel blocks, inverse): shape (B, C, ceil(H / p),
        ceil(W / p)) and, for each one of self, the position of its block's one in the pooled
        idx, so a mask over the pooled ones maps back as ``mask[inverse]`` (cascade.py's Up_p on
        the ones). (self, None) for p = 1."""
        if p == 1:
            return self, None
        b, c, h, w = self.shape
        hp, wp = -(-h // p), -(-w // p)
        # np.unique of (bc * hp + y // p) * wp + x // p with its inverse, in one O(n) pass that
        # also gives both volumes' planes and pixels (kept: the cascade and the grouping use them)
        u, inv, u_bc, u_pix, bc, pix = pool_index(self.idx, h * w, w, int(p), hp, wp)
        self.__dict__.setdefault("bc", bc)
        self.__dict__.setdefault("pix", pix)
        grid = SpikeVolume(u, (b, c, hp, wp))
        grid.__dict__["bc"], grid.__dict__["pix"] = u_bc, u_pix
        return grid, inv

    def to_dense(self, dtype=bool) -> np.ndarray:
        out = np.zeros(int(np.prod(self.shape)), dtype=dtype)
        out[self.idx] = 1
        return out.reshape(self.shape)

    def subset(self, keep: np.ndarray) -> "SpikeVolume":
        """The ones selected by a boolean mask over ``idx`` (e.g. a cascade stage's input)."""
        sub = SpikeVolume(self.idx[keep], self.shape)
        for name in ("bc", "b", "c", "pix"):
            if name in self.__dict__:
                sub.__dict__[name] = self.__dict__[name][keep]
        return sub
