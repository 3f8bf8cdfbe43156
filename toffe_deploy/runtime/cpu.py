"""The ``cpu`` target's OFS cascade: fixed point, event driven (numba-compiled loops over the
window's ones, toffe_deploy/compiled.py), no torch and no Lava.

Same results as ``run_cascade(x, lambda k, inp: run_ofs_fixed(inp, params[k-1]), N, mask_kernel)``
(eq. 3-4), bit exact, but each window is kept as the coordinates of its ones (``SpikeVolume``):

    inp_N      = the window's ones
    out_k      = OFS_k(inp_k)                          on the window's active set (ofs_sparse)
    closed_k   = Close(any_t out_k)                    on the frame compacted around the spikes
                                                       (morph.CompactClosing)
    frame_k    = inp_k & closed_k,   inp_k-1 = inp_k & ~closed_k   (masks over the window's ones)

``cascade_stream`` offers the interface of the Lava adapter (``LavaCascade``): dense (B, 2, H, W)
windows in, dense ``CascadeResult`` out, so the two backends are interchangeable and comparable.
``cascade_sparse`` is the fast path the pipeline uses.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Iterable, Iterator, Sequence

import numpy as np

from ..cascade import CascadeResult
from ..compiled import new_scratch, split_closed, warm_up
from ..fixed_point import LoihiOFSParams
from .morph import CompactClosing
from .ofs_sparse import SparseOFSWindow
from .spikes import SpikeVolume


@dataclass
class SparseCascadeResult:
    """Per stage k at index k - 1, as masks over the window's ones ``volume.idx``:
    inputs[k-1] = inp_k, frames[k-1] = inp_k & closed_k; spikes[k-1] (B, M) on ``window.active``;
    closings[k-1] the stage's closed region."""

    volume: SpikeVolume
    window: SparseOFSWindow
    inputs: list[np.ndarray]
    spikes: list[np.ndarray]
    closings: list[CompactClosing]
    frames: list[np.ndarray]

    def frame_volume(self, k: int) -> SpikeVolume:
        """The speed-separated frame of stage k (1-based) as a SpikeVolume (B, 2, H, W)."""
        return self.volume.subset(self.frames[k - 1])

    def to_dense(self) -> CascadeResult:
        """The dense ``CascadeResult`` that ``run_cascade`` would return for this window."""
        b, c, h, w = self.volume.shape
        n = len(self.inputs)
        res = CascadeResult([None] * n, [None] * n, [None] * n, [None] * n)
        for i in range(n):
            res.inputs[i] = self.volume.subset(self.inputs[i]).to_dense()
            res.frames[i] = self.volume.subset(self.frames[i]).to_dense()
            sp = np.zeros((b, h * w), dtype=bool)
            sp[:, self.window.active] = self.spikes[i]
            res.spikes[i] = sp.reshape(b, h, w)
            res.closed[i] = self.closings[i].dense()
        return res


class CpuCascade:
    """The OFS cascade (eq. 3-4) of fixed-point stages ``params`` (index k - 1) on the host CPU.

    A context manager like ``LavaCascade``: entering compiles (or loads) the compiled kernels;
    there is nothing to stop.
    """

    def __init__(self, params: Sequence[LoihiOFSParams], n_bins: int, mask_kernel: int,
                 sensor_size: tuple[int, int]):
        if not params:
            raise ValueError("the cascade needs at least one OFS stage")
        kernels = {p.kernel_size for p in params}
        if len(kernels) != 1:
            raise ValueError(f"all OFS stages must share one kernel size, got {sorted(kernels)}")
        self.params = list(params)
        self.n_bins = int(n_bins)
        self.mask_kernel = int(mask_kernel)
        self.sensor_size = (int(sensor_size[0]), int(sensor_size[1]))
        self.kernel_size = kernels.pop()
        self._scratch = new_scratch(self.sensor_size[0] * self.sensor_size[1])

    def __enter__(self) -> "CpuCascade":
        warm_up()                      # compile or load the kernels now, not in the first window
        return self

    def __exit__(self, *exc) -> None:
        return None

    @property
    def n_stages(self) -> int:
        return len(self.params)

    def _check(self, shape: tuple[int, ...]) -> None:
        w, h = self.sensor_size
        if tuple(shape) != (self.n_bins, 2, h, w):
            raise ValueError(f"window must be ({self.n_bins}, 2, {h}, {w}), got {tuple(shape)}")

    def cascade_sparse(self, volume: SpikeVolume) -> SparseCascadeResult:
        """Run all stages, k = N..1, on one window given as its ones."""
        self._check(volume.shape)
        _b, _c, h, w = volume.shape
        win = SparseOFSWindow(volume, self.kernel_size, self._scratch)
        n = self.n_stages
        res = SparseCascadeResult(volume, win, [None] * n, [None] * n, [None] * n, [None] * n)
        alive = np.ones(len(volume), dtype=bool)
        for k in range(n, 0, -1):
            spikes, fired = win.run_stage(alive, self.params[k - 1])
            closing = CompactClosing(win.active[fired], h, w, self.mask_kernel)
            res.inputs[k - 1] = alive
            res.spikes[k - 1] = spikes
            res.closings[k - 1] = closing
            if closing.empty:
                res.frames[k - 1] = np.zeros_like(alive)
            else:                                 # inp_k & closed_k, and inp_k-1 = inp_k & ~closed_k
                # the closing is read per input pixel, not per one
                res.frames[k - 1], alive = split_closed(alive, win.pix_inverse, closing.at(win.input_pixels))
        return res

    def cascade_stream(self, windows: Iterable[np.ndarray]) -> Iterator[CascadeResult]:
        """Dense (B, 2, H, W) windows in, dense CascadeResult out (the LavaCascade interface)."""
        for x in windows:
            x = np.asarray(x)
            self._check(x.shape)
            yield self.cascade_sparse(SpikeVolume.from_dense(x > 0)).to_dense()
