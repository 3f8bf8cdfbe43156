"""Multi-object tracking over the windows: identities, smoothed object flow, bin hysteresis.

TOFFE reports each window's objects independently (their order changes from window to window);
the object flow it measures (position, direction, speed) is what makes tracking simple. Per
window of length dt (s), with track i's state (x_i, y_i, vx_i, vy_i) in px and px/s:

    predict    v_i' = R(w_i dt) v_i,  p_i' = p_i + R(w_i dt / 2) v_i dt   (constant turn rate w_i;
               R(a) rotates by a; w_i = 0 is constant velocity); over a run of m_i + b_i
               windows without its own detection (below) the turn adds up to at most
               coast_turn_rad, then the prediction goes straight on (a turn rate measured
               before an object was hidden does not last; at its full rate a curving object's
               prediction swung off it: docs/tracking-log.md)
    associate  d_ij = |p_i' - z_j|; pairs within the gate d_ij <= R_i, the most pairs then the
               least total distance (assignment.match_pairs: Hungarian on the gated matrix),
               confirmed tracks first, then tentative ones with the detections left over;
               R_i = gate_px + (gate_speed + gate_growth m_i + blob_growth b_i) s_i dt grows with
               the m_i windows the track has coasted (a turning object leaves its straight-line
               prediction) and the b_i windows in a row its detection was a blob (merged: the
               blob's centre is not its object's); where a gate holds two candidates the
               Hungarian cost is d_ij + heading_cost_px q_j |angle(u_j, v_i')| (q_j below: a
               fast detection's direction tells two parting objects apart)
    update     p_i = p_i' + alpha (z_j - p_i')                            (alpha-beta filter)
               (a detection without a measured motion, ofpd.faint_objects', moves p_i only, and
               a track it starts is at rest; a detection within the gates of 2+ confirmed tracks,
               a blob of two objects, moves p_i only too: with ``shared_keeps_motion`` v_i, s_i, h_i and the bin stay; the gates
               here without the coasting growth unless ``shared_gate_grows``; so does a
               detection within hidden_px of the prediction p_m' of a confirmed track m still
               missed after re-identification and approaching track i,
               (p_m' - p_i') . (v_m' - v_i') < 0: two converging objects of which one vanished
               are seen as one blob, nearer the bigger share of it, often outside m's gate; its
               motion, neither object's, would turn and slow track i, which then left its object
               where the two part. Objects side by side, not converging, are a miss: the one
               still seen keeps learning its motion. The updates run once every track's
               detection is known, after re-identification)
    merges     a detection z nearer the midpoint c of two confirmed tracks' predictions than to
               either, within gate_px of c, the two at most merge_px apart and each moving at
               least merge_move_px per window, and the two not seen apart (no other detection that
               no third track took within reid_px of either: two objects that parted are two
               detections, and the one between them is one of them), is one blob of both: both
               move by alpha (z - c)
               (each keeps its own motion, so the pair parts where their motions take them), the
               blob is reported as the one of the two missed for fewer windows (it stays with
               the track that had it), the other coasts occluded
               v_i = (1 - beta) v_i + beta u_j,  u_j = s_j (cos th_j, sin th_j)
               s_i = (1 - beta) s_i + beta s_j                            (smoothed speed, px/s)
               h_i = (1 - g_j) h_i + g_j u_j,  g_j = min(1, max(heading_beta, s_j dt / heading_px))
                                          (heading: the reported direction_deg is that of h_i)
               w_i = w_i + turn_beta q_j angle(u_j, v_i') / dt,  q_j = min(1, s_j dt / heading_px),
               |w_i dt| <= max_turn_rad (turn rate: a direction error of a slow object is no turn)
               e_i = e_i + pos_beta ((z_j - l_i) / (n_i dt) - e_i),  l_i = z_j  (the velocity its own
               detections' positions give, l_i its last one n_i windows ago; not from blobs)
    lose       a confirmed track that loses its object (a miss or a blob after its own detection),
               moving at least pos_min_px per window, coasts on e_i (turned by w_i over its mean
               age, (1 - pos_beta) / pos_beta + 1.5 windows) instead of v_i where the two
               differ by at most pos_max_rad: positions are good to ~2 px, while a fast object's
               detected direction can be 20-30 deg off for many windows (the hidden object then
               comes back outside its gate)
    reid       second association (as ByteTrack's of the leftovers): a confirmed track moving at
               least merge_move_px per window and missed so far takes the nearest detection left
               over within reid_px + reid_growth m_i s_i dt of its prediction, if
               d_ik <= reid_ratio d_mk for every other confirmed track m (with
               ``reid_ratio_missed``: every other one also missed in this window; one that has its
               own detection claims no blob) (a track that coasted through a merge picks its
               object up again where it reappears a little outside its gate; a blob between two
               tracks stays unclaimed); updated as a hit; repeated while pairs remain
    hand-over  a tentative track confirmed in this window continues a confirmed track that lost
               its object, missed in this window or died (kept ``lost`` for handover_windows
               windows since its last detection), and takes its id (the lost one is dropped),
               where its position lies within handover_px + handover_reach s_l dt n_l of the lost
               track's last own detection l (n_l windows ago; s_l its speed) and their speeds
               differ by at most a factor handover_speed_ratio (or 1 px a window); the best
               fit (distance over that reach) wins. An object hidden in a blob of two for tens
               of windows, turning or passed over, comes back far from any prediction: without
               this its new track has a new id (IDF1 counts the rest of its run as another object)
    parting    a confirmed track that may go into a blob (occluded, its detection a blob of two,
               or one of two confirmed tracks within merge_px of each other of which one was just
               missed and the other seen: a blob the association took for one object's
               detection) keeps a copy of its state from the window before (x, y, v, w at t_b;
               seen or coasting there, in no blob); when two
               such tracks have their own detections again (neither occluded nor a blob) and
               their copies' predictions lay within merge_px of each other, the two ids are kept
               or swapped by the cheaper pairing of
                   c(i, k) = |P_i(t) - z_k| + parting_heading_px q_k |angle(u_k, R(w_i (t - t_b)) v_i)|
                             + parting_events_px |ln n_k - a_i|
               (P_i: track i's copy carried to now at constant turn rate, the whole turn
               |w_i (t - t_b)| at most parting_turn_rad: a turn rate measured before the blob
               does not last its tens of windows, and at the full rate a curving object's copy
               swung tens of px off and the pairing took the wrong way; q_k as in associate;
               n_k the detection's event ones, a_i the copy's mean ln(event ones) of its own
               detections, EVENTS_BETA; the term is left out where either is not known).
               Why: in a blob the taker follows the blob's centre, which is neither object's,
               and a curving object's straight coast drifts, so the association where they part
               often takes the wrong one (a crossing of our generator: two objects one detection
               for 25 windows, one of them turning from 45 to 95 deg); the motion before the blob
               is the evidence neither has spoiled. The event count is the objects' look:
               size, contrast and speed set it, and two objects that cross rarely share it
               (generated crossings: the two objects' ln counts, seen apart, differ by a median
               2.4-6 of their window-to-window spread), so it still tells them apart where they
               turned or stopped inside the blob and their motion from before misleads. A swap
               redoes this window's update of both tracks with the exchanged detections (their
               predictions updated again, their mean counts too; ids, age and hits go with the
               track). A track seen again waits up to PARTING_WAIT (10)
               windows for its partner to be seen too (a fast object that passed over a slow
               one comes out first), then drops its copy, also where the partner's copy is
               gone (its track died: a piece of one object's); a copy is kept for at most
               PARTING_MAX_WINDOWS (80) windows
    births     an unmatched detection starts a tentative track (its own p, u, s, bin), unless it
               lies within birth_gap_px of a confirmed track (a fragment of that object: a slow
               object's leading and trailing edges; reported without a track); a tentative
               track is confirmed at ``confirm_hits`` hits. With ``confirm_at_start``, a track
               born in the stream's first confirm_hits - 1 windows (counted from the Tracker's
               first window, gaps included) is confirmed at birth: no track could have earned
               its hits there yet, and an object in view when the stream starts is an object,
               not a birth to doubt (ByteTrack activates the first frame's tracks, SORT reports
               tracks in the first min_hits frames). Missed before it has confirm_hits hits, it
               is tentative again (it does not re-identify either): with tentative_misses 0 it
               dies, without coasting or occluded listing (its id, reported as confirmed, may
               still go to the track that continues it: the hand-over's lost tracks). A false
               detection or a fragment of a slow object's edges in the first windows is
               reported only while it lasts (kept, one held a second, occluded track on its
               object for 80 windows)
    deaths     a tentative track dies after more than ``tentative_misses`` misses in a row (0: at
               its first miss); a confirmed one coasts (predicted; listed as coasting, with
               its misses m_i, for the first ``report_misses``) through up to ``max_misses``
               windows in a row, or while m_i s_i dt <= coast_px (up to max_coast), then dies;
               one that is occluded (its prediction within R_i of
               a detection another track took: a merged blob) lives, and is listed, up to
               ``max_occluded`` misses in a row; so does one whose prediction lies within
               ``occluded_px`` of such a detection while it has travelled at most
               ``occluded_travel_px`` since its last own detection ((m_i + 1) s_i dt) and has
               at least ``occluded_min_hits`` hits (a slow object beside a big or long blob, its
               events joined to it, is hidden there but lies outside the blob-centred gate; a
               piece of one object, confirmed on a few hits, is not kept that way)
    bin        hysteresis on the smoothed speed: a track keeps bin b while
               lo_b (1 - h) <= s_i <= hi_b (1 + h), else takes the bin of s_i
               (lo_1 = 0, hi_N = inf; edges are the bundle's bins in px/s)

The smoothed speed s_i is tracked apart from |v_i|: averaging velocity vectors whose directions
are noisy shortens them, averaging speeds does not. The heading h_i is apart from v_i because a
detection's direction is as good as the distance the object moved during the window: an
object moving heading_px or more per window is reported in the direction it was just seen
moving (no lag on a curve: v_i's beta lagged 12 deg behind bin-4 objects), a slow one (bin 1,
0.05-1 px per window, 40-75 deg per-window errors) in an average over its last ~1 / heading_beta
windows (causal: past and current windows only); v_i, what the prediction uses, keeps beta
(a slower v_i cost MOTA on curves: docs/tracking-log.md). The per-window loops are numba-compiled like
compiled.py's (a window has a handful of objects, where numpy's per-call overhead dominates: 11
us per window against 94 us in numpy); torch- and Lava-free, so it runs on every target.
"""
from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field, fields

import numpy as np
from .jit import njit

from .assignment import match_pairs


@dataclass(frozen=True)
class TrackerConfig:
    """Settings of ``step`` (equations in the module doc). gate_px: association radius around a
    track's predicted centre (tighter than eval's 20 px scoring gate: a detection 15-20 px off a
    prediction was more often a merged blob or another object than the track's own;
    docs/tracking-log.md has the measurements); gate_speed: how much of one window's travel s_i dt
    widens every gate (fast objects' predictions err more); alpha, beta: position and
    velocity / speed gains of the alpha-beta filter (1 = trust the detection only);
    confirm_hits: hits before a track is confirmed (reported with ``confirmed`` true and counted
    by the tracking metrics); tentative_misses: misses in a row a tentative track survives (a
    slow or faint object is not detected in every window); max_misses: windows a confirmed track coasts without a
    detection before it dies; hysteresis: h, the fraction by which the smoothed speed must leave
    its bin before the bin changes; gate_growth: how much of the distance a coasting track's
    prediction covers per missed window widens its gate; birth_gap_px: no track is born this close to
    a confirmed one; report_misses: windows a coasting track is listed (``coasting``, scored)
    before it is only kept for re-association (a long straight-line prediction drifts off a
    curving object); max_occluded: misses in a row an occluded track survives (occluded: missed
    while its prediction lies within its gate of a detection another track took, i.e. two
    objects seen as one blob, or the other track of a blob of two (merges); listed in ``coasting``
    all that time); occluded_px, occluded_travel_px, occluded_min_hits: a missed confirmed track
    is also occluded while its prediction lies within occluded_px of a detection another track
    took, it has travelled at most occluded_travel_px since its last own detection and it has at
    least occluded_min_hits hits (occluded_px 0: off; a slow object whose events the grouping
    joined to a neighbour's blob lies tens of px from that blob's centre, outside its gate; the
    hits keep a sparse object's pieces, confirmed on a few hits each, from being kept beside it:
    docs/tracking-log.md, 2026-11-25); heading_px, heading_beta:
    the travel per window (px) at which a detection's direction is taken as it is, and the
    smallest heading gain (slow objects); shared_keeps_motion: a detection inside the gates of
    two or more confirmed tracks (two objects seen as one blob) moves the track it is assigned
    to but leaves its velocity, speed, heading and bin as they were; turn_beta: gain of the turn
    rate (0: constant velocity; the objects follow curves, and a straight-line prediction left
    them during merges that last tens of windows), max_turn_rad: its bound per window; merge_px:
    the farthest apart two tracks' predictions may be for a detection between them to be their
    blob (0: no merges; objects up to ~50 px across touch at that distance), merge_move_px: the
    slowest track (px per window) that can be in a merge or re-identify (a slow object's two
    edge fragments would otherwise hold two tracks on it); shared_gate_grows: whether a coasting
    track's grown gate also makes a detection shared (False: only its base gate, so that the
    one object still seen keeps learning its motion while the other is hidden); reid_px,
    reid_ratio: the second association (re-identification: a missed confirmed track takes a
    detection left over within reid_px of its prediction that is reid_ratio times nearer to it
    than to any other confirmed track, not one between two tracks; 0: off); coast_px,
    max_coast: a confirmed track also lives on after max_misses while its prediction has moved
    at most coast_px since its last detection (m_i s_i dt <= coast_px: a slow object hidden
    behind a passing one is still near its prediction), up to max_coast misses. pos_beta: gain of
    the velocity the track's own detections' positions give (0: off); pos_min_px, pos_max_rad: a
    track moving at least pos_min_px per window that loses its object coasts on that velocity
    if it is within pos_max_rad of v_i's direction (slower objects' positions are mostly noise;
    a larger difference is a wrong detection taken); blob_growth: how much of a window's travel
    each window in a row its detection was a blob (merged) widens its gate; heading_cost_px:
    px added to the association cost per radian between a detection's direction and a track's
    (ambiguous windows only); reid_growth: how much of the distance a coasting track's
    prediction covers per missed window widens reid_px; reid_ratio_missed: the ratio test
    against the other confirmed tracks missed in this window only; hidden_px: a detection
    within this distance of a confirmed track's prediction that is missed in the window and
    converging on the track the detection goes to is a blob of both (its taker keeps its
    motion, as for shared_keeps_motion; 0: off; objects up to ~50 px across hide each other
    from ~40 px apart, and 35-50 measured alike: docs/tracking-log.md). handover_px,
    handover_reach, handover_windows, handover_speed_ratio: the hand-over (module doc; 0 px:
    off): the radius around a lost track's last own detection, its growth in multiples of the
    lost track's travel per window since then, how many windows since its last detection a lost
    track can hand its id over, and the most the two speeds may differ by (a factor).
    parting, parting_heading_px, parting_events_px: the parting re-decision (module doc): two
    confirmed tracks that come out of one blob, each with its own detection again, keep or swap
    their ids by which way round their motion and look before the blob fit the two detections
    (position, plus parting_heading_px per radian of direction difference, weighted as
    heading_cost_px's q_j, plus parting_events_px per unit of |ln(event ones) - the track's mean
    ln(event ones) before the blob|; 0: motion alone); parting_turn_rad: the most a kept state
    turns in all when carried to now (the turn rate measured before a blob does not last the tens
    of windows a blob can: carried at its full rate, a curving object's state swung far off;
    docs/tracking-log.md); coast_turn_rad: the same bound on a track's own prediction over a run
    of windows without its own detection (missed, or in a blob of two): beyond it the
    prediction goes straight on. confirm_at_start: births in the stream's first
    confirm_hits - 1 windows are confirmed at birth (module doc, births; False: they wait for
    confirm_hits hits like any other; docs/tracking-log.md, 2026-11-29)."""

    gate_px: float = 17.0
    gate_growth: float = 0.5
    birth_gap_px: float = 30.0
    alpha: float = 0.7
    beta: float = 0.4
    confirm_hits: int = 3
    tentative_misses: int = 0
    max_misses: int = 20
    hysteresis: float = 0.1
    gate_speed: float = 0.0
    report_misses: int = 5
    max_occluded: int = 80
    occluded_px: float = 50.0
    occluded_travel_px: float = 20.0
    occluded_min_hits: int = 10
    heading_px: float = 5.0
    heading_beta: float = 0.15
    shared_keeps_motion: bool = True
    turn_beta: float = 0.2
    max_turn_rad: float = 0.1
    merge_px: float = 50.0
    merge_move_px: float = 1.5
    shared_gate_grows: bool = False
    reid_px: float = 30.0
    reid_ratio: float = 0.6
    coast_px: float = 30.0
    max_coast: int = 40
    pos_beta: float = 0.2
    pos_min_px: float = 5.0
    pos_max_rad: float = 0.6
    blob_growth: float = 0.5
    heading_cost_px: float = 5.0
    reid_growth: float = 0.5
    reid_ratio_missed: bool = True
    hidden_px: float = 40.0
    handover_px: float = 40.0
    handover_reach: float = 4.0
    handover_windows: int = 80
    handover_speed_ratio: float = 2.0
    parting: bool = True
    parting_heading_px: float = 40.0
    parting_events_px: float = 60.0
    parting_turn_rad: float = 0.3
    coast_turn_rad: float = 0.6
    confirm_at_start: bool = True

    def __post_init__(self):
        for f in fields(self):                  # kinds first: NaN, strings or 2.5 windows fail here
            v = getattr(self, f.name)
            if f.type == "bool":
                ok, what = isinstance(v, (bool, np.bool_)), "true or false"
            elif f.type == "int":
                ok, what = isinstance(v, (int, np.integer)) and not isinstance(v, (bool, np.bool_)), "an integer"
            else:
                ok = (isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, (bool, np.bool_))
                      and math.isfinite(v))
                what = "a finite number"
            if not ok:
                raise ValueError(f"{f.name} must be {what}, got {v!r}")
        if not (self.gate_growth >= 0 and self.birth_gap_px >= 0):
            raise ValueError(f"gate_growth and birth_gap_px must be >= 0, got {self.gate_growth}, {self.birth_gap_px}")
        if not self.gate_px > 0:
            raise ValueError(f"gate_px must be > 0, got {self.gate_px}")
        if not (0 < self.alpha <= 1 and 0 < self.beta <= 1):
            raise ValueError(f"alpha and beta must be in (0, 1], got {self.alpha}, {self.beta}")
        if self.confirm_hits < 1 or self.max_misses < 0 or self.tentative_misses < 0:
            raise ValueError("confirm_hits must be >= 1, max_misses and tentative_misses >= 0")
        if not (self.gate_speed >= 0 and self.report_misses >= 0 and self.max_occluded >= 0):
            raise ValueError("gate_speed, report_misses and max_occluded must be >= 0")
        if not (self.occluded_px >= 0 and self.occluded_travel_px >= 0 and self.occluded_min_hits >= 0):
            raise ValueError(f"occluded_px, occluded_travel_px and occluded_min_hits must be >= 0, got "
                             f"{self.occluded_px}, {self.occluded_travel_px}, {self.occluded_min_hits}")
        if not self.hysteresis >= 0:
            raise ValueError(f"hysteresis must be >= 0, got {self.hysteresis}")
        if not (self.heading_px > 0 and 0 < self.heading_beta <= 1):
            raise ValueError("heading_px must be > 0 and heading_beta in (0, 1]")
        if not (0 <= self.turn_beta <= 1 and self.max_turn_rad >= 0):
            raise ValueError("turn_beta must be in [0, 1] and max_turn_rad >= 0")
        if not min(self.merge_px, self.merge_move_px) >= 0:
            raise ValueError("merge_px and merge_move_px must be >= 0")
        if not (self.coast_px >= 0 and self.max_coast >= 0):
            raise ValueError(f"coast_px and max_coast must be >= 0, got {self.coast_px}, {self.max_coast}")
        if not (self.reid_px >= 0 and self.reid_ratio > 0):
            raise ValueError(f"reid_px must be >= 0 and reid_ratio > 0, got {self.reid_px}, {self.reid_ratio}")
        if not (0 <= self.pos_beta <= 1 and self.pos_min_px >= 0 and self.pos_max_rad >= 0):
            raise ValueError("pos_beta must be in [0, 1], pos_min_px and pos_max_rad >= 0")
        if not min(self.blob_growth, self.heading_cost_px, self.reid_growth, self.hidden_px) >= 0:
            raise ValueError("blob_growth, heading_cost_px, reid_growth and hidden_px must be >= 0")
        if not self.parting_heading_px >= 0:
            raise ValueError(f"parting_heading_px must be >= 0, got {self.parting_heading_px}")
        if not self.parting_events_px >= 0:
            raise ValueError(f"parting_events_px must be >= 0, got {self.parting_events_px}")
        if not self.parting_turn_rad >= 0:
            raise ValueError(f"parting_turn_rad must be >= 0, got {self.parting_turn_rad}")
        if not self.coast_turn_rad >= 0:
            raise ValueError(f"coast_turn_rad must be >= 0, got {self.coast_turn_rad}")
        if not (min(self.handover_px, self.handover_reach, self.handover_windows) >= 0
                and self.handover_speed_ratio >= 1):
            raise ValueError("handover_px, handover_reach and handover_windows must be >= 0 and "
                             f"handover_speed_ratio >= 1, got {self.handover_px}, {self.handover_reach}, "
                             f"{self.handover_windows}, {self.handover_speed_ratio}")


_F = np.float64
#: columns of Tracks.a
ID, X, Y, VX, VY, S, BIN, AGE, HITS, STREAK, MISS, CONF, OCC, HX, HY, W, LX, LY, LT, UX, UY, BLB, EV = range(23)
N_COLS = 23
#: the gain of a track's mean ln(events per detection) (column EV): about the last 5 windows
EVENTS_BETA = 0.2


@dataclass(frozen=True)
class Tracks:
    """Every live track, one row of ``a`` (n, N_COLS) float64 per track (one array, so that keeping
    and adding rows is one operation, not one per field): id (stable int), x, y (px), vx, vy
    (px/s), speed (smoothed, px/s), bin (1-based, with hysteresis), age (windows since birth),
    hits (detections assigned), streak (hits in a row), misses (windows in a row without a
    detection), confirmed (0/1), occluded (0/1: missed under another track's detection), heading
    hx, hy (px/s: the reported direction's vector), turn rate w (rad/s, + turns from x towards y),
    its last own detection's position lx, ly (px) and window lt (its age then), the velocity
    those positions give ux, uy (px/s), blob b (windows in a row its detection was a blob
    of two or more tracks' objects) and ev, the mean ln(event ones) of its own detections
    (EVENTS_BETA; NaN until one told it); the properties give the columns. ``lost``: the confirmed
    tracks that died in the last handover_windows windows (same columns; their id can be handed
    over to a new track)."""

    a: np.ndarray = field(default_factory=lambda: np.zeros((0, N_COLS), _F))
    lost: np.ndarray = field(default_factory=lambda: np.zeros((0, N_COLS), _F))

    def __len__(self) -> int:
        return int(self.a.shape[0])

    id = property(lambda self: self.a[:, ID].astype(np.int64))
    x = property(lambda self: self.a[:, X])
    y = property(lambda self: self.a[:, Y])
    vx = property(lambda self: self.a[:, VX])
    vy = property(lambda self: self.a[:, VY])
    speed = property(lambda self: self.a[:, S])
    bin = property(lambda self: self.a[:, BIN].astype(np.int64))
    age = property(lambda self: self.a[:, AGE].astype(np.int64))
    hits = property(lambda self: self.a[:, HITS].astype(np.int64))
    misses = property(lambda self: self.a[:, MISS].astype(np.int64))
    confirmed = property(lambda self: self.a[:, CONF] > 0)
    occluded = property(lambda self: self.a[:, OCC] > 0)


@dataclass(frozen=True)
class Detections:
    """One window's objects as one (n, 8) array ``a``: x, y (px), velocity ux, uy (px/s, from the
    direction: image plane, y down), speed (px/s), speed bin (1-based), ln(event ones) (NaN:
    not known; an (n, 6) array gets that column) and position-only (1: a detection without a
    measured motion, ofpd.faint_objects': it moves a track's position, not its motion, and a
    track it starts is at rest; 0 where an (n, 6) or (n, 7) array lacks it); columns X..S line
    up with Tracks' (so that one operation updates a track's x, y, vx, vy and speed)."""

    a: np.ndarray

    def __post_init__(self):
        a = np.asarray(self.a, _F)
        if a.ndim != 2 or a.shape[1] not in (6, 7, 8):
            raise ValueError(f"detections must be an (n, 6), (n, 7) or (n, 8) array, got shape {a.shape}")
        if a.shape[1] == 6:
            a = np.concatenate([a, np.full((a.shape[0], 1), np.nan)], axis=1)
        if a.shape[1] == 7:
            a = np.concatenate([a, np.zeros((a.shape[0], 1))], axis=1)
        object.__setattr__(self, "a", np.ascontiguousarray(a))

    def __len__(self) -> int:
        return int(self.a.shape[0])

    x = property(lambda self: self.a[:, 0])
    y = property(lambda self: self.a[:, 1])
    bin = property(lambda self: self.a[:, 5])

    @classmethod
    def of(cls, objects) -> "Detections":
        """From objects with x, y, direction_rad, speed_px_s and speed_bin (pipeline.ObjectFlow)."""
        return cls(_detections(raw_detections(objects)))


def raw_detections(objects) -> np.ndarray:
    """The window's detections as ``Tracker.columns`` takes them, one flat (6 n,) float64 array
    of six columns: the objects' x, then y, direction_rad, speed_px_s, speed_bin and n_events
    (0 where an object has none: not known) (the one pass over the objects' attributes a window
    needs; one flat list: numpy converts it faster than nested ones); a faint object's direction
    goes as NaN (position only: _detections)."""
    flat = [v for o in objects for v in (o.x, o.y, math.nan if getattr(o, "faint", False) else o.direction_rad,
                                         o.speed_px_s, o.speed_bin, getattr(o, "n_events", 0))]
    return np.array(flat, _F).reshape(-1, 6).T.ravel()


@njit(cache=True, nogil=True)
def _detections(zr):
    """Detections.a (n, 8) of raw_detections' (6 n,) columns (velocity from direction and speed,
    ln of the event ones; NaN where not known: 0; a NaN direction: position only, at rest)."""
    n = zr.shape[0] // 6
    z = np.empty((n, 8))
    for k in range(n):
        z[k, 0], z[k, 1], z[k, 4], z[k, 5] = zr[k], zr[n + k], zr[3 * n + k], zr[4 * n + k]
        z[k, 6] = math.log(zr[5 * n + k]) if 0 < zr[5 * n + k] < np.inf else np.nan
        z[k, 2], z[k, 3] = zr[3 * n + k] * math.cos(zr[2 * n + k]), zr[3 * n + k] * math.sin(zr[2 * n + k])
        z[k, 7] = 0.0
        if math.isnan(zr[2 * n + k]):                        # no measured motion (ofpd.faint_objects)
            z[k, 2] = z[k, 3] = z[k, 4] = 0.0
            z[k, 7] = 1.0
    return z


@dataclass(frozen=True)
class BinEdges:
    """The bundle's speed bins in px/s: ``inner`` (N - 1 edges between bins), and each bin's lower
    and upper bound ``lo``, ``hi`` (index k - 1; lo_1 = 0, hi_N = inf)."""

    inner: np.ndarray
    lo: np.ndarray
    hi: np.ndarray

    @classmethod
    def of(cls, config) -> "BinEdges":
        inner = np.array([lo for lo, _hi in config.speed_bins_px_ms[1:]], dtype=_F) * 1000.0
        return cls(inner, np.concatenate([[0.0], inner]), np.concatenate([inner, [np.inf]]))


#: entries of the settings vector the compiled loops take (``params``)
(P_DT, P_GATE, P_GROWTH, P_ALPHA, P_BETA, P_H, P_CONFIRM, P_TENTATIVE, P_MAX_MISSES, P_BIRTH_GAP, P_GATE_SPEED,
 P_MAX_OCCLUDED, P_HEADING_PX, P_HEADING_BETA, P_SHARED_KEEPS, P_TURN_BETA, P_MAX_TURN, P_MERGE_PX, P_MERGE_MOVE,
 P_REPORT, P_REID, P_SHARED_GROWS, P_REID_RATIO, P_COAST_PX, P_MAX_COAST, P_POS_BETA, P_POS_MIN, P_POS_MAX_RAD,
 P_BLOB_GROWTH, P_HEADING_COST, P_REID_GROWTH, P_REID_MISSED, P_HIDDEN, P_HANDOVER, P_HANDOVER_REACH,
 P_HANDOVER_WINDOWS, P_HANDOVER_RATIO, P_COAST_TURN, P_OCC_PX, P_OCC_TRAVEL, P_OCC_HITS, P_BORN_CONFIRMED) = range(42)


def params(cfg: TrackerConfig, dt_s: float) -> np.ndarray:
    """The settings and the window length as one float64 vector (one argument for the compiled
    loops: numba's per-call dispatch cost grows with the number of arguments)."""
    return np.array([dt_s, cfg.gate_px, cfg.gate_growth, cfg.alpha, cfg.beta, cfg.hysteresis, cfg.confirm_hits,
                     cfg.tentative_misses, cfg.max_misses, cfg.birth_gap_px, cfg.gate_speed, cfg.max_occluded,
                     cfg.heading_px, cfg.heading_beta, float(cfg.shared_keeps_motion), cfg.turn_beta,
                     cfg.max_turn_rad, cfg.merge_px, cfg.merge_move_px, cfg.report_misses, cfg.reid_px,
                     float(cfg.shared_gate_grows), cfg.reid_ratio, cfg.coast_px, cfg.max_coast,
                     cfg.pos_beta, cfg.pos_min_px, cfg.pos_max_rad, cfg.blob_growth, cfg.heading_cost_px,
                     cfg.reid_growth, float(cfg.reid_ratio_missed), cfg.hidden_px, cfg.handover_px,
                     cfg.handover_reach, cfg.handover_windows, cfg.handover_speed_ratio, cfg.coast_turn_rad,
                     cfg.occluded_px, cfg.occluded_travel_px, cfg.occluded_min_hits,
                     0.0],                    # P_BORN_CONFIRMED: Tracker sets it in a stream's first windows
                    dtype=_F)


def start_params(p: np.ndarray) -> np.ndarray:
    """A copy of ``params``' vector for a window of the stream's start (confirm_at_start): its
    births are confirmed at birth."""
    q = p.copy()
    q[P_BORN_CONFIRMED] = 1.0
    return q


@njit(cache=True, nogil=True)
def _predict(t, z, p):
    """Predicted tracks, track x detection distances and the gate test (module doc), and whether
    no track and no detection has two candidates (``simple``: the pairs are the gate's)."""
    n_t, n_d = t.shape[0], z.shape[0]
    dt_s = p[P_DT]
    a = t.copy()
    d = np.empty((n_t, n_d))
    ok = np.zeros((n_t, n_d), np.bool_)
    per_col = np.zeros(n_d, np.int64)
    simple = True
    for i in range(n_t):
        th = t[i, W] * dt_s
        hidden = t[i, MISS] + t[i, BLB]              # windows in a row without its own detection
        if (hidden + 1.0) * abs(th) > p[P_COAST_TURN]:    # the turn of that run bounded (coast_turn_rad)
            th = math.copysign(max(0.0, p[P_COAST_TURN] - hidden * abs(th)), th)
        c, s, ch, sh = math.cos(th), math.sin(th), math.cos(0.5 * th), math.sin(0.5 * th)
        a[i, VX], a[i, VY] = c * t[i, VX] - s * t[i, VY], s * t[i, VX] + c * t[i, VY]
        a[i, X] += (ch * t[i, VX] - sh * t[i, VY]) * dt_s
        a[i, Y] += (sh * t[i, VX] + ch * t[i, VY]) * dt_s
        gate = p[P_GATE] + (p[P_GATE_SPEED] + p[P_GROWTH] * t[i, MISS] + p[P_BLOB_GROWTH] * t[i, BLB]) * t[i, S] * dt_s
        n_row = 0
        for k in range(n_d):
            d[i, k] = math.hypot(a[i, X] - z[k, 0], a[i, Y] - z[k, 1])
            if d[i, k] <= gate:
                ok[i, k] = True
                n_row += 1
                per_col[k] += 1
        simple = simple and n_row <= 1
    for k in range(n_d):
        simple = simple and per_col[k] <= 1
    return a, d, ok, simple


@njit(cache=True, nogil=True)
def _merges(a, t, z, r, j, d, p):
    """Blobs of two confirmed tracks (module doc): -> (track of each detection's blob or -1, the
    other track of the pair or -1); the pair's predictions are shifted alpha of the way that
    puts their midpoint on the blob (in place in ``a``)."""
    n_t, n_d = a.shape[0], z.shape[0]
    owner = np.full(n_d, -1, np.int64)
    busy = np.zeros(n_t, np.bool_)
    for m in range(r.shape[0]):
        owner[j[m]] = r[m]
        busy[r[m]] = True
    blob_of = np.full(n_d, -1, np.int64)
    mate = np.full(n_d, -1, np.int64)
    for k in range(n_d):
        best, bi, bm = np.inf, -1, -1
        for i in range(n_t):
            if t[i, CONF] <= 0 or (busy[i] and owner[k] != i) or t[i, S] * p[P_DT] < p[P_MERGE_MOVE]:
                continue
            for m in range(i + 1, n_t):
                if t[m, CONF] <= 0 or (busy[m] and owner[k] != m) or t[m, S] * p[P_DT] < p[P_MERGE_MOVE]:
                    continue
                if math.hypot(a[i, X] - a[m, X], a[i, Y] - a[m, Y]) > p[P_MERGE_PX]:
                    continue
                dm = math.hypot(z[k, 0] - 0.5 * (a[i, X] + a[m, X]), z[k, 1] - 0.5 * (a[i, Y] + a[m, Y]))
                if dm <= p[P_GATE] and dm <= min(d[i, k], d[m, k]) and dm < best and \
                        not _seen_apart(d, owner, k, i, m, p[P_REID]):
                    best, bi, bm = dm, i, m
        if bi < 0:
            continue
        if t[bm, MISS] < t[bi, MISS] or (t[bm, MISS] == t[bi, MISS] and d[bm, k] < d[bi, k]):
            bi, bm = bm, bi                                  # bi: the track the blob is reported as (sticky)
        sx = p[P_ALPHA] * (z[k, 0] - 0.5 * (a[bi, X] + a[bm, X]))
        sy = p[P_ALPHA] * (z[k, 1] - 0.5 * (a[bi, Y] + a[bm, Y]))
        for i in (bi, bm):
            a[i, X] += sx
            a[i, Y] += sy
            busy[i] = True
        blob_of[k], mate[k] = bi, bm
    return blob_of, mate


@njit(cache=True, nogil=True)
def _seen_apart(d, owner, k, i, m, reach):
    """Whether tracks i and m, near detection k, are seen apart: another detection that no third
    track took lies within ``reach`` of either's prediction (the pair has parted, so k is one of
    them, not a blob of both)."""
    for k2 in range(d.shape[1]):
        if k2 != k and (owner[k2] < 0 or owner[k2] == i or owner[k2] == m) and min(d[i, k2], d[m, k2]) <= reach:
            return True
    return False


@njit(cache=True, nogil=True)
def _handover_fit(new, old, p):
    """How well a newly confirmed track (row ``new``) continues a lost one (row ``old``): its
    distance from the lost track's last own detection over the reach there, handover_px +
    handover_reach x the lost track's travel in the windows since (<= 1: within reach), or inf
    where their speeds differ by more than handover_speed_ratio (and more than 1 px a window:
    a slow object's speed is noisy)."""
    dt_s = p[P_DT]
    sa, sb = old[S] * dt_s, new[S] * dt_s
    if abs(sa - sb) > max(HANDOVER_SLOW_PX, (p[P_HANDOVER_RATIO] - 1.0) * min(sa, sb)):
        return np.inf
    reach = p[P_HANDOVER] + p[P_HANDOVER_REACH] * sa * (old[AGE] - old[LT])
    return math.hypot(new[X] - old[LX], new[Y] - old[LY]) / reach


#: below this difference (px per window) two tracks' speeds are alike whatever their ratio
HANDOVER_SLOW_PX = 1.0


@njit(cache=True, nogil=True)
def _agree(ux, uy, vx, vy, max_rad):
    """Whether the directions of (ux, uy) and (vx, vy) differ by at most max_rad."""
    e = math.atan2(uy, ux) - math.atan2(vy, vx)
    return abs((e + math.pi) % (2.0 * math.pi) - math.pi) <= max_rad


@njit(cache=True, nogil=True)
def _hit(a, i, z, k, p, lo, hi, inner, shared):
    """Update of predicted track i (row of ``a``) with detection k (module doc); shared: k lies
    in the gates of two or more confirmed tracks."""
    if (shared and p[P_SHARED_KEEPS] > 0) or z[k, 7] > 0:  # one blob of two objects: its motion is neither's;
        # or a detection without a measured motion (a faint object's position)
        a[i, X] += p[P_ALPHA] * (z[k, 0] - a[i, X])
        a[i, Y] += p[P_ALPHA] * (z[k, 1] - a[i, Y])
        return
    if not math.isnan(z[k, 6]):                             # its look: the mean ln(event ones)
        a[i, EV] = z[k, 6] if math.isnan(a[i, EV]) else a[i, EV] + EVENTS_BETA * (z[k, 6] - a[i, EV])
    if p[P_TURN_BETA] > 0:                                  # turn rate from the direction's innovation
        q = min(1.0, z[k, S - X] * p[P_DT] / p[P_HEADING_PX])
        e = math.atan2(z[k, 3], z[k, 2]) - math.atan2(a[i, VY], a[i, VX])
        e = (e + math.pi) % (2.0 * math.pi) - math.pi
        wmax = p[P_MAX_TURN] / p[P_DT]
        a[i, W] = min(wmax, max(-wmax, a[i, W] + p[P_TURN_BETA] * q * e / p[P_DT]))
    for c in range(X, S + 1):
        g = p[P_ALPHA] if c <= Y else p[P_BETA]
        a[i, c] += g * (z[k, c - X] - a[i, c])
    # heading: a detection's direction is as good as the distance it moved in the window
    g_h = min(1.0, max(p[P_HEADING_BETA], z[k, S - X] * p[P_DT] / p[P_HEADING_PX]))
    a[i, HX] += g_h * (z[k, 2] - a[i, HX])
    a[i, HY] += g_h * (z[k, 3] - a[i, HY])
    if p[P_POS_BETA] > 0:                                   # the velocity its detections' positions give
        n_w = a[i, AGE] + 1.0 - a[i, LT]                     # windows since its last own detection
        if n_w > 0 and a[i, LT] > 0:
            g = p[P_POS_BETA]
            a[i, UX] += g * ((z[k, 0] - a[i, LX]) / (n_w * p[P_DT]) - a[i, UX])
            a[i, UY] += g * ((z[k, 1] - a[i, LY]) / (n_w * p[P_DT]) - a[i, UY])
        a[i, LX], a[i, LY], a[i, LT] = z[k, 0], z[k, 1], a[i, AGE] + 1.0
    h = p[P_H]
    b = int(a[i, BIN]) - 1
    if not (lo[b] * (1.0 - h) <= a[i, S] <= hi[b] * (1.0 + h)):
        a[i, BIN] = np.searchsorted(inner, a[i, S], side="right") + 1


@njit(cache=True, nogil=True)
def _update(a, t, z, r, j, d, p, lo, hi, inner, next_id, lost):
    """Update, confirmation, hand-over, deaths, births and bin hysteresis of ``step`` (module
    doc) on the predicted tracks ``a`` (t: the tracks before the window), the pairs (r, j) and
    the lost tracks -> (tracks, each detection's row, next id, lost tracks)."""
    n_t, n_d = a.shape[0], z.shape[0]
    hit = np.zeros(n_t, np.bool_)
    free = np.ones(n_d, np.bool_)
    det_of = np.full(n_t, -1, np.int64)
    shared = np.zeros(n_d, np.int64)                         # confirmed tracks whose gate holds detection k
    for i in range(n_t):
        if t[i, CONF] > 0:
            gate = p[P_GATE] + (p[P_GATE_SPEED] + p[P_GROWTH] * t[i, MISS] * p[P_SHARED_GROWS]) * t[i, S] * p[P_DT]
            for k in range(n_d):
                if d[i, k] <= gate:
                    shared[k] += 1
    blob_of, mate = _merges(a, t, z, r, j, d, p) if p[P_MERGE_PX] > 0 else (np.full(n_d, -1, np.int64),
                                                                           np.full(n_d, -1, np.int64))
    blob = np.zeros(n_t, np.bool_)                           # hit by a blob of two or more objects
    for k in range(n_d):
        if blob_of[k] >= 0:
            hit[blob_of[k]], free[k], det_of[blob_of[k]], blob[blob_of[k]] = True, False, k, True
    for m in range(r.shape[0]):
        i, k = r[m], j[m]
        if blob_of[k] >= 0:                                  # a blob of two tracks: moved in _merges
            continue
        hit[i], free[k], det_of[i] = True, False, k
    if p[P_REID] > 0:                                        # second association: missed tracks claim leftovers
        while True:
            best, bi, bk = np.inf, -1, -1
            for i in range(n_t):
                if hit[i] or t[i, CONF] <= 0 or t[i, HITS] < p[P_CONFIRM] or t[i, S] * p[P_DT] < p[P_MERGE_MOVE]:
                    continue
                lim = p[P_REID] + p[P_REID_GROWTH] * t[i, MISS] * t[i, S] * p[P_DT]
                for k in range(n_d):
                    if free[k] and d[i, k] <= lim and d[i, k] < best:
                        clear = True                         # not as near another confirmed track: no blob of two
                        for m in range(n_t):
                            if m != i and t[m, CONF] > 0 and d[i, k] > p[P_REID_RATIO] * d[m, k] and \
                                    not (hit[m] and p[P_REID_MISSED] > 0):
                                clear = False
                        if clear:
                            best, bi, bk = d[i, k], i, k
            if bi < 0:
                break
            hit[bi], free[bk], det_of[bi] = True, False, bk
    for i in range(n_t):                                     # the updates, once every track's detection is known
        k = det_of[i]
        if k < 0 or blob_of[k] >= 0:                         # blobs of two tracks: moved in _merges
            continue
        for m in range(n_t):                                 # a confirmed track missed next to it: hidden in k
            if m != i and not hit[m] and t[m, CONF] > 0 and d[m, k] <= p[P_HIDDEN] and p[P_HIDDEN] > 0 and \
                    (a[m, X] - a[i, X]) * (a[m, VX] - a[i, VX]) + (a[m, Y] - a[i, Y]) * (a[m, VY] - a[i, VY]) < 0:
                shared[k] = max(shared[k], 2)
        blob[i] = shared[k] > 1 and p[P_SHARED_KEEPS] > 0
        _hit(a, i, z, k, p, lo, hi, inner, shared[k] > 1)
    keep = np.zeros(n_t, np.bool_)
    taken = ~free                                            # detections assigned to a track
    dt_s = p[P_DT]
    for i in range(n_t):
        a[i, OCC] = 0.0
        if not hit[i] and t[i, CONF] > 0:                    # missed: under another track's detection?
            gate = p[P_GATE] + (p[P_GATE_SPEED] + p[P_GROWTH] * t[i, MISS]) * t[i, S] * dt_s
            if (t[i, MISS] + 1.0) * t[i, S] * dt_s <= p[P_OCC_TRAVEL] and t[i, HITS] >= p[P_OCC_HITS]:
                gate = max(gate, p[P_OCC_PX])                # a slow object beside a blob its events joined
            for k in range(n_d):
                if (taken[k] and d[i, k] <= gate) or mate[k] == i:
                    a[i, OCC] = 1.0
        if (not hit[i] or blob[i]) and t[i, MISS] == 0 and t[i, BLB] == 0 and t[i, CONF] > 0 and p[P_POS_BETA] > 0 \
                and t[i, S] * dt_s >= p[P_POS_MIN]:
            th = a[i, W] * dt_s * ((1.0 - p[P_POS_BETA]) / p[P_POS_BETA] + 1.5)    # e_i's mean age, turned
            ux = math.cos(th) * a[i, UX] - math.sin(th) * a[i, UY]
            uy = math.sin(th) * a[i, UX] + math.cos(th) * a[i, UY]
            if _agree(ux, uy, a[i, VX], a[i, VY], p[P_POS_MAX_RAD]):
                a[i, X] += (ux - a[i, VX]) * dt_s               # loses its object: coasts on the positions' velocity
                a[i, Y] += (uy - a[i, VY]) * dt_s
                a[i, VX], a[i, VY] = ux, uy
        if hit[i]:
            a[i, BLB] = t[i, BLB] + 1 if blob[i] else 0.0
        a[i, AGE] += 1
        a[i, HITS] += hit[i]
        a[i, STREAK] = t[i, STREAK] + 1 if hit[i] else 0.0
        a[i, MISS] = 0.0 if hit[i] else t[i, MISS] + 1
        if a[i, HITS] >= p[P_CONFIRM]:
            a[i, CONF] = 1.0
        elif not hit[i]:                                     # confirmed at birth (confirm_at_start), missed
            a[i, CONF] = 0.0                                 # short of its hits: tentative again
        lim = max(p[P_MAX_MISSES], p[P_MAX_OCCLUDED] * a[i, OCC])
        keep[i] = a[i, MISS] <= (lim if a[i, CONF] > 0 else p[P_TENTATIVE])
        if a[i, CONF] > 0 and a[i, MISS] * a[i, S] * dt_s <= p[P_COAST_PX] and a[i, MISS] <= p[P_MAX_COAST]:
            keep[i] = True                                   # a slow track's prediction is still near its object
        if a[i, CONF] > 0:                                   # no births next to a confirmed track
            for k in range(n_d):
                if d[i, k] <= p[P_BIRTH_GAP]:
                    free[k] = False
    lost = lost.copy()                                       # the lost tracks: one more window missed
    lost[:, AGE] += 1.0
    lost[:, MISS] += 1.0
    used = np.zeros(lost.shape[0], np.bool_)                 # a lost track whose id was handed over
    gone = np.zeros(n_t, np.bool_)                           # a live one that handed its id over
    if p[P_HANDOVER] > 0:
        for i in range(n_t):                                 # a track confirmed in this window
            if not (keep[i] and a[i, CONF] > 0 and t[i, CONF] <= 0):
                continue
            best, bm, bl = 1.0, -1, -1
            for m in range(n_t):                             # a confirmed track that lost its object
                if m != i and not hit[m] and not gone[m] and t[m, CONF] > 0:
                    f = _handover_fit(a[i], a[m], p)
                    if f <= best:
                        best, bm, bl = f, m, -1
            for m in range(lost.shape[0]):                   # one that died of it
                if not used[m]:
                    f = _handover_fit(a[i], lost[m], p)
                    if f <= best:
                        best, bm, bl = f, -1, m
            if bm >= 0:
                a[i, ID], keep[bm], gone[bm] = a[bm, ID], False, True
            elif bl >= 0:
                a[i, ID], used[bl] = lost[bl, ID], True
    n_lost = 0                                               # lost: the dead confirmed tracks, for a while
    for m in range(lost.shape[0]):
        n_lost += not used[m] and lost[m, MISS] <= p[P_HANDOVER_WINDOWS]
    for i in range(n_t):                                     # (a track confirmed at birth that dies short of
        n_lost += p[P_HANDOVER] > 0 and t[i, CONF] > 0 and not keep[i] and not gone[i]   # its hits too)
    lost_out = np.empty((n_lost, a.shape[1]))
    row = 0
    for m in range(lost.shape[0]):
        if not used[m] and lost[m, MISS] <= p[P_HANDOVER_WINDOWS]:
            lost_out[row] = lost[m]
            row += 1
    for i in range(n_t):
        if p[P_HANDOVER] > 0 and t[i, CONF] > 0 and not keep[i] and not gone[i]:
            lost_out[row] = a[i]
            row += 1
    n_keep = int(keep.sum())
    n_new = int(free.sum())
    out = np.zeros((n_keep + n_new, a.shape[1]))
    assigned = np.full(n_d, -1, np.int64)
    row = 0
    for i in range(n_t):
        if keep[i]:
            out[row] = a[i]
            if det_of[i] >= 0:
                assigned[det_of[i]] = row
            row += 1
    for k in range(n_d):
        if free[k]:
            out[row, ID] = next_id
            for c in range(X, S + 1):
                out[row, c] = z[k, c - X]
            out[row, HX], out[row, HY], out[row, UX], out[row, UY] = z[k, 2], z[k, 3], z[k, 2], z[k, 3]
            out[row, LX], out[row, LY], out[row, LT] = z[k, 0], z[k, 1], 1.0
            out[row, BIN] = z[k, 5]
            out[row, EV] = z[k, 6]
            out[row, AGE] = out[row, HITS] = out[row, STREAK] = 1.0
            out[row, CONF] = 1.0 if p[P_CONFIRM] <= 1 or p[P_BORN_CONFIRMED] > 0 else 0.0
            assigned[k] = row
            next_id += 1
            row += 1
    return out, assigned, next_id, lost_out


@njit(cache=True, nogil=True)
def _direction_cost(e, speed_px_s, dt_s, heading_px):
    """q |e| (e wrapped to [-pi, pi), q = min(1, s dt / heading_px)): the direction term of an
    association cost per px of heading_cost_px (or parting_heading_px)."""
    return min(1.0, speed_px_s * dt_s / heading_px) * abs((e + math.pi) % (2.0 * math.pi) - math.pi)


@njit(cache=True, nogil=True)
def _associate(a, d, ok, simple, t, z, p):
    """(track rows, detection columns) of ``step``'s pairs from the predicted tracks ``a``, their
    distances ``d`` and gates ``ok`` (_predict): where the gates pair tracks and detections
    unambiguously (``simple``, the usual window) the gates' pairs; else the Hungarian method on
    the gated pairs (assignment.match_pairs), confirmed tracks first, then tentative ones, the
    cost d_ij + H q_j |angle(u_j, v_i')| (the gates are on d; the choice among gated pairs
    weighs direction too)."""
    n_t, n_d = ok.shape
    if simple:
        r, j = np.empty(n_t, np.int64), np.empty(n_t, np.int64)
        m = 0
        for i in range(n_t):                                 # np.nonzero(ok): at most one pair per row
            for k in range(n_d):
                if ok[i, k]:
                    r[m], j[m] = i, k
                    m += 1
        return r[:m], j[:m]
    cost = d.copy()
    if p[P_HEADING_COST] > 0:
        for i in range(n_t):
            heading = math.atan2(a[i, VY], a[i, VX])
            for k in range(n_d):
                h = _direction_cost(math.atan2(z[k, 3], z[k, 2]) - heading, z[k, 4], p[P_DT], p[P_HEADING_PX])
                cost[i, k] = d[i, k] + p[P_HEADING_COST] * (h if math.isfinite(h) else 0.0)
    first = np.zeros((n_t, n_d), np.bool_)
    for i in range(n_t):
        if t[i, CONF] > 0:
            for k in range(n_d):
                first[i, k] = ok[i, k] and math.isfinite(cost[i, k])
    r1, j1 = match_pairs(cost, first)
    taken = np.zeros(n_d, np.bool_)
    taken[j1] = True
    then = np.zeros((n_t, n_d), np.bool_)
    for i in range(n_t):
        if t[i, CONF] <= 0:
            for k in range(n_d):
                then[i, k] = ok[i, k] and not taken[k] and math.isfinite(cost[i, k])
    r2, j2 = match_pairs(cost, then)
    return np.concatenate((r1, r2)), np.concatenate((j1, j2))


@njit(cache=True, nogil=True)
def _step(t, z, p, lo, hi, inner, next_id, lost):
    """The whole step in one call: -> (tracks, each detection's row, next id, lost tracks)."""
    a, d, ok, simple = _predict(t, z, p)
    r, j = _associate(a, d, ok, simple, t, z, p)
    return _update(a, t, z, r, j, d, p, lo, hi, inner, next_id, lost)


@njit(cache=True, nogil=True)
def _listing(out, assigned, p):
    """What Tracker.update hands out, as one int64 array (one result to box, one ``tolist``):
    each detection's row in ``out`` (-1: none), each detection's track id (-1: none), then the
    rows of the confirmed tracks listed as coasting (missed, for their first report_misses
    misses or while occluded)."""
    n_d = assigned.shape[0]
    n_c = 0
    for i in range(out.shape[0]):
        n_c += out[i, CONF] > 0 and out[i, MISS] > 0 and (out[i, MISS] <= p[P_REPORT] or out[i, OCC] > 0)
    info = np.empty(2 * n_d + n_c, np.int64)
    for k in range(n_d):
        info[k] = assigned[k]
        info[n_d + k] = int(out[assigned[k], ID]) if assigned[k] >= 0 else -1
    m = 2 * n_d
    for i in range(out.shape[0]):
        if out[i, CONF] > 0 and out[i, MISS] > 0 and (out[i, MISS] <= p[P_REPORT] or out[i, OCC] > 0):
            info[m] = i
            m += 1
    return info


N_P = P_BORN_CONFIRMED + 1


@njit(cache=True, nogil=True)
def _window(t, zr, pe, next_id, lost):
    """Tracker.update's window in one compiled call (``_step`` on raw_detections' array): ->
    (tracks, _listing, next id, lost tracks, the parting's _entering_blob rows). pe: params then
    the bin edges lo, hi, inner (one argument: numba's dispatch cost grows with their number;
    _entering_blob here, not in a call of its own: ~2 us a window of dispatch)."""
    n = (pe.shape[0] - N_P + 1) // 3
    p, lo, hi, inner = pe[:N_P], pe[N_P:N_P + n], pe[N_P + n:N_P + 2 * n], pe[N_P + 2 * n:]
    out, assigned, nid, lost = _step(t, _detections(zr), p, lo, hi, inner, next_id, lost)
    return out, _listing(out, assigned, p), nid, lost, _entering_blob(out, t, p[P_MERGE_PX])


def step(tracks: Tracks, dets: Detections, dt_s: float, cfg: TrackerConfig, edges: BinEdges,
         next_id: int, p: np.ndarray | None = None, start: bool = False) -> tuple[Tracks, np.ndarray, int]:
    """One window of tracking (module doc): -> (live and lost tracks, assigned track row of each
    detection in the returned tracks (-1: a fragment, no track), next free id). Pure: the inputs
    are not modified. Compiled loops (numba, as compiled.py): a window has a handful of objects, so
    per-call overhead, not array size, would set the cost of numpy here. p: ``params(cfg,
    dt_s)`` when the caller keeps it. start: a window of the stream's start, whose births are
    confirmed at birth (``confirm_at_start``: Tracker passes it for the first confirm_hits - 1;
    step itself does not read cfg.confirm_at_start)."""
    p = params(cfg, dt_s) if p is None else p
    p = start_params(p) if start else p
    out, assigned, nid, lost = _step(tracks.a, dets.a, p, edges.lo, edges.hi, edges.inner, int(next_id), tracks.lost)
    return Tracks(out, lost), assigned, int(nid)


@njit(cache=True, nogil=True)
def _entering_blob(t, last, reach):
    """(row in t, row in last) of each confirmed track of ``t`` that may be in a blob (occluded,
    its detection a blob, or one of a pair within ``reach`` px of which one was just missed and
    the other seen: a blob the association did not see as one) and was in no blob in ``last``
    (confirmed, neither occluded nor a blob: seen, or coasting on its own prediction): the
    parting's copies are taken from there."""
    out = np.empty((t.shape[0], 2), np.int64)
    m = 0
    near = np.zeros(t.shape[0], np.bool_)
    for r in range(t.shape[0]):
        if t[r, CONF] > 0 and t[r, MISS] == 1:
            for r2 in range(t.shape[0]):
                if r2 != r and t[r2, CONF] > 0 and t[r2, MISS] == 0 and \
                        math.hypot(t[r, X] - t[r2, X], t[r, Y] - t[r2, Y]) <= reach:
                    near[r] = True
                    near[r2] = True
    for r in range(t.shape[0]):
        if t[r, CONF] > 0 and (t[r, OCC] > 0 or t[r, BLB] > 0 or near[r]):
            for q in range(last.shape[0]):
                if last[q, ID] == t[r, ID]:
                    if last[q, CONF] > 0 and last[q, OCC] == 0 and last[q, BLB] == 0:
                        out[m, 0], out[m, 1] = r, q
                        m += 1
                    break
    return out[:m]


#: parting: how long (windows) a track keeps its state from before a blob
PARTING_MAX_WINDOWS = 80
#: parting: how many windows a track seen again waits for its partner to be seen too (a fast
#: object that passed over a slow one is seen at once, the slow one some windows later)
PARTING_WAIT = 10
#: the columns of a track that an update (_hit) sets: what a parting exchange takes from the redone update
_FILTER = [X, Y, VX, VY, S, BIN, HX, HY, W, LX, LY, LT, UX, UY, EV]


def _carried(before: list, t_us: int, max_turn: float) -> tuple[float, float, float]:
    """(x, y, direction) of a track's state from before its blob (its row, t_b) carried to t_us
    at its constant turn rate: x + int_0^T R(w t) v dt (closed form), the rate lowered so that the
    whole turn |w T| is at most max_turn (rad)."""
    row, tb = before[0], before[1]
    T = (t_us - tb) * 1e-6
    vx, vy, w = row[VX], row[VY], row[W]
    if abs(w * T) > max_turn:
        w = math.copysign(max_turn / T, w)
    a = w * T
    if abs(a) < 1e-9:
        dx, dy = vx * T, vy * T
    else:
        sa, ca = math.sin(a), math.cos(a)
        dx, dy = (vx * sa + vy * (ca - 1.0)) / w, (vx * (1.0 - ca) + vy * sa) / w
    return row[X] + dx, row[Y] + dy, math.atan2(vy, vx) + a


def _part_cost(p: tuple, ev: float, zr: np.ndarray, n: int, k: int, per_rad: float, per_ln: float,
               heading_px: float, dt_s: float) -> float:
    """c(i, k) of the parting re-decision (module doc): p = _carried's (x, y, direction), ev the
    track's mean ln(event ones) before its blob (NaN: not known; then, as where the detection's
    count is not known, no events term)."""
    turn = float(_direction_cost(zr[2 * n + k] - p[2], zr[3 * n + k], dt_s, heading_px))
    c = math.hypot(p[0] - zr[k], p[1] - zr[n + k]) + per_rad * turn
    if per_ln > 0 and 0 < zr[5 * n + k] < math.inf and not math.isnan(ev):
        c += per_ln * abs(math.log(zr[5 * n + k]) - ev)
    return c


class Tracker:
    """Stateful wrapper of ``step`` for a stream of windows: ``update(objects, t0_us)`` assigns
    every object of the window a ``track_id`` and its track's smoothed ``track`` state (a
    read-only mapping, ``TrackState``), in place. Windows may be skipped (a gap counts as missed windows)."""

    def __init__(self, config, dt_us: int, settings: TrackerConfig | None = None, px_ms_per_mps: float | None = None):
        """config: the bundle's ToffeConfig (its speed bins); dt_us: the window length;
        px_ms_per_mps: the run's speed scale, for the track's speed in m/s (None: not reported)."""
        self.settings = settings or TrackerConfig()
        self.dt_us = int(dt_us)
        self.edges = BinEdges.of(config)
        self._p = params(self.settings, self.dt_us * 1e-6)
        self._pe = np.concatenate([self._p, self.edges.lo, self.edges.hi, self.edges.inner])   # _window's
        self.k_mps = None if px_ms_per_mps is None else 1.0 / (1000.0 * px_ms_per_mps)
        self._a = Tracks().a                 # the live tracks (``tracks``)
        self._lost = Tracks().lost           # the dead confirmed ones that may hand their id over
        self.next_id = 0
        self.t0_last: int | None = None
        self.n_windows = 0                   # windows since the stream's first, gaps included (confirm_at_start)
        # confirm_at_start: births of the stream's first confirm_hits - 1 windows are confirmed at
        # birth (no track there could have earned it yet), the rest of the settings as they are
        self._pe_start = start_params(self._pe)     # the bin edges after the params: untouched
        self._coasting: list = []
        self._before: dict = {}              # parting: id -> [its row before its blob, t_us, free windows]
        # compile (first run on a machine) or load the cached kernels now, not in the first window
        # (_window for every window; _predict, _hit, _detections and _direction_cost for a parting)
        zr = np.array([0.0, 0.0, 0.0, 1.0, 1.0, 1.0])
        out = _window(_window(Tracks().a, zr, self._pe, 0, self._lost)[0], zr, self._pe, 1, self._lost)[0]
        z = _detections(zr)
        a = _predict(out, z, self._p)[0]
        _hit(a, 0, z, 0, self._p, self.edges.lo, self.edges.hi, self.edges.inner, False)
        _direction_cost(0.0, 1.0, 1e-3, 1.0)

    def update(self, objects: list, t0_us: int) -> Tracks:
        """Track one window's objects (objects with x, y, direction_rad, speed_px_s, speed_bin and,
        for the parting's events term, n_events (optional); each gets ``track_id`` and ``track``);
        returns the live tracks."""
        for o, tid, state in zip(objects, *self.columns(raw_detections(objects), t0_us)):
            o.track_id, o.track = tid, state
        return self.tracks

    @property
    def tracks(self) -> Tracks:
        """Every live track after the last window (and the lost ones)."""
        return Tracks(self._a, self._lost)

    def columns(self, zr: np.ndarray, t0_us: int) -> tuple[list, list]:
        """``update`` on the window's detections as raw_detections' (6 n,) columns (the pipeline
        builds it from the decoder's columns, before the objects exist): -> each detection's
        track id and ``TrackState`` (None and None: a fragment without a track), for the
        objects' constructor (the ids a slice when every detection has a track, the usual
        window: Python work costs microseconds on the cold cache the pipeline's other kernels
        leave)."""
        if zr.ndim != 1 or zr.shape[0] % 6:
            raise ValueError(f"detections must be raw_detections' flat (6 n,) columns, got shape {zr.shape}")
        last, t0_us = self.t0_last, int(t0_us)
        self.t0_last = t0_us
        t, lost = self._a, self._lost
        n_win = 1 if last is None or t0_us - last == self.dt_us else max(1, round((t0_us - last) / self.dt_us))
        self.n_windows += 1 if last is None else n_win
        start = self.settings.confirm_at_start and self.n_windows < self.settings.confirm_hits
        if n_win > 1 and len(t) + len(lost):    # windows never seen: coast the tracks through them
            a, gap = t.copy(), (n_win - 1) * self.dt_us * 1e-6
            a[:, X] += a[:, VX] * gap
            a[:, Y] += a[:, VY] * gap
            a[:, AGE] += n_win - 1
            a[:, MISS] += n_win - 1
            a[:, STREAK] = 0
            s = self.settings
            # who lives through the gap: _update's rule (an occluded track up to max_occluded, a
            # slow one while its coast stays within coast_px)
            was = a[:, CONF] > 0                            # confirmed before the gap (may hand its id over)
            a[a[:, HITS] < s.confirm_hits, CONF] = 0.0        # confirmed at birth and missed: tentative again
            conf = a[:, CONF] > 0
            live = a[:, MISS] <= np.where(conf, np.maximum(s.max_misses, s.max_occluded * (a[:, OCC] > 0)),
                                          s.tentative_misses)
            live |= conf & (a[:, MISS] * a[:, S] * self.dt_us * 1e-6 <= s.coast_px) & (a[:, MISS] <= s.max_coast)
            lost = lost.copy()
            lost[:, AGE] += n_win - 1
            lost[:, MISS] += n_win - 1
            if s.handover_px > 0:       # died in the gap
                lost = np.concatenate([lost, a[~live & was]])
            t, lost = a[live], lost[lost[:, MISS] <= s.handover_windows]
        # the usual window in one compiled call, the results handed out from one int array
        # (Python-level work, not the tracking, was most of the cost)
        out, info, self.next_id, self._lost, entering = _window(t, zr, self._pe_start if start else self._pe,
                                                                self.next_id, lost)
        self._a = out
        n, k, info = zr.shape[0] // 6, self.k_mps, info.tolist()
        self._coasting = info[2 * n:]
        rows, ids = info[:n], info[n:2 * n]
        if self.settings.parting:
            ids = self._parting(t, out, zr, rows, ids, t0_us, entering)
        if min(rows, default=0) >= 0:
            return ids, [TrackState(out, r, k) for r in rows]
        return [i if i >= 0 else None for i in ids], [TrackState(out, r, k) if r >= 0 else None for r in rows]

    def _parting(self, t: np.ndarray, out: np.ndarray, zr: np.ndarray, rows: list, ids: list, t0_us: int,
                 entering: np.ndarray) -> list:
        """The parting re-decision (module doc) on this window's tracks ``out`` (from ``t``, the
        tracks it started from, as of the window before: t0_us - dt; rows redone in place) -> the
        detections' track ids. entering: _entering_blob(out, t, merge_px) (_window's; the usual
        window has none)."""
        before, t_last = self._before, t0_us - self.dt_us
        if not before and entering.shape[0] == 0:
            return ids
        id_now = out[:, ID].astype(np.int64).tolist()
        live = set(id_now)
        for tid in [i for i in before if i not in live or t0_us - before[i][1] > PARTING_MAX_WINDOWS * self.dt_us]:
            del before[tid]
        for r, q in entering.tolist():
            if id_now[r] not in before:
                before[id_now[r]] = [t[q].copy(), t_last, 0]
        blob = (out[:, CONF] > 0) & ((out[:, OCC] > 0) | (out[:, BLB] > 0))
        n = zr.shape[0] // 6
        det_of = {r: k for k, r in enumerate(rows) if r >= 0}
        free = [r for r, tid in enumerate(id_now)
                if tid in before and r in det_of and out[r, MISS] == 0 and not blob[r]]
        if len(before) < 2:                                  # a copy whose partner's is gone waits as below:
            self._wait(free, id_now)                         # kept, it stood for the track's state before
            return ids                                       # a later blob (up to 80 windows old)
        s, dt_s = self.settings, self.dt_us * 1e-6
        pairs = []
        for i, r1 in enumerate(free):
            for r2 in free[i + 1:]:
                b1, b2 = before[id_now[r1]], before[id_now[r2]]
                tb = max(b1[1], b2[1])                       # were the two near each other before?
                q1, q2 = _carried(b1, tb, s.parting_turn_rad), _carried(b2, tb, s.parting_turn_rad)
                if math.hypot(q1[0] - q2[0], q1[1] - q2[1]) > s.merge_px:
                    continue
                p1, p2 = _carried(b1, t0_us, s.parting_turn_rad), _carried(b2, t0_us, s.parting_turn_rad)
                k1, k2 = det_of[r1], det_of[r2]
                c = [[_part_cost(p, b[0][EV], zr, n, k, s.parting_heading_px, s.parting_events_px, s.heading_px,
                                 dt_s) for k in (k1, k2)] for p, b in ((p1, b1), (p2, b2))]
                pairs.append((c[0][1] + c[1][0] - c[0][0] - c[1][1], r1, r2))
        done: set = set()
        for gain, r1, r2 in sorted(pairs):
            if r1 in done or r2 in done:
                continue
            done.update((r1, r2))
            del before[id_now[r1]], before[id_now[r2]]
            if gain < 0.0:                                   # the other way round fits better
                if self._exchange(t, out, zr, r1, r2, det_of[r1], det_of[r2]):
                    ids = [int(out[r, ID]) if r in (r1, r2) else i for r, i in zip(rows, ids)]
        self._wait([r for r in free if r not in done], id_now)   # a partner still hidden: wait for it
        return ids

    def _wait(self, free: list, id_now: list) -> None:
        """The parting's wait: each track of rows ``free`` (seen on its own, its copy kept) counts
        one more window, its copy dropped after PARTING_WAIT."""
        for r in free:
            b = self._before[id_now[r]]
            b[2] += 1
            if b[2] > PARTING_WAIT:
                del self._before[id_now[r]]

    def _exchange(self, t: np.ndarray, out: np.ndarray, zr: np.ndarray, r1: int, r2: int, k1: int, k2: int) -> bool:
        """Rows r1 and r2 of ``out`` (tracks i and j, updated with detections k1 and k2) become j
        updated with k1 and i updated with k2: both tracks' predictions from ``t`` updated again
        (_hit) with the other detection; ids, age, hits and the other bookkeeping go with the
        track, the filter state is the new update's. False (nothing changed) where either row
        is not the same track one window on (a hand-over in this window gave its id to a new one)."""
        where = {int(v): q for q, v in enumerate(t[:, ID].tolist())}
        i, j = int(out[r1, ID]), int(out[r2, ID])
        if i not in where or j not in where or out[r1, AGE] != t[where[i], AGE] + 1 \
                or out[r2, AGE] != t[where[j], AGE] + 1:
            return False
        z = _detections(zr)
        pred = _predict(t, z, self._p)[0]
        a = pred[[where[i], where[j]]]
        _hit(a, 0, z, k2, self._p, self.edges.lo, self.edges.hi, self.edges.inner, False)
        _hit(a, 1, z, k1, self._p, self.edges.lo, self.edges.hi, self.edges.inner, False)
        new1, new2 = out[r2].copy(), out[r1].copy()           # j's bookkeeping, i's
        new1[_FILTER], new2[_FILTER] = a[1, _FILTER], a[0, _FILTER]
        out[r1], out[r2] = new1, new2
        return True

    def confirmed(self) -> list[dict]:
        """Every live confirmed track after the last window, seen (``misses`` 0) or coasting:
        [{"track_id", "track"}] (the API's FlowStream.tracks)."""
        a = self._a
        return [{"track_id": int(a[r, ID]), "track": TrackState(a, r, self.k_mps)}
                for r in np.flatnonzero(a[:, CONF] > 0).tolist()]

    def coasting(self) -> list[dict]:
        """The confirmed tracks no detection of the last window was assigned to, for their first
        report_misses misses or while occluded (they coast on their prediction):
        [{"track_id", "track"}], the window line's ``coasting`` list."""
        if not self._coasting:
            return []
        a = self._a
        return [{"track_id": int(a[r, ID]), "track": TrackState(a, r, self.k_mps)} for r in self._coasting]


class TrackState(Mapping):
    """A track's smoothed state after a window, the JSON ``track`` object: x, y (px),
    direction_deg, speed_px_s, speed_mps (with a speed scale), speed_bin, age, hits, confirmed,
    misses (windows in a row without a detection: 0 when detected in this window, > 0 when
    coasting on its prediction), occluded (coasting under a detection another track took) and
    merged (detected, but in a blob of its object and another confirmed track's: its motion is
    kept, its gate grows).
    A read-only mapping built from row i of the window's tracks array ``a`` (Tracks.a, never
    modified once returned) when first read (a robot loop that reads a few tracks does not pay
    for formatting every one; ``dict(state)`` for JSON)."""

    __slots__ = ("_a", "_i", "_k_mps", "_d")

    def __init__(self, a: np.ndarray, i: int, k_mps: float | None):
        self._a, self._i, self._k_mps, self._d = a, i, k_mps, None

    def _dict(self) -> dict:
        if self._d is None:
            row = self._a[self._i].tolist()
            vx, vy, sp = row[HX], row[HY], row[S]
            d = {"x": round(row[X], 4), "y": round(row[Y], 4),
                 "direction_deg": round(math.degrees(math.atan2(vy, vx)), 4), "speed_px_s": round(sp, 4)}
            if self._k_mps is not None:
                d["speed_mps"] = round(sp * self._k_mps, 4)
            d.update(speed_bin=int(row[BIN]), age=int(row[AGE]), hits=int(row[HITS]), confirmed=row[CONF] > 0,
                     misses=int(row[MISS]), occluded=row[OCC] > 0, merged=row[MISS] == 0 and row[BLB] > 0)
            self._d = d
        return self._d

    @property
    def confirmed(self) -> bool:
        return bool(self._a[self._i, CONF] > 0)

    def to_dict(self) -> dict:
        """``dict(state)``, a new dict, without a Python call per key (the JSON line's ``track``)."""
        return self._dict().copy()

    def __getitem__(self, key):
        return self._dict()[key]

    def __iter__(self):
        return iter(self._dict())

    def __len__(self) -> int:
        return len(self._dict())

    def __repr__(self) -> str:
        return f"TrackState({self._dict()!r})"

    def __deepcopy__(self, memo) -> "TrackState":
        return self                                          # immutable
