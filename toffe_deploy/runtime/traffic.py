"""Host <-> chip traffic of the hybrid cascade on the Lava targets (what the bridges move).

The OFS stages run on Loihi 2; the closing, inversion and masking between them (eq. 3-4) run on
the host, as in the paper's hybrid. Per window, with S_k the input spikes of stage k (OFS_N: the
window's events from the source; OFS_k < N: the masked x_k from bridge k + 1) and O_k its output
spikes:

    to_chip = sum_k |S_k|        to_host = sum_k |O_k|        (spikes)
    bytes   = 4 * spikes         (one 32-bit address-event message per spike)

``dense_bytes`` is the same traffic as bit planes, one bit per pixel, channel and time bin
(what our Lava ports carry, packed): the cost of sending frames instead of events.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

EVENT_BYTES = 4


@dataclass
class Traffic:
    """Totals over ``windows`` windows; ``to_json`` / ``line`` give the per-window means."""

    windows: int = 0
    to_chip_spikes: int = 0
    to_host_spikes: int = 0
    to_chip_dense_bytes: int = 0
    to_host_dense_bytes: int = 0

    def add(self, inputs, spikes) -> None:
        """One window's stage inputs (B, C, H, W) and output spikes (B, H, W), index k - 1."""
        self.windows += 1
        self.to_chip_spikes += sum(int(np.count_nonzero(x)) for x in inputs)
        self.to_host_spikes += sum(int(np.count_nonzero(s)) for s in spikes)
        self.to_chip_dense_bytes += sum((int(np.size(x)) + 7) // 8 for x in inputs)
        self.to_host_dense_bytes += sum((int(np.size(s)) + 7) // 8 for s in spikes)

    def to_json(self) -> dict:
        n = max(self.windows, 1)
        per = {
            "to_chip_spikes": self.to_chip_spikes / n, "to_host_spikes": self.to_host_spikes / n,
            "to_chip_bytes": EVENT_BYTES * self.to_chip_spikes / n, "to_host_bytes": EVENT_BYTES * self.to_host_spikes / n,
            "to_chip_dense_bytes": self.to_chip_dense_bytes / n, "to_host_dense_bytes": self.to_host_dense_bytes / n,
        }
        return {"windows": self.windows, "per_window": per,
                "note": f"bytes as {EVENT_BYTES}-byte address events, dense_bytes as 1-bit planes (runtime/traffic.py)"}

    def line(self) -> str:
        p = self.to_json()["per_window"]
        return (f"bridge traffic per window: host->chip {p['to_chip_spikes']:.0f} spikes ({p['to_chip_bytes'] / 1e3:.1f} kB "
                f"as events, {p['to_chip_dense_bytes'] / 1e3:.1f} kB as bit planes), chip->host "
                f"{p['to_host_spikes']:.0f} spikes ({p['to_host_bytes'] / 1e3:.1f} kB, {p['to_host_dense_bytes'] / 1e3:.1f} kB)")
