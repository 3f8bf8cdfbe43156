#!/usr/bin/env python
"""Energy and latency per inference, TOFFE against DOTIE, on every target (issue 5; paper Table 2).

    python benchmarks/energy_latency.py                 # full size: export/ bundle, 640x480, B = 5
    python benchmarks/energy_latency.py --quick         # a small run CI can afford

One inference = one window of B bins through the whole model, batch 1, from the window's events
to the model's output. For every model (TOFFE through the deployed ``Pipeline``; DOTIE without
clustering; DOTIE with clustering, DBSCAN on every step's separated events as in its public
code; and, for comparison, DOTIE with one DBSCAN per window) and target (cpu, cuda, loihi-sim,
loihi2; each where available) on the same input windows, timed in turn in blocks of --block
windows:

* latency L: wall-time percentiles p50/p90/p99 after warm-up on host targets; on the hybrid,
  the Loihi 2 part is L = sum_t T_ts (T_ts modelled from the activity counted in the
  simulation) plus the host part measured here; Lava simulator wall time is reported as such;
* dynamic energy E = (E_run - P_idle * T_run) / K from a counter (RAPL, NVML, Jetson INA3221)
  with idle measured in the same run, else modelled from counted operations; every row says
  which ("measured (source)", "below noise (source)", "modelled (constants ...)").

On cpu, the like-for-like table (issue 14) comes first: every model of
toffe_deploy/baselines/registry.py at both optimisation levels (reference: plain numpy /
OpenCV / scikit-learn; optimised: compiled, event driven), timed in --blocks interleaved blocks
(CPU time beside wall time, median and min-max), priced by the same counting rules
(energy/rules.py: event-driven and dense, compute and memory apart; time x --power-w), with
quality (recall, pixE, dirE, speedE by eval's gated matching) on the same windows; ratios only
within one level. --dotie-code also scores DOTIE as its code runs (2 ms bins, carried membrane).

Writes energy_latency.{md,json,png} to --out (default benchmarks/results/, --quick:
benchmarks/results/quick/) and prints the markdown table.
"""
from __future__ import annotations

import argparse
import contextlib
import copy
import datetime as _dt
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:          # runnable from a fresh clone without installing
    sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from _args import OneLineParser, nonneg_float, nonneg_int, positive_float  # noqa: E402
from toffe_deploy.commands import add_progress_flag, show_progress  # noqa: E402
from toffe_deploy.errors import InputError, ToffeError  # noqa: E402

DEFAULT_BUNDLE = ROOT / "export"
DEFAULT_OUT = ROOT / "benchmarks" / "results"
SAMPLE = ROOT / "toffe_deploy" / "samples" / "sample_multi.h5"

FULL = dict(windows=60, warmup=10, repeats=3, count_windows=30, sim_windows=4, energy_s=3.0, idle_s=2.0)
QUICK = dict(windows=6, warmup=2, repeats=1, count_windows=3, sim_windows=0, energy_s=0.3, idle_s=0.3)


def parse_args(argv=None) -> argparse.Namespace:
    ap = OneLineParser(prog="energy_latency.py", description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--bundle", default=str(DEFAULT_BUNDLE),
                    help="deploy bundle directory (default: export/; make it with `toffe-deploy export ckpt/`)")
    src = ap.add_mutually_exclusive_group()
    src.add_argument("--events", help="event recording to cut windows from (any format toffe-deploy reads; "
                                      "default: the shipped sample, else --synthetic)")
    src.add_argument("--synthetic", metavar="SEED", type=int,
                     help="generate a multi-object sequence (data-set generator, split 'multi', this seed) as input")
    add_progress_flag(ap)
    ap.add_argument("--targets", default="cpu,cuda,loihi-sim,loihi2",
                    help="comma-separated targets to try; unavailable ones are reported as n/a (default: all)")
    ap.add_argument("--quick", action="store_true",
                    help="small run for CI: few windows, short energy runs, no Lava simulation unless --sim-windows")
    ap.add_argument("--windows", type=int, help=f"distinct input windows timed (default {FULL['windows']}, quick {QUICK['windows']})")
    ap.add_argument("--warmup", type=nonneg_int, help=f"untimed warm-up inferences per model and target (default {FULL['warmup']})")
    ap.add_argument("--repeats", type=int, help=f"timed passes over the windows (default {FULL['repeats']})")
    ap.add_argument("--block", type=int, default=10,
                    help="models are timed in turn in blocks of this many consecutive windows (default 10; "
                         "1 = window by window, each model right after another evicted its data from cache)")
    ap.add_argument("--count-windows", type=int,
                    help=f"windows whose operations are counted for the models (default {FULL['count_windows']})")
    ap.add_argument("--sim-windows", type=int,
                    help=f"windows run through the Lava simulator for its wall time (default {FULL['sim_windows']}, quick 0)")
    ap.add_argument("--energy-s", type=positive_float, help="minimum run length (s) of each counter measurement (default 3)")
    ap.add_argument("--idle-s", type=nonneg_float, help="idle time (s) measured around each counter measurement (default 2)")
    ap.add_argument("--blocks", type=int, default=5,
                    help="like-for-like timing: interleaved blocks, each a pass of every model over the windows "
                         "(default 5; median and min-max over blocks are reported)")
    ap.add_argument("--dotie-code", action="store_true",
                    help="also run DOTIE as its own code does (2 ms bins, membrane carried across the stream) "
                         "for its quality; the comparison with TOFFE stays per window (baselines/dotie.py)")
    ap.add_argument("--power-w", type=float, default=None,
                    help="stated power (W) for the time x power energy (default 42.6 W, the power implied by "
                         "the paper's i9 TOFFE row)")
    ap.add_argument("--min-events", type=nonneg_int, default=1, help="skip windows with fewer events (default 1)")
    ap.add_argument("--sysfs-root", default="/sys", help="where to look for RAPL/INA3221 counters (default /sys)")
    ap.add_argument("--out", help="output directory (default benchmarks/results/, quick: benchmarks/results/quick/)")
    args = ap.parse_args(argv)
    base = QUICK if args.quick else FULL
    for k, v in base.items():
        if getattr(args, k) is None:
            setattr(args, k, v)
    if args.out is None:
        args.out = str(DEFAULT_OUT / "quick") if args.quick else str(DEFAULT_OUT)
    for k in ("windows", "repeats", "count_windows", "block", "blocks"):
        if getattr(args, k) < 1:
            ap.error(f"--{k.replace('_', '-')} must be >= 1")
    if args.sim_windows < 0:
        ap.error("--sim-windows must be >= 0")
    if args.power_w is not None and not 0 < args.power_w < float("inf"):     # NaN made the JSON invalid
        ap.error(f"--power-w must be a positive number of watts, got {args.power_w}")
    if args.synthetic is not None and args.synthetic < 0:
        ap.error(f"--synthetic must be a seed >= 0, got {args.synthetic}")
    args.targets = [t.strip() for t in args.targets.split(",") if t.strip()]
    known = ("cpu", "cuda", "loihi-sim", "loihi2")
    unknown = [t for t in args.targets if t not in known]
    if unknown or not args.targets:
        ap.error(f"--targets: {', '.join(unknown) or 'none given'} (known: {', '.join(known)})")
    return args


def log(msg: str) -> None:
    print(f"[energy_latency] {msg}", file=sys.stderr, flush=True)


# ------------------------------------------------------------------------------------- inputs
def load_bundle_or_explain(path: str):
    from toffe_deploy.deploy.bundle import is_bundle_dir, load_bundle

    p = Path(path)
    if not p.exists() or not is_bundle_dir(p):
        raise InputError(p, "no deploy bundle here; run `toffe-deploy export ckpt/` first (or pass --bundle DIR)")
    return load_bundle(p)


def load_windows(args, config) -> tuple[list[tuple[int, np.ndarray]], list[np.ndarray], dict]:
    """The first ``args.windows`` windows with events: (t0, binned (B, 2, H, W)) and each
    window's events; the input's ground truth (runtime.truth.TruthIndex, or None) and camera
    focal length go to ``args.truth`` / ``args.focal_px`` for the quality columns. Timed runs start from the events (each model builds its own input, as
    ``toffe-deploy run`` does); the binned copies feed the op counting and the Lava simulator."""
    import copy

    from toffe_deploy.events.binning import bin_window, window_slice
    from toffe_deploy.events.support import SupportHistory, front_end, window_pixels
    from toffe_deploy.plane_fit import history_settings
    from toffe_deploy.time_surface import OnesHistory

    dt, b, size = config.dt_us, config.n_bins, tuple(config.sensor_size)
    out: list[tuple[int, np.ndarray]] = []
    events: list[np.ndarray] = []
    counts: list[int] = []
    # input_support: every window read goes into the history; args.supports[i]: window i's (registry.BenchContext)
    hist = SupportHistory(config.input_support[0], size, dt) if config.input_support is not None else None
    args.supports = []
    # plane_fit_history: every window's front-end ones go into the ring; args.ones[i]: the ring before window i
    h = history_settings(config)
    ring = OnesHistory(h[1], size, b, dt) if h is not None else None
    args.ones = []

    def take(t0, ev) -> bool:
        if len(ev) < args.min_events:
            if ring is not None:
                ring.push(t0, np.flatnonzero(front_end(bin_window(ev, t0, dt, b, size), config, hist, int(t0))))
            elif hist is not None:
                hist.push(t0, window_pixels(ev, t0, dt, size))
            return False
        if hist is not None:
            hist.advance(t0)
            args.supports.append(copy.deepcopy(hist))
        if ring is not None:
            args.ones.append(copy.deepcopy(ring))
        # the counts the network sees: through the bundle's input front end (events/support.py's front_end)
        out.append((int(t0), front_end(bin_window(ev, t0, dt, b, size), config, hist, int(t0)).astype(np.uint8)))
        if ring is not None:
            ring.push(t0, np.flatnonzero(out[-1][1]))
        events.append(np.array(ev))
        counts.append(len(ev))
        return len(out) >= args.windows

    if args.synthetic is None and args.events is None and not SAMPLE.exists():
        log(f"no --events and no shipped sample at {SAMPLE}: generating a multi-object sequence (seed 0)")
        args.synthetic = 0
    if args.synthetic is not None:
        from toffe_deploy.dataset.splits import split_specs
        from toffe_deploy.dataset.synth import generate_sequence

        spec = split_specs("multi", seed=args.synthetic, duration_s=(args.windows + 4) * dt * 1e-6)[0]
        ev, gt, gen_size = generate_sequence(spec, seed=args.synthetic)
        args.truth, args.focal_px = _truth_index(gt), None
        if tuple(gen_size) != size:
            raise ToffeError(f"the generator makes {gen_size[0]}x{gen_size[1]} windows but the bundle expects "
                             f"{size[0]}x{size[1]}; pass --events FILE at the bundle's sensor size")
        desc = {"source": f"synthetic: data-set generator split 'multi' sequence {spec.name}, seed {args.synthetic}",
                "objects": len(spec.objects)}
        t_end = int(ev["t"][-1]) + 1 if len(ev) else 0
        for t0 in range(int(ev["t"][0]) if len(ev) else 0, t_end, dt):
            if take(t0, window_slice(ev, t0, dt)):
                break
    else:
        from toffe_deploy.events.io import open_events

        path = Path(args.events) if args.events else SAMPLE
        src = open_events(path)
        if tuple(src.sensor_size) != size:
            raise InputError(path, f"sensor size {src.sensor_size[0]}x{src.sensor_size[1]} differs from the bundle's "
                                   f"{size[0]}x{size[1]}")
        desc = {"source": str(path)}
        from toffe_deploy.runtime.truth import sequence_focal_px

        args.truth, args.focal_px = _truth_index(src.ground_truth), sequence_focal_px(src.attrs)
        for t0, ev in src.iter_windows(dt):
            if take(t0, ev):
                break
    if not out:
        raise ToffeError(f"{desc['source']}: no window of {dt} us with at least {args.min_events} events")
    c = np.asarray(counts)
    desc.update({"sensor_size": list(size), "n_bins": b, "dt_us": dt, "windows": len(out),
                 "events_per_window": {"mean": float(c.mean()), "p50": float(np.median(c)), "max": int(c.max())}})
    return out, events, desc


def pipeline_objects(pipe, i: int, windows, events, args) -> list:
    """The objects the Pipeline reports for window i (untimed). With input_support it gets the raw
    window and the windows before it (load_windows' args.supports): its front end is not
    idempotent; without, the front end's window (which it is). With plane_fit_history it gets
    the plane fit's windows before it too (args.ones)."""
    import copy

    if args.ones:
        pipe.ones_history = copy.deepcopy(args.ones[i])    # the plane fit's windows before (plane_fit_history)
    if not args.supports:
        return list(pipe.process_stream([windows[i]]))[0].objects

    from toffe_deploy.events.binning import bin_window

    cfg, t0 = pipe.config, windows[i][0]
    pipe.support = copy.deepcopy(args.supports[i])
    raw = bin_window(events[i], t0, cfg.dt_us, cfg.n_bins, pipe.sensor_size)
    return list(pipe.process_stream([(t0, raw)]))[0].objects


def _truth_index(gt):
    if gt is None or not len(gt.get("t", [])):
        return None
    from toffe_deploy.runtime.truth import TruthIndex

    return TruthIndex(gt)


# ------------------------------------------------------------------------------------ timing
def stream_latencies(pipe, windows, warmup: int, repeats: int) -> list[float]:
    """Per-window latency through ``pipe.process_stream``: from the moment the pipeline takes a
    window from the input iterator to the moment its result comes out (batch 1, in order)."""
    n = len(windows)
    order = [i % n for i in range(warmup)] + [i for _ in range(repeats) for i in range(n)]
    taken: dict[int, float] = {}

    def feed():
        for j, i in enumerate(order):
            taken[j] = time.perf_counter()
            yield windows[i]

    lat = []
    for j, _res in enumerate(pipe.process_stream(feed())):
        t = time.perf_counter()
        if j >= warmup:
            lat.append(t - taken[j])
    return lat


class SumReader:
    """All counters found, summed (each reads a different device: CPU package, GPU, board)."""

    def __init__(self, readers):
        self.readers = readers
        self.source = " + ".join(r.source for r in readers)
        self.name = "+".join(r.name for r in readers)

    def energy_j(self) -> float:
        return sum(r.energy_j() for r in self.readers)


# -------------------------------------------------------------------------------------- main
def run(args) -> int:
    """_run with torch on one thread for the whole run, restored after (deploy.parity.torch_threads).
    Every timed model runs on one thread (onnxruntime sessions and numba are set so); torch, the
    Adaptive-SpikeNet reference's runtime, otherwise takes every core (2 here), and its thread
    count cannot be switched per call: its pool's idle thread then spins, counted as CPU time. A
    review measured that row at 1,559 ms a window under load against ~40 ms on one thread (CPU
    59.5 against 41.6 ms wall when unloaded)."""
    try:
        import torch  # noqa: F401
    except ImportError:          # no torch: no Adaptive-SpikeNet row either
        return _run(args)
    from toffe_deploy.deploy.parity import torch_threads

    with torch_threads(1):
        return _run(args)


def _run(args) -> int:
    from toffe_deploy.energy.readers import discover

    t_start = time.perf_counter()
    if "loihi-sim" in args.targets and args.sim_windows > 0:
        preload_lava()
    bundle = load_bundle_or_explain(args.bundle)
    cfg = bundle.config
    windows, events, input_desc = load_windows(args, cfg)
    n = len(windows)
    log(f"{n} windows {cfg.sensor_size[0]}x{cfg.sensor_size[1]}, B={cfg.n_bins}, dt={cfg.dt_us} us, "
        f"{input_desc['events_per_window']['mean']:.0f} events/window; bundle {bundle.root}")
    disc = discover(args.sysfs_root)
    try:
        with contextlib.ExitStack() as stack:
            return _measure_all(args, bundle, windows, events, input_desc, disc, t_start, stack)
    finally:
        disc.close()


def preload_lava() -> None:
    """Lava sets the multiprocessing start method when first imported; a tqdm bar made earlier
    fixes the default context first and Lava's import then fails. Import it before any bar."""
    try:
        import lava.magma.core.process.process  # noqa: F401
    except ImportError:
        pass                     # reported by the loihi-sim row (the adapter says what is missing)


def _measure_all(args, bundle, windows, events, input_desc, disc, t_start, stack: contextlib.ExitStack) -> int:
    from tqdm import tqdm

    from toffe_deploy.baselines.dotie import (DotieParams, dotie_detect_window, dotie_detect_x, dotie_frames,
                                              dotie_separate_x)
    from toffe_deploy.runtime.spikes import SpikeVolume
    from toffe_deploy.energy import cost_model as cm
    from toffe_deploy.energy import report
    from toffe_deploy.energy.activity import count_dotie, count_toffe
    from toffe_deploy.energy.cost_model import mean_ops
    from toffe_deploy.energy.machine import describe_machine, short_name
    from toffe_deploy.energy.measure import latency_percentiles, measure_dynamic, time_interleaved
    from toffe_deploy.fileio import atomic_path
    from toffe_deploy.ofpd_io import input_shape

    cfg = bundle.config
    n = len(windows)
    reader = SumReader(disc.readers) if disc.readers else None
    log("energy counters: " + (reader.source if reader else "none readable -> modelled energy only"))
    machine = describe_machine(disc.describe())
    p = DotieParams()
    rows: list[dict] = []
    from toffe_deploy.events.binning import bin_window

    def raw_window(i):
        """Window i's (B, 2, H, W) counts of its own events, before any front end: what DOTIE's
        code bins (as its timed and scored runs do, baselines/registry.py) and what TOFFE's binning
        and front end start from (windows[i][1] is TOFFE's input after its front end)."""
        return bin_window(events[i], windows[i][0], cfg.dt_us, cfg.n_bins, tuple(cfg.sensor_size))

    def energy_fields(run_one, model_mj: float, label: str) -> dict:
        """Headline energy: a counter measurement when there is a counter, else the model."""
        f = {"E_model_mj": model_mj, "E_model_kind": label}
        if reader is None:
            f.update(E_mj=model_mj, E_kind=label)
            return f
        dyn = measure_dynamic(reader, run_one, n, min_run_s=args.energy_s, idle_s=args.idle_s)
        f["energy_measured"] = dyn.to_dict()
        if dyn.per_inference_j is None:
            f.update(E_mj=None, E_kind=f"below noise ({dyn.source})")
        else:
            f.update(E_mj=dyn.per_inference_j * 1e3, E_kind=f"measured ({dyn.source})")
        return f

    pipes = {}                              # entered on ``stack``: the caller stops them on any exit
    for target in ("cpu", "cuda"):
        if target not in args.targets:
            continue
        try:
            from toffe_deploy.runtime.pipeline import Pipeline

            pipes[target] = stack.enter_context(Pipeline(bundle, target))
        except (ToffeError, ImportError, RuntimeError, ValueError) as exc:
            rows.append({"model": "toffe", "target": target, "status": "unavailable", "reason": str(exc)})
    cpu_pipe = pipes.get("cpu")
    # the Loihi target's host part (closing, masking, grouping, OFPD) runs on this CPU whether or
    # not the cpu target's own row was asked for: without it TOFFE's Loihi latency lost its host
    # part while DOTIE-with-clustering's kept its own (unlike counting)
    host_pipe = cpu_pipe
    if host_pipe is None and "loihi-sim" in args.targets:
        try:
            from toffe_deploy.runtime.pipeline import Pipeline

            host_pipe = stack.enter_context(Pipeline(bundle, "cpu"))
        except (ToffeError, ImportError, RuntimeError, ValueError) as exc:
            log(f"loihi-sim: the host part cannot run on the cpu pipeline ({exc}); its latency is left out")
    # ---- counting pass (untimed): operations and Loihi activity per model ----------------------
    n_count = min(args.count_windows, n)
    try:
        macs = cm.onnx_macs(bundle.ofpd_onnx)
    except Exception as exc:   # an ONNX graph we cannot count: say so, do not guess
        raise ToffeError(f"{bundle.ofpd_onnx}: cannot count OFPD MACs ({exc})") from None
    in_elems = int(np.prod(input_shape(cfg)))
    toffe_counts, dotie_counts, dotie_cl_counts, dotie_win_counts, cascades, dotie_spikes = [], [], [], [], [], []
    host_states = []          # (ones history, front-end history) after window i: what the Loihi row's host part reads
    for i in tqdm(range(n_count), desc="counting operations", file=sys.stderr, leave=False,
                  disable=not show_progress(args)):
        binned = windows[i][1]
        # OFPD rows = the objects the deployed pipeline reports for this window (untimed run)
        objs_i = pipeline_objects(host_pipe, i, windows, events, args) if host_pipe is not None else None
        if host_pipe is not None:
            host_states.append((copy.deepcopy(host_pipe.ones_history), copy.deepcopy(host_pipe.support)))
        raw = raw_window(i)
        res, mc = count_toffe(binned, list(bundle.ofs), cfg, macs["macs"], in_elems, macs["params"],
                              macs["activations"], ofpd_rows=None if objs_i is None else len(objs_i),
                              raw=raw, objects=objs_i)   # the raw window: binning and front end
        toffe_counts.append(mc)
        cascades.append(res)
        plain, clus, window, spikes = count_dotie(raw, p)
        dotie_counts.append(plain)
        dotie_cl_counts.append(clus)
        dotie_win_counts.append(window)
        dotie_spikes.append(spikes)

    def host_model(counts, attr="host_all"):
        ops = mean_ops(getattr(c, attr) for c in counts)
        return ops, ops.energy_j() * 1e3

    def loihi_model(counts) -> dict:
        n_layers = len(counts[0].loihi)
        stages = []
        for k in range(n_layers):
            acts = [c.loihi[k] for c in counts]
            summ = [a.summary() for a in acts]
            keys = ("synops", "active_updates", "inactive_updates", "spikes", "t_ts_mean_us", "latency_ms", "energy_mj")
            st = {key: float(np.mean([s[key] for s in summ])) for key in keys}
            st.update(neurons=acts[0].n_neurons, cores=acts[0].n_cores, steps=acts[0].steps)
            stages.append(st)
        return {"stages": stages, "steps_per_stage": cfg.n_bins, "energy_mj": sum(s["energy_mj"] for s in stages),
                "latency_ms": sum(s["latency_ms"] for s in stages), "label": cm.LOIHI_LABEL,
                "cores_total": sum(s["cores"] for s in stages),
                "chips_needed": int(np.ceil(sum(s["cores"] for s in stages) / cm.c("loihi2_cores_per_chip")))}

    # ---- like for like (issue 14): both levels, same rules, CPU time, quality -----------------
    lfl = None
    if "cpu" in args.targets:
        from toffe_deploy.baselines.registry import BenchContext

        ctx = BenchContext(windows=windows, events=events, bundle=bundle, config=cfg, pipe=cpu_pipe,
                           counts={"toffe": toffe_counts, "dotie": dotie_counts, "dotie_cluster": dotie_cl_counts},
                           supports=args.supports, ones=args.ones)
        lfl = like_for_like(args, ctx, machine, reader)

    # ---- cpu: DOTIE without / with clustering and TOFFE (deployed pipeline), timed in turn ------
    # Every timed inference starts from the window's events: DOTIE bins its count frames, TOFFE
    # builds its spike volume (SpikeVolume.from_events, as `toffe-deploy run` does).
    dt, nb, size = cfg.dt_us, cfg.n_bins, tuple(cfg.sensor_size)
    t0s = [t0 for t0, _x in windows]

    def run_plain(i):
        return dotie_separate_x(dotie_frames(events[i], t0s[i], dt, nb, size), p)

    def run_cl(i):              # DBSCAN on every step's separated events, as DOTIE's public code
        return dotie_detect_x(dotie_frames(events[i], t0s[i], dt, nb, size), p)

    def run_cl_window(i):       # one DBSCAN on the union of the steps (not DOTIE's code; for comparison)
        return dotie_detect_window(dotie_frames(events[i], t0s[i], dt, nb, size), p)

    def toffe_input(i):
        return [(t0s[i], SpikeVolume.from_events(events[i], t0s[i], dt, nb, size))]

    def toffe_row(target, lat, run_one) -> dict:
        ops, mj = host_model(toffe_counts)
        pipe = pipes[target]
        row = {"model": "toffe", "target": target, "status": "ok", "latency": latency_percentiles(lat),
               "L_kind": "measured wall time p50", "ops": ops.to_dict(), "ofpd_macs": macs,
               "extra": _mean_extra(toffe_counts), "provider": getattr(getattr(pipe, "ofpd", None), "provider", None)}
        row["L_ms"] = row["latency"]["p50_ms"]
        row.update(energy_fields(run_one, mj, cm.HOST_LABEL))
        return row

    if "cpu" in args.targets:
        fns = {"dotie": run_plain, "dotie_cluster": run_cl, "dotie_cluster_window": run_cl_window}
        if cpu_pipe is not None:
            fns["toffe"] = lambda i: list(cpu_pipe.process_stream(toffe_input(i)))
        log("cpu: " + ", ".join(fns) + f" timed in turn on {n} windows x {args.repeats} passes")
        lats = time_interleaved(fns, n, args.warmup, args.repeats, block=args.block)
        for m, counts in (("dotie", dotie_counts), ("dotie_cluster", dotie_cl_counts),
                          ("dotie_cluster_window", dotie_win_counts)):
            ops, mj = host_model(counts)
            row = {"model": m, "target": "cpu", "status": "ok", "latency": latency_percentiles(lats[m]),
                   "L_kind": "measured wall time p50", "ops": ops.to_dict(), "extra": _mean_extra(counts)}
            row["L_ms"] = row["latency"]["p50_ms"]
            row.update(energy_fields(fns[m], mj, cm.HOST_LABEL))
            rows.append(row)
        if cpu_pipe is not None:
            rows.append(toffe_row("cpu", lats["toffe"], fns["toffe"]))
    if "cuda" in pipes:
        log("cuda: TOFFE (deployed pipeline, OFPD on the GPU)")
        pc = pipes["cuda"]
        lat = time_interleaved({"toffe": lambda i: list(pc.process_stream(toffe_input(i)))}, n, args.warmup,
                               args.repeats)["toffe"]
        rows.append(toffe_row("cuda", lat, lambda i: list(pc.process_stream(toffe_input(i)))))
    if "cuda" in args.targets:
        for m in ("dotie", "dotie_cluster", "dotie_cluster_window"):
            rows.append({"model": m, "target": "cuda", "status": "unavailable",
                         "reason": "the DOTIE baseline here is numpy/OpenCV + scikit-learn (CPU only)"})

    # ---- Loihi 2 model (from counted activity) + host part measured here --------------------
    if "loihi-sim" in args.targets:
        log("loihi-sim: modelled Loihi 2 figures from counted activity; host part timed on this CPU")
        rows.extend(loihi_rows(args, bundle, cfg, windows, events, cascades, dotie_spikes, toffe_counts, dotie_counts,
                               dotie_cl_counts, host_pipe, loihi_model, host_model, p,
                               lambda i: dotie_frames(events[i], t0s[i], dt, nb, size), host_states))
    if "loihi2" in args.targets:
        rows.extend(loihi2_rows(bundle))

    # time x power variant, for the discussion of the CPU energy ratio (JSON only)
    for r in rows:
        if r.get("status") == "ok" and r["target"] in ("cpu", "cuda"):
            r["E_time_power_mj"] = r["L_ms"] * PAPER_CPU_POWER_W
            r["E_time_power_kind"] = PAPER_CPU_POWER_LABEL

    order = {(m, t): i for i, (m, t) in enumerate((m, t) for t in report.TARGETS for m in report.MODELS)}
    rows.sort(key=lambda r: order.get((r["model"], r["target"]), 99))
    machine["loadavg_end"] = [round(v, 2) for v in os.getloadavg()] if hasattr(os, "getloadavg") else None
    result = {
        "format": "toffe-energy-latency", "format_version": 1,
        "created": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
        "command": " ".join([Path(sys.argv[0]).name] + sys.argv[1:]), "quick": bool(args.quick),
        "settings": {k: getattr(args, k) for k in ("windows", "warmup", "repeats", "block", "count_windows",
                                                     "sim_windows", "energy_s", "idle_s", "targets")},
        "machine": machine, "input": input_desc,
        "bundle": {"path": str(bundle.root), "sensor_size": list(cfg.sensor_size), "n_stages": len(bundle.ofs),
                   "ofpd_macs": macs},
        "constants": cm.constants_table(), "paper_table2": report.PAPER_TABLE2,
        "rows": rows, "ratios": report.ratios(rows), "goals": report.goals(rows, lfl), "like_for_like": lfl,
        "wall_s": round(time.perf_counter() - t_start, 1),
    }
    md = render_markdown(result, report, short_name(machine))
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    # the three files as one set: all written first (the plot takes ~1 s and may fail), then
    # renamed back to back, the .json last, so a failed write replaces none of them and a .json
    # as new as its .md marks a whole set (a SIGKILL can fall only between two renames)
    with atomic_path(out / "energy_latency.json") as tmp_json, atomic_path(out / "energy_latency.md") as tmp_md, \
            atomic_path(out / "energy_latency.png", suffix=".png") as tmp_png:
        report.plot(rows, tmp_png, f"Energy and latency per inference ({short_name(machine)}; "
                                   f"{cfg.sensor_size[0]}x{cfg.sensor_size[1]}, B={cfg.n_bins})", lfl)
        tmp_md.write_text(md)
        tmp_json.write_text(json.dumps(result, indent=1, default=_json_default))
    print(md)
    log(f"wrote {out}/energy_latency.{{md,json,png}} in {result['wall_s']} s")
    return 0


def like_for_like(args, ctx, machine: dict, reader=None) -> dict:
    """Every model of baselines/registry.py at both levels on the same windows: interleaved
    blocks of wall and CPU time, energy under both counting rules and time x power, quality
    (gated matching of `eval`) on the same windows; ratios only within a level."""
    from toffe_deploy.baselines.registry import LEVELS, build_models
    from toffe_deploy.energy import rules
    from toffe_deploy.energy.measure import block_ratio, block_summary, time_blocks
    from toffe_deploy.metrics import FlowErrors

    cfg = ctx.config
    n = len(ctx.windows)
    models = build_models(ctx)
    cores = os.cpu_count() or 1
    load0 = os.getloadavg()[0] if hasattr(os, "getloadavg") else None
    warnings = []
    if load0 is not None and load0 > cores:
        warnings.append(f"load average {load0:.2f} > {cores} cores at start: wall times are inflated; "
                        "read the CPU-time columns")
        log("WARNING: " + warnings[-1])
    log(f"like for like: {len(models)} models x {args.blocks} interleaved blocks of {n} windows")
    times = time_blocks({m.key: m.run for m in models}, n, args.blocks, warmup=min(args.warmup, 3))
    load1 = os.getloadavg()[0] if hasattr(os, "getloadavg") else None
    if load1 is not None and load1 > cores and not warnings:
        warnings.append(f"load average {load1:.2f} > {cores} cores at end: wall times are inflated")
    power = args.power_w if args.power_w is not None else PAPER_CPU_POWER_W
    truth = getattr(args, "truth", None)
    rows = []
    for m in models:
        t = times[m.key]
        row = {"key": m.key, "family": m.family, "level": m.level, "label": m.label,
               "wall": block_summary(t["wall"]), "cpu": block_summary(t["cpu"]), "thread": block_summary(t["thread"]),
               "energy": rules.mean_work_energy(m.works) if m.works else
               rules.mean_rule_energy(m.rule_ops) if m.rule_ops else None}
        row["energy_time_power_uj"] = rules.time_power(row["cpu"]["median_ms"] * 1e-3, power)
        if reader is not None:                   # a counter: measured first, the models beside it
            from toffe_deploy.energy.measure import measure_dynamic

            dyn = measure_dynamic(reader, m.run, n, min_run_s=args.energy_s, idle_s=args.idle_s)
            row["energy_measured"] = dyn.to_dict()
        if m.predict is not None and truth is not None:
            fe = FlowErrors(n_bins=cfg.n_speed_bins, pred_scale=cfg.speed_scale)
            for i, (t0, _x) in enumerate(ctx.windows):
                fe.add_window(m.predict(m.run(i)), truth.window(t0, cfg.dt_us), getattr(args, "focal_px", None))
            q = fe.summary()
            q.pop("confusion", None)
            row["quality"] = q
            row["quality_by_bin"] = {str(k): fe.summary(k)["recall"] for k in range(1, cfg.n_speed_bins + 1)}
        rows.append(row)
    by = {r["key"]: r for r in rows}
    ratios = {}
    for lvl in LEVELS:
        for num in ("dotie_cluster", "dotie", "asnet"):
            a, b = by.get(f"{num}@{lvl}"), by.get(f"toffe@{lvl}")
            if not (a and b):
                continue
            ta, tb = times[a["key"]], times[b["key"]]
            r = {"cpu": block_ratio(ta["cpu"], tb["cpu"]), "wall": block_ratio(ta["wall"], tb["wall"])}
            if a["energy"] and b["energy"]:
                for rule in rules.RULES:
                    r[f"energy_{rule}"] = a["energy"][rule]["total_uj"] / b["energy"][rule]["total_uj"]
            ratios[f"{num}/toffe@{lvl}"] = r
    code = dotie_code_protocol(args, ctx) if args.dotie_code else None
    return {"rows": rows, "ratios": ratios, "power_w": power, "blocks": args.blocks, "windows": n,
            "loadavg": [load0, load1], "cores": cores, "warnings": warnings, "dotie_code": code,
            "energy_note": rules.ENERGY_NOTE, "rule_labels": rules.RULE_LABELS}


def dotie_code_protocol(args, ctx) -> dict:
    """DOTIE as its code runs it: one stream of 2 ms bins, membrane carried (optimised level,
    identical to the reference with a carried DotieState). A window's objects are the boxes of
    the 2 ms bin holding its midpoint (the best-aligned bin DOTIE has: favourable to it)."""
    from toffe_deploy.baselines.dotie_fast import FastDotie
    from toffe_deploy.baselines.registry import window_objects
    from toffe_deploy.metrics import FlowErrors

    cfg = ctx.config
    step = 2000
    ev = np.concatenate(ctx.events) if ctx.events else np.zeros(0)
    t_first = ctx.windows[0][0]
    t_last = ctx.windows[-1][0] + cfg.dt_us
    fast = FastDotie(tuple(cfg.sensor_size), 1, step, carry=True)
    boxes, cpu = {}, []
    for tb in range(t_first, t_last, step):
        sel = ev[(ev["t"] >= tb) & (ev["t"] < tb + step)]
        c0 = time.process_time()
        boxes[tb] = fast.detect(sel, tb)
        cpu.append(time.process_time() - c0)
    out = {"bin_us": step, "steps": len(cpu), "cpu_ms_per_step_median": float(np.median(cpu) * 1e3) if cpu else None}
    truth = getattr(args, "truth", None)
    if truth is not None:
        fe = FlowErrors(n_bins=cfg.n_speed_bins, pred_scale=cfg.speed_scale)
        for t0, _x in ctx.windows:
            mid = t0 + cfg.dt_us // 2
            tb = t_first + ((mid - t_first) // step) * step
            fe.add_window(window_objects(boxes.get(tb, [[]])), truth.window(t0, cfg.dt_us), getattr(args, "focal_px", None))
        q = fe.summary()
        q.pop("confusion", None)
        out["quality"] = q
        out["quality_by_bin"] = {str(k): fe.summary(k)["recall"] for k in range(1, cfg.n_speed_bins + 1)}
    return out


PAPER_CPU_POWER_W = 92.5 / 2.17   # W: TOFFE's E / L on the paper's i9-12700KF (Table 2)
PAPER_CPU_POWER_LABEL = "modelled (p50 wall time x 42.6 W, the power implied by the paper's i9 TOFFE row)"


def _mean_extra(counts) -> dict:
    keys = counts[0].extra.keys() if counts else []
    return {k: float(np.mean([c.extra[k] for c in counts])) for k in keys}


def _json_default(o):
    if isinstance(o, (np.integer,)):
        return int(o)
    if isinstance(o, (np.floating,)):
        return float(o)
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


def loihi_rows(args, bundle, cfg, windows, events, cascades, dotie_spikes, toffe_counts, dotie_counts,
               dotie_cl_counts, cpu_pipe, loihi_model, host_model, p, dotie_x, host_states):
    """Rows of the hybrid column: Loihi 2 side modelled, host side measured (latency) and
    modelled (energy) on this machine, and the Lava simulator's wall time where it runs.
    dotie_x(i): window i's (B, H, W) count frames from its own events, DOTIE's input;
    host_states[i]: (ones history, front-end history) after window i, as the deployed host holds
    them when its OFPD step runs (kept from the counting pass's Pipeline)."""
    from toffe_deploy.baselines.dotie import dotie_cluster_steps, dotie_postprocess
    from toffe_deploy.baselines.dotie_fast import FastDotie
    from toffe_deploy.energy import cost_model as cm
    from toffe_deploy.events.support import front_end
    from toffe_deploy.energy.measure import latency_percentiles
    from toffe_deploy.runtime.spikes import SpikeVolume

    rows = []
    n_count = len(cascades)
    reps = max(args.repeats, 1)

    def timed(fn) -> float:
        fn()                                       # warm
        t0 = time.perf_counter()
        for _ in range(reps):
            fn()
        return (time.perf_counter() - t0) / reps

    # TOFFE host part: per stage the closing of Loihi's output spikes and the masking of the
    # window's events (the bridge's work, done here with the runtime's compact closing), then
    # OFPD on the accepted frames through the deployed pipeline's own code.
    from toffe_deploy.runtime.morph import CompactClosing

    host_lat, fe_lat = [], []
    if cpu_pipe is not None:
        h, w = cfg.height, cfg.width
        pool = cfg.ofs_pool
        wg, hg = cfg.ofs_grid((w, h))                                 # the stages' grid (ofs_pool)
        for i, res in enumerate(cascades):
            vol = SpikeVolume.from_dense(windows[i][1] > 0)          # the host streams these to Loihi anyway
            spike_pix = [np.flatnonzero(sp.any(axis=0)) for sp in res.spikes]   # Loihi's output, per stage
            ring, recent = host_states[i]     # the windows before it, as the deployed host keeps them

            def host_part(vol=vol, spike_pix=spike_pix, ring=ring, recent=recent):
                pix = vol.pix
                if pool > 1:                                 # each sensor one reads its grid cell (Up_p)
                    ys, xs = np.divmod(pix, w)
                    pix = (ys // pool) * wg + xs // pool
                alive = np.ones(len(vol), dtype=bool)
                frames = [None] * len(spike_pix)             # bool masks over vol.idx, index k - 1
                for k in range(len(spike_pix), 0, -1):
                    inside = CompactClosing(spike_pix[k - 1], hg, wg, cfg.mask_kernel).at(pix)
                    frames[k - 1] = alive & inside
                    alive &= ~inside
                cpu_pipe.ones_history = ring
                cpu_pipe.objects_of(vol, frames, recent=recent)
                return frames
            # the host part must rebuild exactly the cascade's frames (else the timing is of the wrong work)
            for k, f in enumerate(host_part()):
                if not np.array_equal(vol.subset(f).to_dense(np.uint8) > 0, res.frames[k]):
                    raise RuntimeError(f"host-part frames differ from the cascade's at stage {k + 1} (a bug)")
            # the front end runs on the host before the window's events go to the chip: timed apart
            # (each call on a copy of the history before the window, copied untimed) and added
            t0 = windows[i][0]
            raw = SpikeVolume.from_events(events[i], t0, cfg.dt_us, cfg.n_bins, (w, h))
            before = args.supports[i] if cfg.input_support is not None else None
            fe = []
            for _ in range(reps + 1):                  # the first call warms
                hist = copy.deepcopy(before)
                a = time.perf_counter()
                kept = front_end(raw, cfg, hist, t0)
                fe.append(time.perf_counter() - a)
            if not np.array_equal(kept.idx, np.flatnonzero(windows[i][1])):
                raise RuntimeError(f"the timed front end differs from the counted window {i} (a bug)")
            fe_lat.append(float(np.mean(fe[1:])))
            host_lat.append(timed(host_part) + fe_lat[-1])
    lo = loihi_model(toffe_counts)
    hops, hmj = host_model(toffe_counts, "host_hybrid")
    host = {"latency_ms": latency_percentiles(host_lat).get("p50_ms") if host_lat else None,
            "latency": latency_percentiles(host_lat), "front_end_latency": latency_percentiles(fe_lat),
            "energy_mj": hmj, "energy_kind": cm.HOST_LABEL, "ops": hops.to_dict()}
    row = {"model": "toffe", "target": "loihi-sim", "status": "ok", "loihi": lo, "host": host,
           "E_mj": lo["energy_mj"] + hmj, "E_kind": f"{cm.LOIHI_LABEL} + host {cm.HOST_LABEL}",
           "E_model_mj": lo["energy_mj"] + hmj,
           "L_ms": None if host["latency_ms"] is None else lo["latency_ms"] + host["latency_ms"],
           "L_kind": "modelled Loihi 2 (sum of T_ts over B steps and stages) + host part (front end, masks, "
                     "grouping, OFPD, plane fit) measured p50",
           "notes": [f"Loihi 2 side {lo['cores_total']} cores ({lo['chips_needed']} chip(s) at 128 cores)"]}
    if host["latency_ms"] is None:
        row["notes"].append("host part not timed (the cpu pipeline could not run): no total latency")
    sim = lava_sim_wall(args, bundle, windows, cascades)
    if "error" in sim:
        row["notes"].append(f"Lava simulator not run: {sim['error']}")
    elif sim:
        row["sim_wall"] = sim
        ok = sim["activity_identical_windows"] == sim["activity_check_windows"]
        row["notes"].append(f"simulated cascade {'identical to' if ok else 'DIFFERS FROM'} the counted one on "
                            f"{sim['activity_identical_windows']}/{sim['activity_check_windows']} windows")
    rows.append(row)

    # DOTIE: its one layer on Loihi 2 (modelled); with clustering, the host does morphology + DBSCAN.
    lo_d = loihi_model(dotie_counts)
    _, post_mj = host_model(dotie_counts, "host_hybrid")
    rows.append({"model": "dotie", "target": "loihi-sim", "status": "ok", "loihi": lo_d,
                 "E_mj": lo_d["energy_mj"], "E_model_mj": lo_d["energy_mj"], "E_kind": cm.LOIHI_LABEL,
                 "L_ms": lo_d["latency_ms"], "L_kind": "modelled Loihi 2 (sum of T_ts over B steps)",
                 "notes": ["Loihi side only, as the paper's row; activity counted from the numpy DOTIE layer "
                           "(no Lava process for DOTIE's graded input)", f"its host part (events indexed for the chip, recovery) would "
                           f"add {post_mj:.3g} mJ (modelled)"]})
    # its host part at the level TOFFE's runs at (compiled, event driven: FastDotie, the optimised
    # DOTIE of the like-for-like table), from the layer's spikes and the step's event pixels, as
    # TOFFE's starts from Loihi's spikes and the window's ones; its public code's form (OpenCV,
    # scikit-learn) timed beside it for reference only (until 2026-11-30 it was the row's latency)
    fast = FastDotie(tuple(cfg.sensor_size), cfg.n_bins, cfg.dt_us, p)
    cl_lat, cl_ref_lat = [], []
    for i in range(n_count):
        x = dotie_x(i)
        spikes = dotie_spikes[i]
        spk_pix = [np.flatnonzero(s) for s in spikes]          # Loihi's output, per step
        ev_pix = [np.flatnonzero(f) for f in x]                # the step's events, as the host sent them
        reference = dotie_cluster_steps(dotie_postprocess(x, spikes, p), p)
        if fast.host_part(spk_pix, ev_pix) != reference:      # the same boxes, else it times the wrong work
            raise RuntimeError(f"DOTIE's compiled host part differs from its reference at window {i} (a bug)")
        cl_lat.append(timed(lambda s=spk_pix, e=ev_pix: fast.host_part(s, e)))
        cl_ref_lat.append(timed(lambda x=x, spikes=spikes: dotie_cluster_steps(dotie_postprocess(x, spikes, p), p)))
    _, cl_mj = host_model(dotie_cl_counts, "host_hybrid")
    cl_host_ms = latency_percentiles(cl_lat)["p50_ms"]
    rows.append({"model": "dotie_cluster", "target": "loihi-sim", "status": "ok", "loihi": lo_d,
                 "host": {"latency_ms": cl_host_ms, "latency": latency_percentiles(cl_lat), "energy_mj": cl_mj,
                          "energy_kind": cm.HOST_LABEL,
                          "reference_code_latency": latency_percentiles(cl_ref_lat)},
                 "E_mj": lo_d["energy_mj"] + cl_mj, "E_model_mj": lo_d["energy_mj"] + cl_mj,
                 "E_kind": f"{cm.LOIHI_LABEL} + host {cm.HOST_LABEL}",
                 "L_ms": lo_d["latency_ms"] + cl_host_ms,
                 "L_kind": "modelled Loihi 2 layer + host recovery and DBSCAN (compiled, event driven) measured p50",
                 "notes": [f"host part as DOTIE's public code runs it (OpenCV, scikit-learn): "
                           f"{latency_percentiles(cl_ref_lat)['p50_ms']:.3g} ms p50, not used"]})
    return rows


def lava_sim_wall(args, bundle, windows, cascades) -> dict:
    """Wall time per window of the Lava simulator (loihi-sim pipeline): a simulation cost, never L.

    A second pass runs the simulated cascade alone and compares it with the counted cascades
    (the activity the Loihi 2 model uses must be the simulation's: they must be identical)."""
    if args.sim_windows <= 0:
        return {}
    from toffe_deploy.cascade import pool_any
    from toffe_deploy.energy.measure import latency_percentiles

    sim = windows[:args.sim_windows]
    try:
        from toffe_deploy.runtime.pipeline import Pipeline

        with Pipeline(bundle, "loihi-sim") as pipe:
            t0 = time.perf_counter()
            lat = stream_latencies(pipe, sim, warmup=1, repeats=1)
            total = time.perf_counter() - t0
            n_check = min(len(sim), len(cascades))
            same = 0
            # the network runs on the OFS grid (ofs_pool): fed pooled windows as the Pipeline feeds
            # it, and compared on that grid (spikes, closed masks, stage inputs; the counted
            # cascade's frames are on the sensor grid, the network's on the OFS grid)
            pool = bundle.config.ofs_pool
            grid = (pool_any(np.asarray(w) > 0, pool).astype(np.uint8) for _t0, w in sim[:n_check])
            for i, res in enumerate(pipe.cascade.cascade_stream(grid)):
                ref = cascades[i]
                same += all(np.array_equal(np.asarray(a) > 0, np.asarray(b) > 0)
                            for a, b in zip(res.spikes + res.closed + res.inputs, ref.spikes + ref.closed + ref.inputs))
            startup = getattr(pipe.cascade, "startup_s", None)
    except (ToffeError, ImportError, RuntimeError, ValueError, OSError) as exc:
        return {"error": str(exc).splitlines()[0] if str(exc) else type(exc).__name__}
    d = latency_percentiles(lat)
    d.update(total_s=total, startup_s=startup, activity_check_windows=n_check, activity_identical_windows=int(same),
             what="Lava simulator (Loihi2SimCfg fixed_pt) wall time per window: simulation cost, not Loihi latency")
    return d


def loihi2_rows(bundle) -> list[dict]:
    """The real chip: only with lava-loihi (Intel's NRC package). Otherwise n/a, with why."""
    from toffe_deploy.energy.readers import loihi2_profiler_available

    rows = []
    try:
        if not loihi2_profiler_available():   # checked first: starting Lava just to fail costs seconds
            raise ToffeError("loihi2 needs lava-loihi (Intel's NRC package with Loihi2HwCfg and the board "
                             "profiler), not installed here")
        from toffe_deploy.runtime.pipeline import Pipeline

        with Pipeline(bundle, "loihi2"):
            pass
        reason = ("lava-loihi is present, but the board profiler (energy_latency's Loihi2Profiler) is not wired into "
                  "LavaCascade's run config yet; run `toffe-deploy run --target loihi2` for object flow")
    except (ToffeError, ImportError, RuntimeError, ValueError, OSError) as exc:
        reason = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
    for m in ("dotie", "dotie_cluster", "toffe"):
        rows.append({"model": m, "target": "loihi2", "status": "unavailable", "reason": reason})
    return rows


def render_markdown(result: dict, report, machine_name: str) -> str:
    rows = result["rows"]
    inp = result["input"]
    g = result["goals"]
    toffe_loihi = next((r for r in rows if r["model"] == "toffe" and r["target"] == "loihi-sim"), None)
    lines = [
        f"# Energy and latency per inference (paper Table 2 layout)",
        "",
        f"Machine: {machine_name}; counters: "
        + (", ".join(c["source"] for c in result["machine"]["energy_counters"].get("found", [])) or "none readable")
        + f". Input: {inp['source']}, {inp['windows']} windows of {inp['dt_us']} us, "
          f"{inp['sensor_size'][0]}x{inp['sensor_size'][1]}, B = {inp['n_bins']}, "
          f"{inp['events_per_window']['mean']:.0f} events/window. Load average (1 min) "
          f"{(result['machine'].get('loadavg_1_5_15') or ['?'])[0]} at start, "
          f"{(result['machine'].get('loadavg_end') or ['?'])[0]} at end "
          f"(a shared machine inflates wall times). {result['created']}"
        + (" (--quick)" if result["quick"] else ""),
        "",
        report.markdown_table(rows, machine_name),
        "",
        report.legend(),
        "",
        "## Like for like: both optimisation levels, the same counting rules, CPU time, quality",
        "",
        report.like_for_like_markdown(result.get("like_for_like")),
        "",
        "## TOFFE on Loihi 2 + host: the split",
        "",
        report.hybrid_split_table(toffe_loihi),
        "",
        "## Goals, like for like (DOTIE with clustering / TOFFE, within one level, CPU time)",
        "",
    ]
    lfl = result.get("like_for_like") or {}
    for lvl in ("optimised", "reference"):
        r = (lfl.get("ratios") or {}).get(f"dotie_cluster/toffe@{lvl}")
        if r:
            lat, goal_e = r["cpu"]["median"], report.GOALS["cpu_energy_ratio"]
            met_e = [v is not None and v >= goal_e for v in (r.get("energy_event"), r.get("energy_dense"))]
            lines.append(f"- {lvl} level: CPU time {report.fmt(lat)}x (goal >= {report.fmt(report.GOALS['cpu_latency_ratio'])}x: "
                         f"{'met' if lat >= report.GOALS['cpu_latency_ratio'] else 'NOT met'}); modelled energy "
                         f"{report.fmt(r.get('energy_event'))}x by the event-driven rule, {report.fmt(r.get('energy_dense'))}x "
                         f"by the dense rule (goal >= {report.fmt(goal_e)}x: "
                         f"{'met by both' if all(met_e) else 'met by one rule only' if any(met_e) else 'NOT met'})")
    lines += ["", "## The first goals, across levels (DOTIE reference port / TOFFE optimised: not like for like)", ""]
    if g.get("evaluated"):
        lines += [f"- latency (p50 wall): {report.fmt(g['cpu_latency_ratio'])}x, across levels",
                  f"- energy, modelled from counted operations, DOTIE by the dense rule and TOFFE by the "
                  f"event-driven one: {report.fmt(g['cpu_energy_ratio_modelled'])}x, across counting rules",
                  f"- energy, modelled as p50 wall time x one CPU power (so equal to the latency ratio): "
                  f"{report.fmt(g.get('cpu_energy_ratio_time_power'))}x",
                  f"- against one DBSCAN per window instead of DOTIE's per-step clustering (not the goal's baseline): "
                  f"latency {report.fmt(g.get('cpu_latency_ratio_window'))}x, modelled energy "
                  f"{report.fmt(g.get('cpu_energy_ratio_window_modelled'))}x"]
        if g.get("cpu_energy_headline_kind", "").count("measured") == 2:
            lines.append(f"- energy, measured with a counter: {report.fmt(g['cpu_energy_ratio_headline'])}x")
    else:
        lines.append(f"- not evaluated: {g.get('reason')}")
    lines += ["", "## All rows", "", report.detail_table(rows), ""]
    return "\n".join(lines)


def main(argv=None) -> int:
    args = parse_args(argv)
    try:
        return run(args)
    except ToffeError as exc:
        print(f"energy_latency.py: error: {exc}", file=sys.stderr)
        return 2
    except ModuleNotFoundError as exc:     # scikit-learn / matplotlib / onnx come with the 'lava' extra
        print(f"energy_latency.py: error: Python package {exc.name!r} is missing; install the 'lava' extra "
              f"(pip install -e '.[lava]', as scripts/setup.sh does)", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("energy_latency.py: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
