"""Operation counts of one inference of each benchmarked model, for the cost model.

Counting replays the exact arithmetic (the skeleton's fixed-point ``synaptic_input``/``lif_step``
for OFS, the DOTIE baseline's own layer) with recording switched on; it is never timed. The
cascade it produces equals ``run_cascade`` with ``run_ofs_fixed`` (the test checks it), which is
what every target computes bit-exactly (cpu backend, Lava fixed_pt), so the counts hold for the
Loihi 2 model whatever target produced the timing.

Per model and inference:
* ``loihi``: LoihiActivity per spiking layer (OFS stage k, or DOTIE's layer);
* ``host_all``: HostOps when the whole model runs on a CPU (the ``cpu`` target);
* ``host_hybrid``: HostOps left on the host when the spiking layers run on Loihi 2, for every
  model by one rule (rules.host_part: the event-driven rule without the layers): the events
  indexed, masks, grouping and OFPD for TOFFE; morphology and masks for DOTIE, plus the listing
  and DBSCAN with clustering. (Until 2026-11-30 DOTIE's was counted over whole frames, its
  public code's way, and TOFFE's event by event: 42-44 against ~4 uJ for the same work.)
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np

from ..baselines.dotie import DotieLayerTrace, DotieParams, boxes_from_labels, dotie_separate
from ..cascade import CascadeResult, run_cascade
from ..config import ToffeConfig
from ..ofpd_io import has_object
from ..fixed_point import LoihiOFSParams, lif_step, synaptic_input
from .cost_model import (HostOps, LoihiActivity, ann_ops, dbscan_ops, dense_conv_ops, dense_lif_ops, event_conv_ops,
                         event_index_ops, fixed_lif_ops, mask_ops, morphology_ops, sort_unique_ops, synop_count)
from . import rules
from .rules import LayerWork, Work


@dataclass
class ModelCount:
    loihi: list[LoihiActivity] = field(default_factory=list)
    host_all: HostOps = field(default_factory=HostOps)
    extra: dict = field(default_factory=dict)
    work: Work | None = None           # what the inference computes, for the counting rules (rules.py)

    @property
    def host_hybrid(self) -> HostOps:
        """What stays on the host beside Loihi 2: rules.host_part of ``work`` (module doc)."""
        return rules.host_part(self.work) if self.work is not None else HostOps()


def counted_ofs_stage(inp: np.ndarray, p: LoihiOFSParams, act: LoihiActivity) -> tuple[np.ndarray, int]:
    """``run_ofs_fixed`` with its activity recorded. Returns (spikes (B, H, W), host LIF updates):
    an event-driven host implementation updates only neurons with input or non-zero state."""
    b, _c, h, w = inp.shape
    v = np.zeros((h, w), np.int64)
    o = np.zeros((h, w), bool)
    out = np.zeros((b, h, w), bool)
    host_updates = 0
    for t in range(b):
        s_in = inp[t] > 0
        syn = synop_count(s_in, p.kernel_size)
        live = (syn > 0) | (v != 0) | o
        v, o = lif_step(v, o, synaptic_input(s_in, p.weight), p)
        act.add_step(syn, live | o, o)
        host_updates += int(np.count_nonzero(live))
        out[t] = o
    return out, host_updates


def front_end_ops(raw_ones: int, pixels: int, support_radius: int | None) -> HostOps:
    """The host's input front end on a window, an upper bound of what events/support.py's one
    pass does: per raw one the first-spike test (a compare and a write); per event pixel the
    cluster filter's 8 neighbour reads and union-find (~10 int ops), and with temporal support
    the (2r + 1)^2 box sum of the history counts (as if every pixel were a dropped one) and the
    history update (add this window, subtract the one that leaves). The binning before it is
    counted apart (event_index_ops, sort_unique_ops)."""
    box = (2 * int(support_radius) + 1) ** 2 + 2 if support_radius is not None else 0
    return HostOps(add_int32=2 * raw_ones + (10 + box) * pixels,
                   sram_bytes=16 * raw_ones + (8 * 9 + 2 * box) * pixels)


def grouping_ops(stage_pixels: int, object_ones: int) -> HostOps:
    """Upper bound of the host's object grouping and OFPD input (runtime/ofpd_input.batch, one
    compiled call) on a window, from the stage frames' listed pixels (their listing is the
    rules' scan term): per stage pixel the 8 neighbour reads and union-find of link_components
    (~10 int ops, as front_end_ops' cluster filter) and its group's box and centroid sums (2);
    per object one (each bin and polarity) its crop cell's index (a multiply, 2 adds), the event
    plane's count and the motion planes' 6 integer sums. The planes written are the OFPD's
    input (count_toffe's ofpd term)."""
    return HostOps(add_int32=12 * stage_pixels + 8 * object_ones, mul_int32=object_ones,
                   sram_bytes=(8 * 9 + 16) * stage_pixels + 56 * object_ones)


def faint_ops(event_pixels: int, height: int, width: int) -> HostOps:
    """Upper bound of ofpd.faint_objects on a window (faint_objects.FaintDensity.step): the
    window's event pixels into the counts of the last L and K windows and as many leaving each
    (a compare, an add and the cell's add per pixel and ring: ~6 int ops, 2 + 16 bytes), then the
    whole search as if every window ran it (most stop after one pass over the cells): per cell
    its candidate test and four summed-area tables (~6 ops), per box its four box sums (~16)."""
    from ..faint_objects import BOX, CELL

    hc, wc = -(-int(height) // CELL), -(-int(width) // CELL)
    cells, boxes = hc * wc, max(0, hc - BOX + 1) * max(0, wc - BOX + 1)
    moved = 3 * int(event_pixels)                 # in, out of the L ring, out of the K ring
    return HostOps(add_int32=6 * moved + 6 * cells + 16 * boxes,
                   sram_bytes=18 * moved + 8 * 5 * cells + 8 * 16 * boxes)


#: the plane fit's and outline's bounds per object (time_surface.MAX_PLANES, plane_fit.IRLS_PASSES)
PLANES_MAX, IRLS_PASSES_COUNTED = 256, 4


def plane_fit_ops(objects_ones: list[int], objects_k: list[int], outline: bool) -> HostOps:
    """Upper bound of the plane fit over each object's K latest windows (time_surface.fuse_history)
    and of the position from its outline (outline_centre), per object with n ones this window
    and K windows: the surface filled from K x n ring entries (a compare and a write each, the
    window's n as the size of each), at most PLANES_MAX planes (9 reads, ~12 int and 6 float
    ops each), the IRLS's IRLS_PASSES_COUNTED weighted passes over them (~10 float ops per plane
    and pass) and, with the outline, one distance test per entry (~8 float ops)."""
    ops = HostOps()
    for n, k in zip(objects_ones, objects_k):
        scanned = int(k) * int(n)
        planes = min(PLANES_MAX, scanned)
        ops = ops + HostOps(add_int32=2 * scanned + 12 * planes, add_fp32=6 * planes + 10 * IRLS_PASSES_COUNTED * planes
                            + (8 * scanned if outline else 0),
                            sram_bytes=8 * scanned + 9 * 4 * planes + 16 * IRLS_PASSES_COUNTED * planes)
    return ops


def count_toffe(binned: np.ndarray, params: list[LoihiOFSParams], config: ToffeConfig,
                ofpd_macs: int, ofpd_in_elems: int, ofpd_params: int = 0,
                ofpd_activations: int = 0, ofpd_rows: int | None = None,
                raw: np.ndarray | None = None, objects: list | None = None) -> tuple[CascadeResult, ModelCount]:
    """Counts of one TOFFE inference: the cascade (recorded), masks, and one OFPD row (``ofpd_macs``
    MACs, weights read once, ``ofpd_activations`` outputs written and read, ``ofpd_in_elems``
    inputs) per object: ``ofpd_rows`` when the caller knows it (the objects the deployed pipeline
    reported for this window), else one per stage frame that ``ofpd_io.has_object`` accepts.

    ``raw``: the window's (B, 2, H, W) counts before the front end (``binned`` is after it): the
    binning is then counted on every event, as SpikeVolume.from_events bins them, and the front
    end on every one and pixel (front_end_ops), as DOTIE's count frames are counted on every
    event. ``objects``: the deployed pipeline's objects of this window (ObjectFlow: n_events,
    speed_px_s): the plane fit over their windows before and the outline positions, when the
    config has them, are counted as plane_fit_ops' bound."""
    mask_kernel = config.mask_kernel
    b, ch, h_s, w_s = binned.shape
    w, h = config.ofs_grid((w_s, h_s))             # the stages' grid (ofs_pool)
    n = len(params)
    acts = [LoihiActivity(h * w) for _ in range(n)]
    host_updates = [0] * n

    def stage(k: int, inp: np.ndarray) -> np.ndarray:
        spikes, upd = counted_ofs_stage(inp, params[k - 1], acts[k - 1])
        host_updates[k - 1] = upd
        return spikes

    res = run_cascade(binned, stage, n, mask_kernel, config.ofs_pool)
    ofpd_calls = int(has_object(np.stack(res.frames), config).sum()) if ofpd_rows is None else int(ofpd_rows)
    # Host side as the cpu target runs it (runtime/cpu.py): masks over the window's ones only,
    # closing only over the bounding box of the stage's spikes grown by the kernel.
    masks = HostOps()
    morph, mask_event = [], 0.0
    for k in range(n):
        ones = int(np.count_nonzero(res.inputs[k]))
        masks = masks + HostOps(op_int8=2 * ones, sram_bytes=10 * ones)
        mask_event += 2 * ones
        fired = res.spikes[k].any(axis=0)
        if fired.any():
            ys, xs = np.nonzero(fired)
            bh = min(int(ys.max() - ys.min()) + 1 + 2 * mask_kernel, h)
            bw = min(int(xs.max() - xs.min()) + 1 + 2 * mask_kernel, w)
            masks = masks + morphology_ops(bh, bw, mask_kernel, 2)
            morph.append((bh * bw, mask_kernel, 2))
    if config.ofs_pool > 1:
        # Pool_p: a cell index per sensor one and a sort-unique; Up_p: each stage's frame read
        # back per sensor one (runtime/pipeline.py, SpikeVolume.pool)
        sensor_ones = int(np.count_nonzero(binned))
        masks = masks + HostOps(op_int8=(1 + n) * sensor_ones, sram_bytes=(8 + n) * sensor_ones) + sort_unique_ops(sensor_ones)
        mask_event += (1 + n) * sensor_ones
    ofpd = (ann_ops(ofpd_macs, ofpd_params, ofpd_activations) + HostOps(sram_bytes=8 * ofpd_in_elems)).scaled(ofpd_calls)
    # the cpu target builds its window from the events (SpikeVolume.from_events: index, then
    # its sorted unique values), never scanning a dense volume
    n_raw = int(np.asarray(binned if raw is None else raw).sum())
    binarize = event_index_ops(n_raw) + sort_unique_ops(n_raw)
    extras = HostOps()                             # the host's own work on every target (Loihi's too)
    if raw is not None:                            # the front end
        raw_ones = np.asarray(raw) > 0
        support = config.input_support
        raw_pixels = int(np.count_nonzero(raw_ones.any(axis=(0, 1))))
        extras = extras + front_end_ops(int(np.count_nonzero(raw_ones)), raw_pixels,
                                        None if support is None else support[1])
        from ..faint_objects import faint_settings

        if faint_settings(config) is not None:             # the faint objects' density and search
            extras = extras + faint_ops(raw_pixels, *raw_ones.shape[-2:])
    if objects:
        from ..outline_centre import outline_settings
        from ..plane_fit import history_settings
        from ..time_surface import history_windows

        hist = history_settings(config)
        if hist is not None:
            ks = history_windows([o.speed_px_s / 1000.0 for o in objects], hist[0], hist[1], config.dt_us)
            extras = extras + plane_fit_ops([o.n_events for o in objects], ks, outline_settings(config) is not None)
    # the grouping over the stage frames' pixels, then each object's ones into the OFPD input
    stage_px = sum(int(np.count_nonzero(np.asarray(f).reshape(b, -1).any(axis=0))) for f in res.frames)
    object_ones = sum(int(o.n_events) for o in objects) if objects else int(sum(np.count_nonzero(f) for f in res.frames))
    extras = extras + grouping_ops(stage_px, object_ones)
    ofs_host = HostOps()
    for k in range(n):
        ofs_host = ofs_host + event_conv_ops(sum(acts[k].synops)) + fixed_lif_ops(host_updates[k])
    work = Work(frame_px=h * w, steps=b, channels=ch, input_events=n_raw,
                layers=[LayerWork(h * w, b, ch, params[k].kernel_size, float(sum(acts[k].synops)), float(host_updates[k]))
                        for k in range(n)],
                morph=morph, mask_event=mask_event, mask_dense=float(2 * n * b * ch * h * w),
                scan_event=float(stage_px), scan_dense=float(n * h_s * w_s),
                post=ofpd + sort_unique_ops(n_raw) + extras)
    mc = ModelCount(loihi=acts, host_all=binarize + extras + ofs_host + masks + ofpd,
                    extra={"ofpd_calls": ofpd_calls, "input_events": int(np.count_nonzero(binned)), "raw_events": n_raw},
                    work=work)
    return res, mc


def count_dotie(binned: np.ndarray, p: DotieParams = DotieParams()
                ) -> tuple[ModelCount, ModelCount, ModelCount, np.ndarray]:
    """Counts of one DOTIE inference without clustering, with clustering (per step, as its public
    code) and with one clustering per window (``dotie_detect_window``): dense conv + LIF as its
    public code runs them, per step the recovery of the fast events, and DBSCAN (``count_clustering``);
    what the baseline skips is not counted. Also returns the layer's spikes (B, H, W)."""
    b, ch, h, w = binned.shape
    trace = DotieLayerTrace()
    spikes, out = dotie_separate(binned, p, trace)
    x = np.asarray(binned).sum(axis=1)
    act = LoihiActivity(h * w)
    u_prev = np.zeros((h, w), np.float32)
    for t in range(b):
        syn = synop_count(x[t].astype(np.float32), p.weight.shape[0])
        live = (syn > 0) | (u_prev != 0) | spikes[t]
        act.add_step(syn, live, spikes[t])
        u_prev = trace.potentials[t]
    # dotie_frames: the events' indices, a zero-filled (B, H, W) uint16 count stack, one add per event
    n_raw = int(np.asarray(binned).sum())
    frames = event_index_ops(n_raw) + HostOps(add_int32=n_raw, sram_bytes=2 * b * h * w + 4 * n_raw)
    host_layer = frames + dense_conv_ops(h, w, 1, 1, 3, b) + dense_lif_ops(h * w, b)
    post = mask_ops(b * h * w)                       # any(S[t]) per step
    morph, mask_event = [], float(n_raw)
    reach = p.dilate_kernel + p.close_kernel        # how far Close(Dilate(S)) reaches from a spike
    for t in range(b):
        if spikes[t].any():                          # dilate + close (3 passes of 12x12), AND with x[t] > 0
            post = post + morphology_ops(h, w, p.dilate_kernel, 1) + morphology_ops(h, w, p.close_kernel, 2) \
                + mask_ops(3 * h * w)
            ys, xs = np.nonzero(spikes[t])
            box = (min(int(ys.max() - ys.min()) + 1 + 2 * reach, h) * min(int(xs.max() - xs.min()) + 1 + 2 * reach, w))
            morph += [(box, p.dilate_kernel, 1), (box, p.close_kernel, 2)]
    layer = LayerWork(h * w, b, 1, p.weight.shape[0], float(sum(act.synops)), float(sum(act.active)))
    work = Work(frame_px=h * w, steps=b, channels=1, input_events=n_raw, layers=[layer], morph=morph,
                mask_event=mask_event, mask_dense=float(4 * b * h * w))
    plain = ModelCount(loihi=[act], host_all=host_layer + post,
                       extra={"separated_px": int(out.sum()), "raw_events": n_raw}, work=work)
    cl = HostOps()
    totals = {"dbscan_points": 0, "dbscan_runs": 0, "dbscan_neighbour_pairs": 0, "boxes": 0}
    for t in range(b):
        ops, stats = count_clustering(out[t], p, scan=False)
        cl = cl + ops
        for k, v in stats.items():
            totals[k] += v
    scan = HostOps(op_int8=b * h * w, sram_bytes=b * h * w)     # its code's np.nonzero of every step's frame
    # the listing of the separated pixels is a rule's (scan_*): per pixel by the event rule (it
    # was a full-frame scan by both, 2 uJ of 7.5 by the event rule)
    cl_work = dataclasses.replace(work, post=work.post + cl, scan_event=float(out.sum()), scan_dense=float(b * h * w))
    cluster = ModelCount(loihi=[act], host_all=plain.host_all + scan + cl,
                         extra={"separated_px": int(out.sum()), "raw_events": n_raw, **totals}, work=cl_work)
    union = out.any(axis=0)
    window_ops, window_stats = count_clustering(union, p, scan=False)
    win_work = dataclasses.replace(work, post=work.post + window_ops, scan_event=float(union.sum()),
                                   scan_dense=float(h * w))
    window = ModelCount(loihi=[act], host_all=plain.host_all + HostOps(op_int8=out.size) + HostOps(
                            op_int8=h * w, sram_bytes=h * w) + window_ops,
                        extra={"separated_px": int(out.sum()), **window_stats},
                        work=win_work)
    return plain, cluster, window, spikes


def count_clustering(image: np.ndarray, p: DotieParams = DotieParams(), scan: bool = True) -> tuple[HostOps, dict]:
    """Operations of ``dotie_cluster`` on one (H, W) image: the scan for its pixels (unless
    ``scan`` is False: the counting rules price the listing themselves), then, from
    min_samples pixels on, DBSCAN with its neighbour pairs counted exactly (radius query) and
    the box filter. Returns (ops, {dbscan_points, dbscan_runs, dbscan_neighbour_pairs, boxes})."""
    ys, xs = np.nonzero(image)
    ops = HostOps(op_int8=image.size, sram_bytes=image.size) if scan else HostOps()   # np.nonzero's scan
    stats = {"dbscan_points": 0, "dbscan_runs": 0, "dbscan_neighbour_pairs": 0, "boxes": 0}
    if xs.shape[0] < p.min_samples:
        return ops, stats
    from sklearn.cluster import DBSCAN
    from sklearn.neighbors import NearestNeighbors

    pts = np.column_stack([xs, ys]).astype(np.float64)
    nbrs = NearestNeighbors(radius=p.eps).fit(pts).radius_neighbors(pts, return_distance=False)
    pairs = int(sum(len(a) for a in nbrs))
    labels = DBSCAN(eps=p.eps, min_samples=p.min_samples).fit(pts).labels_
    ops = ops + dbscan_ops(int(pts.shape[0]), pairs) + HostOps(add_fp32=4 * pts.shape[0], sram_bytes=16 * pts.shape[0])
    stats.update(dbscan_points=int(pts.shape[0]), dbscan_runs=1, dbscan_neighbour_pairs=pairs,
                 boxes=len(boxes_from_labels(pts, labels, p)))
    return ops, stats
