"""LIF neuron of the paper, eq. (1)-(2), as a pure step function plus a surrogate spike.

    u[t] = lambda * u[t-1] + I[t] - vth * o[t-1]          (eq. 1, reset "subtract")
    u[t] = lambda * (1 - o[t-1]) * u[t-1] + I[t]          (reset "zero": Loihi 2's stock LIF)
    o[t] = H(u[t] / vth - 1)                               (eq. 2, strict: fires when u > vth)

The zero reset's (1 - o[t-1]) is detached (no gradient through the reset, as snnTorch does).

The backward pass of H uses a fast-sigmoid surrogate. State starts at zero in every window.
"""
from __future__ import annotations

import torch


class SpikeFn(torch.autograd.Function):
    """Heaviside forward (z > 0), fast-sigmoid derivative 1 / (1 + slope |z|)^2 backward."""

    slope = 5.0

    @staticmethod
    def forward(ctx, z):
        ctx.save_for_backward(z)
        return (z > 0).to(z.dtype)

    @staticmethod
    def backward(ctx, grad):
        (z,) = ctx.saved_tensors
        return grad / (1.0 + SpikeFn.slope * z.abs()) ** 2


spike = SpikeFn.apply


def lif_step(u: torch.Tensor, o_prev: torch.Tensor, current: torch.Tensor, vth: torch.Tensor,
             leak: torch.Tensor, reset: str = "subtract") -> tuple[torch.Tensor, torch.Tensor]:
    """One step of eq. (1)-(2) with the given reset (module docstring). Returns (u, o)."""
    if reset == "zero":
        u = leak * (1.0 - o_prev.detach()) * u + current
    else:
        u = leak * u + current - vth * o_prev
    return u, spike(u / vth - 1.0)


def lif_sequence(currents: torch.Tensor, vth: torch.Tensor, leak: torch.Tensor,
                 reset: str = "subtract") -> torch.Tensor:
    """Run eq. (1)-(2) over currents (T, ...) from zero state; returns spikes (T, ...)."""
    u = torch.zeros_like(currents[0])
    o = torch.zeros_like(currents[0])
    out = []
    for t in range(currents.shape[0]):
        u, o = lif_step(u, o, currents[t], vth, leak, reset)
        out.append(o)
    return torch.stack(out)
