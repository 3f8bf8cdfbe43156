"""The models of the like-for-like benchmark (benchmarks/energy_latency.py, issue 14).

Each model family gives one ``BenchModel`` per optimisation level it has:

    reference  the authors' algorithm as plain numpy / OpenCV / scikit-learn / torch
    optimised  compiled and event driven, as TOFFE's cpu target

and each BenchModel gives, for window i of the benchmark's windows, the timed call ``run(i)``,
its object predictions (``predict(output)``, metrics.Prediction; None for a model that reports
no objects) and its counted ``Work`` (energy/rules.py) on the counted windows. A ratio is only
ever taken between two models of the same level. To add a baseline, add a factory
``fn(ctx: BenchContext) -> list[BenchModel]`` to ``FACTORIES``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np

from ..metrics import Prediction, predictions_of
from .dotie import Detection, DotieParams, dotie_detect_x, dotie_frames, dotie_separate_x

LEVELS = ("reference", "optimised")


@dataclass
class BenchContext:
    """What every factory may use: windows (t0, front-end binned (B, 2, H, W)), their events,
    the bundle and its config, the cpu Pipeline (or None), and the counted ModelCounts per
    family ("toffe", "dotie", "dotie_cluster"), index i = window i; ``supports``: with the
    config's input_support, window i's SupportHistory of the K windows before it (events/support.py);
    ``ones``: with plane_fit_history, window i's time_surface.OnesHistory before it."""

    windows: list
    events: list
    bundle: Any
    config: Any
    pipe: Any
    counts: dict = field(default_factory=dict)
    supports: list = field(default_factory=list)
    ones: list = field(default_factory=list)


@dataclass
class BenchModel:
    family: str                                  # the row group: toffe, dotie, dotie_cluster, ...
    level: str                                   # reference | optimised
    label: str
    run: Callable[[int], Any]
    predict: Callable[[Any], list[Prediction]] | None = None
    works: list | None = None                    # energy.rules.Work per counted window
    rule_ops: dict | None = None                 # or, for a model not made of Work: rule -> [HostOps per window]

    @property
    def key(self) -> str:
        return f"{self.family}@{self.level}"


def window_objects(steps: list[list[Detection]]) -> list[Prediction]:
    """One DOTIE window's objects from its per-step boxes: boxes that overlap (inclusive pixel
    bounds) across or within steps are one object, at the point-weighted mean of their centres.
    DOTIE reports no direction or speed (NaN) and no speed bin (stage 0)."""
    boxes = [d for s in steps for d in s]
    n = len(boxes)
    parent = list(range(n))

    def root(a):
        while parent[a] != a:
            parent[a] = parent[parent[a]]
            a = parent[a]
        return a

    for i in range(n):
        for j in range(i + 1, n):
            a, b = boxes[i], boxes[j]
            if a.x0 <= b.x1 and b.x0 <= a.x1 and a.y0 <= b.y1 and b.y0 <= a.y1:
                parent[root(i)] = root(j)
    groups: dict[int, list[Detection]] = {}
    for i in range(n):
        groups.setdefault(root(i), []).append(boxes[i])
    out = []
    for g in groups.values():
        w = float(sum(d.n_points for d in g))
        out.append(Prediction(0, sum(d.cx * d.n_points for d in g) / w, sum(d.cy * d.n_points for d in g) / w,
                              math.nan, math.nan, math.nan))
    return out


def dotie_models(ctx: BenchContext) -> list[BenchModel]:
    from .dotie_fast import FastDotie

    cfg = ctx.config
    dt, nb, size = cfg.dt_us, cfg.n_bins, tuple(cfg.sensor_size)
    p = DotieParams()
    t0s = [t0 for t0, _x in ctx.windows]
    ev = ctx.events
    fast = FastDotie(size, nb, dt, p)

    def works(fam):
        return [c.work for c in ctx.counts[fam]] if fam in ctx.counts else None

    return [
        BenchModel("dotie", "reference", "DOTIE w/o clustering (numpy + OpenCV, dense)",
                   lambda i: dotie_separate_x(dotie_frames(ev[i], t0s[i], dt, nb, size), p), None, works("dotie")),
        BenchModel("dotie", "optimised", "DOTIE w/o clustering (numba, event driven)",
                   lambda i: fast.separate(ev[i], t0s[i]), None, works("dotie")),
        BenchModel("dotie_cluster", "reference", "DOTIE with clustering (numpy + OpenCV + scikit-learn DBSCAN)",
                   lambda i: dotie_detect_x(dotie_frames(ev[i], t0s[i], dt, nb, size), p), window_objects,
                   works("dotie_cluster")),
        BenchModel("dotie_cluster", "optimised", "DOTIE with clustering (numba, event driven, grid DBSCAN)",
                   lambda i: fast.detect(ev[i], t0s[i]), window_objects, works("dotie_cluster")),
    ]


toffe_predictions = predictions_of          # TOFFE's reported objects, scored (metrics.predictions_of)


def toffe_models(ctx: BenchContext, stream: bool = True) -> list[BenchModel]:
    """TOFFE: reference = the numpy fixed-point cascade (model/reference.py, as `eval` runs it)
    with OFPD in onnxruntime; optimised = the deployed cpu Pipeline (numba, event driven).
    ``stream`` False: the optimised model starts every window from copies of its histories (the
    form its streaming is tested against)."""
    if ctx.pipe is None:
        return []
    import copy

    from ..events.binning import bin_window
    from ..events.support import front_end
    from ..model.reference import fixed_stage_fn, predict_window
    from ..runtime.spikes import SpikeVolume

    cfg = ctx.config
    dt, nb, size = cfg.dt_us, cfg.n_bins, tuple(cfg.sensor_size)
    t0s = [t0 for t0, _x in ctx.windows]
    ev = ctx.events
    stage = fixed_stage_fn(list(ctx.bundle.ofs))
    pipe = ctx.pipe

    def history(i):          # a copy: the front end adds window i to it, and a model runs a window many times
        return copy.deepcopy(ctx.supports[i]) if ctx.supports else None

    def run_ref(i):
        hist = history(i)
        binned = front_end(bin_window(ev[i], t0s[i], dt, nb, size, dtype=np.uint8), cfg, hist, t0s[i])
        ring = ctx.ones[i].after(t0s[i], binned) if ctx.ones else None   # the plane fit's windows, this one in
        return predict_window(binned, stage, pipe.ofpd.run, cfg, hist, ring)[0]

    ran = [-1]                   # the window run_opt ran last

    def run_opt(i):
        # Window i right after window i - 1, dt later, continues the Pipeline's own stream, as `run`
        # does: its histories then hold what window i's copies hold. Any other step (a block's first
        # window, a window after ones too sparse to list) starts from copies of window i's
        # histories. So a timed window pays no copy that `run` never makes (0.088 ms a window on
        # the shipped sample, measured; it counted against TOFFE, while DOTIE keeps no state).
        if not (stream and i > 0 and ran[0] == i - 1 and t0s[i] - t0s[i - 1] == dt):
            if ctx.ones:
                pipe.ones_history = copy.deepcopy(ctx.ones[i])
            if ctx.supports:
                pipe.support = history(i)
        ran[0] = i
        vol = SpikeVolume.from_events(ev[i], t0s[i], dt, nb, size)
        return list(pipe.process_stream([(t0s[i], vol)]))[0].objects

    w = [c.work for c in ctx.counts["toffe"]] if "toffe" in ctx.counts else None
    return [BenchModel("toffe", "reference", "TOFFE (numpy fixed-point cascade, onnxruntime OFPD)", run_ref,
                       lambda preds: preds, w),
            BenchModel("toffe", "optimised", "TOFFE (deployed cpu Pipeline: numba, event driven)", run_opt,
                       toffe_predictions, w)]


#: where benchmarks/train_asnet.py writes the Adaptive-SpikeNet (Pico) baseline
ASNET_DIR = Path(__file__).resolve().parents[2] / "ckpt" / "baselines" / "adaptive_spikenet"


def asnet_models(ctx: BenchContext, counted: int = 4) -> list[BenchModel]:
    """Adaptive-SpikeNet (Pico), its optical flow turned into object flow: reference = torch eager,
    optimised = ONNX Runtime (the same weights). Its cost is counted per layer (count_ops) by the
    same two rules: dense MACs, and spike-driven accumulates (rule_ops, on ``counted`` windows).
    No model when it has not been trained (``ASNET_DIR`` empty)."""
    if not (ASNET_DIR / "weights.safetensors").is_file():
        return []
    from ..energy.cost_model import HostOps
    from ..events.binning import bin_window
    from .adaptive_spikenet import AdaptiveSpikeNetBaseline

    cfg = ctx.config
    ref = AdaptiveSpikeNetBaseline.load(ASNET_DIR, cfg)
    opt = ref.optimised()
    t0s = [t0 for t0, _x in ctx.windows]
    ev = ctx.events
    ops = {"event": [], "dense": []}
    for i in range(min(counted, len(ev))):
        c = ref.op_counts(bin_window(ev[i], int(t0s[i]), cfg.dt_us, cfg.n_bins, tuple(cfg.sensor_size), dtype=np.uint8))
        ops["dense"].append(HostOps(**c["host_dense"]))
        ops["event"].append(HostOps(**c["host_event"]))
    return [BenchModel("asnet", "reference", "Adaptive-SpikeNet Pico (torch eager, flow -> objects)",
                       lambda i: ref.detect(ev[i], t0s[i]), lambda preds: preds, None, ops),
            BenchModel("asnet", "optimised", "Adaptive-SpikeNet Pico (ONNX Runtime, flow -> objects)",
                       lambda i: opt.detect(ev[i], t0s[i]), lambda preds: preds, None, ops)]


#: family -> factory; the benchmark builds every model of every factory.
FACTORIES: dict[str, Callable[[BenchContext], list[BenchModel]]] = {"dotie": dotie_models, "toffe": toffe_models,
                                                                   "asnet": asnet_models}


def build_models(ctx: BenchContext) -> list[BenchModel]:
    return [m for f in FACTORIES.values() for m in f(ctx)]
