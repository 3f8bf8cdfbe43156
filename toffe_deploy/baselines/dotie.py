"""DOTIE (Nagaraj et al., ICRA 2023), the speed-separation ancestor of OFS, as the baseline of Table 2.

Torch-free numpy/OpenCV re-implementation of its public code (github.com/manishnagaraj/DOTIE:
``DOTIE_complete_framework.py``, ``visual_helpers.recover_fast_inputs``,
``Clustering_techniques.get_boundaries_DOTIE``), run on the same binned windows as TOFFE
(B bins of dt/B; DOTIE itself bins at 2 ms). Its loop runs the layer, the recovery of the fast
events and the clustering once per time step; one inference here is one window of B steps (the
paper's DOTIE on Loihi 2 takes B = 5 steps per inference):

    x[t]     = ON + OFF event counts of bin t per pixel                       (1 channel, graded)
    I[t]     = conv3x3(x[t], w),  w = 0.15 everywhere, 0.2 at the centre      (zero padding, no bias)
    U[t]     = 0.3 * U[t-1] + I[t] - 1.0 * S[t-1]                             (reset by subtraction, one step late)
    S[t]     = U[t] > 1.0                                                     (U[-1] = S[-1] = 0 each window)
    out[t]   = (x[t] > 0) AND Close_12x12(Dilate_12x12(S[t]))                 (recover_fast_inputs, neighbourhood 12)

DOTIE without clustering stops at the speed-separated events out[t]. DOTIE with clustering adds,
per step, scikit-learn DBSCAN (eps 15 px, min_samples 10) on the pixel coordinates of out[t]
(skipped when out[t] has fewer than min_samples pixels, as the public code does) and turns each
cluster into a box, dropping boxes whose squared diagonal is under 2300 px^2.

Protocol: the comparison with TOFFE runs DOTIE per window, as TOFFE runs: the window's B bins
of dt/B (100 us at dt = 500 us), membrane reset at each window (U[-1] = S[-1] = 0). DOTIE's own
code differs in two ways: it bins at 2 ms and carries its membrane across the whole stream.
``DotieState`` carries it (pass one to the functions below), and with 1 bin of 2000 us per call
they run DOTIE as its code does (benchmarks/energy_latency.py ``--dotie-code``). The per-window
protocol stays the comparison because both models must see the same input windows, answer per
window of dt, and spend the same time span per inference; a 2 ms bin is four TOFFE windows.

``dotie_detect_window`` clusters once per window on the union of the steps' events instead:
not DOTIE's code, reported beside it to show how much the per-step clustering costs.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from ..events.binning import event_bin_index

DOTIE_WEIGHT = 0.15
DOTIE_CENTRE = 0.2
DOTIE_LEAK = 0.3
DOTIE_THRESHOLD = 1.0
DOTIE_CLOSE_KERNEL = 12
DOTIE_DILATE_KERNEL = 12      # recover_fast_inputs dilates and closes with the same 12x12 kernel
DBSCAN_EPS = 15.0
DBSCAN_MIN_SAMPLES = 10
MIN_BOX_DIAG2 = 2300.0


def dotie_kernel() -> np.ndarray:
    """DOTIE's hand-set 3x3 weights (not trained)."""
    w = np.full((3, 3), DOTIE_WEIGHT, dtype=np.float32)
    w[1, 1] = DOTIE_CENTRE
    return w


@dataclass(frozen=True)
class DotieParams:
    """The baseline's settings; the defaults are DOTIE's published ones."""

    weight: np.ndarray = field(default_factory=dotie_kernel)
    leak: float = DOTIE_LEAK
    threshold: float = DOTIE_THRESHOLD
    dilate_kernel: int = DOTIE_DILATE_KERNEL
    close_kernel: int = DOTIE_CLOSE_KERNEL
    eps: float = DBSCAN_EPS
    min_samples: int = DBSCAN_MIN_SAMPLES
    min_box_diag2: float = MIN_BOX_DIAG2


@dataclass
class DotieState:
    """Membrane U (H, W) float32 and last spikes S (H, W) bool carried from call to call (DOTIE's
    own code: one stream); ``DotieState.zeros(h, w)`` is the state at the stream's start."""

    u: np.ndarray
    s: np.ndarray

    @staticmethod
    def zeros(h: int, w: int) -> "DotieState":
        return DotieState(np.zeros((h, w), np.float32), np.zeros((h, w), bool))


@dataclass
class DotieLayerTrace:
    """Per step: synaptic input I (H, W), membrane U after the step, spikes S. Filled on request
    (the cost model counts Loihi activity from it); None fields are not recorded."""

    currents: list[np.ndarray] = field(default_factory=list)
    potentials: list[np.ndarray] = field(default_factory=list)


def dotie_input(binned: np.ndarray) -> np.ndarray:
    """(B, 2, H, W) counts -> (B, H, W): ON + OFF summed (DOTIE's single channel), kept in the
    counts' integer type (OpenCV filters it straight to float32)."""
    b = np.asarray(binned)
    if b.ndim != 4 or b.shape[1] != 2:
        raise ValueError(f"binned window must be (B, 2, H, W), got {b.shape}")
    if b.dtype == np.uint16 or b.dtype == np.uint8:
        return np.add(b[:, 0], b[:, 1], dtype=np.uint16)     # bin_window saturates at 65535 per polarity
    return b.sum(axis=1, dtype=np.float32)


def dotie_frames(events: np.ndarray, t0: int, dt_us: int, n_bins: int, sensor_size: tuple[int, int]) -> np.ndarray:
    """DOTIE's input straight from a window's events: (B, H, W) uint16 ON + OFF counts, bin
    b = (t - t0) * B // dt as in ``bin_window``; O(events) plus one small zeroed frame stack."""
    width, height = int(sensor_size[0]), int(sensor_size[1])
    plane, pix = np.divmod(event_bin_index(events, t0, dt_us, n_bins, sensor_size), height * width)
    out = np.zeros(n_bins * height * width, np.uint16)
    np.add.at(out, (plane >> 1) * (height * width) + pix, 1)     # plane = 2b + p: ON + OFF summed
    return out.reshape(n_bins, height, width)


def dotie_layer(x: np.ndarray, p: DotieParams = DotieParams(), trace: DotieLayerTrace | None = None,
                state: DotieState | None = None) -> np.ndarray:
    """DOTIE's conv + LIF over one window: x (B, H, W) graded counts -> spikes (B, H, W) bool.
    The membrane starts at zero, or from ``state`` (updated in place) when given.

    In-place float32 arithmetic: the baseline should be as fast as a careful numpy port can be."""
    b, h, w = x.shape
    u = np.zeros((h, w), np.float32) if state is None else state.u
    out = np.zeros((b, h, w), bool)
    s = np.zeros((h, w), bool) if state is None else state.s.copy()
    leak, th = np.float32(p.leak), np.float32(p.threshold)
    for t in range(b):
        cur = cv2.filter2D(x[t].astype(np.float32, copy=False), cv2.CV_32F, p.weight, borderType=cv2.BORDER_CONSTANT)
        u *= leak
        u += cur
        np.subtract(u, th, out=u, where=s)          # reset by subtraction of S[t-1], undecayed
        np.greater(u, th, out=out[t])
        s = out[t]
        if trace is not None:
            trace.currents.append(cur)
            trace.potentials.append(u.copy())
    if state is not None:
        state.s = s.copy()
    return out


def _square(k: int) -> np.ndarray:
    return np.ones((k, k), np.uint8)


def dotie_recover(x_t: np.ndarray, spikes_t: np.ndarray, p: DotieParams = DotieParams()) -> np.ndarray:
    """One step's fast events: (x[t] > 0) AND Close(Dilate(S[t])), (H, W) bool. A step without
    spikes has none (its closing is empty), so its morphology is skipped."""
    if not spikes_t.any():
        return np.zeros(x_t.shape, bool)
    mask = cv2.dilate(spikes_t.view(np.uint8), _square(p.dilate_kernel))
    mask = cv2.morphologyEx(mask, cv2.MORPH_CLOSE, _square(p.close_kernel))
    out = mask.view(bool)
    out &= x_t > 0
    return out


def dotie_postprocess(x: np.ndarray, spikes: np.ndarray, p: DotieParams = DotieParams()) -> np.ndarray:
    """out[t] = (x[t] > 0) AND Close(Dilate(S[t])) per step: (B, H, W) bool, the events of the
    objects the layer separated as fast."""
    return np.stack([dotie_recover(x[t], spikes[t], p) for t in range(x.shape[0])])


def dotie_separate_x(x: np.ndarray, p: DotieParams = DotieParams(),
                     trace: DotieLayerTrace | None = None,
                     state: DotieState | None = None) -> tuple[np.ndarray, np.ndarray]:
    """DOTIE without clustering on its (B, H, W) input (``dotie_input`` or ``dotie_frames``):
    (spikes (B, H, W) bool, out (B, H, W) bool)."""
    spikes = dotie_layer(x, p, trace, state)
    return spikes, dotie_postprocess(x, spikes, p)


def dotie_separate(binned: np.ndarray, p: DotieParams = DotieParams(),
                   trace: DotieLayerTrace | None = None) -> tuple[np.ndarray, np.ndarray]:
    """DOTIE without clustering on a binned (B, 2, H, W) window."""
    return dotie_separate_x(dotie_input(binned), p, trace)


@dataclass(frozen=True)
class Detection:
    """One DOTIE object: box [x0, x1] x [y0, y1] (inclusive pixel bounds), centre, point count."""

    x0: int
    y0: int
    x1: int
    y1: int
    cx: float
    cy: float
    n_points: int


def cluster_points(points: np.ndarray, p: DotieParams = DotieParams()) -> np.ndarray:
    """DBSCAN labels (-1 = noise) of (n, 2) pixel coordinates, as DOTIE's public code calls it."""
    from sklearn.cluster import DBSCAN

    if points.shape[0] == 0:
        return np.zeros(0, np.int64)
    return DBSCAN(eps=p.eps, min_samples=p.min_samples).fit(points).labels_


def boxes_from_labels(points: np.ndarray, labels: np.ndarray, p: DotieParams = DotieParams()) -> list[Detection]:
    """One box per cluster (vectorized min/max per label), minus the small ones."""
    keep = labels >= 0
    if not keep.any():
        return []
    pts, lab = points[keep], labels[keep]
    n = int(lab.max()) + 1
    big = np.iinfo(np.int64).max
    x0 = np.full(n, big, np.int64)
    y0 = np.full(n, big, np.int64)
    x1 = np.full(n, -1, np.int64)
    y1 = np.full(n, -1, np.int64)
    np.minimum.at(x0, lab, pts[:, 0])
    np.minimum.at(y0, lab, pts[:, 1])
    np.maximum.at(x1, lab, pts[:, 0])
    np.maximum.at(y1, lab, pts[:, 1])
    cnt = np.bincount(lab, minlength=n)
    cx = np.bincount(lab, weights=pts[:, 0], minlength=n) / np.maximum(cnt, 1)
    cy = np.bincount(lab, weights=pts[:, 1], minlength=n) / np.maximum(cnt, 1)
    diag2 = (x1 - x0).astype(float) ** 2 + (y1 - y0).astype(float) ** 2
    return [Detection(int(x0[i]), int(y0[i]), int(x1[i]), int(y1[i]), float(cx[i]), float(cy[i]), int(cnt[i]))
            for i in range(n) if cnt[i] > 0 and diag2[i] >= p.min_box_diag2]


def dotie_cluster(out: np.ndarray, p: DotieParams = DotieParams()) -> list[Detection]:
    """DBSCAN on the pixel coordinates of one separated-events image (H, W), then the box filter;
    no DBSCAN run (and no box) under min_samples pixels, as in DOTIE's get_boundaries_DOTIE."""
    ys, xs = np.nonzero(out)
    if xs.shape[0] < p.min_samples:
        return []
    points = np.column_stack([xs, ys]).astype(np.float64)
    return boxes_from_labels(points, cluster_points(points, p), p)


def dotie_cluster_steps(out: np.ndarray, p: DotieParams = DotieParams()) -> list[list[Detection]]:
    """``dotie_cluster`` of every step's separated events out (B, H, W): DOTIE's per-step boxes."""
    return [dotie_cluster(o, p) for o in out]


def dotie_detect_x(x: np.ndarray, p: DotieParams = DotieParams(),
                   state: DotieState | None = None) -> list[list[Detection]]:
    """DOTIE with clustering on its (B, H, W) input: the boxes of every step."""
    return dotie_cluster_steps(dotie_separate_x(x, p, state=state)[1], p)


def dotie_detect(binned: np.ndarray, p: DotieParams = DotieParams()) -> list[list[Detection]]:
    """DOTIE with clustering on a binned (B, 2, H, W) window: the boxes of every step."""
    return dotie_detect_x(dotie_input(binned), p)


def dotie_detect_window(x: np.ndarray, p: DotieParams = DotieParams()) -> list[Detection]:
    """One clustering per window on the union of the steps' separated events (not DOTIE's code:
    the comparison row that shows what the per-step clustering costs)."""
    return dotie_cluster(dotie_separate_x(x, p)[1].any(axis=0), p)
