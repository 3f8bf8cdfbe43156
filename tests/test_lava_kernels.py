"""lava_procs' numpy kernels (no Lava runtime): packing and the event-driven OFS stage."""
import numpy as np
import pytest

from lava_procs.ofs_neuron.kernels import DENSE_FRACTION, SparseOFSStage, event_synaptic_input
from lava_procs.packing import pack, pack_indices, packed_width, unpack
from toffe_deploy.fixed_point import quantize_ofs, run_ofs_fixed, synaptic_input


@pytest.mark.parametrize("width", [8, 29, 32])
def test_pack_roundtrip_and_sparse_packing_agree(rng, width):
    x = rng.random((5, 2, 7, width)) < 0.2
    p = pack(x)
    assert p.shape == (5, 2, 7, packed_width(width)) and p.dtype == np.uint8
    assert np.array_equal(unpack(p, width), x)
    assert np.array_equal(pack_indices(np.flatnonzero(x), x.shape), p)
    # bitwise logic on packed planes is logic on the planes, padding bits stay zero
    m = rng.random((7, width)) < 0.5
    assert np.array_equal(unpack(p & ~pack(m), width), x & ~m)
    assert np.array_equal(pack_indices(np.zeros(0, np.int64), x.shape), np.zeros_like(p))


def test_event_synaptic_input_equals_reference_conv(rng):
    w = rng.integers(-127, 128, (1, 2, 3, 3)).astype(np.int32)
    w[0, 1, 0, 2] = 0                                     # a zero tap is skipped, not miscounted
    x = rng.random((2, 24, 32)) < 0.1
    x[0, 0, 0] = x[1, 23, 31] = True                      # corners: zero padding at the border
    a_in, targets = event_synaptic_input(x, w)
    assert np.array_equal(a_in, synaptic_input(x, w).ravel().astype(np.float64))
    assert set(np.unique(targets)) >= set(np.flatnonzero(a_in))


@pytest.mark.parametrize("density", [0.02, 0.08, 0.4])    # 0.4 takes the dense reference path
def test_sparse_stage_is_bit_exact_to_reference_over_windows(rng, density):
    params = quantize_ofs(rng.normal(size=(1, 2, 5, 5)) + 0.2, threshold=0.7, leak=0.55)
    stage = SparseOFSStage(params, 24, 32)
    fired = 0
    for _ in range(3):                                    # state must not leak across windows
        x = rng.random((5, 2, 24, 32)) < density
        stage.reset()
        out = np.stack([stage.step(x[t]).copy() for t in range(5)])
        ref = run_ofs_fixed(x, params)
        assert np.array_equal(out, ref)
        fired += int(ref.sum())
        assert stage._all_active == (x.sum(axis=(1, 2, 3)).max() > DENSE_FRACTION * 24 * 32)
    assert fired > 0


def test_sparse_stage_soft_reset_matches_hand_computation():
    # vth 10, no leak, constant input 11 at one pixel (centre tap 1): v = 704, 768, 832 (all spike)
    params = quantize_ofs(np.pad(np.ones((1, 1, 1, 1)), ((0, 0), (0, 0), (1, 1), (1, 1))), 10 / 127, 1.0)
    assert params.vth_mant == 10 and params.dv == 0
    stage = SparseOFSStage(params, 3, 3)
    x = np.zeros((1, 3, 3), bool)
    x[0, 1, 1] = True
    seq = []
    for _ in range(3):
        o = stage.step(x)
        seq.append((int(stage.v[4]), bool(o[1, 1])))
    # a_in = 127 per step: 127*64 = 8128 > 640 -> spike, then + 8128 - 640 each step
    assert seq == [(8128, True), (15616, True), (23104, True)]


def test_state_buffer_shape_is_checked():
    params = quantize_ofs(np.ones((1, 2, 3, 3)), 1.0, 0.5)
    with pytest.raises(ValueError, match="state buffer"):
        SparseOFSStage(params, 4, 4, v=np.zeros(15, np.int32))


def test_sparse_float_stage_follows_float_eq1(rng):
    """floating_pt kernel against eq. (1)-(2) in torch (the training model's LIF) on float params."""
    import torch

    from lava_procs.ofs_neuron.kernels import SparseFloatOFSStage
    from toffe_deploy.model.lif import lif_sequence

    params = quantize_ofs(rng.normal(size=(1, 2, 3, 3)) + 0.3, threshold=0.8, leak=0.6)
    w_f, vth, lam = params.float_equivalent()
    stage = SparseFloatOFSStage(params, 24, 32)
    for density in (0.05, 0.4):                           # sparse and dense paths
        x = rng.random((5, 2, 24, 32)) < density
        stage.reset()
        out = np.stack([stage.step(x[t]).copy() for t in range(5)])
        cur = torch.nn.functional.conv2d(torch.tensor(x, dtype=torch.float64), torch.tensor(w_f), padding=1)
        ref = lif_sequence(cur, torch.tensor(vth, dtype=torch.float64),
                           torch.tensor(lam, dtype=torch.float64))[:, 0].numpy().astype(bool)
        assert ref.sum() > 0
        assert np.mean(out == ref) > 0.999              # only float rounding at exactly vth may differ
