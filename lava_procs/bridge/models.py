"""Process models of the cascade bridge (binary logic: the same for fixed_pt and floating_pt):
``PyCascadeBridgeModel`` after our OFS neuron, ``PyCascadeBridgeStockModel`` after a stock LIF."""
from __future__ import annotations

import numpy as np
from lava.magma.core.decorator import implements, requires, tag
from lava.magma.core.model.py.model import PyLoihiProcessModel
from lava.magma.core.model.py.ports import PyInPort, PyOutPort
from lava.magma.core.model.py.type import LavaPyType
from lava.magma.core.resources import CPU
from lava.magma.core.sync.protocols.loihi_protocol import LoihiProtocol

from lava_procs.bridge.process import CascadeBridge
from lava_procs.packing import pack, packed_width, unpack
from toffe_deploy.cascade import close_binary


@implements(proc=CascadeBridge, protocol=LoihiProtocol)
@requires(CPU)
@tag("fixed_pt", "floating_pt")
class PyCascadeBridgeModel(PyLoihiProcessModel):
    """Eq. 3-4 on bit-packed planes; the closing itself is toffe_deploy.cascade.close_binary."""

    s_in: PyInPort = LavaPyType(PyInPort.VEC_DENSE, np.uint8, precision=8)
    x_in: PyInPort = LavaPyType(PyInPort.VEC_DENSE, np.uint8, precision=8)
    x_out: PyOutPort = LavaPyType(PyOutPort.VEC_DENSE, np.uint8, precision=8)
    record_out: PyOutPort = LavaPyType(PyOutPort.VEC_DENSE, np.uint8, precision=8)

    def __init__(self, proc_params):
        super().__init__(proc_params)
        h, w = proc_params["shape"]
        c = int(proc_params["channels"])
        self._w = int(w)
        self._n_bins = b = int(proc_params["n_bins"])
        self._kernel = int(proc_params["mask_kernel"])
        self._depth = int(proc_params["depth"])
        wb = packed_width(w)
        # record layout: spikes [0, B), closed [B], inputs [B+1, B+1+BC), frames [B+1+BC, B+1+2BC)
        self._record = np.zeros((b * (1 + 2 * c) + 1, h, wb), np.uint8)
        self._spk = self._record[:b]
        self._closed = self._record[b]
        self._x = self._record[b + 1:b + 1 + b * c].reshape(b, c, h, wb)
        self._frame = self._record[b + 1 + b * c:].reshape(b, c, h, wb)
        self._pending = np.zeros((b, c, h, wb), np.uint8)    # next stage's input, replayed

    def run_spk(self) -> None:
        step = self.time_step - 1
        b = step % self._n_bins
        # Send first: the next stage needs nothing from this step, so it runs concurrently.
        self.x_out.send(self._pending[b])
        self._spk[b] = self.s_in.csp_ports[0].recv()
        self._x[b] = self.x_in.csp_ports[0].recv()
        if b == self._n_bins - 1:
            self._close_window(step // self._n_bins)

    def _close_window(self, period: int) -> None:
        """Eq. 3-4 on the stored window of pipeline period ``period``; record it to the host
        unless it is pipeline fill (a period before this stage's depth)."""
        fired = np.bitwise_or.reduce(self._spk, axis=0)
        self._closed[:] = pack(close_binary(unpack(fired, self._w), self._kernel))
        np.bitwise_and(self._x, self._closed, out=self._frame)
        np.bitwise_and(self._x, ~self._closed, out=self._pending)
        if period >= self._depth:                    # a real window, not pipeline fill
            self.record_out.send(self._record)


@implements(proc=CascadeBridge, protocol=LoihiProtocol)
@requires(CPU)
@tag("fixed_pt", "floating_pt")
class PyCascadeBridgeStockModel(PyCascadeBridgeModel):
    """The bridge between stock processes (CascadeBridge(stock=True)): dense (W, H, 1) spikes in
    one step late, the next stage's input also as dense (W, H, C) for its Conv."""

    s_in: PyInPort = LavaPyType(PyInPort.VEC_DENSE, np.int32, precision=24)
    a_out: PyOutPort = LavaPyType(PyOutPort.VEC_DENSE, np.int32, precision=24)

    def run_spk(self) -> None:
        step = self.time_step - 1
        b = step % self._n_bins
        spk = self.s_in.csp_ports[0].recv()                  # bin b - 1 (Conv delay)
        self._spk[(b - 1) % self._n_bins] = pack(np.asarray(spk)[:, :, 0].T != 0)
        x = self.x_in.csp_ports[0].recv()
        if b == 0 and step > 0:                              # the previous window is complete
            self._close_window(step // self._n_bins - 1)
        self._x[b] = x
        self.x_out.send(self._pending[b])
        self.a_out.send(unpack(self._pending[b], self._w).transpose(2, 1, 0).astype(np.int32))
