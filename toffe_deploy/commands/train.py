"""`toffe-deploy train`: train the OFS stages and the OFPD on a synthetic data set."""
from __future__ import annotations

import sys
from pathlib import Path

from ..config import MAX_DT_US, MAX_MASK_KERNEL
from . import add_progress_flag, show_progress


def register(sub) -> None:
    p = sub.add_parser(
        "train", help="train OFS (per speed bin) and OFPD into a checkpoint directory",
        description="Train TOFFE on the 'train' split of a data set made by `toffe-deploy dataset synth`. "
        "Writes a checkpoint directory (config.json, ofs.safetensors, ofpd.safetensors, train_log.json). "
        "The checkpoint in --out is written when the run's stages are done: an interrupted or failed run leaves it "
        "as it was. Progress is saved after each OFS stage and each OFPD epoch (in --out/.train_state/), so --resume "
        "(same --seed) continues an interrupted run; a run without --resume starts afresh and drops that progress.")
    p.add_argument("--data", required=True, type=Path, help="data-set directory (holds index.json)")
    p.add_argument("--out", required=True, type=Path, help="checkpoint directory to write (e.g. ckpt/)")
    p.add_argument("--stage", choices=("ofs", "ofpd", "all"), default="all",
                   help="what to train: the OFS stages, the OFPD (needs trained OFS in --out), or both (default)")
    p.add_argument("--dt", type=int, default=None,
                   help="window length in microseconds a new checkpoint is trained for (default 500; a run on an "
                        "existing checkpoint (--resume, --stage ofpd, --init-from) keeps its own, and refuses another)")
    p.add_argument("--ofs-epochs", type=int, default=4,
                   help="epochs per OFS stage (default 4; 0 only with --init-from or --resume: keeps their stages)")
    p.add_argument("--epochs", type=int, default=30,
                   help="OFPD epochs (default 30; 0 only with --init-from or --resume: keeps their OFPD)")
    p.add_argument("--windows-per-seq", type=int, default=30,
                   help="training windows sampled per sequence (default 30)")
    p.add_argument("--seed", type=int, default=0, help="random seed for window sampling, init and shuffling (default 0)")
    p.add_argument("--ofpd-pool", type=int, default=None, metavar="P",
                   help="OFPD grid: the network sees (128/P)^2 cells (crop_px 128 / P; with the scaled crop "
                        "each object's crop is pooled to that grid) (default: the checkpoint's setting, else 4); "
                        "a new value trains a fresh OFPD. --stage ofpd/all trains on the current input layout "
                        "(blob grouping, scaled crop, px/ms speed)")
    p.add_argument("--ofpd-kernels", default=None, metavar="K1,K2",
                   help="OFPD conv kernel sizes (default: the checkpoint's, else 3,3); a new value trains a fresh OFPD")
    p.add_argument("--input-norm", choices=("first", "none"), default=None,
                   help="input front end of a new checkpoint: 'first' keeps each pixel's first spike per polarity "
                        "in a window (speed from swept area, not event density; default), 'none' every spike "
                        "(the paper's input)")
    p.add_argument("--min-cluster", type=int, default=None, metavar="N",
                   help="input front end of a new checkpoint: keep only the spikes of pixels in 8-connected "
                        "clusters of >= N event pixels of the window (a background-activity filter; 1 keeps "
                        "all; default 4)")
    p.add_argument("--input-support", default=None, metavar="K,R,M,C",
                   help="input front end of a new checkpoint: also keep a pixel the cluster filter drops when the "
                        "window and the K windows before it fired >= M + C * (2R+1)^2 * (their event-pixel density) "
                        "pixels in its (2R+1)^2 box (config.input_support; the shipped one's: 4,2,5,2; default off)")
    p.add_argument("--ofs-kernel", type=int, default=None, metavar="K",
                   help="OFS conv kernel size of a new checkpoint (odd; default 5, the shipped one's: slow edges move "
                        "under a pixel per time bin; the paper's is 3)")
    p.add_argument("--ofs-pool", type=int, default=None, metavar="P",
                   help="run the OFS stages on the sensor OR-pooled over P x P pixel blocks (their masks come back "
                        "to every pixel, OFPD is unchanged); 2 puts 640x480 x 4 stages on one Loihi 2 chip "
                        "(default: the checkpoint's; a new checkpoint 2)")
    p.add_argument("--mask-kernel", type=int, default=None, metavar="K",
                   help="side of the cascade's closing kernel, in OFS-grid cells (default: the checkpoint's; a new "
                        "checkpoint 5, the paper's)")
    p.add_argument("--reset", choices=("subtract", "zero"), default=None,
                   help="OFS neuron reset: 'subtract' (the paper's eq. 1) or 'zero' (Loihi 2's stock CUBA LIF, "
                        "what NeuroCores, netx and NIR run) (default: the checkpoint's, else subtract)")
    p.add_argument("--init-from", type=Path, default=None, metavar="CKPT",
                   help="start from this checkpoint's config, OFS stages and OFPD (fine-tune them, e.g. with --reset "
                        "zero or on your camera's data; --stage all then fine-tunes the OFPD on the new stages' "
                        "outputs, --epochs 0 keeps it as it is)")
    p.add_argument("--speed-balance", action="store_true",
                   help="OFPD speed loss: weigh each sample by the inverse frequency of its true speed bin "
                        "(model/train.py SpeedLoss; default off: plain L1 on ln speed)")
    p.add_argument("--speed-edge-weight", type=float, default=0.0, metavar="W",
                   help="OFPD speed loss: add W times the distance (ln speed) by which the regressed speed lies "
                        "outside its true bin, whose edges give the reported bin (default 0)")
    p.add_argument("--resume", action="store_true", help="continue from the training state saved in --out")
    p.add_argument("--device", default="auto", help="torch device: auto (CUDA when present, else CPU), cpu, cuda")
    add_progress_flag(p)
    p.set_defaults(func=run)


def run(args) -> int:
    from ..errors import ToffeError

    if args.ofpd_pool is not None and args.ofpd_pool < 1:
        raise ToffeError(f"--ofpd-pool must be a positive number of pixels, got {args.ofpd_pool}")
    kernels = None
    if args.ofpd_kernels is not None:
        try:
            kernels = tuple(int(k) for k in args.ofpd_kernels.split(","))
        except ValueError:
            raise ToffeError(f"--ofpd-kernels needs two odd sizes like 3,3, got {args.ofpd_kernels!r}") from None
    if args.min_cluster is not None and args.min_cluster < 1:
        raise ToffeError(f"--min-cluster must be >= 1, got {args.min_cluster}")
    support = None
    if args.input_support is not None:
        from ..events.frontend import check_support

        try:
            support = check_support([int(v) for v in args.input_support.split(",")])
        except ValueError as exc:
            raise ToffeError(f"--input-support: {exc}") from None
    if args.ofs_pool is not None and not 1 <= args.ofs_pool <= 16:
        raise ToffeError(f"--ofs-pool must be 1..16, got {args.ofs_pool}")
    if args.mask_kernel is not None and not 1 <= args.mask_kernel <= MAX_MASK_KERNEL:
        raise ToffeError(f"--mask-kernel must be 1..{MAX_MASK_KERNEL}, got {args.mask_kernel}")
    if args.seed < 0:
        raise ToffeError(f"--seed must be >= 0, got {args.seed}")
    if args.ofs_kernel is not None and (args.ofs_kernel < 1 or args.ofs_kernel % 2 == 0):
        raise ToffeError(f"--ofs-kernel must be an odd positive size, got {args.ofs_kernel}")
    if not args.speed_edge_weight >= 0:
        raise ToffeError(f"--speed-edge-weight must be >= 0, got {args.speed_edge_weight}")
    for name in ("dt", "ofs_epochs", "epochs", "windows_per_seq"):
        low = 0 if "epochs" in name else 1
        if getattr(args, name) is not None and getattr(args, name) < low:
            raise ToffeError(f"--{name.replace('_', '-')} must be {'>= 0' if low == 0 else 'positive'}, "
                             f"got {getattr(args, name)}")
    # 0 epochs keeps what the run starts from: --init-from's (or a resumed run's) weights; from
    # scratch it wrote a checkpoint with a random OFPD or DOTIE's OFS stages, exit 0
    if not (args.init_from or args.resume):
        if args.epochs == 0 and args.stage in ("ofpd", "all"):
            raise ToffeError("--epochs 0 would leave the OFPD untrained: train it (--epochs N), keep another "
                             "checkpoint's with --init-from CKPT, or train the OFS stages only (--stage ofs)")
        if args.ofs_epochs == 0 and args.stage in ("ofs", "all"):
            raise ToffeError("--ofs-epochs 0 would leave the OFS stages untrained: train them (--ofs-epochs N) or "
                             "keep another checkpoint's with --init-from CKPT")
    if args.dt is not None and args.dt > MAX_DT_US:                 # the checkpoint's config would be refused, after the training
        raise ToffeError(f"--dt must be <= {MAX_DT_US} us, got {args.dt}")
    from ..fileio import check_outputs

    check_outputs(dirs=[("--out", args.out)], inputs=[("the data set", args.data),      # before any training
                                                      ("the --init-from checkpoint", args.init_from)])
    from ..deploy.bundle import is_bundle_dir

    if is_bundle_dir(args.out):          # training wrote a checkpoint into it, exit 0: the bundle's hashes then failed
        raise ToffeError(f"--out {args.out}: a deploy bundle (export's output), which training would overwrite: "
                         "train into a checkpoint directory (e.g. ckpt-mine/), then export it")
    import torch

    if args.device not in ("auto", "cpu") and not args.device.startswith("cuda"):
        raise ToffeError(f"--device must be auto, cpu or cuda[:N], got {args.device}")
    if args.device.startswith("cuda") and not torch.cuda.is_available():
        raise ToffeError("--device cuda: no CUDA device available")
    from ..model.train import SpeedLoss, TrainOptions, train

    from ..signals import signal_behind

    torch.set_num_threads(max(1, min(torch.get_num_threads(), 2)))
    try:
        out = train(TrainOptions(data=args.data, out=args.out, stage=args.stage, ofs_epochs=args.ofs_epochs,
                                 ofpd_epochs=args.epochs, seed=args.seed, resume=args.resume, dt_us=args.dt,
                                 per_file=args.windows_per_seq, device=args.device, ofpd_pool=args.ofpd_pool,
                                 ofpd_kernels=kernels, progress=show_progress(args), input_norm=args.input_norm,
                                 ofs_kernel=args.ofs_kernel, min_cluster=args.min_cluster, reset=args.reset,
                                 init_from=args.init_from, ofs_pool=args.ofs_pool, mask_kernel=args.mask_kernel,
                                 input_support=support,
                                 speed_loss=SpeedLoss(args.speed_balance, float(args.speed_edge_weight))))
    except BaseException as exc:
        if signal_behind(exc) is not None:       # said before cli's "interrupted" line
            print(f"toffe-deploy: {args.out}: left as it was; `train ... --resume` with the same options "
                  "continues from the stages this run finished", file=sys.stderr)
        raise
    if out is not None:                  # None: a --resume of a finished run (train said so)
        print(f"checkpoint written to {out}" + _log_summary(Path(out)))
    return 0


def _log_summary(out: Path) -> str:
    """`` (N training windows, T s; per stage and epoch: OUT/train_log.json)`` from the run's
    log, so that a run without a terminal (no progress bars) says more than where it wrote."""
    from ..errors import InputError
    from ..fileio import read_json

    try:
        log = read_json(out / "train_log.json")
    except InputError:
        return ""
    if not isinstance(log, dict):
        return ""
    parts = [f"{log['train_windows']:,} training windows" if isinstance(log.get("train_windows"), int) else None,
             f"{log['train_seconds']:.0f} s" if isinstance(log.get("train_seconds"), (int, float)) else None]
    loss = log.get("ofpd_loss")
    if isinstance(loss, list) and loss and isinstance(loss[-1], list) and len(loss[-1]) == 3:
        parts.append("OFPD losses of its last epoch: pose {:.3g}, direction {:.3g}, log speed {:.3g}".format(
            *map(float, loss[-1])))
    return " (" + "; ".join([p for p in parts if p] + [f"per stage and epoch: {out / 'train_log.json'}"]) + ")"
