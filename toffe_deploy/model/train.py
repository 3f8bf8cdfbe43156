"""Training of the OFS stages and of the OFPD (torch), resumable, seeded.

OFS stage k (target: fire on events of objects at speed bin >= k, stay silent otherwise and on
noise) is trained from DOTIE's initialisation on binary single-object crops (model/data.py),
computed exactly on the pixels that can fire (model/ofs_sparse.py). With the per-neuron window
margin d = max_t u[t] / vth - 1 (> 0 iff it fired; eq. (1)-(2) with the spike reset) and E the
window's event pixels:

    L_pos(n) = mean_{p in E} max(0, m - d_p)          windows with object bin >= k
    L_neg(n) = mean_{p in E} max(0, d_p + m)          slower windows and noise-only crops
    L = mean_pos L_pos + 2 mean_neg L_neg,   m = 0.2

A margin loss (hinge on the membrane potential) instead of a loss on spikes keeps a gradient on
silent neurons (spike-count losses collapsed to all-silent stages here). W, vth and lambda all
learn; after every step vth > 0 and lambda in [0, 1] (Loihi-representable;
fixed_point.quantize_ofs maps them to 8-bit weights, a 17-bit threshold and a 12-bit decay).

OFPD is trained on what it sees at inference: each training crop goes through the cascade of
the *quantized* OFS stages in Loihi fixed point (model/reference.py), and every reported object
(ofpd_io.merge_frames: the union of the stage frames of one object) becomes one sample,
prepared by ofpd_io.prepare.
Targets: sensor (x, y), (cos, sin) of the direction, ln(speed) (ofpd_io.speed_target: ln px/ms of
the image-plane speed, the ground truth's speed_px_ms or its m/s through config.speed_scale;
ln m/s for a legacy-layout OFPD). A fresh OFPD trains on ofpd_io.CURRENT_LAYOUT. Augmentation: the 8 flips and
transposes of the crop (pose mirrored about the crop centre, direction and motion planes mirrored likewise).
Loss: SmoothL1(pose px / 4) + |d_pred - d_gt|^2 + L_v, by default L_v = mean_i |ln v_i - ln v_i*|.
With the speed loss options (SpeedLoss; `train --speed-balance --speed-edge-weight W`), over the
samples i of a batch with true bin b_i, [lo_b, hi_b] its ln speed range (ofpd_io.speed_bounds_px_ms):

    L_v = mean_i w_i (|ln v_i - ln v_i*| + W (max(0, lo_b_i - ln v_i) + max(0, ln v_i - hi_b_i))),
    w_i = N / (N_bins n_b_i) with --speed-balance (n_b: the training samples of bin b), else 1:

each bin weighs the same, and a speed that leaves its true bin (a wrong reported bin, since
ofpd.bin_from "ofpd" reads the bin from this speed) costs W more per unit of ln speed.
"""
from __future__ import annotations

import dataclasses
import json
import math
import os
import shutil
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from tqdm import tqdm

from ..camera import REFERENCE_HFOV_DEG, focal_px_from_hfov
from ..checkpoint import (CONFIG_FILE, load_checkpoint, random_ofpd_state, save_checkpoint, dotie_ofs)
from ..config import ToffeConfig
from ..errors import InputError, ToffeError, warn
from ..events.frontend import apply_dense
from ..events.support import event_pixels, history_counts, support_dense
from ..fileio import JSON_ERRORS, atomic_path
from .. import ofpd_io
from ..cascade import pool_any, run_cascade, stage_frame
from .data import WindowSet
from .ofs import OFS
from .ofpd import OFPD
from .reference import fixed_stage_fn, quantize_stages

STATE_DIR = ".train_state"
MARGIN = 0.2        # in threshold units: fire with u > 1.2 vth, stay below 0.8 vth
NEG_WEIGHT = 2.0    # negatives: a handful of spikes already leaves a frame with an "object"
OFS_CROP_PX = 128   # centre of each training crop the OFS is trained on (see pack_training_windows)
NEW_OFS_POOL = 2    # OFS grid pooling of a new checkpoint: 640x480 x 4 stages on one Loihi 2 chip (config.ofs_pool)


def pick_device(name: str = "auto") -> torch.device:
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    return torch.device(name)


# ------------------------------------------------------------------------------------ OFS
def ofs_loss(margin: torch.Tensor, event: torch.Tensor, owner: torch.Tensor, positive: torch.Tensor) -> torch.Tensor:
    """See module docstring, on sparse rows (ofs_sparse): margin d (M,), event (M,) float,
    owner (M,) window index in the batch, positive (n,) bool."""
    n = positive.shape[0]
    zeros = margin.new_zeros(n)
    n_ev = zeros.index_add(0, owner, event).clamp(min=1.0)
    pos_px = torch.relu(MARGIN - margin) * event
    neg_px = torch.relu(margin + MARGIN) * event
    l_pos = zeros.index_add(0, owner, pos_px) / n_ev
    l_neg = zeros.index_add(0, owner, neg_px) / n_ev
    loss = margin.new_zeros(())
    if positive.any():
        loss = loss + l_pos[positive].mean()
    if (~positive).any():
        loss = loss + NEG_WEIGHT * l_neg[~positive].mean()
    return loss


def noise_crops(n: int, n_bins: int, crop: int, rng: np.random.Generator) -> np.ndarray:
    """(n, B, 2, R, R) bool background-noise-only windows, densities log-uniform 1e-4..3e-3."""
    dens = np.exp(rng.uniform(np.log(1e-4), np.log(3e-3), size=(n, 1, 1, 1, 1)))
    return rng.random((n, n_bins, 2, crop, crop)) < dens


def pack_training_windows(windows: WindowSet, kernel: int, seed: int, progress: bool = True,
                          input_norm: str = "none", min_cluster: int = 1, pool: int = 1, support=None):
    """Sparse rows of all training crops plus n/8 noise-only crops (through the same input front
    end as the crops; with ``support`` (K, r, m, c), config.input_support, each noise crop has
    K noise windows of its density before it), on the OFS grid (pooled by ``pool``, as the
    cascade sees them); returns (SparseWindows, speed_bin) with speed_bin 0 for the noise crops
    (a negative for every stage)."""
    from .ofs_sparse import pack_windows

    rng = np.random.default_rng(seed)
    n_noise = max(len(windows) // 8, 4)
    # The OFS is local (one K x K conv), so its training needs only the centre of each crop: the
    # crops are sized for the OFPD's largest objects, and their noise events would make the packed
    # neighbourhoods of whole crops tens of GB.
    r = min(windows.crop, OFS_CROP_PX)
    c0 = (windows.crop - r) // 2

    def vols():
        for i in tqdm(range(len(windows)), desc="packing OFS windows", leave=False, disable=not progress):
            yield pool_any(windows.dense([i])[0][:, :, c0:c0 + r, c0:c0 + r], pool)
        for _ in range(n_noise):
            if support is None:
                yield pool_any(apply_dense(noise_crops(1, windows.n_bins, r, rng)[0], input_norm, min_cluster), pool)
                continue
            k, rad, m, c = support           # one density over the crop and the K windows before it
            seq = noise_crops(1, windows.n_bins * (k + 1), r, rng)[0].reshape(k + 1, windows.n_bins, 2, r, r)
            counts = history_counts([event_pixels(w) for w in seq[:k]])
            yield pool_any(support_dense(seq[k], input_norm, min_cluster, counts, rad, m, c), pool)

    sw = pack_windows(vols(), kernel)
    return sw, np.concatenate([windows.speed_bin, np.zeros(n_noise, np.int64)])


def train_ofs_stage(k: int, packed, speed_bin: np.ndarray, epochs: int, seed: int, device: torch.device,
                    batch: int = 64, lr: float = 0.02, init: dict | None = None, progress: bool = True,
                    reset: str = "subtract") -> dict:
    """Train OFS stage k on packed windows with the neuron's ``reset`` rule (model/lif.py);
    returns dict(weight (1,C,K,K) f32, threshold, leak, loss_curve)."""
    from .ofs_sparse import sparse_ofs_margin

    torch.manual_seed(seed + 1000 * k)
    rng = np.random.default_rng(seed + k)
    model = OFS(packed.channels, packed.kernel).to(device)
    if init is not None:
        with torch.no_grad():
            model.conv.weight.copy_(torch.from_numpy(np.asarray(init["weight"], dtype=np.float32)))
            model.threshold.fill_(float(init["threshold"]))
            model.leak.fill_(float(init["leak"]))
    opt = torch.optim.Adam(model.parameters(), lr=lr)
    labels = speed_bin >= k
    n = len(packed)
    losses = []
    for ep in range(epochs):
        order = rng.permutation(n)
        tot, cnt = 0.0, 0
        bar = tqdm(range(0, n, batch), desc=f"OFS stage {k} epoch {ep + 1}/{epochs}", leave=False, disable=not progress)
        for s in bar:
            idx = order[s:s + batch]
            feats, event, owner = packed.batch(idx, device)
            margin = sparse_ofs_margin(feats, model.conv.weight, model.threshold, model.leak, reset)
            loss = ofs_loss(margin, event, owner, torch.from_numpy(labels[idx]).to(device))
            opt.zero_grad()
            loss.backward()
            opt.step()
            model.clamp_()
            tot += float(loss) * len(idx)
            cnt += len(idx)
            bar.set_postfix(loss=f"{tot / cnt:.3f}", vth=f"{float(model.threshold):.2f}", leak=f"{float(model.leak):.2f}")
        losses.append(tot / max(cnt, 1))
    return dict(weight=model.conv.weight.detach().cpu().numpy().astype(np.float32),
                threshold=float(model.threshold), leak=float(model.leak), loss_curve=losses)


def snap_to_loihi(params: dict) -> dict:
    """The float parameters that Loihi 2 fixed point represents exactly (quantize, then map back).

    Saving these makes the float model and the deployed integer one the same network up to the
    truncation of the decay, so fixed-vs-float disagreements are ties at the threshold only
    (measured by the export engineer: stage F1 0.984 -> >= 0.9997 on a trial checkpoint).
    """
    from ..fixed_point import quantize_ofs

    w, th, lam = quantize_ofs(params["weight"], params["threshold"], params["leak"]).float_equivalent()
    return {**params, "weight": w.astype(np.float32), "threshold": float(th), "leak": float(lam)}


def calibrate_threshold(k: int, params: dict, windows: WindowSet, config: ToffeConfig, limit: int = 320,
                        seed: int = 0, scales=(0.8, 0.9, 1.0, 1.1, 1.2, 1.35, 1.5, 1.7, 2.0)) -> tuple[dict, list]:
    """Pick vth' = s * vth for stage k maximising the balanced window-level accuracy of the
    quantized stage alone on a class-balanced subset: (TPR + TNR) / 2 with 'fires' as in
    separation_scores. The margin loss ranks pixels; this sets the operating point that the
    cascade's has_object decision actually uses. Returns (params, [(s, balanced acc)])."""
    from ..fixed_point import quantize_ofs
    from .reference import on_event_bbox
    from ..fixed_point import run_ofs_fixed

    rng = np.random.default_rng(seed + 77 * k)
    pos, neg = np.flatnonzero(windows.speed_bin >= k), np.flatnonzero(windows.speed_bin < k)
    if pos.size == 0 or neg.size == 0:
        return params, []
    idx = np.concatenate([rng.permutation(pos)[:limit // 2], rng.permutation(neg)[:limit // 2]])
    vols = windows.dense(idx)
    labels = windows.speed_bin[idx] >= k
    curve = []

    def score(sc: float) -> None:
        p = quantize_ofs(params["weight"], params["threshold"] * sc, params["leak"], config.reset)
        fired = np.zeros(idx.size, bool)
        for i in range(idx.size):
            spikes = on_event_bbox(lambda x: run_ofs_fixed(x, p), pool_any(vols[i], config.ofs_pool),
                                   p.kernel_size // 2)
            frame = stage_frame(vols[i], spikes, config.mask_kernel, config.ofs_pool)
            fired[i] = ofpd_io.has_object(frame[None], config)[0]
        bal = 0.5 * (np.mean(fired[labels]) + np.mean(~fired[~labels]))
        curve.append((round(float(sc), 4), float(bal)))

    def best() -> float:
        return max(curve, key=lambda c: (round(c[1], 4), -abs(c[0] - 1.0)))[0]

    for sc in scales:
        score(sc)
    coarse = best()
    for sc in (coarse - 0.1, coarse - 0.05, coarse + 0.05, coarse + 0.1):   # refine around the best
        if sc > 0:
            score(sc)
    best = best()
    return dict(params, threshold=float(params["threshold"] * best)), curve


def separation_scores(stages, windows: WindowSet, config: ToffeConfig, limit: int = 600, seed: int = 0) -> list[dict]:
    """Window-level precision/recall of each fixed-point stage run alone on the crops."""
    from ..metrics import SeparationCounts

    rng = np.random.default_rng(seed)
    idx = rng.permutation(len(windows))[:limit]
    run = fixed_stage_fn(stages)
    counts = [SeparationCounts() for _ in stages]
    for i in idx:
        vol = windows.dense([i])[0]
        pooled = pool_any(vol, config.ofs_pool)
        for k in range(1, len(stages) + 1):
            spikes = run(k, pooled)
            frame = stage_frame(vol, spikes, config.mask_kernel, config.ofs_pool)
            counts[k - 1].add(ofpd_io.has_object(frame[None], config), windows.speed_bin[i] >= k)
    return [c.as_dict() for c in counts]


# ----------------------------------------------------------------------------------- OFPD
@dataclass
class OFPDSet:
    """Prepared OFPD samples: planes (N, 2B, g, g) uint16 = pooled fraction * P^2 (event counts
    per cell), origin (N, 3) = (x0, y0, S): sensor px of the prepare crop's top-left and its
    side (P = S / g), motion (N, M, g, g) float32 = the motion planes (ofpd.motion; M = 0 for
    "none"), targets x, y, direction, speed = the OFPD's speed target (ofpd_io.speed_target:
    ln px/ms, or ln m/s for the "mps" layout), stage."""

    planes: np.ndarray
    motion: np.ndarray
    origin: np.ndarray
    x: np.ndarray
    y: np.ndarray
    direction: np.ndarray
    speed: np.ndarray
    stage: np.ndarray
    truth_bin: np.ndarray | None = None   # (N,) the ground truth's 1-based speed bin (SpeedLoss)


def build_ofpd_set(windows: WindowSet, stages, config: ToffeConfig, progress: bool = True) -> OFPDSet:
    """Run the fixed-point cascade on every crop; each reported object (ofpd_io.merge_frames,
    as at inference) is a sample, labelled with the crop's ground truth (speed: the ground
    truth's px/ms where the data set has it, else its m/s through config.speed_scale)."""
    c, g, _ = ofpd_io.input_shape(config)
    run = fixed_stage_fn(stages)
    planes, motion, origin, tx, ty, td, tv, tk, tb = [], [], [], [], [], [], [], [], []
    nb = 2 * config.n_bins
    for i in tqdm(range(len(windows)), desc="OFPD samples (fixed-point cascade)", leave=False, disable=not progress):
        vol = windows.dense([i])[0]
        res = run_cascade(vol, run, config.n_speed_bins, config.mask_kernel, config.ofs_pool)
        ks, merged = ofpd_io.merge_frames(np.stack(res.frames), config)
        if ks.size == 0:
            continue
        x = ofpd_io.prepare(merged, config)
        org = ofpd_io.crop_origins(merged, config)
        org[:, :2] += windows.origin[i]
        v_px = windows.speed_px_ms[i]
        if not np.isfinite(v_px):
            v_px = config.speed_scale.to_px_ms(windows.speed[i])
        for j, k in enumerate(ks):
            pool = int(org[j, 2]) // g
            planes.append(np.rint(x[j, :nb] * pool * pool).astype(np.uint16))
            motion.append(x[j, nb:c - 2])
            origin.append(org[j])
            tx.append(windows.x[i]); ty.append(windows.y[i]); td.append(windows.direction[i])
            tv.append(float(ofpd_io.speed_target(v_px, config, windows.speed[i]))); tk.append(k)
            tb.append(windows.speed_bin[i])
    return OFPDSet(np.asarray(planes, dtype=np.uint16).reshape(-1, nb, g, g),
                   np.asarray(motion, dtype=np.float32).reshape(-1, c - 2 - nb, g, g),
                   np.asarray(origin, dtype=np.float64).reshape(-1, 3),
                   np.asarray(tx), np.asarray(ty), np.asarray(td), np.asarray(tv), np.asarray(tk, dtype=np.int64),
                   np.asarray(tb, dtype=np.int64))


def ofpd_batch(ds: OFPDSet, idx: np.ndarray, rng: np.random.Generator | None):
    """Model input (n, C, g, g) float32 and targets (pose px (n,2), dir (n,2), speed target (n,)),
    with a random flip/transpose per batch when rng is given (see module docstring). A flip
    negates the motion plane of its axis (time runs the other way along it); a transpose swaps
    the two motion planes."""
    g = ds.planes.shape[-1]
    org = ds.origin[idx]
    pool = (org[:, 2] // g).astype(np.float32)
    planes = ds.planes[idx].astype(np.float32) / (pool * pool)[:, None, None, None]
    motion = ds.motion[idx]
    has_motion = motion.shape[1] == 2
    cx = org[:, 0] + (org[:, 2] - 1) / 2.0
    cy = org[:, 1] + (org[:, 2] - 1) / 2.0
    dx, dy = ds.x[idx] - cx, ds.y[idx] - cy
    c, s = np.cos(ds.direction[idx]), np.sin(ds.direction[idx])
    if rng is not None:
        if rng.random() < 0.5:
            planes = planes[..., ::-1]; dx = -dx; c = -c
            motion = motion[..., ::-1] * (np.array([-1, 1], np.float32)[:, None, None] if has_motion else 1)
        if rng.random() < 0.5:
            planes = planes[..., ::-1, :]; dy = -dy; s = -s
            motion = motion[..., ::-1, :] * (np.array([1, -1], np.float32)[:, None, None] if has_motion else 1)
        if rng.random() < 0.5:
            planes = planes.swapaxes(-1, -2); dx, dy = dy, dx; c, s = s, c
            motion = motion.swapaxes(-1, -2)[:, ::-1]
    px, py = ofpd_io.coordinate_planes(org, g)
    coord_x = px[:, None, :] * np.ones((1, g, 1))
    coord_y = py[:, :, None] * np.ones((1, 1, g))
    x = np.concatenate([planes, motion, coord_x[:, None], coord_y[:, None]], axis=1).astype(np.float32)
    pose = np.stack([cx + dx, cy + dy], axis=1)
    return (torch.from_numpy(np.ascontiguousarray(x)), torch.from_numpy(pose.astype(np.float32)),
            torch.from_numpy(np.stack([c, s], axis=1).astype(np.float32)),
            torch.from_numpy(ds.speed[idx].astype(np.float32)))


@dataclass(frozen=True)
class SpeedLoss:
    """The OFPD speed loss L_v of the module docstring: ``balance`` weighs each sample by the
    inverse frequency of its true bin, ``edge_weight`` (W) adds W times the distance (ln speed)
    by which the regressed speed lies outside its true bin. The default (False, 0) is plain L1."""

    balance: bool = False
    edge_weight: float = 0.0

    @property
    def plain(self) -> bool:
        return not self.balance and self.edge_weight == 0.0

    def sample_terms(self, ds: OFPDSet, config: ToffeConfig) -> tuple[np.ndarray, np.ndarray]:
        """Per sample of ds: (weight w_i (N,), [lo, hi] of its true bin in the speed target's
        units (N, 2))."""
        if ds.truth_bin is None:
            raise ValueError("SpeedLoss needs OFPDSet.truth_bin")
        nb = config.n_speed_bins
        counts = np.bincount(ds.truth_bin, minlength=nb + 1)[1:nb + 1].astype(np.float64)
        w = np.ones(ds.truth_bin.size)
        if self.balance:
            w = ds.truth_bin.size / (np.count_nonzero(counts) * counts[ds.truth_bin - 1])
        px_ms = ofpd_io.ofpd_settings(config)["speed_unit"] == "px_ms"
        bounds = np.log(ofpd_io.speed_bounds_px_ms(config) if px_ms else ofpd_io.speed_bounds(config))
        return w, bounds[ds.truth_bin - 1]


def ofpd_loss(model, batch, device, speed_terms=None, edge_weight: float = 0.0):
    """The OFPD loss of the module docstring; ``speed_terms`` = (w (n,), bounds (n, 2)) of the
    batch's samples (SpeedLoss.sample_terms) for the weighted / edge speed loss, None: plain L1."""
    x, pose_t, dir_t, lnv_t = (t.to(device) for t in batch)
    pose, direction, speed = model(x)
    lp = F.smooth_l1_loss(pose / 4.0, pose_t / 4.0)     # px / 4: about cells at the old fixed crop
    ld = ((direction - dir_t) ** 2).sum(dim=1).mean()
    if speed_terms is None:
        lv = (speed[:, 0] - lnv_t).abs().mean()
    else:
        w, bounds = (torch.as_tensor(a, dtype=torch.float32, device=device) for a in speed_terms)
        v = speed[:, 0]
        out = torch.relu(bounds[:, 0] - v) + torch.relu(v - bounds[:, 1])
        lv = (w * ((v - lnv_t).abs() + float(edge_weight) * out)).mean()
    return lp + ld + lv, (float(lp), float(ld), float(lv))


# ------------------------------------------------------------------------------- driver
#: A new checkpoint's model settings where TrainOptions leaves them None (the CLI's defaults).
NEW_CHECKPOINT = {"dt_us": 500, "input_norm": "first", "ofs_kernel": 5, "min_cluster": 4}


def _new_setting(opts: "TrainOptions", key: str):
    v = getattr(opts, key)
    return NEW_CHECKPOINT[key] if v is None else v


def _check_kept_settings(opts: "TrainOptions", config: ToffeConfig, where, why: str, retry: str) -> None:
    """A run on an existing checkpoint's config (--resume, --stage ofpd, --init-from) keeps its
    model settings: an option that sets one of those to another value is refused, one line,
    before any work (they were dropped silently: --dt 1000 trained and wrote a 500 us checkpoint)."""
    for opt, want, have in (("--dt", opts.dt_us, config.dt_us), ("--input-norm", opts.input_norm, config.input_norm),
                            ("--ofs-kernel", opts.ofs_kernel, config.ofs_kernel),
                            ("--min-cluster", opts.min_cluster, config.input_min_cluster),
                            ("--input-support", opts.input_support, config.input_support)):
        if want is None or (have is not None and list(np.atleast_1d(want)) == list(np.atleast_1d(have))):
            continue
        shown = ",".join(map(str, np.atleast_1d(want))) if opt == "--input-support" else want
        raise InputError(where, f"{why} has {opt[2:]} {'off' if have is None else have}, so {opt} {shown} would not "
                                f"apply; {retry}")


@dataclass
class TrainOptions:
    data: Path
    out: Path
    stage: str = "all"
    ofs_epochs: int = 4
    ofpd_epochs: int = 30
    seed: int = 0
    resume: bool = False
    dt_us: int | None = None          # window length of a new checkpoint; None: NEW_CHECKPOINT's
    per_file: int = 30
    device: str = "auto"
    progress: bool = True
    ofpd_pool: int | None = None      # OFPD cell size P; None: the checkpoint's (or OFPD_DEFAULTS')
    ofpd_kernels: tuple[int, int] | None = None   # OFPD conv kernel sizes; None: likewise
    input_norm: str | None = None     # input front end of a new checkpoint (events/frontend.py); None: NEW_CHECKPOINT's
    ofs_kernel: int | None = None     # OFS conv kernel of a new checkpoint; None: NEW_CHECKPOINT's
    min_cluster: int | None = None    # input front end's cluster filter of a new checkpoint; None: NEW_CHECKPOINT's
    reset: str | None = None          # OFS neuron reset (config.RESETS); None: the checkpoint's, else subtract
    init_from: Path | None = None     # checkpoint whose config and OFS stages a new run starts from (fine-tune)
    ofs_pool: int | None = None       # OFS grid pooling (config.ofs_pool); None: the checkpoint's, NEW_OFS_POOL for a new one
    mask_kernel: int | None = None    # cascade closing kernel in grid cells; None: the checkpoint's, else ToffeConfig's
    input_support: tuple[int, int, int, int] | None = None   # front end's temporal support of a new checkpoint (off)
    speed_loss: SpeedLoss = SpeedLoss()   # OFPD speed loss (plain L1 by default)


def _state_path(out: Path) -> Path:
    return out / STATE_DIR


def _pending_path(out: Path) -> Path:
    """The run's checkpoint while it trains (in the state directory): each finished OFS stage is
    saved here, and --out gets the checkpoint only when the run's stages are all done, so an
    interrupted or failed run leaves --out as it was, never new OFS stages beside old ones and an
    OFPD trained for those (--resume continues from here)."""
    return _state_path(out) / "checkpoint"


def _fresh_state(out: Path, keep: bool) -> None:
    """Before training: a new run drops the progress of any run before it (its state, pending
    checkpoint and partial OFPD are not this run's: a --resume after an early stop would continue
    them); a resumed one only the temporary files a killed save left."""
    d = _state_path(out)
    if not keep:
        shutil.rmtree(d, ignore_errors=True)
        return
    for p in [*d.glob(".*.tmp"), *d.glob(".*.old"), *d.glob(".*.old-*")]:   # (.old-PID: before 2026-11-24)
        if p.is_dir():
            shutil.rmtree(p, ignore_errors=True)
        else:
            p.unlink(missing_ok=True)


def _load_state(out: Path) -> dict:
    """The progress --resume continues from (empty without one); InputError when it is unreadable."""
    p = _state_path(out) / "state.json"
    if not p.is_file():
        return {}
    try:
        state = json.loads(p.read_text())
    except (OSError, *JSON_ERRORS) as exc:
        raise InputError(p, f"cannot read the training progress ({exc}); delete {STATE_DIR}/ to start over") from None
    if not isinstance(state, dict):
        state = {"ofs_done": None}                   # reported below as malformed
    done, epoch = state.get("ofs_done", []), state.get("ofpd_epoch", 0)
    if not (isinstance(done, list) and all(isinstance(k, int) and k >= 1 for k in done)
            and isinstance(epoch, int) and epoch >= 0):
        raise InputError(p, f"malformed training progress (ofs_done {done!r}, ofpd_epoch {epoch!r}); "
                            f"delete {STATE_DIR}/ to start over")
    return state


def _save_state(out: Path, state: dict, ofpd_model=None, opt=None) -> None:
    d = _state_path(out)
    d.mkdir(parents=True, exist_ok=True)
    if ofpd_model is not None:
        with atomic_path(d / "ofpd_partial.pt") as tmp:
            torch.save({"model": ofpd_model.state_dict(), "opt": opt.state_dict()}, tmp)
    with atomic_path(d / "state.json") as tmp:
        tmp.write_text(json.dumps(state, indent=1))


def make_config(files, data: Path, dt_us: int, seed: int, input_norm: str, ofs_kernel: int,
                min_cluster: int) -> ToffeConfig:
    """Config from the data set's sensor size, camera and provenance. The speed bins stay the
    reference image-plane bins (px/ms: what the data set's labels and the OFS stages use); when
    every training sequence was recorded with one focal length (a data set for one camera:
    ``dataset synth --focal-px`` or ``--hfov-deg``), they are stated in m/s for that camera at
    the reference depth, so that the bundle's manifest and `run` without ``--focal-px`` speak
    of the data's camera, not of a 640 px one at 60 deg."""
    sensor, focal, prov = data_camera(files, data, seed)
    config = ToffeConfig(sensor_size=sensor, dt_us=int(dt_us), ofpd=dict(ofpd_io.OFPD_DEFAULTS),
                         dataset=prov, input_norm=input_norm, ofs_kernel=int(ofs_kernel),
                         input_min_cluster=int(min_cluster))
    return for_camera(config, stated_focal(data, sensor, focal))


def stated_focal(data: Path, sensor: tuple[int, int], focal: float | None) -> float:
    """The focal length a checkpoint states its m/s for: the data's one camera, or, for
    sequences of several (the randomized data set), the reference 60 deg field of view over the
    data's width (554.3 px at 640 px; it was 554.3 px at every width: a 320 px data set's
    checkpoint spoke of a 32 deg lens nobody used), said in a warning at other widths."""
    if focal is not None:
        return float(focal)
    f = focal_px_from_hfov(sensor[0], REFERENCE_HFOV_DEG)
    if sensor[0] != 640:
        warn(f"{data}: its training sequences were recorded with several focal lengths: the checkpoint states "
             f"speeds in m/s for a {REFERENCE_HFOV_DEG:g} deg field of view over its {sensor[0]} px "
             f"(focal {f:.1f} px); `run --focal-px` / `--hfov-deg` state them for your camera")
    return f


def data_camera(files, data: Path, seed: int) -> tuple[tuple[int, int], float | None, dict]:
    """(sensor size, focal length in px or None, provenance) of a training data set: the first
    sequence's sensor, the focal length when every sequence was recorded with one (else None),
    and where the data came from (config.dataset)."""
    from ..events.io import open_events
    from ..runtime.truth import sequence_focal_px

    focals = set()
    for i, f in enumerate(files):
        with open_events(f) as src:
            if i == 0:
                sensor = src.sensor_size
                attrs = dict(src.attrs)
            focal = sequence_focal_px(src.attrs)
            focals.add(None if focal is None else round(focal, 3))
    prov = {"data_dir": os.fspath(data), "train_sequences": len(files), "train_seed": seed,
            "generator": attrs.get("generator"), "first_sequence": files[0].name}
    (focal,) = focals if len(focals) == 1 else (None,)
    return (int(sensor[0]), int(sensor[1])), focal, prov


def same_camera_data(config: ToffeConfig, files, data: Path, seed: int, out: Path, resume: bool) -> ToffeConfig:
    """``config`` of the checkpoint a --resume or --stage ofpd run goes on training, checked
    against the data it now trains on: another sensor size is refused (its OFS stages and OFPD
    were trained at the checkpoint's; such a run finished, exit 0, still saying the old size
    and data set), and a --stage ofpd run on another data set records it (config.dataset, the
    OFS stages' own data kept as ``ofs_dataset``)."""
    sensor, _focal, prov = data_camera(files, data, seed)
    if tuple(sensor) != tuple(config.sensor_size):
        w, h = config.sensor_size
        raise InputError(data, f"its sequences are {sensor[0]}x{sensor[1]}, the checkpoint in {out} is for {w}x{h} "
                               f"(what {'the run --resume continues' if resume else '--stage ofpd trains on'} was "
                               "trained at): train on data of that size, or fine-tune it on this data with "
                               "--init-from into a new --out")
    old = dict(config.dataset or {})
    if os.path.realpath(old.get("data_dir", "")) == os.path.realpath(data):
        return config
    if resume:              # (a data set moved, or another of the same camera: the caller's to say)
        warn(f"{data}: the run --resume continues began on {old.get('data_dir')}; it goes on with this data set")
        # recorded (it kept naming the first data set): this one, the first as ``resumed_from_dataset``
        return dataclasses.replace(config, dataset={**prov, "resumed_from_dataset": old})
    return dataclasses.replace(config, dataset={**prov, "ofs_dataset": old})


def with_untrained(config: ToffeConfig, parts: list[str]) -> ToffeConfig:
    """``config`` whose ``dataset["untrained"]`` names the parts a checkpoint holds without
    training ("OFPD", "OFS stage 3", ...; none: the key dropped): export warns of them (a
    --stage ofs checkpoint's OFPD is random, a stopped run's pending copy lacks stages), and
    the run that trains them drops them."""
    dataset = {k: v for k, v in (config.dataset or {}).items() if k != "untrained"}
    if parts:
        dataset["untrained"] = list(parts)
    return dataclasses.replace(config, dataset=dataset)


def init_config(init: ToffeConfig, files, data: Path, seed: int, init_from) -> ToffeConfig:
    """The config of a run that starts from another checkpoint's (``--init-from``): its model
    settings, but the camera of the data it now trains on (sensor size; speed bins in m/s for
    the data's focal length, or the reference camera's when the sequences disagree, as
    make_config states them) and that data's provenance, so that fine-tuning the shipped
    640x480 checkpoint on EVK4 data gives a bundle that says 1280x720 and 1646 px."""
    sensor, focal, prov = data_camera(files, data, seed)
    config = dataclasses.replace(init, sensor_size=sensor, dataset={**prov, "init_from": os.fspath(init_from)})
    return for_camera(config, stated_focal(data, sensor, focal))


def for_camera(config: ToffeConfig, focal_px: float) -> ToffeConfig:
    """``config`` stated for a camera of focal length ``focal_px`` at its depth: the same
    image-plane bins (px/ms) and representative speeds, in m/s for that camera."""
    k = config.focal_px / float(focal_px)                  # m/s at the new focal length per m/s at the old
    return dataclasses.replace(config, focal_px=float(focal_px),
                               speed_bins=tuple((lo * k, hi * k) for lo, hi in config.speed_bins),
                               representative_speeds=tuple(v * k for v in config.representative_speeds))


def with_ofpd_settings(config: ToffeConfig, pool: int | None, kernels: tuple[int, int] | None
                       ) -> tuple[ToffeConfig, bool]:
    """(config with the OFPD cell size / conv kernels asked for, whether they changed)."""
    s = ofpd_io.ofpd_settings(config)
    new = dict(s)
    if pool is not None:
        crop = s["crop_px"]
        if pool < 1 or crop % pool or (crop // pool) % 8:
            raise ToffeError(f"--ofpd-pool {pool} must split the {crop} px crop into a multiple of 8 cells")
        new["pool"] = int(pool)
    if kernels is not None:
        if len(kernels) != 2 or any(k < 1 or k % 2 == 0 for k in kernels):
            raise ToffeError(f"--ofpd-kernels needs two odd sizes (e.g. 3,3), got {','.join(map(str, kernels))}")
        new["conv_kernels"] = [int(k) for k in kernels]
    if new == s:
        return config, False
    return dataclasses.replace(config, ofpd=new), True


def with_current_layout(config: ToffeConfig) -> ToffeConfig:
    """config with ofpd_io.CURRENT_LAYOUT (blob grouping, scaled crop, px/ms speed): what a fresh
    OFPD is trained on, also over a checkpoint whose OFPD used the legacy layout."""
    return dataclasses.replace(config, ofpd={**ofpd_io.ofpd_settings(config), **ofpd_io.CURRENT_LAYOUT})


#: the config.ofpd keys that shape the OFPD network and its input (a trained OFPD fits only them);
#: the others are the host's (grouping thresholds, plane fit, outlines), settable after training
OFPD_NETWORK_KEYS = ("crop_px", "pool", "conv_channels", "conv_kernels", "hidden", *ofpd_io.CURRENT_LAYOUT)


def resolve_ofpd_settings(config: ToffeConfig, pool: int | None, kernels: tuple[int, int] | None,
                          interrupted: dict | None = None) -> tuple[ToffeConfig, bool]:
    """The OFPD settings a run trains with, and whether they differ from the checkpoint's.

    ``interrupted``: the settings of the OFPD training that --resume continues (saved in the
    training state; the checkpoint on disk still has the old ones until that run ends). A resume
    goes on with them; asking for other ones is a ValueError."""
    config, fresh = with_ofpd_settings(config, pool, kernels)
    if interrupted is not None and dict(interrupted) != ofpd_io.ofpd_settings(config):
        if fresh:
            raise ValueError("cannot resume: the interrupted OFPD training used other settings than "
                             "--ofpd-pool / --ofpd-kernels ask for (drop them, or start without --resume)")
        config, fresh = dataclasses.replace(config, ofpd=dict(interrupted)), True
    return config, fresh


def train(opts: TrainOptions) -> Path | None:
    """Run the requested training stages into opts.out (a checkpoint directory); None when a
    --resume finds the run finished (nothing written)."""
    from .data import find_sequences, load_windows

    device = pick_device(opts.device)
    out = Path(opts.out)
    files = find_sequences(opts.data, "train")
    state = _load_state(out) if opts.resume else {}
    resume = opts.resume and bool(state)
    if opts.resume and not resume:
        warn(f"{out}: no training progress to resume ({STATE_DIR}/ holds none): a new run")
    if resume and state.get("seed", opts.seed) != opts.seed:
        raise InputError(_state_path(out) / "state.json", f"the progress there is of a run with --seed "
                                                          f"{state['seed']}, not {opts.seed}: resume with its options, "
                                                          "or start a new run without --resume")
    pending = _pending_path(out)
    start, ck = out, None    # --resume: the interrupted run's own checkpoint (_pending_path)
    if resume and (pending / CONFIG_FILE).is_file():
        ck = load_checkpoint(pending)
        n_bins = ck.config.n_speed_bins
        done = sorted(state.get("ofs_done", []))
        if opts.stage == "ofpd" and set(done) < set(range(1, n_bins + 1)):
            raise InputError(pending, f"the interrupted run there finished OFS stages {done} of 1-{n_bins}: an OFPD "
                                      "on them would not fit its OFS; continue it with --resume (--stage all or ofs), "
                                      "or train the OFPD on --out's checkpoint without --resume")
        start = pending
    have_ckpt = (start / CONFIG_FILE).is_file()
    init_ofs = None                  # OFS stages the OFS training starts from (--init-from), else DOTIE's
    if opts.init_from is not None:
        if opts.stage == "ofpd":
            raise ToffeError("--init-from starts the OFS stages from another checkpoint: use --stage ofs or all")
        init = load_checkpoint(opts.init_from)
        init_ofs = [dict(p) for p in init.ofs]
    if have_ckpt and (resume or opts.stage == "ofpd"):
        ck = ck if start is pending else load_checkpoint(start)
        config, ofs_params, ofpd_state = ck.config, ck.ofs, ck.ofpd_state
        if opts.reset is not None and opts.reset != config.reset and opts.stage == "ofpd":
            raise InputError(out, f"its OFS stages were trained with reset {config.reset!r}; --reset {opts.reset} "
                                  "needs them retrained (--stage all)")
        if resume:
            if opts.reset is not None and opts.reset != config.reset:
                raise InputError(out, f"the run --resume continues trains reset {config.reset!r}, not --reset "
                                      f"{opts.reset} (its finished OFS stages would keep the old one): resume with "
                                      "its options, or start a new run without --resume")
            _check_kept_settings(opts, config, out, "the run --resume continues",
                                 "resume with its options, or start a new run without --resume")
        else:
            _check_kept_settings(opts, config, out, "the checkpoint --stage ofpd trains on",
                                 "drop the option, or train a new checkpoint (--stage all)")
        config = same_camera_data(config, files, Path(opts.data), opts.seed, out, resume)
        ofpd_trained = "OFPD" not in config.untrained
    elif init_ofs is not None:
        config = init_config(init.config, files, Path(opts.data), opts.seed, opts.init_from)
        _check_kept_settings(opts, config, opts.init_from, "the --init-from checkpoint",
                             "drop the option (fine-tuning keeps the model's settings), or train from scratch")
        ofs_params, ofpd_state = [dict(p) for p in init_ofs], init.ofpd_state
        ofpd_trained = "OFPD" not in init.config.untrained
        state = {}
    else:
        if opts.stage == "ofpd":
            raise InputError(out, "--stage ofpd needs a checkpoint with trained OFS stages in --out (run --stage ofs first)")
        config = make_config(files, Path(opts.data), _new_setting(opts, "dt_us"), opts.seed,
                             _new_setting(opts, "input_norm"), _new_setting(opts, "ofs_kernel"),
                             _new_setting(opts, "min_cluster"))
        config = dataclasses.replace(config, ofs_pool=NEW_OFS_POOL if opts.ofs_pool is None else int(opts.ofs_pool),
                                     input_support=opts.input_support)
        ofs_params, ofpd_state = dotie_ofs(config), random_ofpd_state(config, opts.seed)
        ofpd_trained = False
        state = {}
    if opts.reset is not None and opts.reset != config.reset:
        config = dataclasses.replace(config, reset=opts.reset)
    for key, want in (("ofs_pool", opts.ofs_pool), ("mask_kernel", opts.mask_kernel)):
        if want is not None and int(want) != getattr(config, key):
            if opts.stage == "ofpd":
                raise InputError(out, f"its OFS stages were trained with {key} {getattr(config, key)}; "
                                      f"--{key.replace('_', '-')} {want} needs them retrained (--stage all)")
            config = dataclasses.replace(config, **{key: int(want)})
    if opts.stage in ("ofpd", "all") and not (resume and state.get("ofpd_settings")):
        config = with_current_layout(config)      # a fresh OFPD trains on today's input/output layout
    # an interrupted run's OFPD settings are in its state (--out's checkpoint has the old ones until
    # it ends). A finished run's network and input layout are the state's too (what its partial
    # OFPD was trained on), but the rest are --out's own, with what the host set since
    # (fit_plane_fit.py --write): comparing all of them with the state's made a resume retrain a
    # random OFPD and drop the fitted keys. Other --ofpd-pool / --ofpd-kernels are refused either
    # way; a finished run that trained no OFPD (--stage ofs) has no settings to keep.
    interrupted = state.get("ofpd_settings") if resume else None
    if resume and state.get("finished") and interrupted:
        interrupted = {**ofpd_io.ofpd_settings(config),
                       **{k: v for k, v in interrupted.items() if k in OFPD_NETWORK_KEYS}}
    try:
        config, fresh = resolve_ofpd_settings(config, opts.ofpd_pool, opts.ofpd_kernels, interrupted)
    except ValueError as exc:
        raise InputError(out, str(exc)) from None
    ofs_left = opts.stage != "ofpd" and len(set(state.get("ofs_done", []))) < config.n_speed_bins
    ofpd_left = opts.stage != "ofs" and int(state.get("ofpd_epoch") or 0) < opts.ofpd_epochs
    if resume and opts.stage != "ofs" and int(state.get("ofpd_epoch") or 0) > opts.ofpd_epochs:
        warn(f"{out}: the run --resume continues had trained {int(state['ofpd_epoch'])} OFPD epochs, more than "
             f"--epochs {opts.ofpd_epochs}: its OFPD is kept as it is")
    if resume and state.get("finished") and not fresh and not ofs_left and not ofpd_left:
        # a finished run: it loaded the data and rewrote the checkpoint for nothing (minutes); other
        # OFPD settings were refused above, as for an interrupted run
        warn(f"{out}: nothing to resume: its run finished its OFS stages and "
             f"{int(state.get('ofpd_epoch') or 0)} OFPD epochs (--epochs {opts.ofpd_epochs}); a larger --epochs "
             "trains the OFPD on, a run without --resume starts afresh; the checkpoint is left as it is")
        return None
    state["finished"] = False               # until its last file is written (the end of this function)
    if fresh:                        # a new OFPD shape: a fresh OFPD (the OFS stages are kept)
        if opts.stage == "ofs":
            raise ToffeError("--ofpd-pool / --ofpd-kernels change the OFPD, which --stage ofs does not train")
        ofpd_state = random_ofpd_state(config, opts.seed)
        ofpd_trained = False
    t_start = time.time()
    windows = load_windows(files, config, config.dt_us, opts.per_file, opts.seed, progress=opts.progress)
    if len(windows) == 0:
        raise InputError(opts.data, "no usable single-object training windows")
    _fresh_state(out, keep=resume)
    state["seed"] = opts.seed
    log = state.setdefault("log", {})
    if opts.stage == "ofpd" and not log and (out / "train_log.json").is_file():
        # an OFPD-only run keeps the OFS stages, and so their training record
        try:
            old = json.loads((out / "train_log.json").read_text())
        except (OSError, *JSON_ERRORS):
            old = {}
        log.update({k: v for k, v in old.items() if k.startswith("ofs_")} if isinstance(old, dict) else {})
    log["train_windows"] = len(windows)
    log["windows_per_bin"] = {str(k): int(np.sum(windows.speed_bin == k)) for k in range(1, config.n_speed_bins + 1)}
    empty = [k for k, n in log["windows_per_bin"].items() if n == 0]
    if empty and opts.stage in ("ofs", "all"):
        warn(f"{opts.data}: no training window of speed bin {', '.join(empty)}: OFS stage {', '.join(empty)} learns "
             f"nothing to fire on (it keeps its initial weights' behaviour); generate more sequences (dataset synth "
             f"--split train without --limit)")

    if opts.stage in ("ofs", "all"):
        done = set(state.get("ofs_done", []))
        if len(done) < config.n_speed_bins:
            packed, bins = pack_training_windows(windows, config.ofs_kernel, opts.seed, opts.progress, config.input_norm,
                                                  config.input_min_cluster, config.ofs_pool, config.input_support)
        for k in range(1, config.n_speed_bins + 1):
            if k in done:
                continue
            r = train_ofs_stage(k, packed, bins, opts.ofs_epochs, opts.seed, device,
                                init=init_ofs[k - 1] if init_ofs is not None else dotie_ofs(config)[0],
                                progress=opts.progress, reset=config.reset)
            cal, curve = calibrate_threshold(k, dict(weight=r["weight"], threshold=r["threshold"], leak=r["leak"]),
                                             windows, config, seed=opts.seed)
            ofs_params[k - 1] = snap_to_loihi(cal)
            log[f"ofs_stage{k}"] = {"loss_curve": r["loss_curve"], "trained_threshold": r["threshold"],
                                    "threshold": cal["threshold"], "leak": r["leak"], "calibration": curve}
            done.add(k)
            state["ofs_done"] = sorted(done)
            pending.parent.mkdir(parents=True, exist_ok=True)
            left = [f"OFS stage {j}" for j in range(1, config.n_speed_bins + 1) if j not in done]
            save_checkpoint(pending, with_untrained(config, left + ([] if ofpd_trained else ["OFPD"])),
                            ofs_params, ofpd_state)                     # not --out: the run is not done
            _save_state(out, state)
        stages = quantize_stages(ofs_params, config.reset)
        log["ofs_separation_train"] = separation_scores(stages, windows, config, seed=opts.seed)
        if opts.stage == "ofs":
            save_checkpoint(out, with_untrained(config, [] if ofpd_trained else ["OFPD"]), ofs_params, ofpd_state)
        _save_state(out, state)

    if opts.stage in ("ofpd", "all"):
        stages = quantize_stages(ofs_params, config.reset)
        ds = build_ofpd_set(windows, stages, config, progress=opts.progress)
        log["ofpd_samples"] = int(ds.planes.shape[0])
        torch.manual_seed(opts.seed)             # before the init: the same OFPD for a seed, however we got here
        model = OFPD.from_config(config).to(device)
        if opts.init_from is not None and not fresh:
            # fine-tuning starts from the other checkpoint's OFPD (it trained a random one: README "Your
            # camera" promises its OFPD), unless today's layout gives the OFPD another shape
            have = {k: torch.as_tensor(np.asarray(v)) for k, v in ofpd_state.items()}
            want = model.state_dict()
            if set(have) == set(want) and all(have[k].shape == want[k].shape for k in want):
                model.load_state_dict(have)
            else:
                warn(f"--init-from {opts.init_from}: its OFPD has another input or layer shape than this "
                     "training's; the OFPD starts from random weights")
        opt = torch.optim.Adam(model.parameters(), lr=2e-3)
        sched_total = max(opts.ofpd_epochs, 1)
        ep0 = 0
        partial = _state_path(out) / "ofpd_partial.pt"
        if resume and state.get("ofpd_epoch") and partial.is_file():
            try:
                blob = torch.load(partial, map_location=device, weights_only=True)
                model.load_state_dict(blob["model"])
                opt.load_state_dict(blob["opt"])
            except Exception as exc:               # torch's unpickler and load_state_dict raise their own kinds
                raise InputError(partial, f"cannot resume from it ({type(exc).__name__}: "
                                          f"{(str(exc).splitlines() or [''])[0][:200]}); delete {STATE_DIR}/ "
                                          "to start over") from None
            ep0 = int(state["ofpd_epoch"])
        rng = np.random.default_rng(opts.seed + ep0)
        state["ofpd_settings"] = ofpd_io.ofpd_settings(config)      # what a --resume must go on with
        n = ds.planes.shape[0]
        terms = None if opts.speed_loss.plain else opts.speed_loss.sample_terms(ds, config)
        if terms is not None:
            log["ofpd_speed_loss"] = dataclasses.asdict(opts.speed_loss)
        for ep in range(ep0, opts.ofpd_epochs):
            for gp in opt.param_groups:      # cosine decay, a function of the epoch so resume agrees
                gp["lr"] = 2e-3 * 0.5 * (1 + math.cos(math.pi * ep / sched_total))
            model.train()
            order = rng.permutation(n)
            agg = np.zeros(3)
            bar = tqdm(range(0, n, 64), desc=f"OFPD epoch {ep + 1}/{opts.ofpd_epochs}", leave=False, disable=not opts.progress)
            for s in bar:
                bi = order[s:s + 64]
                loss, parts = ofpd_loss(model, ofpd_batch(ds, bi, rng), device,
                                        None if terms is None else (terms[0][bi], terms[1][bi]),
                                        opts.speed_loss.edge_weight)
                opt.zero_grad()
                loss.backward()
                opt.step()
                agg += np.array(parts) * len(order[s:s + 64])
                bar.set_postfix(pose=f"{agg[0] / (s + 64):.3f}", dir=f"{agg[1] / (s + 64):.3f}", lnv=f"{agg[2] / (s + 64):.3f}")
            log.setdefault("ofpd_loss", []).append((agg / max(n, 1)).tolist())
            state["ofpd_epoch"] = ep + 1
            _save_state(out, state, model, opt)
        ofpd_state = {k: v.detach().cpu().numpy() for k, v in model.state_dict().items()}
        ofpd_trained = ofpd_trained or opts.ofpd_epochs > 0 or ep0 > 0
        save_checkpoint(out, with_untrained(config, [] if ofpd_trained else ["OFPD"]), ofs_params, ofpd_state)
    log["train_seconds"] = round(time.time() - t_start, 1)
    _save_state(out, state)
    with atomic_path(out / "train_log.json") as tmp:
        tmp.write_text(json.dumps(log, indent=1))
    shutil.rmtree(_pending_path(out), ignore_errors=True)          # --out holds the run's checkpoint now
    state["finished"] = True                # every file written: a --resume of this run has nothing to do
    _save_state(out, state)
    return out
