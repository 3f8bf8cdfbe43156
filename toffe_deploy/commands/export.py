"""`toffe-deploy export CKPT [-o export/]`: the verified deploy bundle (see export/README.md)."""
from __future__ import annotations

from . import add_progress_flag, show_progress, slow_notice
from .dataset import _nonneg_int

CHECK_NAMES = ("fixed_vs_float", "lava_vs_fixed", "netx_vs_fixed", "onnx_vs_torch", "end_to_end")


def register(sub) -> None:
    p = sub.add_parser(
        "export", help="quantize a checkpoint for Loihi 2, export OFPD to ONNX, verify, write a bundle",
        description="Turn a trained checkpoint into a deploy bundle: the OFS stages in Loihi 2 fixed point "
                    "(ofs_loihi.json for lava_procs, lava-dl netx HDF5, a NIR graph), OFPD as ONNX (opset 17, "
                    "dynamic batch), manifest.json with the sha256 of every file, and parity.json from five "
                    "checks run on every export (fixed point vs float, Lava vs fixed point, ONNX vs torch, "
                    "end-to-end object flow). The output is written atomically.")
    p.add_argument("checkpoint", metavar="CKPT", help="checkpoint directory (config.json, ofs.safetensors, "
                                                      "ofpd.safetensors), e.g. ckpt/")
    p.add_argument("-o", "--out", default="export", metavar="DIR",
                   help="bundle directory to write (default: export/); an existing bundle is replaced, unless it "
                        "holds files that are not the bundle's (refused: --force)")
    p.add_argument("--force", action="store_true",
                   help="replace the output directory whole even if it is not a bundle or holds files that are not "
                        "the bundle's")
    p.add_argument("--variants", default="", metavar="LIST",
                   help="comma-separated extra OFPD precisions for the edge GPU: fp16, int8 (default: none)")
    p.add_argument("--data", metavar="DIR", default=None,
                   help="data set directory whose held-out 'test' sequences give the parity windows, recorded at "
                        "the checkpoint's sensor size (the netx and NIR files hold the checkpoint's grid; another "
                        "camera's data is refused) (default: generate small multi-object scenes with a fixed seed)")
    p.add_argument("--windows", type=int, default=16, metavar="N",
                   help="number of held-out windows for the parity checks (default: 16)")
    p.add_argument("--lava-windows", type=int, default=2, metavar="N",
                   help="windows (48x32 crops) run on the Lava simulator for the bit-exactness and netx checks (default: 2)")
    p.add_argument("--checks", default=",".join(CHECK_NAMES), metavar="LIST",
                   help=f"comma-separated parity checks to run, or 'none' (default: all: {','.join(CHECK_NAMES)})")
    p.add_argument("--seed", type=_nonneg_int, default=0,
                   help="seed (>= 0) for choosing/generating held-out windows (default: 0)")
    p.add_argument("--strict", action="store_true",
                   help="exit with status 1 when a parity check fails its goal (the bundle is still written)")
    add_progress_flag(p)
    p.set_defaults(func=run)


def _list(s: str) -> list[str]:
    return [x.strip() for x in s.split(",") if x.strip()]


def check_export_output(args) -> None:
    """-o is replaced as a whole: it may not be, hold or lie inside the checkpoint or --data."""
    import os
    from pathlib import Path

    from ..errors import InputError, ToffeError
    from ..fileio import check_outputs

    if not args.out:                  # "" is the current directory to os.path, and an empty name in messages
        raise ToffeError("-o is empty: name the bundle directory to write, e.g. -o export")
    out = Path(os.path.realpath(args.out))
    for what, p in (("the checkpoint", args.checkpoint), ("the --data set", args.data)):
        if p is None:
            continue
        real = Path(os.path.realpath(p))
        if real.is_relative_to(out) or out.is_relative_to(real):
            raise InputError(args.out, f"-o overlaps {what} {p} (export replaces the whole -o directory); "
                                       "choose another -o")
    check_outputs(dirs=[("-o", args.out)])


def run(args) -> int:
    import sys

    from ..errors import ToffeError
    from ..camera import speed_text
    from ..deploy.exporter import export_bundle
    from ..deploy.parity import summary_lines

    checks = [] if args.checks.strip().lower() == "none" else _list(args.checks)
    if not checks and args.checks.strip().lower() != "none":          # '' ran no check, silently
        raise ToffeError("--checks is empty: give parity checks by name, or none")
    bad = [c for c in checks if c not in CHECK_NAMES]
    if bad:
        raise ToffeError(f"unknown parity check(s) {', '.join(bad)} (choose from {', '.join(CHECK_NAMES)} or none)")
    if args.windows < 1 or args.lava_windows < 1:
        raise ToffeError("--windows and --lava-windows must be >= 1")
    check_export_output(args)
    if args.data is not None and not checks and not _list(args.variants):     # (it was dropped silently)
        print(f"toffe-deploy: warning: --data {args.data} is not read: it gives the windows of the parity checks "
              "and of the OFPD variants' error, and --checks none without --variants runs neither", file=sys.stderr)
    with slow_notice(args, "\ntoffe-deploy: the parity checks run the pipeline, whose kernels the first run on a "
                           "machine compiles (about 2 minutes, once)", after_s=45.0):   # a warm export: ~22 s
        res = export_bundle(args.checkpoint, args.out, force=args.force, variants=_list(args.variants),
                            checks=checks, data=args.data, seed=args.seed, n_windows=args.windows,
                            lava_windows=args.lava_windows, progress=show_progress(args))
    b = res.bundle
    print(f"wrote bundle {b.root}/ ({len(b.manifest['files'])} files, {len(b.ofs)} OFS stages, "
          f"sensor {b.config.width}x{b.config.height}, B={b.config.n_bins}, dt={b.config.dt_us} us) "
          f"in {res.seconds:.1f} s")
    cam = b.manifest["camera"]
    print(f"  camera: focal {cam['focal_px']:.1f} px ({cam['hfov_deg']:.1f} deg over {b.config.width} px); speed bins "
          + ", ".join(f"{lo * 1000:.0f}-{hi * 1000:.0f}" for lo, hi in cam["speed_bins_px_ms"])
          + " px/s = " + ", ".join(f"{speed_text(lo)}-{speed_text(hi)}" for lo, hi in cam["speed_bins_mps"])
          + f" m/s at {cam['depth_m']:g} m")
    for k, st in enumerate(b.manifest["ofs"]["stages"], start=1):
        qr = b.manifest["ofs"]["quantization"][k - 1]
        print(f"  OFS stage {k}: vth_mant {st['vth_mant']}, dv {st['dv']}, weight scale {st['weight_scale']:.4g}; "
              f"weight error {qr['weight_rel_error']:.2%}, threshold error {qr['threshold_rel_error']:.2%}, "
              f"leak error {qr['leak_abs_error']:.2g}" + (f"; clamped: {'; '.join(st['clamps'])}" if st["clamps"] else ""))
    if res.parity is not None:
        for line in summary_lines(res.parity):
            print(line)
    sys.stdout.flush()
    if args.strict and res.parity is not None and not res.parity["all_pass"]:
        return 1
    return 0
