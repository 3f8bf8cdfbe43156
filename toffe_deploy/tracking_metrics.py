"""Tracking metrics against ground truth: CLEAR MOT and IDF1, computed by motmetrics.

Per window, the hypotheses are what the window reports as tracks: the objects whose track is
confirmed (tracking.Tracker; tentative tracks do not count) at their detected centre, and the
confirmed tracks coasting through a miss at their predicted centre; the ground truth
is the window's objects (dataset.groundtruth.window_truth, with their object ids). A hypothesis
can match an object only within the same gate as the detection metrics (metrics.GATE_PX):

    MOTA  = 1 - (misses + false positives + ID switches) / ground-truth objects
    MOTP  = mean centre distance of the matched pairs (px)
    IDF1  = 2 IDTP / (2 IDTP + IDFP + IDFN)     (identity-preserving one-to-one matching over the run)

ID switches: a ground-truth object matched to another track id than at its previous match;
fragmentations: a track of an object interrupted (missed) and resumed. motmetrics (MIT licence)
does the frame-to-frame CLEAR MOT bookkeeping and IDF1's global matching.
"""
from __future__ import annotations

import math

import numpy as np

from .metrics import GATE_PX

#: motmetrics names -> the names we report
METRICS = {"mota": "mota", "motp": "motp_px", "idf1": "idf1", "num_switches": "id_switches",
           "num_fragmentations": "fragmentations", "num_false_positives": "false_positives",
           "num_misses": "misses", "num_objects": "gt_objects", "num_unique_objects": "gt_tracks",
           "mostly_tracked": "mostly_tracked", "mostly_lost": "mostly_lost"}


class TrackingErrors:
    """Accumulates windows (``add_window``) of one or more sequences (``new_sequence``: object
    ids of different sequences never meet); ``summary()`` gives the metrics (module doc)."""

    def __init__(self, gate_px: float = GATE_PX):
        self.gate_px = float(gate_px)
        self._accs: list = []
        self.new_sequence()

    def new_sequence(self) -> None:
        import motmetrics as mm

        self._accs.append(mm.MOTAccumulator(auto_id=True))

    def add_window(self, hyp_ids, hyp_xy, truths) -> None:
        """hyp_ids, hyp_xy: the window's confirmed tracks (ids, (n, 2) centres, px); truths:
        objects with object_id, x, y (dataset ObjectTruth)."""
        truths = list(truths)
        hyp_xy = np.asarray(hyp_xy, dtype=np.float64).reshape(-1, 2)
        gt_xy = np.array([(t.x, t.y) for t in truths], dtype=np.float64).reshape(-1, 2)
        d = np.linalg.norm(gt_xy[:, None, :] - hyp_xy[None, :, :], axis=2)
        d[d > self.gate_px] = np.nan
        self._accs[-1].update([int(t.object_id) for t in truths], [int(i) for i in hyp_ids], d)

    def add_result(self, result, truths) -> None:
        """add_window with what a window reports (pipeline.WindowResult of a tracking Pipeline):
        its objects of confirmed tracks at their detected centre, and its coasting tracks at
        their predicted centre."""
        hyp = reported(result)
        self.add_window([h[0] for h in hyp], [h[1:] for h in hyp], truths)

    def summary(self) -> dict:
        """{mota, motp_px, idf1, id_switches, fragmentations, false_positives, misses, gt_objects,
        gt_tracks, mostly_tracked, mostly_lost, windows, gate_px} over every sequence."""
        import motmetrics as mm

        accs = [a for a in self._accs if len(a.events)]
        n_windows = sum(len(a.events.index.get_level_values(0).unique()) for a in accs)
        if not accs:
            out = {v: (math.nan if k in ("mota", "motp", "idf1") else 0) for k, v in METRICS.items()}
        else:
            df = mm.metrics.create().compute_many(accs, metrics=list(METRICS) + ["num_detections"],
                                                  names=[str(i) for i in range(len(accs))], generate_overall=True)
            row = df.loc["OVERALL"].copy()
            # motmetrics' OVERALL MOTP is NaN when one sequence matched nothing: weight by matches
            seq = df.drop(index="OVERALL")
            n = seq["num_detections"].to_numpy(dtype=np.float64)
            row["motp"] = float(np.nansum(seq["motp"].to_numpy(dtype=np.float64) * n) / n.sum()) if n.sum() else math.nan
            out = {v: (float(row[k]) if k in ("mota", "motp", "idf1") else int(row[k])) for k, v in METRICS.items()}
        out.update(windows=n_windows, gate_px=self.gate_px)
        return out


def reported(result) -> list:
    """What a window of a tracking Pipeline reports as tracked objects, [(track_id, x, y)]: its
    objects of confirmed tracks at their detected centre, then its coasting tracks at their
    predicted centre (what the tracking metrics score)."""
    hyp = [(o.track_id, o.x, o.y) for o in result.objects if o.track is not None and o.track.confirmed]
    return hyp + [(c["track_id"], c["track"]["x"], c["track"]["y"]) for c in result.coasting or ()]


def tracking_line(t: dict) -> str:
    """The summary's tracking line from a TrackingErrors.summary()."""
    def f(v):
        return "-" if v is None or (isinstance(v, float) and math.isnan(v)) else f"{v:.3f}"

    return (f"tracking vs ground truth (within {t['gate_px']:g} px, confirmed tracks, coasting ones included): "
            f"MOTA {f(t['mota'])}, IDF1 {f(t['idf1'])}, MOTP {f(t['motp_px'])} px, {t['id_switches']} ID switches, "
            f"{t['fragmentations']} fragmentations, {t['misses']} misses and {t['false_positives']} false positives "
            f"of {t['gt_objects']} objects ({t['gt_tracks']} true tracks, {t['mostly_tracked']} mostly tracked)")
