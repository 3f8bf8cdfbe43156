"""Object flow metrics (torch-free): the paper's pixE, dirE, speedE plus honest detection counts.

    pixE   = mean |(x, y)_pred - (x, y)_gt|_2                (px, full sensor resolution)
    dirE   = mean wrap(|theta_pred - theta_gt|) in [0, 180]    (deg)
    speedE = mean |v_pred - v_gt|                              (m/s)

The paper calls them mean absolute errors; for pose we take the Euclidean distance (the
absolute error of a 2-D position). Each window's predictions are matched one-to-one to its
ground-truth objects by an optimal assignment on centre distance with a gate (``match_gated``:
the most pairs within ``gate_px``, then the least total distance). Errors are averaged over
matched objects only, so the detection counts say the rest:

    recall            = matched objects / ground-truth objects
    FP per window     = (predictions - matched) / windows         (windows with no object count)
    bin accuracy      = matched objects whose predicted bin is the true bin / matched objects
    confusion[t][p]   = matched objects of true bin t reported in bin p

speedE compares image-plane speeds when both sides have one (ground-truth column
``speed_px_ms``; a prediction's px/ms speed, or its m/s speed at the config's reference scale):
speedE_px_ms = |pred - true| px/ms, and speedE = the same converted to m/s at the object's true
depth (``depth_m``) and the sequence's focal length, the error a user gets with the right
``run --depth-m``. Without those it is the m/s difference (the paper's protocol, where the two
agree).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Iterable, Sequence

import numpy as np

from .assignment import match_pairs, min_cost_pairs
from .camera import SpeedScale

#: The headline gate: a prediction farther than this from an object's centre does not find it.
GATE_PX = 20.0


def angle_error_deg(pred_rad, true_rad) -> np.ndarray:
    """|pred - true| wrapped to [0, 180] degrees."""
    d = np.abs(np.asarray(pred_rad, dtype=np.float64) - np.asarray(true_rad, dtype=np.float64))
    d = np.mod(d, 2 * np.pi)
    return np.degrees(np.minimum(d, 2 * np.pi - d))


def match_nearest(pred_xy: np.ndarray, true_xy: np.ndarray, max_dist_px: float = np.inf) -> list[tuple[int, int]]:
    """Greedy one-to-one matching by distance: list of (true_index, pred_index) pairs (used to pair
    two pipelines' objects, where nearest-first is the intent)."""
    pred_xy = np.asarray(pred_xy, dtype=np.float64).reshape(-1, 2)
    true_xy = np.asarray(true_xy, dtype=np.float64).reshape(-1, 2)
    if not len(pred_xy) or not len(true_xy):
        return []
    d = np.linalg.norm(true_xy[:, None, :] - pred_xy[None, :, :], axis=2)
    order = np.argsort(d, axis=None, kind="stable")
    used_t, used_p, pairs = set(), set(), []
    for flat in order:                      # at most (objects x predictions) per window: tiny
        i, j = divmod(int(flat), d.shape[1])
        if d[i, j] > max_dist_px:
            break
        if i in used_t or j in used_p:
            continue
        used_t.add(i)
        used_p.add(j)
        pairs.append((i, j))
    return pairs


def min_cost_assignment(cost: np.ndarray) -> list[tuple[int, int]]:
    """Exact minimum-cost assignment of a (n, m) matrix: min(n, m) (row, col) pairs, each row and
    column at most once (Hungarian method with potentials; assignment.min_cost_pairs). A NaN or
    inf entry (a forbidden pair) costs more than all the finite ones together."""
    cost = np.array(cost, dtype=np.float64)
    bad = ~np.isfinite(cost)
    if bad.any():
        cost[bad] = float(np.abs(cost[~bad]).sum()) + 1.0
    rows, cols = min_cost_pairs(cost)
    return list(zip(rows.tolist(), cols.tolist()))


def match_gated(pred_xy: np.ndarray, true_xy: np.ndarray, gate_px: float = GATE_PX) -> list[tuple[int, int]]:
    """Optimal one-to-one matching within a gate: (true_index, pred_index) pairs, as many as
    possible with every pair closer than ``gate_px``, and among those the least total distance.

    Pairs beyond the gate cost a constant larger than any sum of in-gate distances, so the
    assignment first maximizes the in-gate pairs; the bipartite "within the gate" graph is split
    into connected components first, so a window of well separated objects costs no more than
    nearest-neighbour search."""
    pred_xy = np.asarray(pred_xy, dtype=np.float64).reshape(-1, 2)
    true_xy = np.asarray(true_xy, dtype=np.float64).reshape(-1, 2)
    if not len(pred_xy) or not len(true_xy):
        return []
    d = np.linalg.norm(true_xy[:, None, :] - pred_xy[None, :, :], axis=2)
    return match_within(d, d <= gate_px)


def match_within(d: np.ndarray, ok: np.ndarray) -> list[tuple[int, int]]:
    """``match_gated`` on a (rows, cols) distance matrix ``d`` whose allowed pairs are ``ok``
    (a gate per row or per pair, as the tracker's): (row, col) pairs, the most allowed pairs,
    then the least total distance (assignment.match_pairs). A pair whose distance is NaN or inf
    is not allowed."""
    d = np.ascontiguousarray(d, dtype=np.float64)
    ok = np.ascontiguousarray(ok, dtype=np.bool_) & np.isfinite(d)
    rows, cols = match_pairs(d, ok)
    return list(zip(rows.tolist(), cols.tolist()))


@dataclass
class Prediction:
    """One reported object: stage (1-based speed bin) and its decoded object flow; ``speed_px_ms``
    is its image-plane speed when the producer has it (NaN: derive it from ``speed_mps``);
    ``measured`` False: a position-only object (ofpd.faint_objects: its speed is its bin's
    representative, its direction a guess), scored in recall, false positives, pixE and the bin,
    left out of dirE and speedE (counted as ``n_position_only``)."""

    stage: int
    x: float
    y: float
    direction_rad: float
    speed_mps: float
    speed_bin_mps: float
    speed_px_ms: float = math.nan
    measured: bool = True


def predictions_of(objects) -> list[Prediction]:
    """The Predictions of a pipeline's reported objects (runtime.pipeline.ObjectFlow: speed_bin, x,
    y, direction_rad, speed_mps, speed_bin_mps, speed_px_s), px/ms included: what `run`'s
    summary, parity.json, the benchmarks and eval score."""
    return [Prediction(int(o.speed_bin), float(o.x), float(o.y), float(o.direction_rad), float(o.speed_mps),
                       float(o.speed_bin_mps), float(o.speed_px_s) / 1000.0, not getattr(o, "faint", False))
            for o in objects]


def _or_nan(v) -> float:
    """An optional ground-truth number (None where the file lacks the column) as a float."""
    return math.nan if v is None else float(v)


def _finite(v) -> bool:
    return v is not None and math.isfinite(float(v))


@dataclass
class FlowErrors:
    """Accumulates one window at a time (``add_window``); ``summary()`` gives the table row.

    gate_px: matching gate (``match_gated``); n_bins: speed bins of the cascade (confusion matrix
    size); pred_scale: the SpeedScale that turned predicted px/ms into m/s (the config's reference
    scale), used to recover a prediction's px/ms speed when it carries none."""

    gate_px: float = GATE_PX
    n_bins: int = 4
    pred_scale: SpeedScale | None = None
    pix: list = field(default_factory=list)
    dir: list = field(default_factory=list)
    speed: list = field(default_factory=list)
    speed_bin: list = field(default_factory=list)
    speed_px_ms: list = field(default_factory=list)
    gt_bin: list = field(default_factory=list)       # matched objects: true bin
    pred_bin: list = field(default_factory=list)     # matched objects: predicted bin
    all_gt_bin: list = field(default_factory=list)   # every ground-truth object
    fp_bin: list = field(default_factory=list)       # every unmatched prediction: its bin
    position_only: list = field(default_factory=list)  # matched objects: not measured (Prediction.measured)
    n_windows: int = 0

    def _px_ms(self, v_mps: float) -> float:
        """A predicted m/s speed back in px/ms (NaN without pred_scale)."""
        return float(v_mps) * self.pred_scale.px_ms_per_mps if self.pred_scale is not None else math.nan

    def add_window(self, preds: Sequence[Prediction], truths: Iterable, focal_px: float | None = None) -> None:
        """truths: objects with x, y, direction, speed, speed_bin and optionally speed_px_ms,
        depth_m (dataset ObjectTruth); focal_px: the sequence's camera (None: unknown)."""
        truths = list(truths)
        self.n_windows += 1
        self.all_gt_bin.extend(int(t.speed_bin) for t in truths)
        pairs = match_gated([(p.x, p.y) for p in preds], [(t.x, t.y) for t in truths], self.gate_px)
        matched_p = {j for _i, j in pairs}
        self.fp_bin.extend(int(p.stage) for j, p in enumerate(preds) if j not in matched_p)
        for i, j in pairs:
            t, p = truths[i], preds[j]
            self.pix.append(float(np.hypot(p.x - t.x, p.y - t.y)))
            self.gt_bin.append(int(t.speed_bin))
            self.pred_bin.append(int(p.stage))
            self.position_only.append(not getattr(p, "measured", True))
            if self.position_only[-1]:                   # no measured motion: left out of dirE and speedE
                self.dir.append(math.nan)
                self.speed_px_ms.append(math.nan)
                self.speed.append(math.nan)
                self.speed_bin.append(math.nan)
                continue
            self.dir.append(float(angle_error_deg(p.direction_rad, t.direction)))
            true_px = _or_nan(getattr(t, "speed_px_ms", None))
            depth = _or_nan(getattr(t, "depth_m", None))
            pred_px = float(p.speed_px_ms) if _finite(p.speed_px_ms) else self._px_ms(p.speed_mps)
            bin_px = self._px_ms(p.speed_bin_mps)
            self.speed_px_ms.append(abs(pred_px - true_px) if _finite(true_px) and _finite(pred_px) else math.nan)
            # the error in m/s at the object's true depth seen by the sequence's camera
            truth_scale = SpeedScale(float(focal_px), depth) if _finite(true_px) and _finite(depth) and depth > 0 \
                and _finite(focal_px) and focal_px > 0 else None
            self.speed.append(truth_scale.to_mps(abs(pred_px - true_px)) if truth_scale and _finite(pred_px)
                              else abs(p.speed_mps - float(t.speed)))
            self.speed_bin.append(truth_scale.to_mps(abs(bin_px - true_px)) if truth_scale and _finite(bin_px)
                                  else abs(p.speed_bin_mps - float(t.speed)))

    @property
    def labels(self) -> list[int]:
        """Bins of the confusion matrix: 1..n_bins, plus any other bin the truth holds (0: slower
        than the first bin)."""
        return sorted(set(range(1, self.n_bins + 1)) | set(self.gt_bin) | set(self.pred_bin))

    def confusion(self) -> dict:
        """{"labels": bins, "matrix": rows = true bin, columns = predicted bin} over matched objects."""
        labels = self.labels
        pos = {b: i for i, b in enumerate(labels)}
        m = np.zeros((len(labels), len(labels)), dtype=np.int64)
        for t, p in zip(self.gt_bin, self.pred_bin):
            m[pos[t], pos[p]] += 1
        return {"labels": labels, "matrix": m.tolist()}

    def summary(self, bin_k: int | None = None) -> dict:
        """Means over matched objects and detection counts: all, or the ground truth of bin k
        (its recall, errors and bin accuracy; false positives are those reported in bin k)."""
        gt_bin = np.asarray(self.gt_bin, dtype=np.int64)
        sel = np.ones(gt_bin.size, dtype=bool) if bin_k is None else (gt_bin == bin_k)
        n = int(sel.sum())
        all_gt = np.asarray(self.all_gt_bin, dtype=np.int64)
        n_gt = int(all_gt.size if bin_k is None else np.sum(all_gt == bin_k))
        fp = len(self.fp_bin) if bin_k is None else sum(1 for b in self.fp_bin if b == bin_k)

        def mean(v):
            a = np.asarray(v, dtype=np.float64)[sel]
            a = a[np.isfinite(a)]
            return float(a.mean()) if a.size else float("nan")

        hit = gt_bin == np.asarray(self.pred_bin, dtype=np.int64)
        out = {"n_matched": n, "n_gt": n_gt, "recall": n / n_gt if n_gt else float("nan"),
               "false_positives": fp, "fp_per_window": fp / self.n_windows if self.n_windows else float("nan"),
               "pixE": mean(self.pix), "dirE": mean(self.dir), "speedE": mean(self.speed),
               "speedE_bin_only": mean(self.speed_bin), "speedE_px_ms": mean(self.speed_px_ms),
               "bin_accuracy": float(hit[sel].mean()) if n else float("nan"),
               "n_position_only": int(np.asarray(self.position_only, bool)[sel].sum()) if n else 0}
        if bin_k is None:
            out.update(n_pred=n + fp, n_windows=self.n_windows, gate_px=self.gate_px, confusion=self.confusion())
        return out


@dataclass
class SeparationCounts:
    """Window-level speed separation of one OFS stage k: fires (>= min_events spike pixels)
    vs should fire (object speed bin >= k). precision = TP / (TP + FP), recall = TP / (TP + FN)."""

    tp: int = 0
    fp: int = 0
    fn: int = 0
    tn: int = 0

    def add(self, fired: np.ndarray, positive: np.ndarray) -> None:
        fired = np.asarray(fired, dtype=bool)
        positive = np.asarray(positive, dtype=bool)
        self.tp += int(np.sum(fired & positive))
        self.fp += int(np.sum(fired & ~positive))
        self.fn += int(np.sum(~fired & positive))
        self.tn += int(np.sum(~fired & ~positive))

    @property
    def precision(self) -> float:
        return self.tp / (self.tp + self.fp) if self.tp + self.fp else float("nan")

    @property
    def recall(self) -> float:
        return self.tp / (self.tp + self.fn) if self.tp + self.fn else float("nan")

    def as_dict(self) -> dict:
        return dict(tp=self.tp, fp=self.fp, fn=self.fn, tn=self.tn, precision=self.precision, recall=self.recall)
