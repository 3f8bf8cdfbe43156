"""Event-driven OFS stage: ``toffe_deploy.fixed_point.run_ofs_fixed`` computed only where it can
be nonzero, bit exact.

Why it is exact: the state v starts at zero every window and a pixel's synaptic input

    a_in[t, y, x] = sum_{c,i,j} w[c,i,j] * s_in[t, c, y+i-r, x+j-r]        (r = K // 2)

is zero unless an input spike lies within r of (y, x). A pixel that never receives input keeps
v = 0, and 0 > vth_mant << 6 is false (vth_mant >= 1), so it never spikes. The stage therefore
only needs the *active set*: the window's event pixels dilated by the kernel. On it, a_in is a
scatter-add of one weight per (spike, tap) (``np.bincount``, exact: small integers in float64),
and the neuron runs ``lif_step``'s integer arithmetic on (M,) vectors instead of (H, W) images
(``lif_window``: the same integers, in float64, tested bit exact).

One ``SparseOFSWindow`` is built per window and shared by every stage of the cascade: a stage's
input is a subset of the window's ones (masked by the faster stages), so its active set is a
subset of the window's.
"""
from __future__ import annotations

import numpy as np

from ..fixed_point import DECAY_UNITY, STATE_MAX, STATE_SHIFT, LoihiOFSParams
from .spikes import SpikeVolume


def dedupe(values: np.ndarray, lookup: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(unique values, inverse) of non-negative ints < len(lookup), in O(n) without sorting.

    ``lookup`` is scratch memory (contents irrelevant, overwritten at ``values``). Fancy
    assignment keeps exactly one writer per distinct value; that writer defines the unique
    entry. The order of the unique values is unspecified.
    """
    n = values.shape[0]
    ar = np.arange(n, dtype=lookup.dtype)
    lookup[values] = ar
    uniq = values[lookup[values] == ar]
    lookup[uniq] = np.arange(uniq.shape[0], dtype=lookup.dtype)
    return uniq, lookup[values].astype(np.int64, copy=False)


def padded_lookup(sensor_size: tuple[int, int], kernel_size: int) -> np.ndarray:
    """Scratch memory for SparseOFSWindow on a sensor (width, height), padded by kernel // 2."""
    r = int(kernel_size) // 2
    return np.empty((int(sensor_size[1]) + 2 * r) * (int(sensor_size[0]) + 2 * r), dtype=np.int64)


class SparseOFSWindow:
    """The active set of one window and the (spike, tap) -> active-slot scatter map.

    Targets are indexed on the sensor padded by r = K // 2, so every (input pixel, tap) has a
    target and no per-tap bounds test is needed; slots [0, M) are the active pixels on the
    sensor, slots [M, M_pad) the few padding pixels next to events at the border (computed, never
    reported: the dense reference has no neuron there, and a neuron never feeds another).
    active: (M,) linear pixel ids y * W + x of slots 0..M-1 (unspecified order).
    tap_target[q, i*K + j]: slot of the pixel that input pixel q feeds through weight tap (i, j).
    """

    def __init__(self, volume: SpikeVolume, kernel_size: int, lookup: np.ndarray | None = None):
        n_bins, _c, height, width = volume.shape
        self.volume = volume
        self.kernel_size = k = int(kernel_size)
        r = k // 2
        wp = width + 2 * r
        if lookup is None:
            lookup = padded_lookup((width, height), k)
        self.b = volume.b
        self.c = volume.c
        in_pix, self.pix_inverse = volume.pixel_index(lookup)
        self.input_pixels = in_pix          # unique pixels of the window's ones; pix = in_pix[pix_inverse]
        y, x = np.divmod(in_pix, width)
        ii, jj = np.divmod(np.arange(k * k), k)
        offsets = (r - ii) * wp + (r - jj)
        target = ((y + r) * wp + (x + r))[:, None] + offsets[None, :]
        slots, inv = dedupe(target.ravel(), lookup)
        ay, ax = np.divmod(slots, wp)
        ay -= r
        ax -= r
        self.n_slots = int(slots.shape[0])
        if in_pix.size == 0 or (int(y.min()) >= r and int(y.max()) < height - r
                                and int(x.min()) >= r and int(x.max()) < width - r):
            # no input pixel within r of the sensor's edge: every slot is on the sensor, in order
            self.active = ay * width + ax
            self.tap_target = inv.reshape(target.shape)
        else:
            inside = (ay >= 0) & (ay < height) & (ax >= 0) & (ax < width)
            order = np.concatenate([np.flatnonzero(inside), np.flatnonzero(~inside)])
            rank = np.empty_like(order)
            rank[order] = np.arange(order.shape[0])
            first = order[:int(np.count_nonzero(inside))]
            self.active = ay[first] * width + ax[first]
            self.tap_target = rank[inv].reshape(target.shape)
        self.n_bins = n_bins
        self._keys_all: np.ndarray | None = None

    @property
    def n_active(self) -> int:
        return int(self.active.shape[0])

    def _keys(self) -> np.ndarray:
        """(n, K*K) scatter keys b * M_pad + slot of every (input one, tap); built once per window."""
        if self._keys_all is None:
            self._keys_all = (self.b * self.n_slots)[:, None] + self.tap_target[self.pix_inverse]
        return self._keys_all

    def synaptic_input(self, alive: np.ndarray, weight: np.ndarray, scale: float = 1.0,
                       w_taps: np.ndarray | None = None) -> np.ndarray:
        """a_in (B, M_pad) of the input ones selected by ``alive`` (bool over volume.idx), times
        ``scale`` (a power of two), as float64 holding exact integers (|a_in| <= 127 * C * K * K
        * scale, far below 2**53). ``w_taps``: weight[0] as (C, K*K) float64 times scale, when
        the caller has it already (StageConstants)."""
        if w_taps is None:
            w_taps = np.multiply(weight[0].reshape(weight.shape[1], -1), scale, dtype=np.float64)   # (C, K*K)
        keys = self._keys()
        if alive.all():
            c = self.c
        else:
            sel = np.flatnonzero(alive)
            keys, c = keys[sel], self.c[sel]
        acc = np.bincount(keys.ravel(), weights=w_taps[c].ravel(), minlength=self.n_bins * self.n_slots)
        return acc.reshape(self.n_bins, self.n_slots)

    def run_stage(self, alive: np.ndarray, params: LoihiOFSParams,
                  consts: "StageConstants | None" = None) -> np.ndarray:
        """Output spikes (B, M) bool on the active set; the same as run_ofs_fixed there.

        The neuron runs on every active pixel: a pre-filter of the pixels that can reach the
        threshold costs more numpy calls than it saves on a few thousand pixels."""
        if params.kernel_size != self.kernel_size:
            raise ValueError(f"stage kernel {params.kernel_size} != window kernel {self.kernel_size}")
        if self.n_active == 0 or not alive.any():
            return np.zeros((self.n_bins, self.n_active), dtype=bool)
        if consts is None:
            consts = StageConstants(params, self.n_bins)
        # a_in << 6 directly (the weights scaled by 2**6: the same integers, one pass fewer)
        a64 = self.synaptic_input(alive, params.weight, float(1 << STATE_SHIFT), consts.w_taps)[:, :self.n_active]
        return _lif_scaled(a64, params, consts.clip)


class StageConstants:
    """Per-stage constants of the sparse OFS, computed once per cascade rather than per window:
    w_taps = weight[0] as (C, K*K) float64 times 2**6 (a_in << 6 by scatter-add), and whether
    the 24-bit clip can bind over B steps. The inputs are binary, so |a_in| <= sum |w| and
    |v| <= B * (sum|w| << 6 + vth) (see lif_window) bounds every step."""

    def __init__(self, params: LoihiOFSParams, n_bins: int):
        w = params.weight[0].reshape(params.weight.shape[1], -1)
        self.w_taps = np.multiply(w, float(1 << STATE_SHIFT), dtype=np.float64)
        bound = float(np.abs(self.w_taps).sum())
        self.clip = int(n_bins) * (bound + float(params.vth_mant << STATE_SHIFT)) > STATE_MAX


def lif_window(a_in: np.ndarray, p: LoihiOFSParams) -> np.ndarray:
    """Spikes (B, M) of ``fixed_point.lif_step`` iterated over a window from v = 0, o = 0.

    The same integers as lif_step, computed in float64 for speed (half the passes of the int64
    sign/abs/shift form): v stays an integer with |v| <= 2**23 - 1; v * (4096 - dv) / 4096 is
    one exact float product (f = (4096 - dv) / 4096 has a 13-bit mantissa, the product < 2**37)
    and np.trunc rounds toward zero exactly as trunc0; sums of integers below 2**53 are exact.
    The 24-bit clip is skipped when it cannot bind: |v[t]| <= |v[t-1]| + max|a_in << 6| + vth,
    so |v| <= B * (max|a_in << 6| + vth) bounds every step. Bit exactness against lif_step is
    tested (tests/test_run_sparse.py), saturation included.
    """
    vth = float(p.vth_mant << STATE_SHIFT)
    a64 = np.multiply(a_in, float(1 << STATE_SHIFT), dtype=np.float64)
    clip = a64.shape[0] * (float(np.abs(a64).max(initial=0.0)) + vth) > STATE_MAX
    return _lif_scaled(a64, p, clip)


def _lif_scaled(a64: np.ndarray, p: LoihiOFSParams, clip: bool) -> np.ndarray:
    """lif_window on a_in << 6 (float64, exact integers); ``clip``: whether the 24-bit clip may
    bind. The reset v -= vth * o[t-1] subtracts vth or exactly 0.0 (cheaper than a masked
    subtract on these short vectors; the same numbers)."""
    f = (DECAY_UNITY - p.dv) / DECAY_UNITY
    vth = float(p.vth_mant << STATE_SHIFT)
    n_steps = a64.shape[0]
    out = np.empty(a64.shape, dtype=bool)
    v = a64[0].copy()
    reset = np.empty_like(v)
    for t in range(n_steps):                # B (= 5) steps, each vectorized over the active set
        if t:
            if f != 1.0:
                v *= f
                np.trunc(v, out=v)
            v += a64[t]
            np.multiply(out[t - 1], vth, out=reset)
            v -= reset
        if clip:
            np.clip(v, -STATE_MAX, STATE_MAX, out=v)
        np.greater(v, vth, out=out[t])
    return out


def run_ofs_sparse(spikes_in: np.ndarray, params: LoihiOFSParams) -> np.ndarray:
    """Drop-in for ``run_ofs_fixed`` on a dense (B, C, H, W) input: (B, H, W) bool."""
    volume = SpikeVolume.from_dense(np.asarray(spikes_in) > 0)
    win = SparseOFSWindow(volume, params.kernel_size)
    spikes = win.run_stage(np.ones(len(volume), dtype=bool), params)
    b, _c, h, w = volume.shape
    out = np.zeros((b, h * w), dtype=bool)
    out[:, win.active] = spikes
    return out.reshape(b, h, w)
