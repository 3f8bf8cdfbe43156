"""Export quantizer: round trips, range edges, one-line errors for what Loihi 2 cannot hold."""
import numpy as np
import pytest

from toffe_deploy.deploy.quantize import quantize_stages
from toffe_deploy.errors import InputError
from toffe_deploy.fixed_point import DECAY_UNITY, VTH_MANT_MAX, WEIGHT_MAX, quantize_ofs


def stage(w=None, threshold=1.0, leak=0.3):
    if w is None:
        w = np.full((1, 2, 3, 3), 0.15, np.float32)
        w[0, :, 1, 1] = 0.2
    return dict(weight=np.asarray(w, np.float32), threshold=threshold, leak=leak)


def test_round_trip_is_a_fixed_point_of_the_quantizer(rng):
    """Quantizing the float values a quantized stage represents gives the same integers back."""
    for _ in range(20):
        w = rng.normal(0, 0.3, (1, 2, 3, 3))
        p = quantize_ofs(w, float(rng.uniform(0.05, 3.0)), float(rng.uniform(0.0, 1.0)))
        wf, vth, lam = p.float_equivalent()
        p2 = quantize_ofs(wf, vth, lam)
        assert np.array_equal(p.weight, p2.weight)
        assert (p.vth_mant, p.dv, p.weight_scale) == (p2.vth_mant, p2.dv, pytest.approx(p.weight_scale))


def test_report_errors_are_bounded_by_half_a_step(rng):
    q = quantize_stages([stage(rng.normal(0, 0.2, (1, 2, 3, 3)), float(t), float(l))
                         for t, l in zip(rng.uniform(0.1, 2, 4), rng.uniform(0, 1, 4))])
    for p, r in zip(q.params, q.report):
        assert np.abs(p.weight).max() == WEIGHT_MAX             # full 8-bit range used
        assert r["weight_max_abs_error"] <= 0.5 / p.weight_scale + 1e-12
        assert r["weight_rel_error"] <= 0.5 / WEIGHT_MAX + 1e-12
        assert r["threshold_rel_error"] <= 0.5 / p.vth_mant + 1e-12
        assert r["leak_abs_error"] <= 0.5 / DECAY_UNITY + 1e-12
    assert q.warnings == []


def test_threshold_at_the_17_bit_edge_lowers_the_scale_and_warns():
    """A threshold/weight ratio beyond 2^17/127 cannot keep max |w| = 127: the scale drops."""
    big = 2000.0      # ratio 2000/0.2 = 10^4 > 131071/127
    q = quantize_stages([stage(threshold=big)])
    p = q.params[0]
    assert p.vth_mant == VTH_MANT_MAX
    assert np.abs(p.weight).max() < WEIGHT_MAX
    assert q.warnings and "stage1" in q.warnings[0] and "17 bits" in q.warnings[0]
    assert q.report[0]["clamps"]
    assert q.report[0]["threshold_rel_error"] < 1e-5


def test_leak_edges():
    q = quantize_stages([stage(leak=1.0), stage(leak=0.0)])
    assert q.params[0].dv == 0 and not q.report[0]["clamps"]
    assert q.params[1].dv == DECAY_UNITY - 1                       # 12-bit field: 4096 does not fit
    assert any("stage2" in w and "dv = 4095" in w for w in q.warnings)


@pytest.mark.parametrize("bad,what", [
    (stage(threshold=1e-6), "stage2.threshold"),                 # mantissa would round to 0
    (stage(w=np.zeros((1, 2, 3, 3))), "all weights are zero"),
    (stage(w=np.full((1, 2, 3, 3), np.nan)), "NaN"),
    (stage(threshold=-1.0), "must be > 0"),
    (stage(threshold=float("inf")), "not finite"),
])
def test_unrepresentable_stage_is_one_line_input_error(bad, what):
    with pytest.raises(InputError) as ei:
        quantize_stages([stage(), bad], source="ck/ofs.safetensors")
    msg = str(ei.value)
    assert msg.startswith("ck/ofs.safetensors: ") and "\n" not in msg and what in msg
    assert "stage2" in msg
