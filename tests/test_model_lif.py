"""LIF eq. (1)-(2) semantics and trainability of the OFS parameters."""
from __future__ import annotations

import torch

from toffe_deploy.model.lif import lif_sequence
from toffe_deploy.model.ofs import OFS


def test_lif_matches_hand_computed_sequence_with_reset_timing():
    # vth = 1, lambda = 0.5; u[t] = 0.5 u[t-1] + I[t] - 1 * o[t-1]
    cur = torch.tensor([0.8, 0.8, 0.8, 0.0, 0.0, 1.0, 2.5, 0.0])
    out = lif_sequence(cur[:, None], torch.tensor(1.0), torch.tensor(0.5))[:, 0]
    # t0 u=0.8 | t1 u=1.2 spike | t2 u=0.6+0.8-1=0.4 (reset at t, undecayed) | t3 0.2 | t4 0.1
    # t5 u=0.05+1.0=1.05 spike | t6 u=0.525+2.5-1=2.025 spike | t7 u=1.0125-1=0.0125
    assert out.tolist() == [0, 1, 0, 0, 0, 1, 1, 0]


def test_lif_fires_strictly_above_threshold():
    out = lif_sequence(torch.tensor([[1.0], [0.0]]), torch.tensor(1.0), torch.tensor(0.0))
    assert out.sum() == 0


def test_gradients_reach_weight_threshold_and_leak():
    torch.manual_seed(0)
    m = OFS(2, 3)
    x = (torch.rand(5, 2, 2, 12, 12) < 0.4).float()
    m(x).sum().backward()
    for p in (m.conv.weight, m.threshold, m.leak):
        assert p.grad is not None and torch.isfinite(p.grad).all() and p.grad.abs().sum() > 0


def test_clamp_keeps_parameters_loihi_representable():
    m = OFS(2, 3)
    with torch.no_grad():
        m.leak.fill_(1.7)
        m.threshold.fill_(-3.0)
    m.clamp_()
    assert 0.0 <= float(m.leak) <= 1.0 and float(m.threshold) > 0
