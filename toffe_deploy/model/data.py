"""Training windows: object-centred crops of binned single-object windows (numpy, no torch).

OFS is one conv layer into LIF neurons, so its output at a pixel depends only on the K x K
input around it: training on a crop around the object is exact away from the crop border and
costs (R / 640)^2 of a full sensor. A sample is one window [t0, t0 + dt) of a single-object
sequence, binned as the deployment bins it (bin_window, then count > 0), cut to an R x R crop
centred on the object's ground-truth centre, stored sparsely as the linear indices of its
active (bin, polarity, y, x) cells, so tens of thousands of windows fit in a few hundred MB.

Labels come from the window's ground truth at its midpoint (dataset.groundtruth.window_truth):
centre (x, y) px on the sensor, direction rad, speed m/s, speed bin.
"""
from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable

import numpy as np

from ..config import ToffeConfig
from ..errors import InputError
from ..events.binning import bin_window
from ..events.frontend import apply_dense
from ..events.support import sampled_index

CROP_PX = 320   # R: crop side for training windows (holds objects up to ~250 px with their motion)


@dataclass
class WindowSet:
    """N sparse crops: cells[offsets[i]:offsets[i+1]] are the active cells of sample i.

    origin (N, 2) = sensor (x, y) of the crop's top-left pixel; labels x, y (sensor px),
    direction (rad), speed (m/s), speed_bin (1..N_bins); seq (N,) index of the source file;
    speed_px_ms (N,) the ground truth's image-plane speed (px/ms), NaN where the data set has no
    such column (then training derives it from m/s with config.speed_scale).
    """

    n_bins: int
    crop: int
    cells: np.ndarray
    offsets: np.ndarray
    origin: np.ndarray
    x: np.ndarray
    y: np.ndarray
    direction: np.ndarray
    speed: np.ndarray
    speed_bin: np.ndarray
    seq: np.ndarray
    speed_px_ms: np.ndarray | None = None

    def __post_init__(self):
        if self.speed_px_ms is None:
            self.speed_px_ms = np.full(self.origin.shape[0], np.nan)

    def __len__(self) -> int:
        return int(self.origin.shape[0])

    def dense(self, idx: Iterable[int]) -> np.ndarray:
        """(n, B, 2, R, R) bool volumes of the given samples."""
        idx = np.asarray(list(idx), dtype=np.int64)
        vol = np.zeros((idx.size, self.n_bins * 2 * self.crop * self.crop), dtype=bool)
        for r, i in enumerate(idx):
            vol[r, self.cells[self.offsets[i]:self.offsets[i + 1]]] = True
        return vol.reshape(idx.size, self.n_bins, 2, self.crop, self.crop)

    @classmethod
    def from_dense(cls, vols: np.ndarray, speed_bin, x=None, y=None, direction=None, speed=None) -> "WindowSet":
        """Build from (N, B, 2, R, R) volumes (origin 0; labels default to zeros)."""
        n, b, _c, r, _ = vols.shape
        flat = [np.flatnonzero(v.reshape(-1)).astype(np.int32) for v in vols]
        z = np.zeros(n)
        pick = lambda a: z.copy() if a is None else np.asarray(a, dtype=np.float64)
        return cls(b, r, np.concatenate(flat), np.concatenate([[0], np.cumsum([f.size for f in flat])]).astype(np.int64),
                   np.zeros((n, 2), np.int64), pick(x), pick(y), pick(direction), pick(speed),
                   np.asarray(speed_bin, dtype=np.int64), np.zeros(n, np.int64))

    def subset(self, mask: np.ndarray) -> "WindowSet":
        keep = np.flatnonzero(mask)
        parts = [self.cells[self.offsets[i]:self.offsets[i + 1]] for i in keep]
        lens = np.array([p.size for p in parts], dtype=np.int64)
        return WindowSet(self.n_bins, self.crop, np.concatenate(parts) if parts else np.zeros(0, np.int32),
                         np.concatenate([[0], np.cumsum(lens)]), self.origin[keep], self.x[keep], self.y[keep],
                         self.direction[keep], self.speed[keep], self.speed_bin[keep], self.seq[keep],
                         self.speed_px_ms[keep])


def crop_window(events: np.ndarray, t0: int, dt_us: int, n_bins: int, centre_xy: tuple[float, float],
                crop: int, input_norm: str = "none", min_cluster: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Bin the events of [t0, t0 + dt) inside the crop centred on centre_xy, through the input
    front end (events/frontend.py), as deployment sees them.

    Returns (linear indices of active (bin, p, y, x) cells int32, origin (x0, y0)).
    """
    x0 = int(round(centre_xy[0])) - crop // 2
    y0 = int(round(centre_xy[1])) - crop // 2
    ex = events["x"].astype(np.int64) - x0
    ey = events["y"].astype(np.int64) - y0
    inside = (ex >= 0) & (ex < crop) & (ey >= 0) & (ey < crop)
    sub = events[inside].copy()
    sub["x"] = ex[inside]
    sub["y"] = ey[inside]
    vol = apply_dense(bin_window(sub, t0, dt_us, n_bins, (crop, crop), dtype=np.uint8), input_norm,
                      min_cluster)
    return np.flatnonzero(vol.reshape(-1)).astype(np.int32), np.array([x0, y0], dtype=np.int64)


def crop_index(idx: np.ndarray, sensor_size: tuple[int, int], centre_xy: tuple[float, float],
               crop: int) -> tuple[np.ndarray, np.ndarray]:
    """The ones of a sorted linear index into a whole-sensor (B, 2, H, W) volume (the front end
    run on the whole window) inside the crop centred on centre_xy: crop_window's result."""
    w, h = int(sensor_size[0]), int(sensor_size[1])
    x0 = int(round(centre_xy[0])) - crop // 2
    y0 = int(round(centre_xy[1])) - crop // 2
    plane, pix = np.divmod(np.asarray(idx, np.int64), h * w)
    ey, ex = np.divmod(pix, w)
    ex -= x0
    ey -= y0
    inside = (ex >= 0) & (ex < crop) & (ey >= 0) & (ey < crop)
    out = (plane[inside] * crop + ey[inside]) * crop + ex[inside]
    return out.astype(np.int32), np.array([x0, y0], dtype=np.int64)


def find_sequences(data: str | os.PathLike, split: str) -> list[Path]:
    """The sequence files of one split, as the data set's index.json lists them."""
    from ..dataset.build import iter_split_files

    root = Path(data)
    if not root.is_dir():
        raise InputError(root, "is a file, not a data-set directory" if root.exists() else "data directory does not exist")
    files = list(iter_split_files(root, split))
    if not files:
        raise InputError(root / "index.json", f"lists no '{split}' sequences")
    missing = [f for f in files if not f.is_file()]
    if missing:
        raise InputError(missing[0], "missing file (listed in index.json)")
    return files


def load_windows(files: list[Path], config: ToffeConfig, dt_us: int | None = None, per_file: int = 200,
                 seed: int = 0, crop: int = CROP_PX, min_events: int = 1, progress: bool = True) -> WindowSet:
    """Sample up to ``per_file`` single-object windows per sequence (seeded) into a WindowSet.

    Windows with no visible object, several objects or fewer than ``min_events`` active cells
    are skipped (a window without events teaches nothing and is not evaluated either).
    """
    from tqdm import tqdm

    from ..dataset.groundtruth import window_truth
    from ..events.io import open_events

    dt = int(dt_us or config.dt_us)
    rng = np.random.default_rng(seed)
    cells, lens, origin, lab, seq = [], [], [], [], []
    for fi, path in enumerate(tqdm(files, desc=f"windows dt={dt}us", unit="seq", disable=not progress, file=None)):
        with open_events(path) as src:
            gt = src.ground_truth
            if gt is None:
                raise InputError(path, "has no ground truth (needed for training)")
            starts = np.arange(src.t_start_us, src.t_end_us - dt + 1, dt)
            if starts.size > per_file:
                starts = np.sort(rng.choice(starts, per_file, replace=False))
            for t0 in starts:
                truth = window_truth(gt, int(t0), dt)
                if len(truth) != 1 or int(truth[0].speed_bin) < 1:
                    continue
                o = truth[0]
                if config.input_support is None:
                    ev = src.read(int(t0), int(t0) + dt)
                    idx, org = crop_window(ev, int(t0), dt, config.n_bins, (o.x, o.y), crop, config.input_norm,
                                           config.input_min_cluster)
                else:    # temporal support: its threshold follows the whole sensor's event density
                    idx, org = crop_index(sampled_index(src.read, int(t0), dt, config, src.sensor_size),
                                          src.sensor_size, (o.x, o.y), crop)
                if idx.size < min_events:
                    continue
                cells.append(idx)
                lens.append(idx.size)
                origin.append(org)
                lab.append((o.x, o.y, o.direction, o.speed, o.speed_bin, getattr(o, "speed_px_ms", np.nan)))
                seq.append(fi)
    lab_a = np.asarray(lab, dtype=np.float64).reshape(-1, 6)
    return WindowSet(config.n_bins, crop, np.concatenate(cells) if cells else np.zeros(0, np.int32),
                     np.concatenate([[0], np.cumsum(lens)]).astype(np.int64),
                     np.asarray(origin, dtype=np.int64).reshape(-1, 2), lab_a[:, 0], lab_a[:, 1], lab_a[:, 2],
                     lab_a[:, 3], lab_a[:, 4].astype(np.int64), np.asarray(seq, dtype=np.int64), lab_a[:, 5])
