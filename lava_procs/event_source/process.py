"""The event-bin source Process: host-binned windows in, one time bin per step out.

The host sends one window per n_bins steps, bit-packed, through an external pipe (the same
mechanism as lava.proc.io.Injector, but uint8 and one message per window instead of one
float64 message per step). At step t the source emits bin (t - 1) mod n_bins of the window it
received at the window's first step, so window w occupies steps w * n_bins + 1 ... (w + 1) * n_bins.
"""
from __future__ import annotations

import typing as ty

import numpy as np
from lava.magma.core.process.ports.ports import InPort, OutPort
from lava.magma.core.process.process import AbstractProcess, LogConfig

from lava_procs.packing import packed_width


class EventBinSource(AbstractProcess):
    """Feeds windows (n_bins, C, H, W) of binary spikes into the network step by step.

    shape: (C, H, W). window_in (host side, external pipe of ``buffer_size`` windows):
    (n_bins, C, H, ceil(W/8)) uint8 packed; s_out: (C, H, ceil(W/8)) packed, one bin per step.
    The model blocks on the host at each window start, which keeps host and network in step.
    stock: also emit each bin dense on a_out (W, H, C), the input layout of lava.proc.conv Conv.
    """

    def __init__(self, *, shape: tuple[int, int, int], n_bins: int, buffer_size: int = 4, stock: bool = False,
                 name: ty.Optional[str] = None, log_config: ty.Optional[LogConfig] = None) -> None:
        c, h, w = (int(s) for s in shape)
        super().__init__(shape=(c, h, w), n_bins=int(n_bins), stock=bool(stock), name=name, log_config=log_config)
        self.window_in = InPort(shape=(int(n_bins), c, h, packed_width(w)))
        self.window_in.flag_external_pipe(buffer_size=int(buffer_size))
        self.s_out = OutPort(shape=(c, h, packed_width(w)))
        if stock:
            self.a_out = OutPort(shape=(w, h, c))

    def send(self, window_packed: np.ndarray) -> None:
        """Host side: queue one packed window (blocks only when ``buffer_size`` are queued)."""
        port = getattr(self.window_in, "external_pipe_csp_send_port", None)
        if port is None:
            raise RuntimeError("EventBinSource.send needs a created runtime (compile and start first)")
        port.send(np.ascontiguousarray(window_packed, dtype=np.uint8))
