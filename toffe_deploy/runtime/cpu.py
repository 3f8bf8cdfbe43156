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
``cascade_sparse`` is the fast path: one compiled call per window (compiled.cascade_window)
runs every stage of these steps; ``pooled_frames`` (the pipeline's, on a pooled grid) runs the
pooling and the frames' way back to the sensor in the same call.
"""
from __future__ import annotations

import collections.abc
from dataclasses import dataclass
from typing import Iterable, Iterator, Sequence

import numpy as np

from ..cascade import CascadeResult
from ..compiled import cascade_window, new_scratch, pooled_cascade, warm_up
from ..fixed_point import LoihiOFSParams
from .morph import CompactClosing
from .ofs_sparse import SparseOFSWindow
from .spikes import SpikeVolume


class StageClosings(collections.abc.Sequence):
    """closings[k-1]: stage k's closed region (CompactClosing of its fired active pixels), made
    when first asked for: the cascade itself reads the closing only at the window's pixels
    (compiled.cascade_window), so a window that nobody inspects never builds these."""

    def __init__(self, active: np.ndarray, fired: np.ndarray, height: int, width: int, kernel: int):
        self._args = (active, fired, height, width, kernel)
        self._made: dict[int, CompactClosing] = {}

    def __len__(self) -> int:
        return int(self._args[1].shape[0])

    def __getitem__(self, i):
        if isinstance(i, slice):
            return [self[j] for j in range(*i.indices(len(self)))]
        i = range(len(self))[i]
        if i not in self._made:
            active, fired, h, w, kernel = self._args
            self._made[i] = CompactClosing(active[fired[i]], h, w, kernel)
        return self._made[i]


@dataclass
class SparseCascadeResult:
    """Per stage k at index k - 1, as masks over the window's ones ``volume.idx``:
    inputs[k-1] = inp_k, frames[k-1] = inp_k & closed_k; spikes[k-1] (B, M) on ``window.active``;
    closings[k-1] the stage's closed region."""

    volume: SpikeVolume
    window: SparseOFSWindow
    inputs: Sequence[np.ndarray]
    spikes: Sequence[np.ndarray]
    closings: Sequence[CompactClosing]
    frames: Sequence[np.ndarray]

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
        # the stages' constants as cascade_window takes them, made once: weights (N, C, K*K)
        self._weights = np.ascontiguousarray(np.stack([p.weight[0].reshape(p.weight.shape[1], -1) for p in self.params]),
                                             dtype=np.int64)
        self._dv = np.array([int(p.dv) for p in self.params], dtype=np.int64)
        self._vth = np.array([int(p.vth_mant) for p in self.params], dtype=np.int64)
        self._reset_zero = np.array([p.reset == "zero" for p in self.params], dtype=bool)

    #: the compiled.warm_up groups __enter__ loads (None: all); a Pipeline narrows it to its path
    warm_groups = None

    def __enter__(self) -> "CpuCascade":
        warm_up(self.warm_groups)      # compile or load the kernels now, not in the first window
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
        """Run all stages, k = N..1, on one window given as its ones (one compiled call,
        compiled.cascade_window): inputs, spikes and frames are its (N, ...) arrays, stage k
        at row k - 1."""
        self._check(volume.shape)
        _b, _c, h, w = volume.shape
        win = SparseOFSWindow(volume, self.kernel_size, self._scratch)
        spikes, fired, inputs, frames = cascade_window(
            win.b, win.c, win.pix_inverse, win.input_pixels, win.tap_target, win.active, self._weights, self._dv,
            self._vth, self._reset_zero, self.n_bins, h, w, self.mask_kernel)
        return SparseCascadeResult(volume, win, inputs, spikes, StageClosings(win.active, fired, h, w, self.mask_kernel),
                                   frames)

    def pooled_frames(self, volume: SpikeVolume, pool: int) -> np.ndarray:
        """The stage frames (N, n) bool over the sensor ones of ``volume``, for a cascade built
        for its OFS grid pooled p x p (p = ``pool`` > 1): ``up_frames(cascade_sparse(grid).frames,
        inverse)`` of ``volume.pool(pool)``, in one compiled call (compiled.pooled_cascade), for
        the pipeline, which needs nothing else of the cascade. Sets the volume's bc and pix."""
        b, c, h, w = volume.shape
        wp, hp = self.sensor_size
        self._check((b, c, hp, wp))
        bc, pix, frames = pooled_cascade(volume.idx, h * w, w, int(pool), hp, wp, c, self.kernel_size, self._scratch,
                                         self._weights, self._dv, self._vth, self._reset_zero, self.n_bins,
                                         self.mask_kernel)
        volume.__dict__.setdefault("bc", bc)
        volume.__dict__.setdefault("pix", pix)
        return frames

    def cascade_stream(self, windows: Iterable[np.ndarray]) -> Iterator[CascadeResult]:
        """Dense (B, 2, H, W) windows in, dense CascadeResult out (the LavaCascade interface)."""
        for x in windows:
            x = np.asarray(x)
            self._check(x.shape)
            yield self.cascade_sparse(SpikeVolume.from_dense(x > 0)).to_dense()
