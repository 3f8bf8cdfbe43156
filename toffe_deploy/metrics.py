"""Object flow metrics (torch-free): the paper's pixE, dirE, speedE plus detection bookkeeping.

    pixE   = mean |(x, y)_pred - (x, y)_gt|_2                (px, full sensor resolution)
    dirE   = mean wrap(|theta_pred - theta_gt|) in [0, 180]    (deg)
    speedE = mean |v_pred - v_gt|                              (m/s)

The paper calls them mean absolute errors; for pose we take the Euclidean distance (the
absolute error of a 2-D position). Errors are averaged over *matched* ground-truth objects:
each ground-truth object of a window is matched to its nearest prediction (greedy by distance,
one-to-one, within ``max_dist_px``); a ground-truth object left without a prediction is a miss
and lowers the detection rate instead of being silently dropped, a prediction left without an
object is a false positive.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Iterable, Sequence

import numpy as np


def angle_error_deg(pred_rad, true_rad) -> np.ndarray:
    """|pred - true| wrapped to [0, 180] degrees."""
    d = np.abs(np.asarray(pred_rad, dtype=np.float64) - np.asarray(true_rad, dtype=np.float64))
    d = np.mod(d, 2 * np.pi)
    return np.degrees(np.minimum(d, 2 * np.pi - d))


def match_nearest(pred_xy: np.ndarray, true_xy: np.ndarray, max_dist_px: float = np.inf) -> list[tuple[int, int]]:
    """Greedy one-to-one matching by distance: list of (true_index, pred_index) pairs."""
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


@dataclass
class Prediction:
    """One reported object: stage (1-based speed bin) and its decoded object flow."""

    stage: int
    x: float
    y: float
    direction_rad: float
    speed_mps: float
    speed_bin_mps: float


@dataclass
class FlowErrors:
    """Accumulates matched errors and detection counts; ``summary()`` gives the table row."""

    max_dist_px: float = 64.0
    pix: list = field(default_factory=list)
    dir: list = field(default_factory=list)
    speed: list = field(default_factory=list)
    speed_bin: list = field(default_factory=list)
    gt_bin: list = field(default_factory=list)
    pred_bin: list = field(default_factory=list)
    n_gt: int = 0
    n_pred: int = 0
    n_windows: int = 0

    def add_window(self, preds: Sequence[Prediction], truths: Iterable) -> None:
        """truths: objects with x, y, direction, speed, speed_bin (dataset ObjectTruth)."""
        truths = list(truths)
        self.n_windows += 1
        self.n_gt += len(truths)
        self.n_pred += len(preds)
        pairs = match_nearest([(p.x, p.y) for p in preds], [(t.x, t.y) for t in truths], self.max_dist_px)
        for i, j in pairs:
            t, p = truths[i], preds[j]
            self.pix.append(float(np.hypot(p.x - t.x, p.y - t.y)))
            self.dir.append(float(angle_error_deg(p.direction_rad, t.direction)))
            self.speed.append(abs(p.speed_mps - float(t.speed)))
            self.speed_bin.append(abs(p.speed_bin_mps - float(t.speed)))
            self.gt_bin.append(int(t.speed_bin))
            self.pred_bin.append(int(p.stage))

    def summary(self, bin_k: int | None = None) -> dict:
        """Means over matched objects (all, or those whose ground truth is in speed bin k)."""
        sel = np.ones(len(self.pix), dtype=bool) if bin_k is None else (np.asarray(self.gt_bin) == bin_k)
        n = int(sel.sum())

        def mean(v):
            return float(np.mean(np.asarray(v)[sel])) if n else float("nan")

        out = {"n_matched": n, "pixE": mean(self.pix), "dirE": mean(self.dir), "speedE": mean(self.speed),
               "speedE_bin_only": mean(self.speed_bin),
               "bin_accuracy": float(np.mean((np.asarray(self.gt_bin) == np.asarray(self.pred_bin))[sel])) if n else float("nan")}
        if bin_k is None:
            out.update(n_gt=self.n_gt, n_pred=self.n_pred, n_windows=self.n_windows,
                       detection_rate=(n / self.n_gt) if self.n_gt else float("nan"),
                       false_positives=self.n_pred - n)
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
