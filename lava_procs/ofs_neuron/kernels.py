"""Event-driven evaluation of one OFS stage, bit exact to ``toffe_deploy.fixed_point``.

The reference (``run_ofs_fixed``) updates every pixel every step. Within a window the state
starts at zero, and a pixel whose state is zero, whose last output is zero and whose synaptic
input is zero stays exactly so under ``lif_step`` (zero decays to zero, and v = 0 is not above a
positive threshold). So only the *active* pixels, those that received any synaptic input since
the window started, need updating:

    A_t     = A_{t-1} | {p : some input spike s[t, c, q] has p in its K x K fan-out}
    a_in[p] = sum_{c,i,j} w[c,i,j] * s[t, c, p_y + i - K//2, p_x + j - K//2]     (zero padded)
    (v, o)[A_t] = lif_step((v, o)[A_t], a_in[A_t])                               (the reference)

The synaptic input is scattered from the spikes (one bincount over spike x kernel-tap pairs,
exact integers in float64), or, when the input is dense, computed by the reference
``synaptic_input`` itself. The neuron arithmetic is the reference ``lif_step``.
"""
from __future__ import annotations

import cv2
import numpy as np

from toffe_deploy.fixed_point import LoihiOFSParams, lif_step, synaptic_input

DENSE_FRACTION = 1 / 16
"""Above this fraction of spiking input pixels the dense reference conv is cheaper."""


def _fanout(weight: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Nonzero taps of a (1, C, K, K) cross-correlation kernel as scatter offsets.

    A spike at (c, qy, qx) adds w[c, i, j] to pixel (qy - i + K//2, qx - j + K//2).
    Returns (channel, dy, dx, w) arrays, one entry per nonzero tap.
    """
    k = weight.shape[-1]
    c, i, j = np.nonzero(weight[0])
    return c, (k // 2 - i), (k // 2 - j), weight[0, c, i, j].astype(np.float64)


def event_synaptic_input(spikes: np.ndarray, weight: np.ndarray, fanout=None) -> tuple[np.ndarray, np.ndarray]:
    """a_in of one step by scattering each input spike through the kernel.

    spikes: (C, H, W) bool. Returns (a_in (H * W,) float64 holding exact integers, targets):
    targets are the flat pixels reached by some spike through a nonzero tap (with repeats).
    ``a_in`` equals ``synaptic_input(spikes, weight).ravel()`` (a test checks it).
    """
    c_in, h, w = spikes.shape
    tap_c, dy, dx, tap_w = fanout if fanout is not None else _fanout(weight)
    targets, weights = [], []
    for c in range(c_in):                      # 2 polarity channels; vectorized within each
        sel = tap_c == c
        if not sel.any():
            continue
        q = np.flatnonzero(spikes[c])
        if q.size == 0:
            continue
        qy, qx = np.divmod(q, w)
        ty = qy[:, None] + dy[sel][None, :]
        tx = qx[:, None] + dx[sel][None, :]
        ok = (ty >= 0) & (ty < h) & (tx >= 0) & (tx < w)
        targets.append((ty * w + tx)[ok])
        weights.append(np.broadcast_to(tap_w[sel][None, :], ok.shape)[ok])
    if not targets:
        return np.zeros(h * w), np.zeros(0, np.int64)
    t = np.concatenate(targets)
    return np.bincount(t, weights=np.concatenate(weights), minlength=h * w), t


class SparseOFSStage:
    """One OFS stage stepped event by event; state (v, o) reset by ``reset()`` at window start.

    Same outputs as ``toffe_deploy.fixed_point.run_ofs_fixed`` step by step (see module doc).
    """

    state_dtype = np.int64

    def __init__(self, params: LoihiOFSParams, height: int, width: int, v: np.ndarray | None = None):
        self.params = params
        self.shape = (int(height), int(width))
        n = self.shape[0] * self.shape[1]
        self._fanout = self._make_fanout()
        # v may be a caller's buffer (the Lava model's Var, int32: the state fits in 24 bits);
        # it is only ever written in place.
        self.v = v if v is not None else np.zeros(n, self.state_dtype)
        if self.v.shape != (n,):
            raise ValueError(f"state buffer has shape {self.v.shape}, expected ({n},)")
        self.o = np.zeros(n, bool)
        self._active = np.zeros(n, bool)
        self._all_active = False

    def _make_fanout(self):
        return _fanout(np.asarray(self.params.weight))

    def _dense_input(self, spikes: np.ndarray) -> np.ndarray:
        return synaptic_input(spikes, self.params.weight).ravel()

    def _neuron(self, v: np.ndarray, o: np.ndarray, a_in: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
        a = a_in.astype(np.int64) if a_in is not None else np.zeros(v.shape, np.int64)
        return lif_step(v, o, a, self.params)

    def reset(self) -> None:
        """Zero the state: the paper starts every window from rest."""
        if self._all_active:
            self.v[:] = 0
            self.o[:] = False
        else:
            idx = np.flatnonzero(self._active)
            self.v[idx] = 0
            self.o[idx] = False
        self._active[:] = False
        self._all_active = False

    def step(self, spikes: np.ndarray) -> np.ndarray:
        """Advance one time step with input spikes (C, H, W) bool; returns o (H, W) bool (a view)."""
        n_spk = int(np.count_nonzero(spikes))
        if n_spk > DENSE_FRACTION * spikes[0].size:
            a_in = self._dense_input(spikes)
            self._all_active = True
        elif n_spk:
            a_in, targets = event_synaptic_input(spikes, self.params.weight, self._fanout)
            self._active[targets] = True
        else:
            a_in = None
        if self._all_active:
            self.v[:], self.o[:] = self._neuron(self.v, self.o, a_in)
        else:
            idx = np.flatnonzero(self._active)
            if idx.size:
                a = a_in[idx] if a_in is not None else None
                self.v[idx], self.o[idx] = self._neuron(self.v[idx], self.o[idx], a)
        return self.o.reshape(self.shape)


class SparseFloatOFSStage(SparseOFSStage):
    """The float eq. (1)-(2) with the float parameters the integer stage stands for:

        v[t] = lambda * v[t-1] + conv(W, s[t]) - vth * o[t-1],   o[t] = v[t] > vth
        W = w / s,  vth = vth_mant / s,  lambda = 1 - dv / 4096     (float64)

    Event driven like the fixed-point stage (the same rest argument holds for floats). Not bit
    exact to it: no truncation of the decay, no 24-bit saturation.
    """

    state_dtype = np.float64

    def __init__(self, params: LoihiOFSParams, height: int, width: int, v: np.ndarray | None = None):
        w_f, self._vth, self._lam = params.float_equivalent()
        self._w_f = w_f
        super().__init__(params, height, width, v)

    def _make_fanout(self):
        c, dy, dx, w_int = _fanout(np.asarray(self.params.weight))
        return c, dy, dx, w_int / self.params.weight_scale

    def _dense_input(self, spikes: np.ndarray) -> np.ndarray:
        acc = np.zeros(self.shape, np.float64)
        for c in range(spikes.shape[0]):
            if spikes[c].any():
                acc += cv2.filter2D(spikes[c].astype(np.float64), cv2.CV_64F, self._w_f[0, c],
                                    borderType=cv2.BORDER_CONSTANT)
        return acc.ravel()

    def _neuron(self, v, o, a_in):
        v = self._lam * v - self._vth * o
        if a_in is not None:
            v = v + a_in
        return v, v > self._vth
