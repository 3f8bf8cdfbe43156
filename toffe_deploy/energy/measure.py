"""Dynamic energy per inference from a counter, with the idle power measured in the same run.

The paper's definition (Results, "dynamic energy per inference"): subtract what the machine
draws when idle from what it draws while running the model only:

    E_dyn = (E_run - P_idle * T_run) / K

E_run: counter increase over K back-to-back inferences lasting T_run; P_idle: mean power over
idle intervals taken just before and just after the run (so slow drift cancels). The idle
intervals are cut into segments; the spread of their powers (sample standard deviation
sigma_idle) is the noise floor: a dynamic energy not above n_sigma * sigma_idle * T_run / K
(or negative) is reported as "below noise", never as a number.
"""
from __future__ import annotations

import gc
import math
import time
from dataclasses import asdict, dataclass
from typing import Callable

import numpy as np

from .readers import EnergyReader

BELOW_NOISE = "below noise"
MEASURED = "measured"


@dataclass(frozen=True)
class IdlePower:
    """Mean idle power (W) and the standard deviation across idle segments (W)."""

    mean_w: float
    std_w: float
    seconds: float
    segments: int


@dataclass(frozen=True)
class DynamicEnergy:
    """E_dyn = (run_j - idle_w * run_s) / k; ``per_inference_j`` is None when below noise."""

    source: str
    status: str                      # "measured" or "below noise"
    per_inference_j: float | None
    raw_per_inference_j: float       # the number before the noise test, kept for the JSON
    noise_per_inference_j: float
    run_j: float
    run_s: float
    k: int
    idle_w: float
    idle_std_w: float

    def to_dict(self) -> dict:
        return asdict(self)


def dynamic_energy(run_j: float, run_s: float, k: int, idle_w: float, idle_std_w: float, source: str = "",
                   n_sigma: float = 2.0) -> DynamicEnergy:
    """Pure arithmetic of the definition above (tested by hand-computed cases)."""
    if k <= 0:
        raise ValueError("k must be positive")
    raw = (run_j - idle_w * run_s) / k
    noise = n_sigma * idle_std_w * run_s / k
    below = (not math.isfinite(raw)) or raw <= 0.0 or raw <= noise
    return DynamicEnergy(source=source, status=BELOW_NOISE if below else MEASURED,
                         per_inference_j=None if below else raw, raw_per_inference_j=raw,
                         noise_per_inference_j=noise, run_j=run_j, run_s=run_s, k=k, idle_w=idle_w,
                         idle_std_w=idle_std_w)


def measure_idle(reader: EnergyReader, seconds: float, segments: int = 5,
                 sleep: Callable[[float], None] = time.sleep) -> list[float]:
    """Idle power of each of ``segments`` equal intervals (W). The process sleeps meanwhile."""
    seg = seconds / segments
    powers = []
    e0, t0 = reader.energy_j(), time.perf_counter()
    for _ in range(segments):
        sleep(seg)
        e1, t1 = reader.energy_j(), time.perf_counter()
        powers.append((e1 - e0) / max(t1 - t0, 1e-9))
        e0, t0 = e1, t1
    return powers


def combine_idle(*segment_lists: list[float], seconds: float = 0.0) -> IdlePower:
    p = np.concatenate([np.asarray(s, float) for s in segment_lists])
    std = float(p.std(ddof=1)) if p.size > 1 else 0.0
    return IdlePower(float(p.mean()), std, seconds, int(p.size))


def measure_dynamic(reader: EnergyReader, run_one: Callable[[int], None], n_items: int, min_run_s: float = 2.0,
                    idle_s: float = 2.0, n_sigma: float = 2.0, max_k: int = 100_000) -> DynamicEnergy:
    """Idle, then ``run_one(i % n_items)`` back to back for at least ``min_run_s``, then idle.

    Counters update every few ms (RAPL ~1 ms, NVML ~10-100 ms, INA3221 sampled at 10 ms), so a
    run of at least a couple of seconds keeps the quantization far below the signal.
    """
    before = measure_idle(reader, idle_s / 2)
    e0, t0 = reader.energy_j(), time.perf_counter()
    k = 0
    while True:
        run_one(k % n_items)
        k += 1
        if k >= max_k or time.perf_counter() - t0 >= min_run_s:
            break
    e1, t1 = reader.energy_j(), time.perf_counter()
    after = measure_idle(reader, idle_s / 2)
    idle = combine_idle(before, after, seconds=idle_s)
    return dynamic_energy(e1 - e0, t1 - t0, k, idle.mean_w, idle.std_w, reader.source, n_sigma)


def latency_percentiles(seconds: list[float] | np.ndarray) -> dict[str, float]:
    """p50/p90/p99/mean/min/max of per-inference wall times, in ms."""
    a = np.asarray(seconds, float) * 1e3
    if a.size == 0:
        return {}
    p50, p90, p99 = np.percentile(a, [50, 90, 99])
    return {"p50_ms": float(p50), "p90_ms": float(p90), "p99_ms": float(p99), "mean_ms": float(a.mean()),
            "min_ms": float(a.min()), "max_ms": float(a.max()), "n": int(a.size)}


def time_each(run_one: Callable[[int], None], n_items: int, warmup: int = 5, repeats: int = 1) -> list[float]:
    """Batch-1 wall time of each item (``repeats`` passes), after ``warmup`` untimed calls."""
    for i in range(min(warmup, max(n_items, 1) * 10)):
        run_one(i % n_items)
    out = []
    for _ in range(repeats):
        for i in range(n_items):
            t0 = time.perf_counter()
            run_one(i)
            out.append(time.perf_counter() - t0)
    return out


def time_interleaved(fns: dict[str, Callable[[int], None]], n_items: int, warmup: int = 5,
                     repeats: int = 1, block: int = 10) -> dict[str, list[float]]:
    """Batch-1 wall times of several models on the same items, taken in turn in short blocks:
    model A on items i..i+block-1, then B on the same items, ... so a shared machine's changing
    load hits every model alike and their same-run ratios stay fair, while each model runs on
    consecutive windows with its own working set in cache, as a deployed pipeline does (with
    block = 1, a small model is timed right after a large one has evicted its data, a state no
    deployment is in). Each model gets ``warmup`` untimed calls first, and one untimed call
    before each of its blocks (the first call after another model is the cold one). The garbage
    collector runs between blocks, not inside timed calls (as in ``timeit``)."""
    for fn in fns.values():
        for i in range(warmup):
            fn(i % n_items)
    block = max(int(block), 1)
    out: dict[str, list[float]] = {name: [] for name in fns}
    gc.collect()
    was_enabled = gc.isenabled()
    gc.disable()                 # as timeit does: no collector pauses inside the timed calls
    try:
        for _ in range(repeats):
            for start in range(0, n_items, block):
                items = range(start, min(start + block, n_items))
                for name, fn in fns.items():
                    fn(items[0])
                    for i in items:
                        t0 = time.perf_counter()
                        fn(i)
                        out[name].append(time.perf_counter() - t0)
                gc.collect()     # between blocks, untimed
    finally:
        if was_enabled:
            gc.enable()
    return out


def time_blocks(fns: dict[str, Callable[[int], None]], n_items: int, blocks: int = 5,
                warmup: int = 2) -> dict[str, dict[str, list[float]]]:
    """Wall and CPU time per item of several models, interleaved: in each of ``blocks`` blocks
    every model runs once over all items (A, B, C, then the next block starts one model later:
    B, C, A, ...), so the machine's load changes hit every model alike. Per model and block:
    the mean per item of wall time (perf_counter), process CPU time (process_time: all the
    process's threads) and thread CPU time (thread_time). Returns {name: {"wall": [...],
    "cpu": [...], "thread": [...]}} in seconds, one value per block."""
    for fn in fns.values():
        for i in range(warmup):
            fn(i % n_items)
    names = list(fns)
    out = {n: {"wall": [], "cpu": [], "thread": []} for n in names}
    was_enabled = gc.isenabled()
    gc.collect()
    gc.disable()
    try:
        for b in range(max(int(blocks), 1)):
            for name in names[b % len(names):] + names[:b % len(names)]:
                fn = fns[name]
                w0, c0, t0 = time.perf_counter(), time.process_time(), time.thread_time()
                for i in range(n_items):
                    fn(i)
                out[name]["wall"].append((time.perf_counter() - w0) / n_items)
                out[name]["cpu"].append((time.process_time() - c0) / n_items)
                out[name]["thread"].append((time.thread_time() - t0) / n_items)
                gc.collect()
    finally:
        if was_enabled:
            gc.enable()
    return out


def block_summary(values: list[float]) -> dict[str, float]:
    """median, min, max (ms) of per-block times in seconds."""
    a = np.asarray(values, float) * 1e3
    return {"median_ms": float(np.median(a)), "min_ms": float(a.min()), "max_ms": float(a.max()), "blocks": int(a.size)}


def block_ratio(num: list[float], den: list[float]) -> dict[str, float]:
    """The ratio num / den block by block (same block: same load), as median and min-max."""
    r = np.asarray(num, float) / np.maximum(np.asarray(den, float), 1e-12)
    return {"median": float(np.median(r)), "min": float(r.min()), "max": float(r.max())}
