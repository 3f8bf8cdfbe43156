"""Benchmark of the Lava OFS cascade (loihi-sim target): windows/s, startup, peak memory.

Streams synthetic windows (a few square objects at different speeds, sensor noise) through
``toffe_deploy.runtime.loihi.LavaCascade`` and reports

  * startup_s: build + compile + start of the Lava network (paid once per run),
  * first_result_s: from the first window sent to its result (pipeline latency, N windows),
  * windows_per_s and per-window wall time percentiles in steady state,
  * peak memory: PSS of the host and every Lava process plus the /dev/shm segments of Lava's
    channels (every page counted once, sampled every 0.1 s),
  * bit-exactness: every ``--check-every``-th window is compared with the numpy reference
    ``run_cascade(..., run_ofs_fixed)`` after the timed loop; ``mismatched_bytes``: the bytes
    of the bit-packed arrays (8 cells each) that differ (0: bit-exact),
  * device: this machine (CPU model and cores, as bench_run.py describes it) and the simulator.

Memory figures are MiB (2**20 bytes).

Simulator wall time is not Loihi latency. Example (the figures in the report):

    nice -n 10 .venv/bin/python benchmarks/bench_lava.py --windows 200
"""
from __future__ import annotations

import json
import os
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from tqdm import tqdm

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from toffe_deploy.cascade import run_cascade  # noqa: E402
from toffe_deploy.commands import add_progress_flag, show_progress  # noqa: E402
from toffe_deploy.fileio import atomic_path  # noqa: E402
from toffe_deploy.fixed_point import quantize_ofs, run_ofs_fixed  # noqa: E402
from toffe_deploy.runtime.loihi import LavaCascade  # noqa: E402
from _args import OneLineParser, guarded, int_in, json_output, nonneg_int, positive_int  # noqa: E402
from bench_run import machine  # noqa: E402
from peak_memory import pss_without_shm  # noqa: E402


@dataclass(frozen=True)
class SparseWindow:
    """A binary (B, C, H, W) window as the unique flat indices of its ones (SpikeVolume-like)."""

    idx: np.ndarray
    shape: tuple[int, int, int, int]

    def to_dense(self) -> np.ndarray:
        out = np.zeros(int(np.prod(self.shape)), np.uint8)
        out[self.idx] = 1
        return out.reshape(self.shape)


def synthetic_windows(n: int, width: int, height: int, n_bins: int, seed: int = 0,
                      noise_per_window: int = 300) -> list[SparseWindow]:
    """n windows of 4 squares moving right at 0.5, 2, 5 and 10 px per bin plus noise.

    Each bin's events are the squares' leading (ON) and trailing (OFF) edges swept in that bin,
    each pixel kept with probability 0.7, as an event camera sees a textureless object.
    """
    rng = np.random.default_rng(seed)
    objects = [(40, 0.5, 60), (130, 2.0, 40), (250, 5.0, 50), (360, 10.0, 30)]   # (y, px/bin, size)
    objects = [(int(y * height / 480), v, max(4, int(s * height / 480))) for y, v, s in objects]
    out = []
    for i in range(n):
        idx = []
        for b in range(n_bins):
            step = i * n_bins + b
            for y0, v, size in objects:
                span = width - size - 1
                x_prev = int(round((step * v) % span))
                x_now = int(round(((step + 1) * v) % span))
                if x_now < x_prev:                     # wrapped around: no sweep this bin
                    continue
                for c, (a, z) in ((1, (x_prev + size, x_now + size)), (0, (x_prev, x_now))):
                    if z <= a:
                        continue
                    yy, xx = np.mgrid[y0:y0 + size, a:z]
                    keep = rng.random(yy.shape) < 0.7
                    idx.append((((b * 2 + c) * height + yy[keep]) * width + xx[keep]).astype(np.int64))
        idx.append(rng.integers(0, n_bins * 2 * height * width, noise_per_window))
        out.append(SparseWindow(np.unique(np.concatenate(idx)), (n_bins, 2, height, width)))
    return out


def dotie_params(n_stages: int):
    """DOTIE's hand-set kernel on both polarities; thresholds rise with the speed bin."""
    w = np.full((1, 2, 3, 3), 0.15)
    w[..., 1, 1] = 0.2
    return [quantize_ofs(w, 0.5 + 0.2 * k, 0.3) for k in range(n_stages)]


def _shm_bytes(names: list[str]) -> int:
    total = 0
    for n in names:
        try:
            total += os.stat(os.path.join("/dev/shm", n)).st_blocks * 512
        except FileNotFoundError:
            pass
    return total


class MemorySampler(threading.Thread):
    """Peak of (PSS of host + Lava processes, without shm) + (/dev/shm of Lava's channels)."""

    def __init__(self, interval: float = 0.1):
        super().__init__(daemon=True)
        self.interval = interval
        self.pids: list[int] = []
        self.shm: list[str] = []
        self.peak = 0
        self.peak_shm = 0
        self._halt = threading.Event()

    def sample(self) -> None:
        rss = pss_without_shm(os.getpid()) + sum(pss_without_shm(p) for p in self.pids)
        shm = _shm_bytes(self.shm)
        self.peak = max(self.peak, rss + shm)
        self.peak_shm = max(self.peak_shm, shm)

    def run(self) -> None:
        while not self._halt.wait(self.interval):
            self.sample()

    def stop(self) -> None:
        self._halt.set()
        self.join()
        self.sample()


def main(argv=None) -> int:
    ap = OneLineParser(prog="bench_lava.py", description=__doc__.split("\n\n")[0])
    ap.add_argument("--width", type=int_in(16, 4096), default=640, help="sensor width in pixels (default 640)")
    ap.add_argument("--height", type=int_in(16, 4096), default=480, help="sensor height in pixels (default 480)")
    ap.add_argument("--bins", type=positive_int, default=5, help="time bins per window, the paper's B (default 5)")
    ap.add_argument("--stages", type=positive_int, default=4, help="OFS stages = speed bins N (default 4)")
    ap.add_argument("--windows", type=positive_int, default=200, help="windows to stream (default 200)")
    ap.add_argument("--distinct", type=positive_int, default=50, help="distinct synthetic windows, cycled (default 50)")
    ap.add_argument("--tag", default="fixed_pt", choices=["fixed_pt", "floating_pt"], help="Lava model tag")
    ap.add_argument("--dense", action="store_true", help="feed dense (B, 2, H, W) arrays instead of sparse volumes")
    ap.add_argument("--check-every", type=nonneg_int, default=10,
                    help="compare every n-th window with the numpy reference (0: never; default 10)")
    ap.add_argument("--out", type=json_output, default=ROOT / "benchmarks" / "results" / "lava.json",
                    help="JSON results file (default benchmarks/results/lava.json)")
    add_progress_flag(ap)
    args = ap.parse_args(argv)
    return guarded("bench_lava", run, args)


def run(args) -> int:
    from toffe_deploy.fileio import check_outputs

    check_outputs(files=[("--out", args.out)])

    distinct = synthetic_windows(min(args.distinct, args.windows), args.width, args.height, args.bins)
    params = dotie_params(args.stages)

    def feed():
        for i in range(args.windows):
            w = distinct[i % len(distinct)]
            yield w.to_dense() if args.dense else w

    mem = MemorySampler()
    mem.start()
    checked: dict[int, object] = {}
    times = []
    t_start = time.perf_counter()
    with LavaCascade(params, n_bins=args.bins, mask_kernel=5, sensor_size=(args.width, args.height),
                     tag=args.tag) as lc:
        startup = time.perf_counter() - t_start
        mem.pids, mem.shm = list(lc.child_pids), list(lc.shm_names)
        t0 = time.perf_counter()
        last = t0
        for i, res in enumerate(tqdm(lc.cascade_stream(feed()), total=args.windows, unit="win",
                                     file=sys.stderr, desc="lava cascade",
                                     disable=not show_progress(args))):
            now = time.perf_counter()
            times.append(now - last)
            last = now
            if args.check_every and i % args.check_every == 0:   # kept packed: memory is measured
                checked[i] = {f: [np.packbits(a) for a in getattr(res, f)]
                              for f in ("inputs", "spikes", "closed", "frames")}
        t_end = time.perf_counter()
    mem.stop()
    n = len(times)
    steady = np.array(times[args.stages:]) if n > args.stages else np.array(times)
    spikes = [int(s.sum()) for s in res.spikes]
    mismatches = 0            # differing bytes of the bit-packed arrays
    for i, res in checked.items():
        x = distinct[i % len(distinct)].to_dense()
        ref = run_cascade(x, lambda k, inp: run_ofs_fixed(inp, params[k - 1]), args.stages, 5)
        for f in ("inputs", "spikes", "closed", "frames"):
            mismatches += sum(int(np.count_nonzero(np.packbits(a) != b)) for a, b in zip(getattr(ref, f), res[f]))
    m = machine()
    result = {
        "device": f"{m['cpu']}, {m['cores']} cores, Lava simulator (Loihi2SimCfg)", "tag": args.tag,
        "sensor_size": [args.width, args.height], "n_bins": args.bins, "n_stages": args.stages,
        "windows": n, "input": "dense" if args.dense else "sparse",
        "events_per_window_mean": float(np.mean([len(w.idx) for w in distinct])),
        "startup_s": round(startup, 3), "first_result_s": round(times[0], 3) if times else None,
        "windows_per_s": round(len(steady) / float(steady.sum()), 2) if len(steady) else None,
        "overall_windows_per_s": round(n / (t_end - t0), 2),
        "window_ms_p50_p90_p99": [round(float(np.percentile(steady, q)) * 1e3, 2) for q in (50, 90, 99)],
        "peak_memory_mb": round(mem.peak / 2**20, 1), "peak_shm_mb": round(mem.peak_shm / 2**20, 1),
        "shm_allocated_mb": round(lc.shm_bytes / 2**20, 1),
        "checked_windows": len(checked), "mismatched_bytes": mismatches,
        "last_window_spikes_per_stage": spikes,
    }
    with atomic_path(args.out) as tmp:
        tmp.write_text(json.dumps(result, indent=2) + "\n")
    print(json.dumps(result, indent=2))
    return 0 if mismatches == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
