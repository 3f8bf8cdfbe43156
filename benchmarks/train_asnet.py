#!/usr/bin/env python
"""Train and evaluate the Adaptive-SpikeNet (Pico) baseline on the synthetic data set's flow.

    python benchmarks/train_asnet.py --data data/synth --minutes 35      # train, then evaluate
    python benchmarks/train_asnet.py --data data/synth --eval-only       # evaluate the shipped weights
    python benchmarks/train_asnet.py --data data/synth --cost-only       # op counts, modelled energy, timing

Training windows: ``--per-seq`` windows of dt (500 us, TOFFE's) from every ``train`` sequence,
binned at full resolution and summed over d x d blocks (d = --downsample, 4: 160 x 120 network
input, padded to 160 x 128), cut to a 64 x 64 crop around a moving object (the network is
convolutional: crops cut the training cost 5x; evaluation runs on the whole frame); the target is the per-pixel flow of ``dataset.flowgt`` on the
window's event pixels (objects: their velocity, other events: 0), averaged per block and divided
by d (network px/ms). Loss: mean end-point error over the blocks with events (supervised EPE, as
the paper trains on ground-truth flow), Adam, cosine learning rate, BPTT over the B = 5 steps.

Evaluation: the ``test`` split, the windows ``toffe-deploy eval`` samples (evenly spaced,
--eval-windows per sequence), flow -> objects (baselines.adaptive_spikenet.flow_objects) and
the project's matching and metrics (metrics.FlowErrors, 20 px gate), beside ckpt/eval_test.json.

Cost (--cost-only): per inference on --cost-windows test windows, at the trained resolution and
at the published 640 x 480 (same weights), the op counts of ``op_counts`` under both host rules
(dense, event-driven), their modelled energy (energy.cost_model) and the wall time of the torch
reference and of ONNX Runtime (the optimised level).

Writes to --out (default ckpt/baselines/adaptive_spikenet/): weights.safetensors, config.json,
train_log.json, eval_test.json, cost.json.
"""
from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from toffe_deploy.baselines.registry import ASNET_DIR as DEFAULT_OUT  # noqa: E402  (where the benchmark looks)
from toffe_deploy.commands import add_progress_flag, show_progress  # noqa: E402
from _args import OneLineParser, existing_dir, guarded, nonneg_int, positive_float, positive_int  # noqa: E402

EVAL_WINDOWS, COST_WINDOWS = 6, 16      # the shipped eval_test.json's and cost.json's


def parse_args(argv=None):
    ap = OneLineParser(prog="train_asnet.py", description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", type=Path, default=str(ROOT / "data" / "synth"), help="data set directory (default data/synth)")
    ap.add_argument("--ckpt", type=existing_dir, default=str(ROOT / "ckpt"), help="TOFFE checkpoint whose config (sensor, bins, "
                                                               "grouping) the baseline shares (default ckpt/)")
    ap.add_argument("--out", default=str(DEFAULT_OUT), help="output directory (default ckpt/baselines/adaptive_spikenet/)")
    ap.add_argument("--minutes", type=positive_float, default=35.0, help="training wall-time budget (default 35)")
    ap.add_argument("--per-seq", type=positive_int, default=12, help="training windows per train sequence (default 12)")
    ap.add_argument("--downsample", type=positive_int, default=4, help="sensor pixels summed per network pixel, per side (default 4)")
    ap.add_argument("--batch", type=positive_int, default=16)
    ap.add_argument("--lr", type=positive_float, default=2e-3)
    ap.add_argument("--threads", type=positive_int, default=1, help="torch threads (default 1: on a shared 2-core machine 2 threads ran 10x slower)")
    ap.add_argument("--seed", type=nonneg_int, default=0)
    ap.add_argument("--eval-windows", type=positive_int, default=EVAL_WINDOWS,
                    help=f"test windows per sequence (default {EVAL_WINDOWS}, as ckpt/eval_test.json)")
    add_progress_flag(ap)
    ap.add_argument("--eval-only", action="store_true", help="evaluate the weights in --out, no training "
                    "(with --cost-only: both)")
    ap.add_argument("--limit", type=positive_int, help="use only this many sequences per split (quick runs)")
    ap.add_argument("--cost-only", action="store_true", help="only count operations and time inference (cost.json)")
    ap.add_argument("--cost-windows", type=positive_int, default=COST_WINDOWS,
                    help=f"test windows for the cost figures (default {COST_WINDOWS})")
    return ap.parse_args(argv)


def log(msg: str) -> None:
    print(f"[train_asnet] {msg}", file=sys.stderr, flush=True)


def window_sample(src, gt, radii, t0: int, cfg, config):
    """(network input (B, 2, H', W') uint8, target (2, H', W') float16 network px/ms, weight
    (H', W') uint8 = event pixels per block) of one window."""
    from toffe_deploy.baselines.adaptive_spikenet import network_input
    from toffe_deploy.dataset.flowgt import dense_flow
    from toffe_deploy.dataset.groundtruth import window_truth
    from toffe_deploy.events.binning import bin_window

    dt, d = config.dt_us, cfg.downsample
    binned = bin_window(src.read(t0, t0 + dt), t0, dt, config.n_bins, tuple(config.sensor_size), dtype=np.uint8)
    mask = binned.any(axis=(0, 1))
    flow, _owner = dense_flow(mask, window_truth(gt, t0, dt), radii, dt)
    x = network_input(binned, cfg)
    x = np.minimum(x, 255).astype(np.uint8)
    one = network_input(flow[None], cfg)[0]          # flow summed over each block's event pixels
    wsum = network_input(np.stack([mask, mask]).astype(np.float32)[None], cfg)[0, 0]
    target = np.where(wsum > 0, one / np.maximum(wsum, 1) / d, 0).astype(np.float16)
    return x, target, np.minimum(wsum, 255).astype(np.uint8)


CROP = 64   # network px per side of a training crop (256 sensor px at d = 4): a multiple of 16


def crop_sample(x, target, weight, rng, crop: int = CROP):
    """A crop x crop cut of one sample around a random moving-object block (jitter: anywhere the
    block stays inside), else around a random event block; the crop stays inside the frame."""
    h, w = weight.shape
    moving = np.argwhere((np.abs(target).sum(axis=0) > 0) & (weight > 0))
    cand = moving if moving.size else np.argwhere(weight > 0)
    cy, cx = cand[rng.integers(cand.shape[0])] if cand.size else (h // 2, w // 2)
    y0 = int(np.clip(cy - rng.integers(8, crop - 8), 0, h - crop))
    x0 = int(np.clip(cx - rng.integers(8, crop - 8), 0, w - crop))
    sl = (slice(y0, y0 + crop), slice(x0, x0 + crop))
    return x[(Ellipsis,) + sl], target[(Ellipsis,) + sl], weight[sl]


def build_set(files, cfg, config, per_seq: int, rng, progress: bool = False) -> dict:
    from toffe_deploy.dataset.flowgt import object_radii_px
    from toffe_deploy.events.io import open_events
    from tqdm import tqdm

    xs, ts, ws = [], [], []
    for path in tqdm(files, desc="training windows", unit="seq", file=sys.stderr, disable=not progress):
        with open_events(path) as src:
            gt, radii = src.ground_truth, object_radii_px(src.attrs)
            starts = np.arange(src.t_start_us, src.t_end_us - config.dt_us + 1, config.dt_us)
            for t0 in rng.choice(starts, size=min(per_seq, starts.size), replace=False):
                x, t, w = crop_sample(*window_sample(src, gt, radii, int(t0), cfg, config), rng)
                if w.any():
                    xs.append(x)
                    ts.append(t)
                    ws.append(w)
    return {"x": np.stack(xs), "target": np.stack(ts), "weight": np.stack(ws)}


def epe_loss(pred, target, weight):
    """Mean end-point error over blocks with events (each block counts once)."""
    import torch

    m = (weight > 0).to(pred.dtype)
    err = torch.sqrt(((pred - target) ** 2).sum(dim=1) + 1e-6)
    return (err * m).sum() / m.sum().clamp(min=1.0)


def train(args, config, cfg, files) -> dict:
    import torch

    from toffe_deploy.baselines.adaptive_spikenet import build_model, save_baseline

    torch.manual_seed(args.seed)
    rng = np.random.default_rng(args.seed)
    t_build = time.perf_counter()
    data = build_set(files, cfg, config, args.per_seq, rng, progress=show_progress(args))
    n = data["x"].shape[0]
    log(f"{n} training windows {tuple(data['x'].shape[1:])} in {time.perf_counter() - t_build:.0f} s")
    model = build_model(cfg)
    opt = torch.optim.Adam(model.parameters(), lr=args.lr)
    budget = args.minutes * 60.0
    t0 = time.perf_counter()
    history, it, running = [], 0, None
    while True:
        el = time.perf_counter() - t0
        if el >= budget:
            break
        for g in opt.param_groups:        # cosine over the wall-time budget
            g["lr"] = args.lr * 0.5 * (1.0 + np.cos(np.pi * min(el / budget, 1.0)))
        idx = rng.choice(n, size=min(args.batch, n), replace=False)
        x = torch.from_numpy(data["x"][idx].astype(np.float32))
        tgt = torch.from_numpy(data["target"][idx].astype(np.float32))
        w = torch.from_numpy(data["weight"][idx].astype(np.float32))
        if rng.random() < 0.5:            # horizontal flip: u changes sign
            x, tgt, w = x.flip(-1), tgt.flip(-1), w.flip(-1)
            tgt = torch.stack([-tgt[:, 0], tgt[:, 1]], dim=1)
        loss = epe_loss(model(x), tgt, w)
        opt.zero_grad()
        loss.backward()
        opt.step()
        running = float(loss) if running is None else 0.98 * running + 0.02 * float(loss)
        it += 1
        if it % 50 == 0:
            history.append({"iter": it, "s": round(time.perf_counter() - t0, 1), "loss_ema": round(running, 5),
                            "lr": opt.param_groups[0]["lr"]})
            log(f"iter {it} {history[-1]['s']:.0f} s EPE(ema) {running:.4f} net px/ms")
    wall = time.perf_counter() - t0
    lif = {"leak": model.leak.detach().clamp(0, 1).tolist(), "vth": model.vth.detach().clamp(min=0.05).tolist()}
    train_log = {"windows": int(n), "iterations": it, "batch": args.batch, "lr": args.lr, "wall_s": round(wall, 1),
                 "threads": args.threads, "per_seq": args.per_seq, "seed": args.seed, "final_epe_ema_net": running,
                 "final_epe_ema_sensor_px_ms": running * cfg.downsample if running is not None else None,
                 "history": history, "learned_lif": lif}
    save_baseline(args.out, model, cfg, {"trained_on": str(args.data), "train_split": "train",
                                         "dt_us": config.dt_us, "sensor_size": list(config.sensor_size)})
    return train_log


def evaluate(args, config, files) -> dict:
    from tqdm import tqdm

    from toffe_deploy.baselines.adaptive_spikenet import AdaptiveSpikeNetBaseline
    from toffe_deploy.dataset.groundtruth import window_truth
    from toffe_deploy.evaluate import _sample_starts
    from toffe_deploy.events.binning import bin_window
    from toffe_deploy.events.io import open_events
    from toffe_deploy.metrics import GATE_PX, FlowErrors
    from toffe_deploy.runtime.truth import sequence_focal_px

    base = AdaptiveSpikeNetBaseline.load(args.out, config)
    dt = config.dt_us
    errs = FlowErrors(gate_px=GATE_PX, n_bins=config.n_speed_bins, pred_scale=config.speed_scale)
    t_inf = []
    for path in tqdm(files, desc="eval test", unit="seq", file=sys.stderr, disable=not show_progress(args)):
        with open_events(path) as src:
            gt, focal = src.ground_truth, sequence_focal_px(src.attrs)
            for t0 in _sample_starts(src.t_start_us, src.t_end_us, dt, args.eval_windows):
                ev = src.read(int(t0), int(t0) + dt)
                binned = bin_window(ev, int(t0), dt, config.n_bins, tuple(config.sensor_size), dtype=np.uint8)
                t1 = time.perf_counter()
                preds = base.detect_binned(binned)
                t_inf.append(time.perf_counter() - t1)
                errs.add_window(preds, window_truth(gt, int(t0), dt), focal)
    return {"checkpoint": str(args.out), "split": "test", "dt_us": dt, "sequences": len(files),
            "max_windows_per_sequence": args.eval_windows, "network_downsample": base.cfg.downsample,
            "all": errs.summary(), "per_bin": {str(k): errs.summary(k) for k in range(1, config.n_speed_bins + 1)},
            "wall_ms_per_window_p50": float(np.median(t_inf) * 1e3) if t_inf else None}


def cost(args, config, files) -> dict:
    """Operations, modelled energy and reference wall time per inference on test windows, at the
    trained resolution (d = downsample) and at the published full resolution (d = 1, the same
    weights on the unsummed 640 x 480 window: the sizes the paper's Table 2 ran; its spike rates
    are those of weights trained at d)."""
    import dataclasses

    import torch

    from toffe_deploy.baselines.adaptive_spikenet import AdaptiveSpikeNetBaseline, network_input
    from toffe_deploy.energy.cost_model import HOST_LABEL, HostOps
    from toffe_deploy.energy.measure import latency_percentiles
    from toffe_deploy.evaluate import _sample_starts
    from toffe_deploy.events.binning import bin_window
    from toffe_deploy.events.io import open_events

    base = AdaptiveSpikeNetBaseline.load(args.out, config)
    full = AdaptiveSpikeNetBaseline(base.model, dataclasses.replace(base.cfg, downsample=1), config)
    dt = config.dt_us
    wins = []
    for path in files[:: max(1, len(files) // args.cost_windows)][:args.cost_windows]:
        with open_events(path) as src:
            t0 = int(_sample_starts(src.t_start_us, src.t_end_us, dt, 3)[1])
            ev = np.array(src.read(t0, t0 + dt))
            wins.append((t0, ev, bin_window(ev, t0, dt, config.n_bins, tuple(config.sensor_size), dtype=np.uint8)))
    out = {"windows": len(wins), "dt_us": dt, "energy_kind": HOST_LABEL, "torch_threads": torch.get_num_threads(),
           "timing": "batch 1, reference = torch eager fp32, optimised = ONNX Runtime fp32 (onnx_session), one "
                     "thread each; the whole inference (binning, network, flow -> objects) at the trained resolution, "
                     "binning + network at full resolution"}
    for name, b in (("trained_resolution", base), ("full_resolution", full)):
        rows = [b.op_counts(w[2]) for w in wins]
        tot = {k: float(np.mean([r["totals"][k] for r in rows])) for k in rows[0]["totals"]}
        dense = HostOps(**{k: float(np.mean([r["host_dense"][k] for r in rows])) for k in rows[0]["host_dense"]})
        event = HostOps(**{k: float(np.mean([r["host_event"][k] for r in rows])) for k in rows[0]["host_event"]})
        layers = [{"name": l0["name"], "in_hw": l0["in_hw"], "c_in": l0["c_in"], "c_out": l0["c_out"],
                   "kernel": l0["kernel"], "stride": l0["stride"],
                   "input_rate": float(np.mean([r["layers"][i]["input_rate"] for r in rows])),
                   "dense_macs": l0["dense_macs"],
                   "event_ops": float(np.mean([r["layers"][i]["event_ops"] for r in rows]))}
                  for i, l0 in enumerate(rows[0]["layers"])]
        lats = {}
        for level, bb in (("reference", b), ("optimised", b.optimised())):
            if name == "trained_resolution":
                def run(i, bb=bb):
                    return bb.detect(wins[i][1], wins[i][0])
            else:
                def run(i, bb=bb):
                    return bb.net_flow(bin_window(wins[i][1], wins[i][0], dt, config.n_bins,
                                                  tuple(config.sensor_size), dtype=np.uint8))
            for i in range(min(3, len(wins))):
                run(i)
            lat = []
            for i in range(len(wins)):
                t1 = time.perf_counter()
                run(i)
                lat.append(time.perf_counter() - t1)
            lats[level] = latency_percentiles(lat)
        out[name] = {"network_input_wh": rows[0]["network_input_wh"], "params": rows[0]["params"], "totals": tot,
                     "host_dense": dense.to_dict(), "host_event": event.to_dict(),
                     "E_dense_mj": dense.energy_j() * 1e3, "E_event_mj": event.energy_j() * 1e3,
                     "latency": lats, "layers": layers}
        log(f"{name}: {tot['dense_macs'] / 1e9:.3f} GMAC dense, {tot['event_acs'] / 1e6:.1f} M AC + "
            f"{tot['event_macs'] / 1e6:.2f} M MAC event-driven; E dense {dense.energy_j() * 1e3:.3g} mJ, "
            f"event {event.energy_j() * 1e3:.3g} mJ (modelled); L p50 {lats['reference']['p50_ms']:.1f} ms "
            f"torch, {lats['optimised']['p50_ms']:.1f} ms onnxruntime")
    return out


def writes_results(args) -> bool:
    """Whether the run writes its JSON files: not a reduced run (--limit, fewer windows) into the
    shipped directory, which would replace the figures the README quotes (it did, silently, with
    recall NaN); its results are printed instead."""
    reduced = args.limit is not None or args.eval_windows != EVAL_WINDOWS or args.cost_windows != COST_WINDOWS
    return not (reduced and Path(args.out).resolve() == DEFAULT_OUT.resolve())


def main(argv=None) -> int:
    return guarded("train_asnet", run, parse_args(argv))


def run(args) -> int:
    import torch

    from toffe_deploy.baselines.adaptive_spikenet import ASNetConfig
    from toffe_deploy.checkpoint import load_checkpoint
    from toffe_deploy.evaluate import split_files
    from toffe_deploy.fileio import atomic_path, check_outputs, json_text

    torch.set_num_threads(args.threads)
    config = load_checkpoint(args.ckpt).config
    cfg = ASNetConfig(downsample=args.downsample, n_bins=config.n_bins, dt_us=config.dt_us)
    out = Path(args.out)
    check_outputs(dirs=[("--out", out)])
    keep = writes_results(args)

    def write(name: str, obj: dict) -> None:
        if not keep:
            log(f"{name} not written: a reduced run (--limit, --eval-windows, --cost-windows) does not replace "
                f"the shipped figures in {out} (copy the baseline elsewhere and give that as --out to keep it)")
            return
        with atomic_path(out / name, suffix=".json") as tmp:
            tmp.write_text(json_text(obj, indent=1) + "\n")
        log(f"wrote {out / name}")

    test = split_files(Path(args.data), "test")[:args.limit]        # before training: a missing split fails now
    if not (args.eval_only or args.cost_only):
        files = split_files(Path(args.data), "train")[:args.limit]
        write("train_log.json", train(args, config, cfg, files))
    if args.cost_only:
        c = cost(args, config, test)
        write("cost.json", c)
        if not keep:
            print(json_text(c, indent=1))
        if not args.eval_only:
            return 0
    res = evaluate(args, config, test)
    write("eval_test.json", res)
    a = res["all"]
    print(json_text({k: a[k] for k in ("recall", "fp_per_window", "pixE", "dirE", "speedE", "speedE_px_ms",
                                       "bin_accuracy")}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
