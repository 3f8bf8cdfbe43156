"""The OFPD speed loss options (model/train.py SpeedLoss): plain L1 by default, per-bin balance,
a cost for leaving the true bin."""
from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from toffe_deploy import ofpd_io
from toffe_deploy.config import ToffeConfig
from toffe_deploy.model.train import OFPDSet, SpeedLoss, ofpd_loss

CFG = ToffeConfig(sensor_size=(64, 48))


class _Fixed(torch.nn.Module):
    """A stand-in OFPD that returns set outputs (the loss is what is tested)."""

    def __init__(self, speed):
        super().__init__()
        self.speed = torch.tensor(speed, dtype=torch.float32)[:, None]

    def forward(self, x):
        n = x.shape[0]
        return torch.zeros(n, 2), torch.tensor([[1.0, 0.0]]).repeat(n, 1), self.speed


def _batch(lnv_true):
    n = len(lnv_true)
    return (torch.zeros(n, 1, 2, 2), torch.zeros(n, 2), torch.tensor([[1.0, 0.0]]).repeat(n, 1),
            torch.tensor(lnv_true, dtype=torch.float32))


def _set(truth_bin):
    n = len(truth_bin)
    z = np.zeros(n)
    return OFPDSet(np.zeros((n, 1, 2, 2), np.uint16), np.zeros((n, 0, 2, 2), np.float32), np.zeros((n, 3)),
                   z, z, z, z, np.ones(n, np.int64), np.asarray(truth_bin, np.int64))


def test_balance_weights_each_bin_alike_and_bounds_are_the_true_bins():
    w, bounds = SpeedLoss(balance=True).sample_terms(_set([1, 1, 1, 2, 3, 4]), CFG)
    # every bin's weights sum to the same share of N; the mean weight is 1
    assert [w[np.asarray([1, 1, 1, 2, 3, 4]) == b].sum() for b in (1, 2, 3, 4)] == pytest.approx([1.5] * 4)
    assert w.mean() == pytest.approx(1.0)
    edges = np.log(ofpd_io.speed_bounds_px_ms(CFG))
    np.testing.assert_allclose(bounds, edges[[0, 0, 0, 1, 2, 3]])
    w_plain, _ = SpeedLoss(edge_weight=1.0).sample_terms(_set([1, 1, 2]), CFG)
    assert w_plain.tolist() == [1.0, 1.0, 1.0]


def test_edge_term_costs_only_a_speed_outside_the_true_bin():
    edges = np.log(ofpd_io.speed_bounds_px_ms(CFG))
    lo2, hi2 = edges[1]
    inside, outside = (lo2 + hi2) / 2, hi2 + 0.1          # bin 2's middle; 0.1 past its upper edge
    truth = [inside - 0.05, inside - 0.05]
    model = _Fixed([inside, outside])
    bounds = np.array([edges[1], edges[1]])
    _, (_, _, plain) = ofpd_loss(model, _batch(truth), "cpu")
    _, (_, _, same) = ofpd_loss(model, _batch(truth), "cpu", (np.ones(2), bounds), 0.0)
    _, (_, _, edged) = ofpd_loss(model, _batch(truth), "cpu", (np.ones(2), bounds), 2.0)
    assert same == pytest.approx(plain)                  # weights 1, W 0: the plain L1
    assert edged - plain == pytest.approx(2.0 * 0.1 / 2, abs=1e-5)   # only the outside sample pays, W x 0.1


def test_default_speed_loss_is_plain():
    assert SpeedLoss().plain and not SpeedLoss(balance=True).plain and not SpeedLoss(edge_weight=0.5).plain
    with pytest.raises(ValueError):
        SpeedLoss(balance=True).sample_terms(OFPDSet(*([np.zeros(1)] * 8)), CFG)
    assert math.isfinite(SpeedLoss(balance=True).sample_terms(_set([4]), CFG)[0][0])


def test_cli_refuses_a_negative_edge_weight(tmp_path, capsys):
    from toffe_deploy.cli import main

    assert main(["train", "--data", str(tmp_path), "--out", str(tmp_path / "ck"), "--stage", "ofpd",
                 "--speed-edge-weight", "-1", "--no-progress"]) == 2
    assert "--speed-edge-weight" in capsys.readouterr().err
