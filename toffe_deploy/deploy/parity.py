"""The four parity checks every export runs, against the staged bundle that will ship.

1. fixed_vs_float: the numpy fixed-point OFS (toffe_deploy.fixed_point, the arithmetic Lava runs)
   against the float torch OFS of the checkpoint, each stage on the same held-out inputs;
   spikes of the float model are the reference: F1 = 2 TP / (2 TP + FP + FN).   goal F1 >= 0.99
2. lava_vs_fixed: the Lava simulator (Loihi2SimCfg, fixed_pt, lava_procs via
   toffe_deploy.runtime.loihi.run_ofs_lava) against the numpy reference on a few small crops
   of held-out windows; differing spikes.                                      goal 0
3. onnx_vs_torch: onnxruntime on the bundle's ofpd.onnx against the torch OFPD on real OFPD
   inputs (prepared held-out frames), batched and one by one (dynamic N): max |diff|.
                                                                               goal < 1e-4
4. end_to_end: object flow of the deployed pipeline (fixed-point cascade + onnxruntime; the
   runtime's cpu Pipeline when importable) against the float pipeline (torch OFS + torch
   OFPD), both scored with toffe_deploy.metrics against ground truth: pixE, dirE, speedE and
   their relative difference.                                                  goal within 2 %

A check that cannot run reports ``skipped: <reason>``; none passes silently.
"""
from __future__ import annotations

import copy
import math
import sys
import time
from pathlib import Path
from typing import Sequence, TextIO

import cv2
import numpy as np

from ..cascade import pool_any
from ..config import ToffeConfig
from ..fixed_point import LoihiOFSParams, run_ofs_fixed
from .bundle import Bundle
from .windows import HeldOut

F1_GOAL = 0.99
ONNX_GOAL = 1e-4
E2E_GOAL = 0.02
VARIANT_E2E_GOAL = 0.10   # a reduced-precision OFPD end to end vs the fp32 one (reported, not a pass/fail)
LAVA_CROP = (48, 32)       # (width, height) of the crops the Lava simulator runs on


# ----------------------------------------------------------------------------- helpers

def float_ofs_models(ofs: Sequence[dict], config: ToffeConfig):
    """The checkpoint's float OFS stages as torch modules (index k-1), eval mode."""
    import torch

    from ..model.ofs import OFS

    models = []
    for st in ofs:
        m = OFS(config.ofs_in_channels, config.ofs_kernel, float(st["threshold"]), float(st["leak"]), reset=config.reset)
        with torch.no_grad():
            m.conv.weight.copy_(torch.from_numpy(np.asarray(st["weight"], dtype=np.float32)))
        models.append(m.eval())
    return models


def ofpd_inputs(held: HeldOut, params: Sequence[LoihiOFSParams], config: ToffeConfig, limit: int = 64) -> np.ndarray:
    """Prepared OFPD inputs (n, C, h, w) of the fixed-point cascade's frames on held-out windows.

    Frames that has_object accepts come first; if there are fewer than 4, other stage frames
    fill up so that the comparison (and int8 calibration) always has inputs.
    """
    from .. import ofpd_io
    from ..model.reference import fixed_stage_fn
    from ..cascade import run_cascade

    run = fixed_stage_fn(list(params))
    good, other = [], []
    for w in held.windows:
        res = run_cascade(w, run, config.n_speed_bins, config.mask_kernel, config.ofs_pool)
        frames = np.stack(res.frames)
        ok = ofpd_io.has_object(frames, config)
        good += [f for f, o in zip(frames, ok) if o]
        other += [f for f, o in zip(frames, ok) if not o and f.any()]
        if len(good) >= limit:
            break
    frames = (good + other)[:max(len(good), 4)][:limit]
    if not frames:
        frames = [np.zeros((config.n_bins, 2, config.height, config.width), dtype=bool)]
    return ofpd_io.prepare(np.stack(frames), config)


def runtime_ofpd_inputs(held: HeldOut, params: Sequence[LoihiOFSParams], config: ToffeConfig,
                        windows: Sequence[int] | None = None) -> np.ndarray:
    """The OFPD inputs (n, C, g, g) float32 the runtime's cpu pipeline builds on held-out windows:
    the cascade's frames grouped into objects and cropped (runtime.ofpd_input.batch, as
    Pipeline.objects_of), one row per object. ``windows``: indices of held.windows to use (all).
    These are what int8 calibration and its error report must see: real objects, not frames."""
    from ..compiled import new_scratch
    from ..runtime import ofpd_input
    from ..runtime.cpu import CpuCascade
    from ..runtime.pipeline import sensor_frames
    from ..runtime.spikes import SpikeVolume

    casc = CpuCascade(list(params), config.n_bins, config.mask_kernel, config.ofs_grid())
    scratch = new_scratch(config.width * config.height)
    xs = []
    for i in (range(len(held.windows)) if windows is None else windows):
        vol = SpikeVolume.from_dense(np.asarray(held.windows[i]) > 0).front_end(config.input_norm)
        _ks, x, _n, _ones = ofpd_input.batch(vol, sensor_frames(casc, vol, config.ofs_pool), config, scratch,
                                             held.recent(i, config))
        xs.append(x)
    from ..ofpd_io import input_shape

    return np.concatenate(xs) if xs else np.zeros((0,) + tuple(input_shape(config)), np.float32)


def variant_error(fp32_onnx, variant_onnx, x: np.ndarray) -> dict:
    """A reduced-precision OFPD against fp32 on inputs x: pose error (px), direction error (deg),
    speed ratio exp|ln v - ln v_fp32| (the speed head is ln speed), as max / p95 / mean."""
    from ..metrics import angle_error_deg
    from .onnx_export import ort_session, run_onnx

    if len(x) == 0:
        return {"inputs": 0}
    ref, got = run_onnx(ort_session(fp32_onnx), x), run_onnx(ort_session(variant_onnx), x)
    pose = np.hypot(*(got[0] - ref[0]).T)
    ang = angle_error_deg(np.arctan2(got[1][:, 1], got[1][:, 0]), np.arctan2(ref[1][:, 1], ref[1][:, 0]))
    ratio = np.exp(np.abs(got[2][:, 0] - ref[2][:, 0]))

    def stats(v):
        v = np.asarray(v, np.float64)
        return {"max": float(v.max()), "p95": float(np.percentile(v, 95)), "mean": float(v.mean())}
    return {"inputs": int(len(x)), "pose_px": stats(pose), "direction_deg": stats(ang), "speed_ratio": stats(ratio)}


def _f1(tp: int, fp: int, fn: int) -> float:
    return 1.0 if tp + fp + fn == 0 else 2 * tp / (2 * tp + fp + fn)


def _rel(a: float, b: float) -> float:
    """|a - b| / |b| (0 when both are 0, inf when only b is)."""
    if not (math.isfinite(a) and math.isfinite(b)):
        return float("nan")
    if b == 0:
        return 0.0 if a == 0 else float("inf")
    return abs(a - b) / abs(b)


def _status(ok: bool) -> str:
    return "pass" if ok else "fail"


# ----------------------------------------------------------------------------- 1. fixed vs float

def float_ofs_potentials(model, inp: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Float OFS spikes and membrane potentials (B, H, W) of one window: the module's own conv
    and eq. (1)-(2) step (model.lif.lif_step), unrolled so the potentials are visible."""
    import torch

    from ..model.lif import lif_step

    with torch.no_grad():
        cur = model.conv(torch.from_numpy(inp.astype(np.float32)))[:, 0]        # (B, H, W)
        u = torch.zeros_like(cur[0])
        o = torch.zeros_like(cur[0])
        us, os_ = [], []
        for t in range(cur.shape[0]):
            u, o = lif_step(u, o, cur[t], model.threshold, model.leak, model.reset)
            us.append(u.clone())
            os_.append(o > 0)
    return torch.stack(os_).numpy(), torch.stack(us).numpy()


def event_bbox(inp: np.ndarray, margin: int) -> tuple[slice, slice] | None:
    """(rows, cols) of the events of (B, C, H, W) grown by margin; None without events.

    A stage computed on this crop equals the full-sensor run inside it and is silent outside
    (zero state and zero input never fire; an input reaches only K//2 pixels).
    """
    any_px = inp.any(axis=(0, 1))
    rows, cols = np.flatnonzero(any_px.any(axis=1)), np.flatnonzero(any_px.any(axis=0))
    if rows.size == 0:
        return None
    h, w = any_px.shape
    return (slice(max(rows[0] - margin, 0), min(rows[-1] + margin + 1, h)),
            slice(max(cols[0] - margin, 0), min(cols[-1] + margin + 1, w)))


def quantization_band(st: dict, n_steps: int) -> float:
    """Bound on |u_float - u_fixed| (float units) within a window of n_steps, all inputs active,
    for the stage's ideal quantization (quantize_ofs of its float values, not the bundle's
    integers: an export bug then shows as differences outside the band).

    Per step the integer stage's current differs by at most sum |W - w/s|, its reset by
    |vth - vth_mant/s|, its leak by |lambda - lambda_q| times the potential (taken as <= 2 vth)
    plus Loihi's truncation (one state unit, 1 / (64 s)); with leak lambda a per-step
    difference accumulates to at most sum_{i<n} lambda^i <= min(1 / (1 - lambda), n) times it.
    A float potential within this band of the threshold can fall either way after quantization.
    """
    from ..fixed_point import quantize_ofs

    w = np.asarray(st["weight"], dtype=np.float64)
    p = quantize_ofs(w, float(st["threshold"]), float(st["leak"]))
    wq, vq, lq = p.float_equivalent()
    vth, lam = float(st["threshold"]), float(st["leak"])
    step = float(np.abs(w - wq).sum()) + abs(vth - vq) + abs(lam - lq) * 2 * vth + 1.0 / (64 * p.weight_scale)
    return step * (min(1.0 / (1.0 - lam), n_steps) if lam < 1.0 else n_steps)


def check_fixed_vs_float(bundle: Bundle, models, held: HeldOut, float_params: Sequence[dict] | None = None) -> dict:
    """Per stage, on each held-out window's full input: float spikes vs fixed-point spikes.

    Besides the plain F1 (the goal), differences are attributed to the quantization band:
    pixels where the float potential came within ``quantization_band`` of the threshold at some
    step, where 8-bit weights / 17-bit thresholds may legitimately decide the other way (e.g.
    DOTIE-like weights whose sums land on or next to the threshold). F1 outside the band is
    reported beside the plain F1; a difference outside the band would be an export bug.
    """
    stages = []
    pool = bundle.config.ofs_pool
    for k, p in enumerate(bundle.ofs, start=1):
        m = models[k - 1]
        st = float_params[k - 1] if float_params is not None else {
            "weight": m.conv.weight.detach().numpy(), "threshold": float(m.threshold), "leak": float(m.leak)}
        band = quantization_band(st, bundle.config.n_bins)
        vth = float(st["threshold"])
        tp = fp = fn = total = in_band = tp_x = fp_x = fn_x = 0
        for w in held.windows:
            inp = pool_any(w, pool)                  # what the stage sees (OFS grid)
            total += inp.shape[0] * inp.shape[2] * inp.shape[3]
            box = event_bbox(inp, p.kernel_size // 2)
            if box is None:
                continue
            crop = inp[:, :, box[0], box[1]]
            a, u = float_ofs_potentials(m, crop)
            b = run_ofs_fixed(crop, p)
            near = (np.abs(u - vth) <= band).any(axis=0)[None]
            tp += int(np.sum(a & b))
            fp += int(np.sum(~a & b))
            fn += int(np.sum(a & ~b))
            in_band += int(np.sum((a != b) & near))
            tp_x += int(np.sum(a & b & ~near))
            fp_x += int(np.sum(~a & b & ~near))
            fn_x += int(np.sum(a & ~b & ~near))
        stages.append({"stage": k, "f1": _f1(tp, fp, fn), "precision": tp / (tp + fp) if tp + fp else 1.0,
                       "recall": tp / (tp + fn) if tp + fn else 1.0, "agreement": 1.0 - (fp + fn) / total,
                       "float_spikes": tp + fn, "fixed_spikes": tp + fp, "differing": fp + fn,
                       "quantization_band": band, "differing_in_band": in_band,
                       "f1_outside_band": _f1(tp_x, fp_x, fn_x)})
    worst = min(s["f1"] for s in stages)
    silent = [s["stage"] for s in stages if s["float_spikes"] + s["fixed_spikes"] == 0]
    head = f"min F1 {worst:.4f}"
    if worst < 1.0:
        n_diff = sum(s["differing"] for s in stages)
        n_band = sum(s["differing_in_band"] for s in stages)
        head += f"; {n_band} of {n_diff} differing spikes within the quantization band"
    if silent:
        head += f"; no spikes at all in stage {', '.join(map(str, silent))}"
    return {"status": _status(worst >= F1_GOAL), "goal": f"F1 >= {F1_GOAL} per stage (float spikes = reference)",
            "headline": head, "inputs": "each stage on the full (unmasked) binary window, on the OFS grid",
            "stages": stages}


# ----------------------------------------------------------------------------- 2. Lava vs fixed

def _crop_origin(score: np.ndarray, size: tuple[int, int]) -> tuple[int, int, int, int]:
    """(x0, y0, w, h) of the size-(w, h) crop holding the most of ``score`` (H, W)."""
    cw, ch = min(size[0], score.shape[1]), min(size[1], score.shape[0])
    s = cv2.boxFilter(score.astype(np.float32), -1, (cw, ch), normalize=False, borderType=cv2.BORDER_CONSTANT)
    cy, cx = np.unravel_index(int(np.argmax(s)), s.shape)
    y0 = int(np.clip(cy - ch // 2, 0, score.shape[0] - ch))
    x0 = int(np.clip(cx - cw // 2, 0, score.shape[1] - cw))
    return x0, y0, cw, ch


def lava_crops(held: HeldOut, params: Sequence[LoihiOFSParams], n_windows: int,
               size: tuple[int, int] = LAVA_CROP, pool: int = 1) -> list[np.ndarray]:
    """Small binary crops (B, C, h, w) of the windows on the OFS grid (pooled by ``pool``) where
    the fixed-point OFS fires most.

    The simulator is slow, so it sees a few small crops; choosing the windows and places with
    the most reference spikes (then events) keeps the bit-exactness check from being vacuous.
    """
    from ..model.reference import fixed_stage_fn

    run = fixed_stage_fn(list(params))
    scored = []
    grids = [pool_any(w, pool) for w in held.windows]
    for i, inp in enumerate(grids):
        spikes = sum(run(k, inp).sum(axis=0).astype(np.float32) for k in range(1, len(params) + 1))
        score = spikes * 1000.0 + inp.sum(axis=(0, 1))
        x0, y0, cw, ch = _crop_origin(score, size)
        scored.append((float(score[y0:y0 + ch, x0:x0 + cw].sum()), i, x0, y0, cw, ch))
    scored.sort(key=lambda t: (-t[0], t[1]))
    return [grids[i][:, :, y0:y0 + ch, x0:x0 + cw].astype(np.uint8)
            for _s, i, x0, y0, cw, ch in sorted(scored[:n_windows], key=lambda t: t[1])]


def check_lava_vs_fixed(bundle: Bundle, held: HeldOut, n_windows: int = 2) -> dict:
    """run_ofs_lava (fixed_pt) vs run_ofs_fixed per stage on small crops: differing spikes."""
    goal = "0 differing spikes (bit exact)"
    try:
        from ..runtime.loihi import run_ofs_lava
    except ImportError as exc:
        return {"status": f"skipped: Lava adapter not importable ({exc})", "goal": goal, "headline": "not run"}
    crops = lava_crops(held, bundle.ofs, n_windows, pool=bundle.config.ofs_pool)
    stages, t0 = [], time.perf_counter()
    for k, p in enumerate(bundle.ofs, start=1):
        try:
            lava = run_ofs_lava(crops, p, tag="fixed_pt")
        except Exception as exc:   # the bundle is still valid; the check says why it could not pass
            msg = str(exc).splitlines()[0][:200] if str(exc) else ""
            return {"status": "fail", "goal": goal, "headline": f"Lava run failed at stage {k}: "
                    f"{type(exc).__name__}: {msg}", "error": f"{type(exc).__name__}: {msg}"}
        ref = [run_ofs_fixed(c, p) for c in crops]
        diff = sum(int(np.sum(np.asarray(a, dtype=bool) != b)) for a, b in zip(lava, ref))
        stages.append({"stage": k, "differing": diff, "spikes_reference": int(sum(r.sum() for r in ref)),
                       "spikes_lava": int(sum(np.asarray(a, dtype=bool).sum() for a in lava)),
                       "neuron_steps": int(sum(r.size for r in ref))})
    total = sum(s["differing"] for s in stages)
    n_ref = sum(s["spikes_reference"] for s in stages)
    return {"status": _status(total == 0), "goal": goal,
            "headline": f"{total} differing spikes ({n_ref} reference spikes compared)",
            "run_config": "Loihi2SimCfg(select_tag='fixed_pt') via toffe_deploy.runtime.loihi.run_ofs_lava",
            "windows": len(crops), "crop_size": [int(crops[0].shape[-1]), int(crops[0].shape[-2])] if crops else None,
            "seconds": round(time.perf_counter() - t0, 2), "stages": stages}


def check_netx_vs_fixed(bundle: Bundle, held: HeldOut, n_windows: int = 2) -> dict:
    """Each stage's netx/ofs_stage<k>.net through lava-dl's own netx.hdf5.Network (with the
    manifest's reset_interval / reset_offset) vs run_ofs_fixed on the lava_crops windows, the
    file's layer shapes set to the crop (netx_h5.resize_netx: same integers and neuron).

    Reset "zero" bundles must match bit for bit; netx's neuron cannot subtract, so for
    "subtract" bundles the spike F1 is reported for information (status "informational")."""
    import tempfile

    from .netx_h5 import NETX_RESET_OFFSET, resize_netx, run_netx_stage

    zero = bundle.config.reset == "zero"
    goal = "0 differing spikes (reset zero)" if zero else "none: netx resets to zero, this bundle subtracts"
    crops = lava_crops(held, bundle.ofs, n_windows, pool=bundle.config.ofs_pool)
    stages, t0 = [], time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="toffe-netx-") as tmp:
        for k, p in enumerate(bundle.ofs, start=1):
            src = bundle.root / "netx" / f"ofs_stage{k}.net"
            try:
                got = []
                for i, c in enumerate(crops):
                    f = resize_netx(src, Path(tmp) / f"s{k}_{i}.net", c.shape[-2], c.shape[-1])
                    got += run_netx_stage(f, [c], reset_offset=NETX_RESET_OFFSET)
            except Exception as exc:   # noqa: BLE001 - the check reports why it could not run
                msg = str(exc).splitlines()[0][:200] if str(exc) else ""
                return {"status": "fail" if zero else "informational", "goal": goal,
                        "headline": f"netx run failed at stage {k}: {type(exc).__name__}: {msg}"}
            ref = [run_ofs_fixed(c, p) for c in crops]
            tp = sum(int((g & r).sum()) for g, r in zip(got, ref))
            n_got, n_ref = sum(int(g.sum()) for g in got), sum(int(r.sum()) for r in ref)
            stages.append({"stage": k, "differing": sum(int((g != r).sum()) for g, r in zip(got, ref)),
                           "spikes_reference": n_ref, "spikes_netx": n_got,
                           "f1": 2 * tp / (n_got + n_ref) if n_got + n_ref else 1.0})
    total = sum(s["differing"] for s in stages)
    f1 = ", ".join(f"{s['f1']:.3f}" for s in stages)
    return {"status": _status(total == 0) if zero else "informational", "goal": goal,
            "headline": f"{total} differing spikes (F1 per stage {f1})",
            "netx": {"reset_interval": bundle.config.n_bins, "reset_offset": NETX_RESET_OFFSET},
            "windows": len(crops), "crop_size": [int(crops[0].shape[-1]), int(crops[0].shape[-2])] if crops else None,
            "seconds": round(time.perf_counter() - t0, 2), "stages": stages}


# ----------------------------------------------------------------------------- 3. ONNX vs torch

def check_onnx_vs_torch(bundle: Bundle, model, x: np.ndarray) -> dict:
    """Max |diff| of onnxruntime vs torch on x, batched (N = len(x)) and one row at a time."""
    import torch

    from .onnx_export import OUTPUT_NAMES, ort_session, run_onnx

    with torch.no_grad():
        ref = [t.numpy() for t in model(torch.from_numpy(x))]
    sess = ort_session(bundle.ofpd_onnx)
    batched = run_onnx(sess, x)
    single = [np.concatenate(parts) for parts in zip(*(run_onnx(sess, x[i:i + 1]) for i in range(len(x))))]
    diffs = {n: float(max(np.abs(a - r).max(), np.abs(s - r).max())) for n, a, s, r in zip(OUTPUT_NAMES, batched, single, ref)}
    worst = max(diffs["pose"], diffs["direction"])
    out = {"status": _status(worst < ONNX_GOAL), "goal": f"max |diff| < {ONNX_GOAL:g} on pose and direction",
           "headline": f"pose {diffs['pose']:.2g}, direction {diffs['direction']:.2g}",
           "inputs": int(len(x)), "max_abs_diff": diffs,
           "pose_scale_px": float(np.abs(ref[0]).max()), "variants": {}}
    out["direction_max_deg"] = _direction_deg(batched[1], ref[1])
    for name, path in bundle.ofpd_variants.items():
        got = run_onnx(ort_session(path), x)
        bad = int(sum(np.sum(~np.isfinite(a)) for a in got))
        out["variants"][name] = {
            "max_abs_diff": {n: float(np.nanmax(np.abs(a - r))) for n, a, r in zip(OUTPUT_NAMES, got, ref)},
            "direction_max_deg": _direction_deg(got[1], ref[1]), "non_finite_outputs": bad,
            "status": "fail (non-finite outputs)" if bad else "informational: reduced precision, no goal"}
    return out


def _direction_deg(d: np.ndarray, ref: np.ndarray) -> float:
    """Largest angle (deg) between (cos, sin) direction outputs."""
    from ..metrics import angle_error_deg

    e = angle_error_deg(np.arctan2(d[:, 1], d[:, 0]), np.arctan2(ref[:, 1], ref[:, 0]))
    return float(np.nanmax(e)) if e.size else 0.0


# ----------------------------------------------------------------------------- 4. end to end

def _predictions_float(held: HeldOut, models, model, config: ToffeConfig) -> list[list]:
    from ..model.reference import float_stage_fn, ofpd_torch_fn, predict_window

    run, ofpd = float_stage_fn(models), ofpd_torch_fn(model)
    return [predict_window(w, run, ofpd, config, held.recent(i, config), held.ones_after(i))[0]
            for i, w in enumerate(held.windows)]


def _predictions_fixed_reference(bundle: Bundle, held: HeldOut) -> list[list]:
    """Deployed arithmetic through the training side's reference code: the fixed-point cascade
    of the bundle's integers (model.reference) + onnxruntime on the bundle's ONNX."""
    from ..model.reference import fixed_stage_fn, predict_window
    from .onnx_export import ort_session, run_onnx

    sess = ort_session(bundle.ofpd_onnx)
    run = fixed_stage_fn(bundle.ofs)
    return [predict_window(w, run, lambda x: run_onnx(sess, x), bundle.config, held.recent(i, bundle.config),
                           held.ones_after(i))[0] for i, w in enumerate(held.windows)]


def _predictions_runtime(bundle: Bundle, held: HeldOut, variant: str = "fp32") -> list[list] | None:
    """The runtime's cpu Pipeline on the bundle (what `toffe-deploy run --target cpu` computes)
    with OFPD ``variant``; None when the runtime is not importable."""
    from ..metrics import predictions_of

    try:
        from ..runtime.pipeline import Pipeline
    except ImportError:
        return None
    preds = []
    with Pipeline(bundle, "cpu", ofpd_variant=variant) as p:
        def results():
            if not held.support and not held.ones:   # the front end's output again: it is idempotent
                yield from p.process_stream((t0, w) for t0, w in zip(held.t0, held.windows))
                return
            for i, t0 in enumerate(held.t0):     # temporal support: raw window, its history; the plane fit's
                raw, hist = held.support[i] if held.support else (held.windows[i], None)
                p.support = copy.deepcopy(hist)
                if held.ones:
                    p.ones_history = copy.deepcopy(held.ones[i])
                yield from p.process_stream([(t0, raw)])

        for r in results():
            preds.append(predictions_of(r.objects))   # px/ms too: speedE_px_ms was null for the deployed pipeline
    if len(preds) != len(held.windows):
        raise RuntimeError(f"cpu pipeline returned {len(preds)} windows for {len(held.windows)}")
    return preds


def _agreement(flt: list[list], dep: list[list]) -> dict:
    """Objects of two pipelines matched window by window (nearest first): counts and mean differences."""
    from ..metrics import angle_error_deg, match_nearest

    dpix, ddir, dspd, same = [], [], [], 0
    for pf, pd in zip(flt, dep):
        for i, j in match_nearest([(p.x, p.y) for p in pd], [(p.x, p.y) for p in pf]):
            a, b = pf[i], pd[j]
            dpix.append(float(np.hypot(a.x - b.x, a.y - b.y)))
            ddir.append(float(angle_error_deg(a.direction_rad, b.direction_rad)))
            dspd.append(abs(a.speed_mps - b.speed_mps))
            same += int(a.stage == b.stage)
    return {"objects_float": sum(len(p) for p in flt), "objects_deployed": sum(len(p) for p in dep),
            "matched": len(dpix), "same_stage": same,
            "mean_pose_diff_px": float(np.mean(dpix)) if dpix else 0.0,
            "mean_direction_diff_deg": float(np.mean(ddir)) if ddir else 0.0,
            "mean_speed_diff_mps": float(np.mean(dspd)) if dspd else 0.0}


def _scores(preds: list[list], truths: list[list], focal_px: list) -> dict:
    """FlowErrors over the windows, each with its camera's focal length, as eval and run score:
    speedE is the px/ms error in m/s at each object's true depth (without the focal length it
    compared m/s at the bundle's depth with the truth's, ~12x too large on DAVIS346 data)."""
    from ..metrics import FlowErrors

    fe = FlowErrors()
    focal_px = list(focal_px) + [None] * (len(truths) - len(focal_px))      # a HeldOut built without them
    for p, t, f in zip(preds, truths, focal_px):
        fe.add_window(p, t, focal_px=f)
    return fe.summary()


def check_end_to_end(bundle: Bundle, models, model, held: HeldOut) -> dict:
    """pixE, dirE, speedE of the deployed pipeline vs the float pipeline on held-out windows.

    "deployed" is the runtime's cpu Pipeline (what ships); "fixed_reference" runs the same
    integers and ONNX through the training side's reference cascade code, which separates the
    effect of quantization + ONNX (fixed_reference vs float) from the runtime's integration
    (deployed vs fixed_reference). The goal is judged on the deployed pipeline.
    """
    cfg = bundle.config
    metrics = ("pixE", "dirE", "speedE")
    flt = _predictions_float(held, models, model, cfg)
    ref = _predictions_fixed_reference(bundle, held)
    run = _predictions_runtime(bundle, held)
    dep = run if run is not None else ref
    out = {"goal": f"deployed pixE, dirE, speedE within {E2E_GOAL:.0%} of the float model's",
           "deployed": "toffe_deploy.runtime.pipeline.Pipeline(bundle, 'cpu')" if run is not None else
                       "fixed-point reference cascade + onnxruntime (runtime pipeline not importable)",
           "fixed_reference": "model.reference.predict_window with the bundle's integers (fixed_point) + onnxruntime",
           "float": "model.reference.predict_window with the torch OFS stages + torch OFPD",
           "agreement": _agreement(flt, dep), "agreement_fixed_reference": _agreement(flt, ref)}
    if not held.truths or any(t is None for t in held.truths):
        out.update(status="skipped: held-out windows have no ground truth (agreement reported instead)",
                   headline=f"{out['agreement']['matched']} of {out['agreement']['objects_float']} float objects matched")
        return out
    sf, sd, sr = (_scores(x, held.truths, held.focal_px) for x in (flt, dep, ref))
    out.update(float_errors=sf, deployed_errors=sd, fixed_reference_errors=sr)
    if sf["n_matched"] == 0 or sd["n_matched"] == 0:
        out.update(status=f"skipped: no ground-truth object matched (float {sf['n_matched']}, deployed "
                          f"{sd['n_matched']} of {sf['n_gt']})", headline="no matched objects")
        return out
    rel = {m: _rel(sd[m], sf[m]) for m in metrics}
    out["relative_difference"] = rel
    out["relative_difference_fixed_reference"] = {m: _rel(sr[m], sf[m]) for m in metrics}
    ok = all(math.isfinite(v) and v <= E2E_GOAL for v in rel.values())
    if run is not None:          # each reduced-precision OFPD end to end, against the fp32 deployment
        out["variants"] = {}
        for v in bundle.ofpd_variants:
            sv = _scores(_predictions_runtime(bundle, held, v), held.truths, held.focal_px)
            out["variants"][v] = {"errors": sv, "relative_to_fp32": {m: _rel(sv[m], sd[m]) for m in metrics},
                                  "goal": f"informational: within {VARIANT_E2E_GOAL:.0%} of fp32 to be worth shipping"}
    unit = {"pixE": " px", "dirE": " deg", "speedE": " m/s"}
    head = ", ".join(f"{m} {sd[m]:.3g} vs {sf[m]:.3g}{unit[m]}" for m in metrics)
    if run is not None and not ok:
        head += " (fixed reference: " + ", ".join(f"{m} {sr[m]:.3g}" for m in metrics) + ")"
    out.update(status=_status(ok), headline=head)
    return out


# ----------------------------------------------------------------------------- all

def _preload_lava() -> None:
    """Import Lava before the first tqdm bar (see runtime.loihi.import_lava); without Lava the
    Lava check reports itself skipped later."""
    from ..errors import ToffeError
    from ..runtime.loihi import import_lava
    try:
        import_lava()
    except ToffeError:
        pass


def run_parity(bundle: Bundle, ckpt, held: HeldOut, checks: Sequence[str], model=None, lava_windows: int = 2,
               progress: bool = True, log: TextIO | None = sys.stderr) -> dict:
    """Run the named checks; returns the parity.json content."""
    from .onnx_export import build_ofpd

    config = bundle.config
    model = model if model is not None else build_ofpd(config, ckpt.ofpd_state)
    models = float_ofs_models(ckpt.ofs, config)
    todo = {
        "fixed_vs_float": lambda: check_fixed_vs_float(bundle, models, held, ckpt.ofs),
        "lava_vs_fixed": lambda: check_lava_vs_fixed(bundle, held, lava_windows),
        "netx_vs_fixed": lambda: check_netx_vs_fixed(bundle, held, lava_windows),
        "onnx_vs_torch": lambda: check_onnx_vs_torch(bundle, model, ofpd_inputs(held, bundle.ofs, config)),
        "end_to_end": lambda: check_end_to_end(bundle, models, model, held),
    }
    unknown = [c for c in checks if c not in todo]
    if unknown:
        raise ValueError(f"unknown parity checks {unknown}")
    if "lava_vs_fixed" in checks or "netx_vs_fixed" in checks:
        _preload_lava()
    results: dict = {}
    with torch_threads(1):
        _run_checks(todo, checks, results, progress, log)
    return json_safe({"format": "toffe-deploy-parity", "format_version": 1, "windows": held.source, "checks": results,
                      "all_pass": all(r["status"] in ("pass", "informational") for r in results.values())})


def _run_checks(todo, checks, results, progress, log) -> None:
    """Run checks in order into results (name -> report with its seconds), with a progress bar."""
    from tqdm import tqdm

    bar = tqdm(list(checks), desc="parity", unit="check", file=log or sys.stderr, disable=not progress or log is None,
               leave=False)
    for name in bar:
        bar.set_postfix_str(name)
        t0 = time.perf_counter()
        res = todo[name]()
        res.setdefault("seconds", round(time.perf_counter() - t0, 2))
        results[name] = res


class torch_threads:
    """Run torch with n intra-op threads inside the block (restored after).

    The float reference runs many small element-wise steps; on a shared 2-core machine torch's
    default thread pool makes them 20x slower (measured: 29.9 s vs 1.8 s for fixed_vs_float at
    640x480 while another process trained), so the checks use one thread.
    """

    def __init__(self, n: int):
        self.n = n
        self.old = None

    def __enter__(self):
        import torch

        self.old = torch.get_num_threads()
        torch.set_num_threads(self.n)
        return self

    def __exit__(self, *exc):
        import torch

        torch.set_num_threads(self.old)
        return False


def json_safe(obj):
    """NaN and infinities -> None (strict JSON), numpy scalars -> Python numbers, recursively."""
    if isinstance(obj, dict):
        return {str(k): json_safe(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [json_safe(v) for v in obj]
    if isinstance(obj, np.generic):
        obj = obj.item()
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj


def summary_lines(parity: dict) -> list[str]:
    """The printed summary: one line per check."""
    src = parity["windows"]
    where = (f"data set {src.get('data')} ({src.get('split')})" if src.get("kind") == "data set"
             else f"generated {src.get('generator')}, seed {src.get('seed')}")
    lines = [f"parity on {src.get('n_windows')} held-out windows from {where}:"]
    for name, c in parity["checks"].items():
        lines.append(f"  {name:15s} {c['status']:6s}  {c.get('headline', '')}   [goal: {c['goal']}]")
    return lines
