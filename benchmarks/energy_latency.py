#!/usr/bin/env python
"""Energy and latency per inference, TOFFE against DOTIE, on every target (issue 5; paper Table 2).

    python benchmarks/energy_latency.py                 # full size: export/ bundle, 640x480, B = 5
    python benchmarks/energy_latency.py --quick         # a small run CI can afford

One inference = one window of B bins through the whole model, batch 1, from the window's events
to the model's output. For every model (TOFFE through the deployed ``Pipeline``; DOTIE without
clustering; DOTIE with clustering, DBSCAN on every step's separated events as in its public
code; for comparison, DOTIE with one DBSCAN per window; and Adaptive-SpikeNet (Pico) from
ckpt/baselines/adaptive_spikenet/ when trained, its flow turned into object flow) and target (cpu, cuda, loihi-sim,
loihi2; each where available) on the same input windows, timed in turn in blocks of --block
windows:

* latency L: wall-time percentiles p50/p90/p99 after warm-up on host targets; on the hybrid,
  the Loihi 2 part is L = sum_t T_ts (T_ts modelled from the activity counted in the
  simulation) plus the host part measured here; Lava simulator wall time is reported as such;
* dynamic energy E = (E_run - P_idle * T_run) / K from a counter (RAPL, NVML, Jetson INA3221)
  with idle measured in the same run, else modelled from counted operations; every row says
  which ("measured (source)", "below noise (source)", "modelled (constants ...)").

Writes energy_latency.{md,json,png} to --out (default benchmarks/results/, --quick:
benchmarks/results/quick/) and prints the markdown table.
"""
from __future__ import annotations

import argparse
import contextlib
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

from toffe_deploy.errors import InputError, ToffeError  # noqa: E402

DEFAULT_BUNDLE = ROOT / "export"
DEFAULT_OUT = ROOT / "benchmarks" / "results"
SAMPLE = ROOT / "toffe_deploy" / "samples" / "sample_multi.h5"

FULL = dict(windows=60, warmup=10, repeats=3, count_windows=30, sim_windows=4, energy_s=3.0, idle_s=2.0)
QUICK = dict(windows=6, warmup=2, repeats=1, count_windows=3, sim_windows=0, energy_s=0.3, idle_s=0.3)


def parse_args(argv=None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(prog="energy_latency.py", description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--bundle", default=str(DEFAULT_BUNDLE),
                    help="deploy bundle directory (default: export/; make it with `toffe-deploy export ckpt/`)")
    src = ap.add_mutually_exclusive_group()
    src.add_argument("--events", help="event recording to cut windows from (any format toffe-deploy reads; "
                                      "default: the shipped sample, else --synthetic)")
    src.add_argument("--synthetic", metavar="SEED", type=int,
                     help="generate a multi-object sequence (data-set generator, split 'multi', this seed) as input")
    ap.add_argument("--targets", default="cpu,cuda,loihi-sim,loihi2",
                    help="comma-separated targets to try; unavailable ones are reported as n/a (default: all)")
    ap.add_argument("--quick", action="store_true",
                    help="small run for CI: few windows, short energy runs, no Lava simulation unless --sim-windows")
    ap.add_argument("--windows", type=int, help=f"distinct input windows timed (default {FULL['windows']}, quick {QUICK['windows']})")
    ap.add_argument("--warmup", type=int, help=f"untimed warm-up inferences per model and target (default {FULL['warmup']})")
    ap.add_argument("--repeats", type=int, help=f"timed passes over the windows (default {FULL['repeats']})")
    ap.add_argument("--block", type=int, default=10,
                    help="models are timed in turn in blocks of this many consecutive windows (default 10; "
                         "1 = window by window, each model right after another evicted its data from cache)")
    ap.add_argument("--count-windows", type=int,
                    help=f"windows whose operations are counted for the models (default {FULL['count_windows']})")
    ap.add_argument("--sim-windows", type=int,
                    help=f"windows run through the Lava simulator for its wall time (default {FULL['sim_windows']}, quick 0)")
    ap.add_argument("--energy-s", type=float, help="minimum run length (s) of each counter measurement (default 3)")
    ap.add_argument("--idle-s", type=float, help="idle time (s) measured around each counter measurement (default 2)")
    ap.add_argument("--min-events", type=int, default=1, help="skip windows with fewer events (default 1)")
    ap.add_argument("--sysfs-root", default="/sys", help="where to look for RAPL/INA3221 counters (default /sys)")
    ap.add_argument("--out", help="output directory (default benchmarks/results/, quick: benchmarks/results/quick/)")
    args = ap.parse_args(argv)
    base = QUICK if args.quick else FULL
    for k, v in base.items():
        if getattr(args, k) is None:
            setattr(args, k, v)
    if args.out is None:
        args.out = str(DEFAULT_OUT / "quick") if args.quick else str(DEFAULT_OUT)
    for k in ("windows", "repeats", "count_windows", "block"):
        if getattr(args, k) < 1:
            ap.error(f"--{k.replace('_', '-')} must be >= 1")
    args.targets = [t.strip() for t in args.targets.split(",") if t.strip()]
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
    window's events. Timed runs start from the events (each model builds its own input, as
    ``toffe-deploy run`` does); the binned copies feed the op counting and the Lava simulator."""
    from toffe_deploy.events.binning import bin_window, window_slice
    from toffe_deploy.events.frontend import apply_dense

    dt, b, size = config.dt_us, config.n_bins, tuple(config.sensor_size)
    out: list[tuple[int, np.ndarray]] = []
    events: list[np.ndarray] = []
    counts: list[int] = []

    def take(t0, ev) -> bool:
        if len(ev) < args.min_events:
            return False
        # the counts the network sees: through the bundle's input front end (events/frontend.py)
        out.append((int(t0), apply_dense(bin_window(ev, t0, dt, b, size), config.input_norm, config.input_min_cluster).astype(np.uint8)))
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
        ev, _gt, gen_size = generate_sequence(spec, seed=args.synthetic)
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
        for t0, ev in src.iter_windows(dt):
            if take(t0, ev):
                break
    if not out:
        raise ToffeError(f"{desc['source']}: no window of {dt} us with at least {args.min_events} events")
    c = np.asarray(counts)
    desc.update({"sensor_size": list(size), "n_bins": b, "dt_us": dt, "windows": len(out),
                 "events_per_window": {"mean": float(c.mean()), "p50": float(np.median(c)), "max": int(c.max())}})
    return out, events, desc


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
    # ---- counting pass (untimed): operations and Loihi activity per model ----------------------
    n_count = min(args.count_windows, n)
    try:
        macs = cm.onnx_macs(bundle.ofpd_onnx)
    except Exception as exc:   # an ONNX graph we cannot count: say so, do not guess
        raise ToffeError(f"{bundle.ofpd_onnx}: cannot count OFPD MACs ({exc})") from None
    in_elems = int(np.prod(input_shape(cfg)))
    toffe_counts, dotie_counts, dotie_cl_counts, dotie_win_counts, cascades, dotie_spikes = [], [], [], [], [], []
    for i in tqdm(range(n_count), desc="counting operations", file=sys.stderr, leave=False):
        binned = windows[i][1]
        # OFPD rows = the objects the deployed pipeline reports for this window (untimed run)
        rows_i = len(list(cpu_pipe.process_stream([windows[i]]))[0].objects) if cpu_pipe is not None else None
        res, mc = count_toffe(binned, list(bundle.ofs), cfg, macs["macs"], in_elems, macs["params"],
                              macs["activations"], ofpd_rows=rows_i)
        toffe_counts.append(mc)
        cascades.append(res)
        plain, clus, window, spikes = count_dotie(binned, p)
        dotie_counts.append(plain)
        dotie_cl_counts.append(clus)
        dotie_win_counts.append(window)
        dotie_spikes.append(spikes)

    asnet, asnet_counts = load_asnet(cfg), []
    if asnet is not None:
        for i in tqdm(range(n_count), desc="counting Adaptive-SpikeNet", file=sys.stderr, leave=False):
            asnet_counts.append(asnet.op_counts(_raw_window(events[i], windows[i][0], cfg)))

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
        if asnet is not None:             # its whole inference: binning, network, flow -> objects
            asnet_ort = asnet.optimised()
            fns["asnet"] = lambda i: asnet.detect(events[i], t0s[i])
            fns["asnet_ort"] = lambda i: asnet_ort.detect(events[i], t0s[i])
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
        if asnet is not None:
            rows.append(asnet_row(asnet, asnet_counts, lats["asnet_ort"], lats["asnet"], energy_fields,
                                  fns["asnet_ort"]))
    if "cpu" in args.targets and asnet is None:
        rows.append({"model": "asnet", "target": "cpu", "status": "unavailable",
                     "reason": f"no trained baseline at {ASNET_DIR} (benchmarks/train_asnet.py)"})
    for t in [t for t in ("cuda", "loihi-sim", "loihi2") if t in args.targets]:
        rows.append({"model": "asnet", "target": t, "status": "unavailable",
                     "reason": "Adaptive-SpikeNet runs as a torch CPU reference here" if t == "cuda" else
                     "paper: exceeds one Loihi 2 chip's memory and Lava has no skip connections"})
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
        rows.extend(loihi_rows(args, bundle, cfg, windows, cascades, dotie_spikes, toffe_counts, dotie_counts,
                               dotie_cl_counts, cpu_pipe, loihi_model, host_model, p))
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
        "rows": rows, "ratios": report.ratios(rows), "goals": report.goals(rows),
        "wall_s": round(time.perf_counter() - t_start, 1),
    }
    md = render_markdown(result, report, short_name(machine))
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    with atomic_path(out / "energy_latency.json") as tmp:
        tmp.write_text(json.dumps(result, indent=1, default=_json_default))
    with atomic_path(out / "energy_latency.md") as tmp:
        tmp.write_text(md)
    with atomic_path(out / "energy_latency.png", suffix=".png") as tmp:
        report.plot(rows, tmp, f"Energy and latency per inference ({short_name(machine)}; "
                               f"{cfg.sensor_size[0]}x{cfg.sensor_size[1]}, B={cfg.n_bins})")
    print(md)
    log(f"wrote {out}/energy_latency.{{md,json,png}} in {result['wall_s']} s")
    return 0


ASNET_DIR = ROOT / "ckpt" / "baselines" / "adaptive_spikenet"


def load_asnet(cfg):
    """The trained Adaptive-SpikeNet (Pico) baseline, None when it is not there (row n/a)."""
    if not (ASNET_DIR / "weights.safetensors").exists():
        return None
    from toffe_deploy.baselines.adaptive_spikenet import AdaptiveSpikeNetBaseline

    return AdaptiveSpikeNetBaseline.load(ASNET_DIR, cfg)


def _raw_window(ev, t0, cfg):
    """The raw (B, 2, H, W) counts Adaptive-SpikeNet takes (no TOFFE front end)."""
    from toffe_deploy.events.binning import bin_window

    return bin_window(ev, int(t0), cfg.dt_us, cfg.n_bins, tuple(cfg.sensor_size), dtype=np.uint8)


def asnet_row(asnet, counts, lat, lat_reference, energy_fields, run_one) -> dict:
    """cpu row of Adaptive-SpikeNet: L measured with ONNX Runtime (the optimised level; the torch
    eager reference beside it), E modelled from its dense op count (what both do); the
    event-driven count is given beside it."""
    from toffe_deploy.energy import cost_model as cm
    from toffe_deploy.energy.measure import latency_percentiles

    dense = cm.mean_ops(cm.HostOps(**c["host_dense"]) for c in counts)
    event = cm.mean_ops(cm.HostOps(**c["host_event"]) for c in counts)
    tot = {k: float(np.mean([c["totals"][k] for c in counts])) for k in counts[0]["totals"]}
    row = {"model": "asnet", "target": "cpu", "status": "ok", "latency": latency_percentiles(lat),
           "L_kind": "measured wall time p50 (ONNX Runtime)", "latency_reference": latency_percentiles(lat_reference),
           "ops": dense.to_dict(),
           "ops_event_driven": event.to_dict(), "E_event_driven_mj": event.energy_j() * 1e3, "totals": tot,
           "network_input_wh": counts[0]["network_input_wh"], "params": counts[0]["params"],
           "notes": [f"network at {counts[0]['network_input_wh'][0]}x{counts[0]['network_input_wh'][1]} "
                     f"(sensor / {asnet.cfg.downsample}, as trained); full-resolution figures in "
                     f"{ASNET_DIR.relative_to(ROOT)}/cost.json",
                     f"torch eager reference p50 {latency_percentiles(lat_reference).get('p50_ms', float('nan')):.3g} ms",
                     f"event-driven count: {event.energy_j() * 1e3:.3g} mJ (modelled)"]}
    row["L_ms"] = row["latency"]["p50_ms"]
    row.update(energy_fields(run_one, dense.energy_j() * 1e3, cm.HOST_LABEL))
    return row


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


def loihi_rows(args, bundle, cfg, windows, cascades, dotie_spikes, toffe_counts, dotie_counts, dotie_cl_counts,
               cpu_pipe, loihi_model, host_model, p):
    """Rows of the hybrid column: Loihi 2 side modelled, host side measured (latency) and
    modelled (energy) on this machine, and the Lava simulator's wall time where it runs."""
    from toffe_deploy.baselines.dotie import dotie_cluster_steps, dotie_input, dotie_postprocess
    from toffe_deploy.energy import cost_model as cm
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

    host_lat = []
    if cpu_pipe is not None:
        h, w = cfg.height, cfg.width
        for i, res in enumerate(cascades):
            vol = SpikeVolume.from_dense(windows[i][1] > 0)          # the host streams these to Loihi anyway
            spike_pix = [np.flatnonzero(sp.any(axis=0)) for sp in res.spikes]   # Loihi's output, per stage

            def host_part(vol=vol, spike_pix=spike_pix):
                pix = vol.pix
                alive = np.ones(len(vol), dtype=bool)
                frames = [None] * len(spike_pix)             # bool masks over vol.idx, index k - 1
                for k in range(len(spike_pix), 0, -1):
                    inside = CompactClosing(spike_pix[k - 1], h, w, cfg.mask_kernel).at(pix)
                    frames[k - 1] = alive & inside
                    alive &= ~inside
                cpu_pipe.objects_of(vol, frames)
                return frames
            # the host part must rebuild exactly the cascade's frames (else the timing is of the wrong work)
            for k, f in enumerate(host_part()):
                if not np.array_equal(vol.subset(f).to_dense(np.uint8) > 0, res.frames[k]):
                    raise RuntimeError(f"host-part frames differ from the cascade's at stage {k + 1} (a bug)")
            host_lat.append(timed(host_part))
    lo = loihi_model(toffe_counts)
    hops, hmj = host_model(toffe_counts, "host_hybrid")
    host = {"latency_ms": latency_percentiles(host_lat).get("p50_ms") if host_lat else None,
            "latency": latency_percentiles(host_lat), "energy_mj": hmj, "energy_kind": cm.HOST_LABEL,
            "ops": hops.to_dict()}
    row = {"model": "toffe", "target": "loihi-sim", "status": "ok", "loihi": lo, "host": host,
           "E_mj": lo["energy_mj"] + hmj, "E_kind": f"{cm.LOIHI_LABEL} + host {cm.HOST_LABEL}",
           "E_model_mj": lo["energy_mj"] + hmj,
           "L_ms": lo["latency_ms"] + (host["latency_ms"] or 0.0),
           "L_kind": "modelled Loihi 2 (sum of T_ts over B steps and stages) + host part measured p50",
           "notes": [f"Loihi 2 side {lo['cores_total']} cores ({lo['chips_needed']} chip(s) at 128 cores)"]}
    if host["latency_ms"] is None:
        row["notes"].append("host part not timed (cpu target not run)")
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
                           "(no Lava process for DOTIE's graded input)", f"host post-processing would add {post_mj:.3g} mJ (modelled)"]})
    cl_lat = []
    for i in range(n_count):
        x = dotie_input(windows[i][1])
        spikes = dotie_spikes[i]
        cl_lat.append(timed(lambda x=x, spikes=spikes: dotie_cluster_steps(dotie_postprocess(x, spikes, p), p)))
    _, cl_mj = host_model(dotie_cl_counts, "host_hybrid")
    cl_host_ms = latency_percentiles(cl_lat)["p50_ms"]
    rows.append({"model": "dotie_cluster", "target": "loihi-sim", "status": "ok", "loihi": lo_d,
                 "host": {"latency_ms": cl_host_ms, "latency": latency_percentiles(cl_lat), "energy_mj": cl_mj,
                          "energy_kind": cm.HOST_LABEL},
                 "E_mj": lo_d["energy_mj"] + cl_mj, "E_model_mj": lo_d["energy_mj"] + cl_mj,
                 "E_kind": f"{cm.LOIHI_LABEL} + host {cm.HOST_LABEL}",
                 "L_ms": lo_d["latency_ms"] + cl_host_ms,
                 "L_kind": "modelled Loihi 2 layer + host morphology and DBSCAN measured p50"})
    return rows


def lava_sim_wall(args, bundle, windows, cascades) -> dict:
    """Wall time per window of the Lava simulator (loihi-sim pipeline): a simulation cost, never L.

    A second pass runs the simulated cascade alone and compares it with the counted cascades
    (the activity the Loihi 2 model uses must be the simulation's: they must be identical)."""
    if args.sim_windows <= 0:
        return {}
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
            for i, res in enumerate(pipe.cascade.cascade_stream(w for _t0, w in sim[:n_check])):
                ref = cascades[i]
                same += all(np.array_equal(a, b) for a, b in zip(res.spikes + res.frames, ref.spikes + ref.frames))
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
        "## TOFFE on Loihi 2 + host: the split",
        "",
        report.hybrid_split_table(toffe_loihi),
        "",
        "## Goals (same-run ratios on cpu, DOTIE with clustering / TOFFE)",
        "",
    ]
    if g.get("evaluated"):
        lines += [f"- latency: {report.fmt(g['cpu_latency_ratio'])}x (goal >= {report.fmt(g['cpu_latency_goal'])}x): "
                  f"{'met' if g['cpu_latency_met'] else 'NOT met'}",
                  f"- energy, modelled from counted operations: {report.fmt(g['cpu_energy_ratio_modelled'])}x "
                  f"(goal >= {report.fmt(g['cpu_energy_goal'])}x): {'met' if g['cpu_energy_met'] else 'NOT met'}",
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
        print(f"energy_latency: error: {exc}", file=sys.stderr)
        return 2
    except ModuleNotFoundError as exc:     # scikit-learn / matplotlib / onnx come with the 'lava' extra
        print(f"energy_latency: error: Python package {exc.name!r} is missing; install the 'lava' extra "
              f"(pip install -e '.[lava]', as scripts/setup.sh does)", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("energy_latency: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
