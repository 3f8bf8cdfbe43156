"""Counting rules (energy/rules.py), the block timer, and DOTIE's window objects."""
from __future__ import annotations

import math
import time

import pytest

from toffe_deploy.baselines.dotie import Detection
from toffe_deploy.baselines.registry import window_objects
from toffe_deploy.energy import rules
from toffe_deploy.energy.cost_model import HostOps, c
from toffe_deploy.energy.measure import block_ratio, time_blocks


def _work(synops=900.0, active=300.0, events=100):
    return rules.Work(frame_px=64 * 48, steps=5, channels=1, input_events=events,
                      layers=[rules.LayerWork(64 * 48, 5, 1, 3, synops, active)], morph=[(400, 12, 2)],
                      mask_event=events, mask_dense=5 * 64 * 48, post=HostOps(mac_fp32=1000))


def test_rules_price_the_same_work_by_their_definitions():
    w = _work()
    ev, de = rules.event_driven(w), rules.dense(w)
    # event rule: one int32 accumulate per synop, 1 mul + 3 adds per active update, 6 ops per event index
    assert ev.add_int32 == 900 + 3 * 300 + 6 * 100 and ev.mul_int32 == 300 and ev.mac_fp32 == 1000
    # dense rule: 9 MACs per neuron and step, plus 1 LIF MAC each, plus the network's
    assert de.mac_fp32 == 64 * 48 * 5 * 9 + 64 * 48 * 5 + 1000
    assert ev.op_int8 == 400 * 2 * 12 * 2 + 100 and de.op_int8 == 64 * 48 * 2 * 12 * 2 + 5 * 64 * 48
    # event-driven counts follow the activity; dense counts do not
    assert rules.dense(_work(synops=0, active=0)).mac_fp32 == de.mac_fp32
    assert rules.event_driven(_work(synops=0, active=0)).add_int32 < ev.add_int32


def test_energy_split_is_compute_plus_memory():
    ops = HostOps(add_int32=1e6, sram_bytes=8e6)
    e = rules.energy_split(ops)
    assert e["compute_uj"] == pytest.approx(1e6 * c("int32_add") * 1e-6)
    assert e["memory_uj"] == pytest.approx(1e6 * c("sram_read_64b") * 1e-6)
    assert e["total_uj"] == pytest.approx(e["compute_uj"] + e["memory_uj"])
    assert e["memory_dram_uj"] > 100 * e["memory_uj"]
    assert rules.time_power(2e-3, 42.6) == pytest.approx(85200.0)


def test_time_blocks_interleave_and_count_cpu_time():
    calls = []

    def busy(i):
        calls.append("busy")
        t = time.thread_time()              # its own thread's time: the process's also counts threads
        while time.thread_time() - t < 2e-4:    # that earlier tests left running, which made it spin
            pass                                # less than 2e-4 of its own (a flaky failure under load)

    def sleepy(i):
        calls.append("sleepy")
        time.sleep(2e-4)

    out = time_blocks({"busy": busy, "sleepy": sleepy}, 3, blocks=5, warmup=1)
    assert all(len(out[m][k]) == 5 for m in out for k in ("wall", "cpu", "thread"))
    # sleeping costs wall time, not CPU time; spinning costs both (the sleeper compared by its own
    # thread's CPU time: the process's also counts threads earlier tests of the suite left running)
    assert min(out["busy"]["cpu"]) >= 1.5e-4 and max(out["sleepy"]["thread"]) < min(out["busy"]["thread"])
    assert min(out["sleepy"]["wall"]) >= 1.5e-4
    timed = calls[2:]                           # after the warm-up: blocks alternate which model starts
    assert timed[:3] == ["busy"] * 3 and timed[6:9] == ["sleepy"] * 3
    r = block_ratio([2.0, 4.0, 6.0], [1.0, 1.0, 2.0])
    assert r == {"median": 3.0, "min": 2.0, "max": 4.0}


def test_window_objects_merge_overlapping_boxes_across_steps():
    a = Detection(0, 0, 10, 10, 5.0, 5.0, 10)
    b = Detection(8, 8, 20, 20, 14.0, 14.0, 30)       # overlaps a: one object
    far = Detection(40, 40, 50, 50, 45.0, 45.0, 5)
    objs = window_objects([[a], [], [b, far]])
    assert len(objs) == 2
    m = min(objs, key=lambda p: p.x)
    assert m.x == pytest.approx((5 * 10 + 14 * 30) / 40) and math.isnan(m.direction_rad) and m.stage == 0
