"""Idle subtraction and the noise rule of the dynamic energy, by hand-computed cases."""
from __future__ import annotations

import pytest

from toffe_deploy.energy.measure import (BELOW_NOISE, MEASURED, combine_idle, dynamic_energy, latency_percentiles,
                                         time_interleaved)


def test_idle_power_times_duration_is_subtracted_then_divided_by_k():
    # 10 J over 2 s with 3 W idle: 4 J dynamic over 4 inferences = 1 J each
    d = dynamic_energy(run_j=10.0, run_s=2.0, k=4, idle_w=3.0, idle_std_w=0.1, source="RAPL package-0")
    assert d.status == MEASURED and d.per_inference_j == pytest.approx(1.0)
    assert d.noise_per_inference_j == pytest.approx(2 * 0.1 * 2.0 / 4)
    assert d.source == "RAPL package-0"


def test_negative_dynamic_energy_is_below_noise_not_a_number():
    d = dynamic_energy(run_j=5.0, run_s=2.0, k=4, idle_w=3.0, idle_std_w=0.0)
    assert d.status == BELOW_NOISE and d.per_inference_j is None
    assert d.raw_per_inference_j == pytest.approx(-0.25)     # kept for the JSON


def test_dynamic_energy_within_idle_noise_is_below_noise():
    # raw 0.1 J per inference; idle spread 0.5 W over 2 s at 2 sigma = 2 J: below noise
    d = dynamic_energy(run_j=6.1, run_s=2.0, k=1, idle_w=3.0, idle_std_w=0.5)
    assert d.status == BELOW_NOISE and d.per_inference_j is None
    d = dynamic_energy(run_j=6.1, run_s=2.0, k=1, idle_w=3.0, idle_std_w=0.01)
    assert d.status == MEASURED and d.per_inference_j == pytest.approx(0.1)


def test_k_must_be_positive():
    with pytest.raises(ValueError):
        dynamic_energy(1.0, 1.0, 0, 0.0, 0.0)


def test_idle_before_and_after_are_pooled():
    idle = combine_idle([2.0, 2.2], [1.8, 2.0], seconds=4.0)
    assert idle.mean_w == pytest.approx(2.0) and idle.segments == 4
    assert idle.std_w == pytest.approx((0.08 / 3) ** 0.5)


def test_latency_percentiles_in_ms():
    lat = latency_percentiles([i * 1e-3 for i in range(1, 101)])      # 1..100 ms
    assert lat["p50_ms"] == pytest.approx(50.5) and lat["p90_ms"] == pytest.approx(90.1)
    assert lat["p99_ms"] == pytest.approx(99.01) and lat["n"] == 100 and lat["max_ms"] == pytest.approx(100.0)


def test_models_are_timed_in_turn_in_blocks_of_windows():
    calls = []
    fns = {m: (lambda i, m=m: calls.append((m, i))) for m in ("a", "b")}
    lat = time_interleaved(fns, n_items=5, warmup=1, repeats=2, block=2)
    assert {m: len(v) for m, v in lat.items()} == {"a": 10, "b": 10}      # every item, every pass, per model
    assert calls[:2] == [("a", 0), ("b", 0)]                                # warm-up
    # then per block: one untimed call, the block's items; model a, then b, on the same items
    assert calls[2:8] == [("a", 0), ("a", 0), ("a", 1), ("b", 0), ("b", 0), ("b", 1)]
    assert calls[-4:] == [("a", 4), ("a", 4), ("b", 4), ("b", 4)]          # the last block holds one item
    assert all(t >= 0 for v in lat.values() for t in v)
