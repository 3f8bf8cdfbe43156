"""Multi-object tracking over the windows: identities, smoothed object flow, bin hysteresis.

TOFFE reports each window's objects independently (their order changes from window to window);
the object flow it measures (position, direction, speed) is what makes tracking simple. Per
window of length dt (s), with track i's state (x_i, y_i, vx_i, vy_i) in px and px/s:

    predict    p_i' = p_i + v_i dt                                        (constant velocity)
    associate  d_ij = |p_i' - z_j|; pairs within the gate d_ij <= R_i, the most pairs then the
               least total distance (metrics.match_within: Hungarian on the gated matrix),
               confirmed tracks first, then tentative ones with the detections left over;
               R_i = gate_px + gate_growth m_i s_i dt grows with the m_i windows the track has
               coasted (a turning object leaves its straight-line prediction)
    update     p_i = p_i' + alpha (z_j - p_i')                            (alpha-beta filter)
               v_i = (1 - beta) v_i + beta u_j,  u_j = s_j (cos th_j, sin th_j)
               s_i = (1 - beta) s_i + beta s_j                            (smoothed speed, px/s)
    births     an unmatched detection starts a tentative track (its own p, u, s, bin), unless it
               lies within birth_gap_px of a confirmed track (a fragment of that object: a slow
               object's leading and trailing edges; reported without a track); a tentative
               track is confirmed after ``confirm_hits`` hits in a row
    deaths     a tentative track dies at its first miss; a confirmed one coasts (predicted,
               not reported) through up to ``max_misses`` windows in a row, then dies
    bin        hysteresis on the smoothed speed: a track keeps bin b while
               lo_b (1 - h) <= s_i <= hi_b (1 + h), else takes the bin of s_i
               (lo_1 = 0, hi_N = inf; edges are the bundle's bins in px/s)

The smoothed speed s_i is tracked apart from |v_i|: averaging velocity vectors whose directions
are noisy shortens them, averaging speeds does not. Everything is small-array numpy (a window
has a handful of objects), torch- and Lava-free, so it runs on every target.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, fields

import numpy as np

from .metrics import GATE_PX, match_within


@dataclass(frozen=True)
class TrackerConfig:
    """Settings of ``step`` (equations in the module doc). gate_px: association radius around a
    track's predicted centre (the eval matching gate by default); alpha, beta: position and
    velocity / speed gains of the alpha-beta filter (1 = trust the detection only);
    confirm_hits: hits in a row before a track is confirmed (reported with ``confirmed`` true and
    counted by the tracking metrics); max_misses: windows a confirmed track coasts without a
    detection before it dies; hysteresis: h, the fraction by which the smoothed speed must leave
    its bin before the bin changes; gate_growth: how much of the distance a coasting track's
    prediction covers per missed window widens its gate; birth_gap_px: no track is born this close to
    a confirmed one."""

    gate_px: float = GATE_PX
    gate_growth: float = 0.5
    birth_gap_px: float = 30.0
    alpha: float = 0.7
    beta: float = 0.4
    confirm_hits: int = 2
    max_misses: int = 6
    hysteresis: float = 0.1

    def __post_init__(self):
        if not self.gate_px > 0:
            raise ValueError(f"gate_px must be > 0, got {self.gate_px}")
        if not (0 < self.alpha <= 1 and 0 < self.beta <= 1):
            raise ValueError(f"alpha and beta must be in (0, 1], got {self.alpha}, {self.beta}")
        if self.confirm_hits < 1 or self.max_misses < 0:
            raise ValueError("confirm_hits must be >= 1 and max_misses >= 0")
        if not self.hysteresis >= 0:
            raise ValueError(f"hysteresis must be >= 0, got {self.hysteresis}")


_F = np.float64
_I = np.int64


@dataclass(frozen=True)
class Tracks:
    """Every live track as parallel arrays (one row per track): id (stable int), x, y (px),
    vx, vy (px/s), speed (smoothed, px/s), bin (1-based, with hysteresis), age (windows since
    birth), hits (detections assigned), streak (hits in a row), misses (windows in a row without
    a detection), confirmed (bool)."""

    id: np.ndarray = field(default_factory=lambda: np.zeros(0, _I))
    x: np.ndarray = field(default_factory=lambda: np.zeros(0, _F))
    y: np.ndarray = field(default_factory=lambda: np.zeros(0, _F))
    vx: np.ndarray = field(default_factory=lambda: np.zeros(0, _F))
    vy: np.ndarray = field(default_factory=lambda: np.zeros(0, _F))
    speed: np.ndarray = field(default_factory=lambda: np.zeros(0, _F))
    bin: np.ndarray = field(default_factory=lambda: np.zeros(0, _I))
    age: np.ndarray = field(default_factory=lambda: np.zeros(0, _I))
    hits: np.ndarray = field(default_factory=lambda: np.zeros(0, _I))
    streak: np.ndarray = field(default_factory=lambda: np.zeros(0, _I))
    misses: np.ndarray = field(default_factory=lambda: np.zeros(0, _I))
    confirmed: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))

    def __len__(self) -> int:
        return int(self.id.shape[0])

    def take(self, rows) -> "Tracks":
        return Tracks(**{f.name: getattr(self, f.name)[rows] for f in fields(self)})

    @staticmethod
    def concat(a: "Tracks", b: "Tracks") -> "Tracks":
        return Tracks(**{f.name: np.concatenate([getattr(a, f.name), getattr(b, f.name)]) for f in fields(a)})


@dataclass(frozen=True)
class Detections:
    """One window's objects as arrays: x, y (px), direction (rad, image plane, y down),
    speed (px/s) and speed bin (1-based)."""

    x: np.ndarray
    y: np.ndarray
    direction: np.ndarray
    speed: np.ndarray
    bin: np.ndarray

    def __len__(self) -> int:
        return int(self.x.shape[0])

    @classmethod
    def of(cls, objects) -> "Detections":
        """From objects with x, y, direction_rad, speed_px_s and speed_bin (pipeline.ObjectFlow)."""
        rows = [(o.x, o.y, o.direction_rad, o.speed_px_s, o.speed_bin) for o in objects]
        a = np.array(rows, dtype=_F).reshape(-1, 5)
        return cls(a[:, 0], a[:, 1], a[:, 2], a[:, 3], a[:, 4].astype(_I))


def bin_edges_px_s(config) -> np.ndarray:
    """The inner bin edges in px/s (N - 1 values) of a ToffeConfig's image-plane speed bins."""
    return np.array([lo for lo, _hi in config.speed_bins_px_ms[1:]], dtype=_F) * 1000.0


def hysteresis_bin(current: np.ndarray, speed: np.ndarray, inner: np.ndarray, h: float) -> np.ndarray:
    """Bins with hysteresis (module doc): keep ``current`` while the speed stays within its bin
    widened by the fraction h on both sides, else the bin of the speed."""
    lo = np.concatenate([[0.0], inner])[current - 1] * (1.0 - h)
    hi = np.concatenate([inner, [np.inf]])[current - 1] * (1.0 + h)
    return np.where((speed >= lo) & (speed <= hi), current, np.searchsorted(inner, speed, side="right") + 1)


def _associate(d: np.ndarray, gate: np.ndarray, rows: np.ndarray, free: np.ndarray):
    """(track row, detection) pairs between the tracks ``rows`` and the detections still ``free``
    (d: track x detection distances, gate: each track's radius)."""
    if not rows.size or not free.any():
        return []
    cols = np.flatnonzero(free)
    sub = d[np.ix_(rows, cols)]
    pairs = match_within(sub, sub <= gate[rows, None])
    return [(int(rows[i]), int(cols[j])) for i, j in pairs]


def step(tracks: Tracks, dets: Detections, dt_s: float, cfg: TrackerConfig, inner_edges: np.ndarray,
         next_id: int) -> tuple[Tracks, np.ndarray, int]:
    """One window of tracking (module doc): -> (live tracks, assigned track row of each detection
    in the returned tracks (-1: a fragment, no track), next free id). Pure: the inputs are not
    modified."""
    n_t, n_d = len(tracks), len(dets)
    px = tracks.x + tracks.vx * dt_s
    py = tracks.y + tracks.vy * dt_s
    d = np.hypot(px[:, None] - dets.x[None, :], py[:, None] - dets.y[None, :])
    gate = cfg.gate_px + cfg.gate_growth * tracks.misses * tracks.speed * dt_s
    free = np.ones(n_d, dtype=bool)
    conf = np.flatnonzero(tracks.confirmed)
    pairs = _associate(d, gate, conf, free)
    for _r, j in pairs:
        free[j] = False
    pairs += _associate(d, gate, np.flatnonzero(~tracks.confirmed), free)
    hit = np.zeros(n_t, dtype=bool)
    det_of = np.full(n_t, -1, dtype=_I)
    if pairs:
        r, j = np.array(pairs, dtype=_I).T
        hit[r], det_of[r] = True, j
        free[j] = False
    j = det_of[hit]
    ux, uy = dets.speed[j] * np.cos(dets.direction[j]), dets.speed[j] * np.sin(dets.direction[j])
    a, b = cfg.alpha, cfg.beta
    x, y = px.copy(), py.copy()
    vx, vy, speed = tracks.vx.copy(), tracks.vy.copy(), tracks.speed.copy()
    x[hit] += a * (dets.x[j] - px[hit])
    y[hit] += a * (dets.y[j] - py[hit])
    vx[hit] += b * (ux - vx[hit])
    vy[hit] += b * (uy - vy[hit])
    speed[hit] += b * (dets.speed[j] - speed[hit])
    streak = np.where(hit, tracks.streak + 1, 0)
    misses = np.where(hit, 0, tracks.misses + 1)
    confirmed = tracks.confirmed | (streak >= cfg.confirm_hits)
    old = Tracks(tracks.id, x, y, vx, vy, speed,
                 np.where(hit, hysteresis_bin(tracks.bin, speed, inner_edges, cfg.hysteresis), tracks.bin),
                 tracks.age + 1, tracks.hits + hit, streak, misses, confirmed)
    alive = np.where(confirmed, misses <= cfg.max_misses, misses == 0)
    near = d[confirmed & alive] <= cfg.birth_gap_px if n_t else np.zeros((0, n_d), bool)
    new = np.flatnonzero(free & ~near.any(axis=0))
    n_new = new.size
    born = Tracks(np.arange(next_id, next_id + n_new, dtype=_I), dets.x[new], dets.y[new],
                  dets.speed[new] * np.cos(dets.direction[new]), dets.speed[new] * np.sin(dets.direction[new]),
                  dets.speed[new].copy(), dets.bin[new].copy(), np.ones(n_new, _I), np.ones(n_new, _I),
                  np.ones(n_new, _I), np.zeros(n_new, _I), np.full(n_new, cfg.confirm_hits <= 1))
    keep = np.flatnonzero(alive)
    out = Tracks.concat(old.take(keep), born)
    row_of_old = np.full(n_t, -1, dtype=_I)
    row_of_old[keep] = np.arange(keep.size)
    assigned = np.full(n_d, -1, dtype=_I)
    assigned[det_of[hit]] = row_of_old[hit]
    assigned[new] = keep.size + np.arange(n_new)
    return out, assigned, next_id + n_new


class Tracker:
    """Stateful wrapper of ``step`` for a stream of windows: ``update(objects, t0_us)`` assigns
    every object of the window a ``track_id`` and its track's smoothed ``track`` state (dict,
    ``track_state``), in place. Windows may be skipped (a gap counts as missed windows)."""

    def __init__(self, config, dt_us: int, settings: TrackerConfig | None = None, px_ms_per_mps: float | None = None):
        """config: the bundle's ToffeConfig (its speed bins); dt_us: the window length;
        px_ms_per_mps: the run's speed scale, for the track's speed in m/s (None: not reported)."""
        self.settings = settings or TrackerConfig()
        self.dt_us = int(dt_us)
        self.inner = bin_edges_px_s(config)
        self.k_mps = None if px_ms_per_mps is None else 1.0 / (1000.0 * px_ms_per_mps)
        self.tracks = Tracks()
        self.next_id = 0
        self.t0_last: int | None = None

    def update(self, objects: list, t0_us: int) -> Tracks:
        """Track one window's objects (objects with x, y, direction_rad, speed_px_s, speed_bin;
        each gets ``track_id`` and ``track``); returns the live tracks."""
        n_win = 1 if self.t0_last is None else max(1, round((int(t0_us) - self.t0_last) / self.dt_us))
        self.t0_last = int(t0_us)
        tr = self.tracks
        if n_win > 1 and len(tr):       # windows never seen: coast the tracks through them
            gap = (n_win - 1) * self.dt_us * 1e-6
            tr = Tracks(tr.id, tr.x + tr.vx * gap, tr.y + tr.vy * gap, tr.vx, tr.vy, tr.speed, tr.bin,
                        tr.age + n_win - 1, tr.hits, np.where(tr.misses + n_win - 1 > 0, 0, tr.streak),
                        tr.misses + n_win - 1, tr.confirmed)
            tr = tr.take(np.flatnonzero(np.where(tr.confirmed, tr.misses <= self.settings.max_misses, tr.misses == 0)))
        self.tracks, assigned, self.next_id = step(tr, Detections.of(objects), self.dt_us * 1e-6, self.settings,
                                                   self.inner, self.next_id)
        for o, r in zip(objects, assigned.tolist()):
            o.track_id, o.track = (int(self.tracks.id[r]), self.track_state(r)) if r >= 0 else (None, None)
        return self.tracks

    def coasting(self) -> list[dict]:
        """The confirmed tracks no detection of the last window was assigned to (they coast on
        their prediction for up to max_misses windows): [{"track_id", "track"}], the window line's
        ``coasting`` list."""
        t = self.tracks
        return [{"track_id": int(t.id[r]), "track": self.track_state(r)}
                for r in np.flatnonzero(t.confirmed & (t.misses > 0)).tolist()]

    def track_state(self, r: int) -> dict:
        """The JSON ``track`` object of live track row r (README, JSON lines)."""
        t = self.tracks
        vx, vy, s = float(t.vx[r]), float(t.vy[r]), float(t.speed[r])
        out = {"x": round(float(t.x[r]), 4), "y": round(float(t.y[r]), 4),
               "direction_deg": round(math.degrees(math.atan2(vy, vx)), 4), "speed_px_s": round(s, 4)}
        if self.k_mps is not None:
            out["speed_mps"] = round(s * self.k_mps, 4)
        out.update(speed_bin=int(t.bin[r]), age=int(t.age[r]), hits=int(t.hits[r]),
                   confirmed=bool(t.confirmed[r]))
        return out
