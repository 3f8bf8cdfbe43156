"""The OFS neuron Process: one speed-separation stage as a population of H x W neurons.

Per time step t of a window (state zero at every window start, i.e. every n_bins steps):

    a_in[t] = sum_{c,i,j} w[c,i,j] * s_in[t, c, y+i-K//2, x+j-K//2]         (conv, zero padded)
    v[t]    = clip24( trunc0(v[t-1] * (4096 - dv) / 4096) + (a_in[t] << 6) - (vth << 6) * o[t-1] )
    o[t]    = v[t] > (vth << 6)

the paper's eq. (1)-(2) with reset by subtraction of vth * o[t-1], undecayed, at step t
(Lava's LIF only resets to zero). The conv is fused into the neuron because the stage's only
synapses are that one K x K kernel: one port crossing per step instead of two, and no one-step
Conv delay. Ports carry bit-packed spike planes (lava_procs.packing).
"""
from __future__ import annotations

import typing as ty

import numpy as np
from lava.magma.core.process.ports.ports import InPort, OutPort
from lava.magma.core.process.process import AbstractProcess, LogConfig
from lava.magma.core.process.variable import Var

from lava_procs.packing import packed_width


class OFSNeuron(AbstractProcess):
    """One OFS stage (see module docstring).

    shape: (H, W) neurons. weight: (1, C, K, K) int in [-127, 127] (torch cross-correlation
    layout). vth: threshold mantissa; dv, du: 12-bit decays (du must be 4095: the stage's
    current is memoryless, u = a_in << 6); weight_scale: s, so the float stage is W = w / s,
    vth = vth_mant / s, lambda = 1 - dv / 4096 (used by the floating_pt model).
    n_bins: steps per window; the state is zeroed before steps 1, n_bins + 1, ...

    Ports: s_in (C, H, ceil(W/8)) uint8 packed input spikes; s_out (H, ceil(W/8)) packed output.
    """

    def __init__(self, *, shape: tuple[int, int], weight: np.ndarray, vth: int, dv: int,
                 du: int = 4095, weight_scale: float = 1.0, n_bins: int = 5,
                 name: ty.Optional[str] = None, log_config: ty.Optional[LogConfig] = None) -> None:
        weight = np.asarray(weight)
        if weight.ndim != 4 or weight.shape[0] != 1 or weight.shape[2] != weight.shape[3]:
            raise ValueError(f"weight must be (1, C, K, K), got {weight.shape}")
        if int(du) != 4095:
            raise ValueError(f"du = {du}: the OFS current is memoryless (du = 4095), as in toffe_deploy.fixed_point")
        h, w = (int(s) for s in shape)
        super().__init__(shape=(h, w), n_bins=int(n_bins), name=name, log_config=log_config)
        c = int(weight.shape[1])
        self.s_in = InPort(shape=(c, h, packed_width(w)))
        self.s_out = OutPort(shape=(h, packed_width(w)))
        self.weight = Var(shape=weight.shape, init=weight.astype(np.int32))
        self.vth = Var(shape=(1,), init=int(vth))
        self.dv = Var(shape=(1,), init=int(dv))
        self.du = Var(shape=(1,), init=int(du))
        self.weight_scale = Var(shape=(1,), init=float(weight_scale))
        self.v = Var(shape=(h, w), init=0)
