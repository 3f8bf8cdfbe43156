"""The cost model's arithmetic: per-op constants times counts, Loihi 2 T_ts from per-core activity."""
from __future__ import annotations

import numpy as np
import pytest

from toffe_deploy.energy import cost_model as cm


def test_host_energy_is_counts_times_published_constants():
    ops = cm.HostOps(mac_fp32=1e6, add_fp32=2e6, add_int32=1e6, mul_int32=1e6, op_int8=1e6, sram_bytes=8e6)
    pj = 1e6 * 4.6 + 2e6 * 0.9 + 1e6 * 0.1 + 1e6 * 3.1 + 1e6 * 0.03 + 1e6 * 10.0
    assert ops.energy_j() == pytest.approx(pj * 1e-12)
    assert (ops + ops).energy_j() == pytest.approx(2 * ops.energy_j())
    assert cm.mean_ops([ops, cm.HostOps()]).mac_fp32 == 5e5


def test_op_counts_of_building_blocks():
    conv = cm.dense_conv_ops(h=4, w=5, c_in=2, c_out=1, k=3, steps=2)
    assert conv.mac_fp32 == 4 * 5 * 2 * 2 * 9
    assert cm.dense_lif_ops(10, steps=3).mac_fp32 == 30
    assert cm.morphology_ops(4, 5, kernel=5, passes=2).op_int8 == 4 * 5 * 2 * 2 * 5
    assert cm.dbscan_ops(0, 0).energy_j() == 0.0
    d = cm.dbscan_ops(100, 2000)
    assert d.mac_fp32 == 4000 and d.add_int32 == 2000
    assert cm.event_index_ops(1000).add_int32 == 6000 and cm.event_index_ops(1000).sram_bytes == 24000
    u = cm.sort_unique_ops(1024)                  # 1024 keys: 10 comparison levels
    assert u.add_int32 == 10240 and u.sram_bytes == 16 * 10240 and cm.sort_unique_ops(1).energy_j() == 0.0


def test_synop_count_is_exact_fan_in_with_zero_padding():
    s = np.zeros((2, 5, 5), bool)
    s[0, 2, 2] = True            # centre spike reaches 9 neurons
    s[1, 0, 0] = True            # corner spike reaches 4
    syn = cm.synop_count(s, 3)
    assert syn.sum() == 13 and syn[1, 1] == 2 and syn[2, 2] == 1 and syn[4, 4] == 0


def test_loihi_step_time_is_slowest_core_plus_barrier():
    n = 10_000                                   # two cores: 8192 + 1808 neurons
    act = cm.LoihiActivity(n)
    syn = np.zeros(n, np.int64)
    syn[9000] = 1000                             # all synaptic work on core 2
    active = np.zeros(n, bool)
    active[9000] = True
    spikes = active.copy()
    act.add_step(syn, active, spikes)
    core1 = 8192 * 5.3
    core2 = 1807 * 5.3 + 1 * 8.4 + 1000 * 3.5
    assert act.n_cores == 2
    assert act.t_ts_s()[0] == pytest.approx((max(core1, core2) + 465.0) * 1e-9)
    e = (1000 * 23.6 + 1 * 81.0 + (n - 1) * 52.0 + 1 * 1.7) * 1e-12
    assert act.energy_j() == pytest.approx(e)
    act.add_step(np.zeros(n), np.zeros(n, bool), np.zeros(n, bool))
    assert act.latency_s() == pytest.approx(sum(act.t_ts_s()))


def test_dotie_layer_model_lands_near_the_papers_loihi_figures():
    """DOTIE's single 640x480 layer, B = 5, silent: E = 307200 * 5 * 52 pJ, L = 5 * (8192 * 5.3 + 465) ns;
    the paper measured 0.083 mJ / 0.29 ms on Loihi 2."""
    act = cm.LoihiActivity(640 * 480)
    for _ in range(5):
        act.add_step(np.zeros(640 * 480), np.zeros(640 * 480, bool), np.zeros(640 * 480, bool))
    assert act.n_cores == 38
    assert act.energy_j() * 1e3 == pytest.approx(0.0799, rel=1e-3)
    assert act.latency_s() * 1e3 == pytest.approx(5 * (8192 * 5.3 + 465) * 1e-6)
    assert 0.8 < act.energy_j() * 1e3 / 0.083 < 1.2 and 0.5 < act.latency_s() * 1e3 / 0.29 < 1.0


def test_onnx_macs_counts_conv_and_gemm(tmp_path):
    import onnx
    from onnx import TensorProto, helper, numpy_helper

    w = numpy_helper.from_array(np.zeros((4, 2, 3, 3), np.float32), "w")
    fw = numpy_helper.from_array(np.zeros((256, 3), np.float32), "fw")
    shape = numpy_helper.from_array(np.array([-1, 256], np.int64), "shape")
    g = helper.make_graph(
        [helper.make_node("Conv", ["x", "w"], ["c"], pads=[1, 1, 1, 1]),
         helper.make_node("Reshape", ["c", "shape"], ["r"]),
         helper.make_node("MatMul", ["r", "fw"], ["y"])],
        "g", [helper.make_tensor_value_info("x", TensorProto.FLOAT, ["N", 2, 8, 8])],
        [helper.make_tensor_value_info("y", TensorProto.FLOAT, ["N", 3])], [w, fw, shape])
    path = tmp_path / "m.onnx"
    onnx.save(helper.make_model(g, opset_imports=[helper.make_opsetid("", 17)]), path)
    m = cm.onnx_macs(path)
    assert m["by_op"] == {"Conv": 4 * 8 * 8 * 2 * 9, "MatMul": 256 * 3}
    assert m["macs"] == 4608 + 768
    assert m["params"] == 4 * 2 * 9 + 256 * 3 + 2 and m["activations"] == 4 * 8 * 8 + 3


def test_every_constant_names_its_source():
    for name, const in cm.CONSTANTS.items():
        assert const.source and const.unit, name
    assert cm.HOST_LABEL.startswith("modelled") and cm.LOIHI_LABEL.startswith("modelled")


def test_loihi2_footprint_of_the_paper_sensor_needs_two_chips():
    from toffe_deploy.energy.cost_model import loihi2_footprint

    f = loihi2_footprint(640, 480, 4, 3)
    assert f["per_stage"] == {"neurons": 307_200, "synapses": 307_200 * 18, "shared_weights": 18, "cores": 38}
    assert (f["neurons"], f["cores"], f["chips"], f["fits_one_chip"]) == (1_228_800, 152, 2, False)
    assert f["max_pixels_one_chip"] == 262_144
    one = loihi2_footprint(512, 512, 4, 5)          # exactly 32 cores a stage: one chip
    assert (one["cores"], one["chips"], one["fits_one_chip"]) == (128, 1, True)
