"""OFS: one conv layer (C_in -> 1, K x K, no bias) into LIF neurons with one trainable threshold
and one trainable leak per model (what one Loihi LIF process holds)."""
from __future__ import annotations

import torch
from torch import nn

from .lif import lif_sequence

# DOTIE's hand-set layer (anchors.md): 0.15 everywhere, 0.2 at the centre; leak 0.3, vth 1.0.
DOTIE_WEIGHT = 0.15
DOTIE_CENTRE = 0.2
DOTIE_LEAK = 0.3
DOTIE_THRESHOLD = 1.0


class OFS(nn.Module):
    """Forward: spikes (B, N, 1, H, W) from binary input (B, N, C_in, H, W), time first."""

    def __init__(self, in_channels: int = 2, kernel_size: int = 3, threshold: float = DOTIE_THRESHOLD,
                 leak: float = DOTIE_LEAK, reset: str = "subtract"):
        super().__init__()
        self.reset = reset            # "subtract" (paper eq. 1) or "zero" (stock Loihi 2 LIF)
        self.conv = nn.Conv2d(in_channels, 1, kernel_size, padding=kernel_size // 2, bias=False)
        with torch.no_grad():
            self.conv.weight.fill_(DOTIE_WEIGHT)
            self.conv.weight[:, :, kernel_size // 2, kernel_size // 2] = DOTIE_CENTRE
        self.threshold = nn.Parameter(torch.tensor(float(threshold)))
        self.leak = nn.Parameter(torch.tensor(float(leak)))

    def clamp_(self) -> None:
        """Keep the parameters inside what Loihi 2 can represent (call after each step)."""
        with torch.no_grad():
            self.leak.clamp_(0.0, 1.0)
            self.threshold.clamp_(min=1e-3)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        t, n = x.shape[:2]
        cur = self.conv(x.flatten(0, 1)).unflatten(0, (t, n))
        return lif_sequence(cur, self.threshold, self.leak, self.reset)
