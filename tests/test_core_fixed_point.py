"""The fixed-point OFS reference: quantizer ranges and the step arithmetic by hand."""
import numpy as np
import pytest
import torch

from toffe_deploy.cascade import close_binary, run_cascade
from toffe_deploy.fixed_point import (DECAY_UNITY, WEIGHT_MAX, lif_step, quantize_ofs, run_ofs_fixed,
                                      trunc_decay)
from toffe_deploy.model.lif import lif_sequence


def test_trunc_decay_truncates_toward_zero():
    v = np.array([4097, -4097, 100, -100])
    # (4096 - 2048) / 4096 = 0.5: 2048.5 -> 2048, -2048.5 -> -2048, 50 -> 50, -50 -> -50
    assert trunc_decay(v, 2048).tolist() == [2048, -2048, 50, -50]


def test_quantize_uses_full_weight_range_and_maps_threshold():
    w = np.array([[[[0.1, -0.2], [0.05, 0.0]]]])
    p = quantize_ofs(w, threshold=0.3, leak=0.75)
    assert np.abs(p.weight).max() == WEIGHT_MAX
    assert p.weight[0, 0, 0, 1] == -WEIGHT_MAX
    assert p.vth_mant == round(0.3 * WEIGHT_MAX / 0.2)
    assert p.dv == DECAY_UNITY // 4


@pytest.mark.parametrize("w,th,leak", [(np.full((1, 1, 1, 1), np.nan), 1.0, 0.5), (np.ones((1, 1, 1, 1)), -1.0, 0.5),
                                       (np.zeros((1, 1, 1, 1)), 1.0, 0.5), (np.ones((1, 1, 1, 1)), float("inf"), 0.5)])
def test_quantize_rejects_unrepresentable(w, th, leak):
    with pytest.raises(ValueError):
        quantize_ofs(w, th, leak)


def test_quantize_clamps_leak_and_says_so():
    p = quantize_ofs(np.ones((1, 1, 1, 1)), 1.0, 1.3)
    assert p.dv == 0 and any("leak" in n for n in p.notes)


def test_soft_reset_is_undecayed_and_one_step_late():
    # vth = 10 (mantissa), input 11 each step, no leak (dv = 0): v = 11*64 -> spike;
    # next step v = 704 + 704 - 640 = 768 -> spike; next 768 + 704 - 640 = 832 ...
    p = quantize_ofs(np.ones((1, 1, 1, 1)), 10.0 / WEIGHT_MAX, 1.0)
    assert p.vth_mant == 10 and p.dv == 0
    v = np.zeros(1, np.int64)
    o = np.zeros(1, bool)
    seq = []
    for _ in range(3):
        v, o = lif_step(v, o, np.array([11]), p)
        seq.append((int(v[0]), bool(o[0])))
    assert seq == [(704, True), (768, True), (832, True)]


def test_fixed_point_matches_float_eq1_when_exactly_representable():
    rng = np.random.default_rng(0)
    x = (rng.random((5, 2, 12, 10)) < 0.3).astype(np.uint8)
    w = rng.integers(-20, 40, (1, 2, 3, 3)).astype(np.float64) / 127.0 * 0.5
    w[0, 0, 0, 0] = 0.5                      # max |w| -> exactly 127
    p = quantize_ofs(w, threshold=64 / 254, leak=0.5)   # dv = 2048; threshold exactly 64
    assert p.vth_mant == 64
    fixed = run_ofs_fixed(x, p)
    wt = torch.tensor(w, dtype=torch.float64)
    cur = torch.nn.functional.conv2d(torch.tensor(x, dtype=torch.float64), wt, padding=1)
    flt = lif_sequence(cur, torch.tensor(64 / 254, dtype=torch.float64), torch.tensor(0.5, dtype=torch.float64))
    agree = (fixed == flt[:, 0].numpy().astype(bool)).mean()
    assert agree > 0.99   # truncation of the decay may flip a borderline neuron


def test_cascade_masks_faster_stages_out_of_slower_inputs():
    x = np.zeros((2, 1, 20, 20), np.uint8)
    x[:, 0, 2:5, 2:5] = 1          # "fast" blob: stage 2 fires on it
    x[:, 0, 12:15, 12:15] = 1      # "slow" blob
    def stage(k, inp):
        out = np.zeros(inp.shape[:1] + inp.shape[2:], bool)
        if k == 2:
            out[:, 2:5:2, 2:5:2] = True   # corners only: closing fills the blob
        else:
            out[:] = inp[:, 0]
        return out
    res = run_cascade(x, stage, n_stages=2, mask_kernel=5)
    assert res.frames[1][:, 0, 2:5, 2:5].all() and not res.frames[1][:, 0, 12:15, 12:15].any()
    assert not res.inputs[0][:, 0, 2:5, 2:5].any() and res.inputs[0][:, 0, 12:15, 12:15].all()


def test_close_binary_fills_gaps_and_keeps_edges():
    img = np.zeros((9, 9), bool)
    img[0, 0:3] = True
    img[0, 4:7] = True
    out = close_binary(img, 5)
    assert out[0, 0:7].all()            # gap filled, border not eroded
