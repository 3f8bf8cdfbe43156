"""The cascade bridge Process between OFS stage k and stage k - 1 (paper eq. 3-4).

Over the n_bins steps of a window it stores stage k's input x_k and output spikes o_k. At the
window's last step it computes

    closed_k = Close(OR_t o_k[t])                 (square kernel mask_kernel, OpenCV borders)
    x_{k-1}  = x_k & ~closed_k                    (eq. 3-4: mask = Invert(closed))
    frame_k  = x_k & closed_k                     (the speed-separated events of bin k)

and then replays x_{k-1} to stage k - 1 one bin per step during the next window's n_bins
steps, while stage k already works on the next window: the stages form a pipeline, stage k
running ``depth = N - k`` windows behind the source. Each finished window goes to the host as
one record through an external pipe, all planes bit-packed (lava_procs.packing):

    record = [o_k (n_bins), closed_k (1), x_k (n_bins * C), frame_k (n_bins * C)]   planes

``stock=True`` sits between stock Lava processes (reset "zero" bundles: lava.proc.conv Conv ->
lava.proc.lif LIFReset per stage): s_in then takes the LIF's dense (W, H, 1) spikes, which the
Conv's one-step delay puts one step late (bin b of a window arrives at its step b + 1, the last
bin at the next window's first step), and a second output ``a_out`` (W, H, C) dense feeds the
next stage's Conv. The window is closed at the next window's first step, before that step's
x_{k-1} goes out, so stage k - 1 still runs exactly one window behind stage k; the record of a
window leaves one step later than without ``stock``.
"""
from __future__ import annotations

import typing as ty

import numpy as np
from lava.magma.core.process.ports.ports import InPort, OutPort
from lava.magma.core.process.process import AbstractProcess, LogConfig

from lava_procs.packing import packed_width


def record_planes(n_bins: int, channels: int) -> int:
    """Number of packed planes in one bridge record (see module docstring)."""
    return int(n_bins) * (1 + 2 * int(channels)) + 1


class CascadeBridge(AbstractProcess):
    """Masking bridge after one OFS stage (see module docstring).

    shape: (H, W); channels: C of the event volume; depth: windows this stage lags the source
    (records of windows before the first one, pipeline fill, are not sent).
    Ports: s_in (H, Wb) stage output; x_in (C, H, Wb) stage input; x_out (C, H, Wb) next stage's
    input; record_out (host side, external pipe): (record_planes, H, Wb) uint8.
    stock: s_in is a stock LIF's (W, H, 1) output, plus a_out (W, H, C) (see module docstring).
    """

    def __init__(self, *, shape: tuple[int, int], channels: int, n_bins: int, mask_kernel: int,
                 depth: int, buffer_size: int = 4, stock: bool = False, name: ty.Optional[str] = None,
                 log_config: ty.Optional[LogConfig] = None) -> None:
        h, w = (int(s) for s in shape)
        c = int(channels)
        super().__init__(shape=(h, w), channels=c, n_bins=int(n_bins), mask_kernel=int(mask_kernel),
                         depth=int(depth), stock=bool(stock), name=name, log_config=log_config)
        wb = packed_width(w)
        self.s_in = InPort(shape=(w, h, 1) if stock else (h, wb))
        self.x_in = InPort(shape=(c, h, wb))
        self.x_out = OutPort(shape=(c, h, wb))
        if stock:
            self.a_out = OutPort(shape=(w, h, c))
        self.record_out = OutPort(shape=(record_planes(n_bins, c), h, wb))
        self.record_out.flag_external_pipe(buffer_size=int(buffer_size))

    def receive_port(self):
        """Host side: the receiving end of record_out (exists once the runtime is created)."""
        port = getattr(self.record_out, "external_pipe_csp_recv_port", None)
        if port is None:
            raise RuntimeError("CascadeBridge records need a created runtime (compile and start first)")
        return port
