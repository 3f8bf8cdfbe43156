"""Event-driven OFS stage: ``toffe_deploy.fixed_point.run_ofs_fixed`` computed only where it can
be nonzero, bit exact.

Why it is exact: the state v starts at zero every window and a pixel's synaptic input

    a_in[t, y, x] = sum_{c,i,j} w[c,i,j] * s_in[t, c, y+i-r, x+j-r]        (r = K // 2)

is zero unless an input spike lies within r of (y, x). A pixel that never receives input keeps
v = 0, and 0 > vth_mant << 6 is false (vth_mant >= 1), so it never spikes. The stage therefore
only needs the *active set*: the window's event pixels dilated by the kernel. On it, a_in is a
scatter-add of one weight per (alive one, tap), and the neuron runs ``lif_step``'s integer
arithmetic per active pixel (``compiled.ofs_stage``: int64, the same integers, tested bit exact).

One ``SparseOFSWindow`` is built per window and shared by every stage of the cascade: a stage's
input is a subset of the window's ones (masked by the faster stages), so its active set is a
subset of the window's.
"""
from __future__ import annotations

import numpy as np

from ..fixed_point import LoihiOFSParams
from .. import compiled
from .spikes import SpikeVolume


class SparseOFSWindow:
    """The active set of one window and the (input pixel, tap) -> active-slot map.

    active: (M,) linear pixel ids y * W + x of the active set (unspecified order).
    tap_target[q, i*K + j]: slot in ``active`` of the pixel that input pixel q (``input_pixels``)
    feeds through weight tap (i, j), -1 where that pixel lies off the sensor (zero padding).
    ``scratch``: an all -1 (H * W,) array (``compiled.new_scratch``) the caller keeps
    across windows; made here when not given.
    """

    def __init__(self, volume: SpikeVolume, kernel_size: int, scratch: np.ndarray | None = None):
        n_bins, _c, height, width = volume.shape
        self.volume = volume
        self.kernel_size = k = int(kernel_size)
        if scratch is None:
            scratch = compiled.new_scratch(height * width)
        if "_pixel_index" in volume.__dict__:           # the volume's own pixel order, as it was made
            self.b = volume.b
            self.c = volume.c
            in_pix, self.pix_inverse = volume.pixel_index(scratch)
            self.active, self.tap_target = compiled.active_set(in_pix, width, height, k, scratch)
        else:                                           # all of it in one compiled call (the cpu hot path)
            self.b, self.c, in_pix, self.pix_inverse, self.active, self.tap_target = compiled.ofs_window(
                volume.bc, volume.pix, volume.shape[1], width, height, k, scratch)
            volume.__dict__.update(b=self.b, c=self.c, _pixel_index=(in_pix, self.pix_inverse))
        self.input_pixels = in_pix          # unique pixels of the window's ones; pix = in_pix[pix_inverse]
        self.n_bins = n_bins

    @property
    def n_active(self) -> int:
        return int(self.active.shape[0])

    def run_stage(self, alive: np.ndarray, params: LoihiOFSParams) -> tuple[np.ndarray, np.ndarray]:
        """(spikes (B, M) bool on the active set, fired (M,) = spikes.any(axis=0)) of the stage
        on the input ones selected by ``alive`` (bool over volume.idx); the same as
        run_ofs_fixed there."""
        if params.kernel_size != self.kernel_size:
            raise ValueError(f"stage kernel {params.kernel_size} != window kernel {self.kernel_size}")
        weight = np.ascontiguousarray(params.weight[0].reshape(params.weight.shape[1], -1), dtype=np.int64)
        return compiled.ofs_stage(alive, self.b, self.c, self.pix_inverse, self.tap_target, weight,
                                  self.n_bins, self.n_active, int(params.dv), int(params.vth_mant),
                                  params.reset == "zero")


def run_ofs_sparse(spikes_in: np.ndarray, params: LoihiOFSParams) -> np.ndarray:
    """Drop-in for ``run_ofs_fixed`` on a dense (B, C, H, W) input: (B, H, W) bool."""
    volume = SpikeVolume.from_dense(np.asarray(spikes_in) > 0)
    win = SparseOFSWindow(volume, params.kernel_size)
    spikes, _fired = win.run_stage(np.ones(len(volume), dtype=bool), params)
    b, _c, h, w = volume.shape
    out = np.zeros((b, h * w), dtype=bool)
    out[:, win.active] = spikes
    return out.reshape(b, h, w)
