"""``toffe-deploy export``: checkpoint -> verified deploy bundle.

Order of work, chosen so that a failure never leaves anything at the output path and so that
the parity checks test the very bytes that ship:

1. refuse a non-bundle output directory (before any work), load and validate the checkpoint;
2. quantize the OFS stages (one-line error naming an unrepresentable parameter; clamps become
   warnings), export OFPD to ONNX (+ variants), write netx and NIR files into a staging dir;
3. write a staging bundle and load it back through ``load_bundle`` (hash-verified);
4. run the parity checks against that loaded bundle and the float checkpoint;
5. write the final bundle atomically (same files + parity.json, manifest last).
"""
from __future__ import annotations

import os
import shutil
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence, TextIO

from ..checkpoint import load_checkpoint
from ..errors import ToffeError
from ..fileio import clear_killed, temp_prefix
from .bundle import Bundle, check_output_dir, sha256_file, write_bundle
from .parity import torch_threads
from .quantize import quantize_stages

DEFAULT_CHECKS = ("fixed_vs_float", "lava_vs_fixed", "netx_vs_fixed", "onnx_vs_torch", "end_to_end")


@dataclass
class ExportResult:
    bundle: Bundle
    parity: dict | None
    warnings: list[str]
    seconds: float


def _checkpoint_hashes(root: Path) -> dict[str, str]:
    return {p.name: sha256_file(p) for p in sorted(root.iterdir()) if p.is_file() and not p.name.startswith(".")}


def export_bundle(ckpt_dir: str | os.PathLike, out_dir: str | os.PathLike, *, force: bool = False,
                  variants: Sequence[str] = (), checks: Sequence[str] | None = DEFAULT_CHECKS,
                  data: str | os.PathLike | None = None, seed: int = 0, n_windows: int = 16, lava_windows: int = 2,
                  progress: bool = True, log: TextIO | None | str = "stderr") -> ExportResult:
    """Export a checkpoint directory to a bundle at ``out_dir`` (see module docstring).

    log: where the warnings are printed: a stream, None for nowhere, or "stderr" (the default):
    sys.stderr as it is at the call (a default of sys.stderr itself was the stream of the import,
    not a later redirection's).

    checks: which parity checks to run (None or () = none, for quick bundles in tests).
    data: a data-set directory whose held-out ('test') sequences provide the parity windows;
    otherwise windows are generated with the synthetic generator (seeded, small).
    """
    t_start = time.perf_counter()
    if log == "stderr":
        log = sys.stderr
    out_dir = Path(out_dir)
    check_output_dir(out_dir, force=force)
    if checks and ("lava_vs_fixed" in checks or "netx_vs_fixed" in checks):
        from .parity import _preload_lava
        _preload_lava()         # before the first tqdm bar (see runtime.loihi.import_lava)
    ckpt = load_checkpoint(ckpt_dir)
    config = ckpt.config
    q = quantize_stages(ckpt.ofs, Path(ckpt_dir) / "ofs.safetensors", config.reset)
    warnings = list(q.warnings)
    if config.untrained:           # train's record (model.train.with_untrained): a bundle of it runs, badly
        warnings.append(f"the checkpoint holds parts never trained: {', '.join(map(str, config.untrained))} (a `train "
                        "--stage ofs` checkpoint, or a stopped run's .train_state copy): train them (`train --stage "
                        "ofpd`, or `train --resume`) before deploying")

    from . import onnx_export
    from ..energy.cost_model import loihi2_footprint
    from .parity import VARIANT_E2E_GOAL
    from .netx_h5 import NETX_RESET_OFFSET, RESET_NOTES, write_ofs_netx
    from .nir_graph import NIR_RESET, time_step_s, write_ofs_nir

    for v in variants:
        if v not in onnx_export.VARIANTS:
            raise ToffeError(f"unknown ONNX variant {v!r} (choose from {', '.join(onnx_export.VARIANTS)})")

    parent = _parent(out_dir)
    clear_killed(parent / out_dir.name)         # the staging an export killed before this one left
    stage_root = Path(tempfile.mkdtemp(prefix=temp_prefix(out_dir), suffix=".tmp", dir=parent))
    try:
        stage = stage_root / "files"
        stage.mkdir()
        model = onnx_export.build_ofpd(config, ckpt.ofpd_state)
        with torch_threads(1):
            onnx_path = onnx_export.export_ofpd_onnx(model, config, stage / "ofpd.onnx")
        files: dict[str, Path] = {}
        netx = write_ofs_netx(stage / "netx", config, q.params)
        files.update({f"netx/{p.name}": p for p in netx})
        files["ofs.nir"] = write_ofs_nir(stage / "ofs.nir", config, q.params)

        windows = None
        if variants or checks:
            from .windows import heldout_windows
            windows = heldout_windows(config, data=data, seed=seed, n_windows=n_windows, progress=progress)
        variant_info = {}
        from .parity import variant_error
        calib, held_out = _variant_inputs(windows, q.params, config) if variants else (None, None)
        for v in variants:
            p = onnx_export.make_variant(v, onnx_path, stage / f"ofpd_{v}.onnx", calib=calib if v == "int8" else None)
            files[p.name] = p
            variant_info[v] = {"file": p.name, **_variant_doc(v),
                               "error_vs_fp32": {**variant_error(onnx_path, p, held_out),
                                                 "inputs_from": "objects of the held-out windows not used for calibration "
                                                                "(runtime OFPD inputs, parity.runtime_ofpd_inputs)"}}
            if v == "int8":
                variant_info[v]["calibration_inputs"] = int(len(calib))

        manifest = {
            "source": {"checkpoint": str(Path(ckpt_dir).resolve()), "files_sha256": _checkpoint_hashes(Path(ckpt_dir))},
            "ofs": {"quantization": q.report, "arithmetic": "toffe_deploy.fixed_point (see README.md)",
                    "reset": config.reset,
                    "loihi2_footprint": loihi2_footprint(config.width, config.height, config.n_speed_bins,
                                                         config.ofs_kernel, config.ofs_in_channels, config.ofs_pool)},
            "ofpd": {**onnx_export.onnx_io_info(onnx_path), "variants": variant_info},
            "netx": {"files": sorted(f for f in files if f.startswith("netx/")),
                     "reset_interval": config.n_bins, "reset_offset": NETX_RESET_OFFSET,
                     "input_timing": "bin b of window i enters at Lava step i * n_bins + b + 1",
                     "reproduces_bundle": config.reset == "zero", "reset_note": RESET_NOTES[config.reset]},
            "nir": {"file": "ofs.nir", "nir_version": _version("nir"), "time_step_s": time_step_s(config),
                    "reproduces_bundle": config.reset == "zero", "reset_note": NIR_RESET[config.reset],
                    "note": "tau in seconds, r = 1, the gain in the conv weights; the cascade masking is "
                            "described in the graph metadata"},
            "warnings": warnings,
        }
        staged = write_bundle(stage_root / "bundle", config, q.params, onnx_path, files=files, manifest=manifest,
                              float_params=ckpt.ofs)
        parity = None
        if checks:
            from .parity import run_parity
            parity = run_parity(staged, ckpt, windows, checks=checks, model=model, lava_windows=lava_windows,
                                progress=progress, log=log)
            files["parity.json"] = _json_bytes(parity)
            manifest["parity"] = {name: {"status": c["status"], "headline": c.get("headline")}
                                  for name, c in parity["checks"].items()}
            for v, rep in parity["checks"].get("onnx_vs_torch", {}).get("variants", {}).items():
                variant_info[v]["max_abs_diff_vs_torch"] = rep["max_abs_diff"]
                if rep["non_finite_outputs"]:
                    warnings.append(f"ONNX variant {v}: {rep['non_finite_outputs']} non-finite outputs on held-out inputs")
            warnings += [f"parity {name}: {c['status']} ({c.get('headline')})" for name, c in parity["checks"].items()
                         if c["status"] == "fail"]
            for v, rep in parity["checks"].get("end_to_end", {}).get("variants", {}).items():
                variant_info[v]["end_to_end"] = rep
                worse = {m: r for m, r in rep["relative_to_fp32"].items() if not r <= VARIANT_E2E_GOAL}
                if worse:
                    warnings.append(f"ONNX variant {v}: end to end " + ", ".join(
                        f"{m} {rep['errors'][m]:.3g} ({r:.0%} off fp32)" for m, r in worse.items())
                        + f": more than {VARIANT_E2E_GOAL:.0%} off the fp32 OFPD")
        bundle = write_bundle(out_dir, config, q.params, onnx_path, files=files, manifest=manifest,
                              float_params=ckpt.ofs, force=force)
        for rel, entry in staged.manifest["files"].items():
            if bundle.manifest["files"].get(rel, {}).get("sha256") != entry["sha256"]:
                raise RuntimeError(f"bundle file {rel} differs from the one the parity checks ran on")
    finally:
        shutil.rmtree(stage_root, ignore_errors=True)
    if log is not None:
        for w in warnings:
            print(f"toffe-deploy: warning: {w}", file=log)
    return ExportResult(bundle=bundle, parity=parity, warnings=warnings, seconds=time.perf_counter() - t_start)


def _variant_inputs(windows, params, config):
    """(calibration, held-out) OFPD inputs for the reduced-precision variants: the objects the
    runtime crops from the even and the odd held-out windows (parity.runtime_ofpd_inputs);
    whole stage frames (parity.ofpd_inputs) when the windows hold no object."""
    from .parity import ofpd_inputs, runtime_ofpd_inputs

    n = len(windows.windows)
    calib = runtime_ofpd_inputs(windows, params, config, range(0, n, 2))
    held_out = runtime_ofpd_inputs(windows, params, config, range(1, n, 2))
    if len(calib) == 0:
        calib = ofpd_inputs(windows, params, config)
    if len(held_out) == 0:
        held_out = calib
    return calib, held_out


def _parent(p: Path) -> Path:
    parent = p.resolve().parent
    parent.mkdir(parents=True, exist_ok=True)
    return parent


def _json_bytes(d) -> bytes:
    import json

    return (json.dumps(d, indent=2) + "\n").encode("utf-8")


def _version(name: str) -> str | None:
    from .bundle import package_versions

    return package_versions((name,))[name]


def _variant_doc(v: str) -> dict:
    if v == "fp16":
        return {"precision": "float16 weights and activations, float32 inputs and outputs"}
    return {"precision": "int8 QDQ (static: per-channel int8 weights, int8 activations with ranges calibrated on "
                         "the runtime's OFPD inputs of held-out windows; the three output heads fp32)"}
