"""Process models of the OFS neuron: ``fixed_pt`` (bit exact, event driven) and ``floating_pt``.

Both reset the state at the first step of every window ((time_step - 1) mod n_bins == 0).
"""
from __future__ import annotations

import numpy as np
from lava.magma.core.decorator import implements, requires, tag
from lava.magma.core.model.py.model import PyLoihiProcessModel
from lava.magma.core.model.py.ports import PyInPort, PyOutPort
from lava.magma.core.model.py.type import LavaPyType
from lava.magma.core.resources import CPU
from lava.magma.core.sync.protocols.loihi_protocol import LoihiProtocol

from lava_procs.ofs_neuron.kernels import SparseFloatOFSStage, SparseOFSStage
from lava_procs.ofs_neuron.process import OFSNeuron
from lava_procs.packing import pack, unpack
from toffe_deploy.fixed_point import LoihiOFSParams


@implements(proc=OFSNeuron, protocol=LoihiProtocol)
@requires(CPU)
@tag("fixed_pt", "bit_accurate_loihi")
class PyOFSNeuronModelFixed(PyLoihiProcessModel):
    """Loihi 2 fixed point, bit exact to toffe_deploy.fixed_point.run_ofs_fixed.

    Event driven (lava_procs.ofs_neuron.kernels.SparseOFSStage): only neurons that received
    synaptic input in the current window are updated; the others are provably at rest.
    """

    s_in: PyInPort = LavaPyType(PyInPort.VEC_DENSE, np.uint8, precision=8)
    s_out: PyOutPort = LavaPyType(PyOutPort.VEC_DENSE, np.uint8, precision=8)
    weight: np.ndarray = LavaPyType(np.ndarray, np.int32, precision=8)
    vth: np.ndarray = LavaPyType(np.ndarray, np.int32, precision=17)
    dv: np.ndarray = LavaPyType(np.ndarray, np.int32, precision=12)
    du: np.ndarray = LavaPyType(np.ndarray, np.int32, precision=12)
    weight_scale: np.ndarray = LavaPyType(np.ndarray, float)
    v: np.ndarray = LavaPyType(np.ndarray, np.int32, precision=24)

    def __init__(self, proc_params):
        super().__init__(proc_params)
        self._h, self._w = proc_params["shape"]
        self._n_bins = int(proc_params["n_bins"])
        self._stage = None

    def _build(self) -> SparseOFSStage:
        # Vars are assigned by the builder after __init__: build the kernel on the first step.
        p = LoihiOFSParams(weight=np.asarray(self.weight, np.int32), vth_mant=int(self.vth[0]),
                           dv=int(self.dv[0]), du=int(self.du[0]), weight_scale=float(self.weight_scale[0]))
        return SparseOFSStage(p, self._h, self._w, v=self.v.reshape(-1))

    def run_spk(self) -> None:
        if self._stage is None:
            self._stage = self._build()
        if (self.time_step - 1) % self._n_bins == 0:
            self._stage.reset()
        spikes = unpack(self.s_in.csp_ports[0].recv(), self._w)   # one source
        self.s_out.send(pack(self._stage.step(spikes)))


@implements(proc=OFSNeuron, protocol=LoihiProtocol)
@requires(CPU)
@tag("floating_pt")
class PyOFSNeuronModelFloat(PyLoihiProcessModel):
    """Float eq. (1)-(2) with the float parameters the integer stage stands for:

        v[t] = lambda * v[t-1] + conv(W, s_in[t]) - vth * o[t-1],   o[t] = v[t] > vth
        W = w / s,  vth = vth_mant / s,  lambda = 1 - dv / 4096.

    Event driven (kernels.SparseFloatOFSStage). Not bit exact to fixed_pt (no truncation of
    the decay, no 24-bit saturation).
    """

    s_in: PyInPort = LavaPyType(PyInPort.VEC_DENSE, np.uint8, precision=8)
    s_out: PyOutPort = LavaPyType(PyOutPort.VEC_DENSE, np.uint8, precision=8)
    weight: np.ndarray = LavaPyType(np.ndarray, float)
    vth: np.ndarray = LavaPyType(np.ndarray, float)
    dv: np.ndarray = LavaPyType(np.ndarray, float)
    du: np.ndarray = LavaPyType(np.ndarray, float)
    weight_scale: np.ndarray = LavaPyType(np.ndarray, float)
    v: np.ndarray = LavaPyType(np.ndarray, float)

    def __init__(self, proc_params):
        super().__init__(proc_params)
        self._h, self._w = proc_params["shape"]
        self._n_bins = int(proc_params["n_bins"])
        self._stage = None

    def run_spk(self) -> None:
        if self._stage is None:
            p = LoihiOFSParams(weight=np.asarray(self.weight).astype(np.int32), vth_mant=int(self.vth[0]),
                               dv=int(self.dv[0]), du=int(self.du[0]), weight_scale=float(self.weight_scale[0]))
            self._stage = SparseFloatOFSStage(p, self._h, self._w, v=self.v.reshape(-1))
        if (self.time_step - 1) % self._n_bins == 0:
            self._stage.reset()
        spikes = unpack(self.s_in.csp_ports[0].recv(), self._w)   # one source
        self.s_out.send(pack(self._stage.step(spikes)))
