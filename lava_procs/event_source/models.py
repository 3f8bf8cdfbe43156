"""Process model of the event-bin source (binary spikes: the same for fixed_pt and floating_pt)."""
from __future__ import annotations

import numpy as np
from lava.magma.core.decorator import implements, requires, tag
from lava.magma.core.model.py.model import PyLoihiProcessModel
from lava.magma.core.model.py.ports import PyInPort, PyOutPort
from lava.magma.core.model.py.type import LavaPyType
from lava.magma.core.resources import CPU
from lava.magma.core.sync.protocols.loihi_protocol import LoihiProtocol

from lava_procs.event_source.process import EventBinSource
from lava_procs.packing import unpack


@implements(proc=EventBinSource, protocol=LoihiProtocol)
@requires(CPU)
@tag("fixed_pt", "floating_pt")
class PyEventBinSourceModel(PyLoihiProcessModel):
    """Receives a packed window from the host at each window start, emits one bin per step."""

    window_in: PyInPort = LavaPyType(PyInPort.VEC_DENSE, np.uint8, precision=8)
    s_out: PyOutPort = LavaPyType(PyOutPort.VEC_DENSE, np.uint8, precision=8)

    def __init__(self, proc_params):
        super().__init__(proc_params)
        self._n_bins = int(proc_params["n_bins"])
        self._window = None

    def run_spk(self) -> None:
        b = (self.time_step - 1) % self._n_bins
        if b == 0:
            # One external-pipe port, so take it directly (PyInPort.recv would add it to zeros).
            self._window = self.window_in.csp_ports[-1].recv()
        self.s_out.send(self._window[b])


@implements(proc=EventBinSource, protocol=LoihiProtocol)
@requires(CPU)
@tag("fixed_pt", "floating_pt")
class PyEventBinSourceStockModel(PyEventBinSourceModel):
    """EventBinSource(stock=True): each bin also dense (W, H, C) int32 for a stock Conv."""

    a_out: PyOutPort = LavaPyType(PyOutPort.VEC_DENSE, np.int32, precision=24)

    def __init__(self, proc_params):
        super().__init__(proc_params)
        self._width = int(proc_params["shape"][2])

    def run_spk(self) -> None:
        super().run_spk()
        b = (self.time_step - 1) % self._n_bins
        self.a_out.send(unpack(self._window[b], self._width).transpose(2, 1, 0).astype(np.int32))
