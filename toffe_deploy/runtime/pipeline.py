"""The deployed TOFFE on a stream of windows: OFS cascade on a backend, OFPD in onnxruntime.

Per window [t0, t0 + dt) and speed bin k = N..1 (paper section "TOFFE Inference"):

    frames_k  = speed-separated event volume of stage k          (cascade, eq. 3-4)
    objects   = ofpd_io's grouping of the frames into objects (report_objects_xy: an object's
                speed bin is the fastest stage reporting it; object_masks_xy: its frame is the
                events of all stages in its region), then decode(OFPD(prepare_xy(merged_j)), k_j)
                for each object j -- the same coordinate core that ofpd_io's dense
                merge_frames / prepare (training, evaluation, export) run, called through
                runtime.ofpd_input on the window's event coordinates

with all objects of a window prepared and sent to OFPD in one batched session run.

Sensor size: the OFS is a convolution and OFPD sees a crop, so a bundle runs on any sensor: the
cascade (numpy or Lava processes) is built for the recording's ``sensor_size``, not the bundle's,
pooled to the bundle's OFS grid (``ofs_pool``: the stages see the window OR-pooled over p x p
blocks, and their frames come back to every sensor pixel; toffe_deploy/cascade.py).
Speeds: OFPD's speed is an image-plane speed; it is reported in px/s and in m/s through the run's
``SpeedScale`` (``speeds_of``): the bundle's camera by default, another depth / focal length on request.

Targets: ``cpu`` (fixed point, event driven, compiled loops; onnxruntime CPU; imports neither torch nor
Lava), ``cuda`` (the same cascade, OFPD on the CUDA/TensorRT provider), ``loihi-sim`` (the Lava
engineer's ``LavaCascade`` in Loihi2SimCfg) and ``loihi2`` (the same on Loihi2HwCfg). Every
backend's cascade result goes through the same frame -> OFPD code, so targets whose cascades are
bit exact report identical object flow.
"""
from __future__ import annotations

import collections
import math
from dataclasses import dataclass, field
from itertools import repeat
from typing import Any, Iterable, Iterator, Union

import numpy as np

from ..camera import SpeedScale
from ..config import MAX_SENSOR_PIXELS, ToffeConfig, sensor_too_large
from ..errors import InputError
from ..events.support import SupportHistory, front_end
from ..events.validate import whole_number
from ..events.support import warm_up as support_warm_up
from ..faint_objects import FaintDensity, faint_settings
from ..faint_objects import warm_up as faint_warm_up
from ..ofpd_io import Decoder, input_shape, ofpd_settings
from ..plane_fit import PlaneFusion, object_planes_flow
from ..plane_fit import warm_up as plane_fit_warm_up
from ..outline_centre import outline_positions, outline_settings
from ..outline_centre import warm_up as outline_warm_up
from ..time_surface import OnesHistory, fuse_history
from ..time_surface import warm_up as history_warm_up
from ..tracking import Tracker, TrackerConfig, TrackState, raw_detections
from . import ofpd_input
from ..compiled import warm_up
from ..events.frontend import slots_for
from .cpu import CpuCascade
from .ofpd_runner import OFPDRunner, providers_for
from .run_camera import resolve_camera
from .spikes import SpikeVolume
from .window_front import WindowFront
from .window_front import warm_up as window_front_warm_up

TARGETS = ("cpu", "cuda", "loihi-sim", "loihi2")
TAGS = ("fixed_pt", "floating_pt")
_NO_DETECTIONS = np.zeros(0)       # a window without objects, for the tracker (tracking.raw_detections' columns)

Window = Union[np.ndarray, SpikeVolume]
"""A window as a dense binned (B, 2, H, W) array (nonzero = event) or as a SpikeVolume."""


@dataclass
class ObjectFlow:
    """One object in one window: speed bin k (ofpd.bin_from: the bin of the OFPD's regressed
    speed, or the OFS stage that separated it), ofs_bin (that stage: the fastest OFS that fired
    on the object), speed (m/s, regressed; within the stage's bin for bin_from "ofs";
    speed_bin_mps is the paper's bin-only estimate of speed_bin; both through the
    run's SpeedScale), the same regressed speed on the image plane (speed_px_s, px/s: what the
    camera measured, independent of depth and focal length), centre (x, y) in sensor pixels,
    direction of motion in rad (image plane, y down: atan2(dy, dx)) and the number of event ones
    (bin, polarity, pixel) in its speed-separated frame; speed_clipped: the regressed speed lay
    outside the range decode clips it to (it is reported at the bound); track_id and track: its
    track and the track's smoothed state (tracking.Tracker; None without a tracker)."""

    speed_bin: int
    ofs_bin: int
    speed_mps: float
    speed_bin_mps: float
    speed_px_s: float
    x: float
    y: float
    direction_rad: float
    n_events: int
    speed_clipped: bool = False
    track_id: int | None = None
    track: Any = None        # tracking.TrackState (a read-only mapping) or None
    faint: bool = False      # found by ofpd.faint_objects (position only: bin 1's speed, a rough direction)

    @property
    def direction_deg(self) -> float:
        return math.degrees(self.direction_rad)

    def to_json(self) -> dict:
        """The JSON line's object: the fields in order, direction_deg after n_events, then
        speed_clipped, track_id and track where not None; floats to 4 decimals (_json_float). Built field by
        field: dataclasses.asdict (recursion, a deepcopy per field) cost ~25 us an object, the
        most of what `run` spent outside the pipeline."""
        d = {"speed_bin": self.speed_bin, "ofs_bin": self.ofs_bin, "speed_mps": self.speed_mps,
             "speed_bin_mps": self.speed_bin_mps, "speed_px_s": self.speed_px_s, "x": self.x, "y": self.y,
             "direction_rad": self.direction_rad, "n_events": self.n_events, "direction_deg": self.direction_deg}
        if self.speed_clipped is not None:
            d["speed_clipped"] = self.speed_clipped
        if self.faint:
            d["faint"] = True
        if self.track_id is not None:
            d["track_id"] = self.track_id
        out = {k: (_json_float(v) if isinstance(v, float) else v) for k, v in d.items()}
        if self.track is not None:
            out["track"] = _track_dict(self.track)
        return out


@dataclass
class WindowResult:
    """Object flow of window [t0_us, t1_us)."""

    t0_us: int
    t1_us: int
    objects: list[ObjectFlow] = field(default_factory=list)
    cascade: Any = None      # Lava targets: the window's CascadeResult (bridge traffic, runtime/traffic.py)
    stages: Any = None       # Pipeline(keep_stages=True): (stage_input (N, B, 2, H, W), stage_output (N, B, H, W)) bool
    coasting: list | None = None   # with a tracker: confirmed tracks not seen this window (Tracker.coasting)

    def to_json(self) -> dict:
        out = {"t0_us": int(self.t0_us), "t1_us": int(self.t1_us), "objects": [o.to_json() for o in self.objects]}
        if self.coasting is not None:
            out["coasting"] = [{"track_id": c["track_id"], "track": _track_dict(c["track"])} for c in self.coasting]
        return out


def _json_float(v: float) -> float:
    """A float of the JSON line: 4 decimals, or 4 significant digits where 4 decimals would write
    a non-zero value as 0.0 (a camera with a tiny metres-per-pixel scale gives speeds of 1e-5
    m/s: those stay readable, every other value is written as before)."""
    r = round(v, 4)
    return float(f"{v:.4g}") if r == 0.0 and v != 0.0 and math.isfinite(v) else r


def _track_dict(track) -> dict:
    """A track state as a new dict: TrackState.to_dict, or dict() of any other mapping."""
    return track.to_dict() if isinstance(track, TrackState) else dict(track)


def ofpd_model(bundle, variant: str = "fp32"):
    """The bundle's OFPD ONNX file for a variant: fp32 (the reference), or fp16 / int8 when the
    bundle was exported with ``--variants`` (smaller and faster on edge GPUs / CPUs)."""
    from ..deploy.onnx_export import VARIANTS

    if variant == "fp32":
        return bundle.ofpd_onnx
    if variant not in VARIANTS:
        raise ValueError(f"unknown OFPD variant {variant!r}; choose one of fp32, {', '.join(VARIANTS)}")
    path = getattr(bundle, "ofpd_variants", {}).get(variant)
    if path is None:
        raise InputError(bundle.root, f"bundle has no {variant} OFPD variant (re-export with "
                                      f"`toffe-deploy export CKPT --variants {variant}`, or use the fp32 model)")
    return path


def speeds_of(dec: dict, config: ToffeConfig, scale: SpeedScale) -> tuple[list, list, list]:
    """(px/ms, m/s, bin-only m/s) lists of decoded OFPD rows, m/s through the run's ``scale``.

    The image-plane speed is decode's ``speed_px_ms`` when it gives one, else its ``speed_mps``
    taken back to px/ms with the bundle's camera (``config.speed_scale``, what the m/s were
    stated for); the bin's representative speed goes the same way. Scalar factors on lists, not
    SpeedScale calls on arrays: a window has a handful of objects and this is the cpu hot path."""
    k_bundle = config.focal_px / (1000.0 * config.depth_m)       # px/ms per m/s, config.speed_scale
    k_run = scale.px_ms_per_mps
    px_ms = dec.get("speed_px_ms")
    px_ms = [v * k_bundle for v in _floats(dec["speed_mps"])] if px_ms is None else _floats(px_ms)
    ratio = k_bundle / k_run
    return px_ms, [v / k_run for v in px_ms], [v * ratio for v in _floats(dec["speed_bin_mps"])]


def _floats(a) -> list:
    """A decoded column as a list of floats (Decoder.columns gives lists, decode arrays)."""
    return a if isinstance(a, list) else np.asarray(a, dtype=np.float64).tolist()


def sensor_frames(cascade: CpuCascade, volume: SpikeVolume, pool: int) -> list[np.ndarray]:
    """The stage frames of one window as masks over ``volume.idx`` (its sensor-grid ones), from a
    cpu cascade built for the OFS grid (ToffeConfig.ofs_grid) that the window is pooled to."""
    grid, inverse = volume.pool(pool)
    return up_frames(cascade.cascade_sparse(grid).frames, inverse)


def up_frames(frames, inverse: np.ndarray | None):
    """Stage frames as masks over the OFS grid's ones -> over the sensor ones (Up_p; cascade.py):
    each sensor one takes its cell's value. The cpu cascade's (N, n) array stays one array."""
    if inverse is None:
        return frames
    if isinstance(frames, np.ndarray):
        return frames.take(inverse, axis=1)      # = frames[:, inverse], ~4x faster than 2-d fancy indexing
    return [np.asarray(f)[inverse] for f in frames]


def _make_cascade(bundle, target: str, tag: str, sensor_size: tuple[int, int]):
    cfg = bundle.config
    if target in ("cpu", "cuda"):
        if tag != "fixed_pt":
            raise ValueError(f"target {target} runs the fixed-point OFS only (tag fixed_pt), not {tag}")
        return CpuCascade(bundle.ofs, cfg.n_bins, cfg.mask_kernel, sensor_size)
    from .loihi import LavaCascade   # Lava only for the Loihi targets

    return LavaCascade(params=bundle.ofs, n_bins=cfg.n_bins, mask_kernel=cfg.mask_kernel,
                       sensor_size=sensor_size, tag=tag, hardware=(target == "loihi2"))


class Pipeline:
    """``Pipeline(bundle, target)``: a context manager whose ``process_stream`` turns
    (t0_us, window) pairs into ``WindowResult``s, in order. Entering starts the backend (the Lava
    runtime for loihi targets); leaving stops it, also on errors and Ctrl-C.

    ``sensor_size`` (width, height): the recording's sensor (default: the bundle's); ``speed_scale``:
    the camera the reported m/s assume (default: `run`'s rule, run_camera.resolve_camera: the
    bundle's ``config.speed_scale`` on a sensor as wide as the bundle's, else the bundle's
    horizontal field of view spread over the sensor's width, at the bundle's depth).
    ``track``: follow objects over the windows (toffe_deploy.tracking; True: default settings, a
    TrackerConfig, or False): each ObjectFlow gets ``track_id`` and ``track``; the tracks live as
    long as the Pipeline, over every ``process_stream`` call (``reset_tracks`` starts afresh)."""

    def __init__(self, bundle, target: str = "cpu", tag: str = "fixed_pt", ofpd_threads: int | None = 1,
                 ofpd_variant: str = "fp32", sensor_size: tuple[int, int] | None = None,
                 speed_scale: SpeedScale | None = None, keep_stages: bool = False,
                 track: "bool | TrackerConfig" = True, processes: int = 1):
        """keep_stages: each WindowResult also carries the masked input and the output spikes of
        every OFS stage as dense arrays (``stages``; for `run --dump-spikes`: about 18 MB per
        640x480 window, so for short runs only). processes: 2 runs the front end, the cascade,
        the grouping and the OFPD of the next window in a second process while this one runs
        what follows (cpu and cuda targets; runtime/split.py), bit exact with 1."""
        if target not in TARGETS:
            raise ValueError(f"unknown target {target!r}; choose one of {', '.join(TARGETS)}")
        if tag not in TAGS:
            raise ValueError(f"unknown tag {tag!r}; choose one of {', '.join(TAGS)}")
        if not (isinstance(track, (bool, np.bool_, TrackerConfig)) or track is None):
            raise ValueError(f"track must be True, False or a TrackerConfig, got {track!r}")
        if processes not in (1, 2) or isinstance(processes, bool):
            raise ValueError(f"processes must be 1 or 2, got {processes!r}")
        if processes == 2 and (target not in ("cpu", "cuda") or keep_stages):
            raise ValueError("processes=2 splits the host steps of the cpu and cuda targets (not the Lava "
                             "targets, and not with keep_stages / --dump-spikes)")
        self.processes = int(processes)
        self._split = None
        #: which half of the host steps this process runs, for the kernels its __enter__ loads:
        #: "all"; "back" (run's process with processes=2: binning, plane fit, faint objects,
        #: tracker); "front" (split.py's worker: front end, cascade, grouping; it sets it)
        self.half = "back" if self.processes == 2 else "all"
        if speed_scale is not None and not isinstance(speed_scale, SpeedScale):
            raise ValueError(f"speed_scale must be a toffe_deploy.camera.SpeedScale(focal_px, depth_m), got {speed_scale!r}")
        if not hasattr(bundle, "config"):              # a bundle's directory, as FlowStream takes
            from ..deploy.bundle import load_bundle
            bundle = load_bundle(bundle)
        self.bundle = bundle
        self.config = bundle.config
        self.target = target
        self.tag = tag
        self.ofpd_variant, self.ofpd_threads = ofpd_variant, ofpd_threads     # (split.py's worker builds the same)
        provider = "cuda" if target == "cuda" else "cpu"
        if processes == 2 and provider == "cuda":     # the OFPD runs in split.py's worker: a CPU session
            providers_for(provider)                   # here checks the model (no second CUDA context), and
            provider = "cpu"                          # a missing CUDA provider is said here, not there
        self.ofpd = OFPDRunner(ofpd_model(bundle, ofpd_variant), provider, threads=ofpd_threads)
        size = self.config.sensor_size if sensor_size is None else sensor_size
        try:
            w, h = (whole_number("sensor size", v) for v in size)
        except (TypeError, ValueError):
            raise ValueError(f"sensor size must be (width, height), each a whole number of px, got {sensor_size!r}") from None
        self.sensor_size = (w, h)
        if min(self.sensor_size) < 1:
            raise ValueError(f"sensor size must be positive, got {self.sensor_size}")
        if w * h > MAX_SENSOR_PIXELS:
            raise ValueError(sensor_too_large(self.sensor_size))
        want = input_shape(self.config)
        if tuple(self.ofpd.input_shape) != tuple(want):     # n_bins, motion planes or crop edited apart from the model
            raise InputError(self.ofpd.path, f"the OFPD takes input {tuple(self.ofpd.input_shape)} (C, h, w) but the "
                                             f"bundle's config.json makes {tuple(want)}: they do not belong together")
        # run's camera rule (run_camera.resolve_camera): the bundle's focal length on a sensor as
        # wide as the bundle's, else the bundle's field of view over this sensor's width
        self.speed_scale = resolve_camera(self.config, self.sensor_size).scale if speed_scale is None else speed_scale
        self.cascade = _make_cascade(bundle, target, tag, self.config.ofs_grid(self.sensor_size))
        self.keep_stages = bool(keep_stages)
        self._decode = Decoder(self.config)          # ofpd_io.decode, set up once
        self._batch = ofpd_input.batch_settings(self.config)   # the same for ofpd_input.batch
        self._fusion = PlaneFusion(self.config)
        self._track = bool(track) if isinstance(track, np.bool_) else track
        self.support = (SupportHistory(self.config.input_support[0], self.sensor_size, self.config.dt_us)
                        if self.config.input_support is not None else None)   # the front end's windows before
        h = self._fusion.history
        self._outline = outline_settings(self.config)        # a slow object's position from its outline
        self.ones_history = (OnesHistory(h[1], self.sensor_size, self.config.n_bins, self.config.dt_us)
                             if h is not None and (self._fusion.on or self._outline is not None)
                             else None)   # the plane fit's windows (time_surface), also the outline's
        faint = faint_settings(self.config)                  # faint slow objects from the windows' density
        self.faint = FaintDensity(faint, self.sensor_size, self.config.dt_us) if faint is not None else None
        #: the fast path's steps before the OFPD in one compiled call (runtime/window_front.py), or None
        self._window_front = WindowFront(self) if WindowFront.applies(self) else None
        self.reset_tracks()
        self._entered = False

    def reset_tracks(self) -> None:
        """Forget every track (a new recording, or a jump in time); ids start again at 0. The
        front end's windows before (``input_support``) are forgotten too."""
        if self.support is not None:
            self.support.reset()
        if self.ones_history is not None:
            self.ones_history.reset()
        if self.faint is not None:
            self.faint.reset()
        if getattr(self, "_split", None) is not None:
            self._split.reset()                  # the front end's history lives in the second process
                                                 # (refused inside a stream: windows ahead went through it)
        settings = self._track if isinstance(self._track, TrackerConfig) else None
        self.tracker = (Tracker(self.config, self.config.dt_us, settings, self.speed_scale.px_ms_per_mps)
                        if self._track is not False and self._track is not None else None)

    def _result(self, t0: int, volume: SpikeVolume, frames, recent=None, pixels=None, **kw) -> "WindowResult":
        """The WindowResult of window t0 (its objects tracked, with the tracker's coasting list);
        recent: the front end's history after it (objects_of); pixels: the window's event pixels
        before the front end (ofpd.faint_objects). Windows come here in time order on every
        target, so the plane fit's history and the faint objects' density take this window here."""
        return self._result_of_batch(t0, volume, self.batch(volume, frames, recent), pixels, **kw)

    def batch(self, volume: SpikeVolume, frames, recent=None) -> tuple:
        """ofpd_input.batch of a window's ones and stage frames with this Pipeline's settings:
        (stage_k, OFPD input, n_events, ones) of its objects (what objects_of runs first)."""
        return ofpd_input.batch(volume, frames, self.config, self._scratch, recent, self._batch)

    def _result_of_batch(self, t0: int, volume: SpikeVolume, batch: tuple, pixels=None, ofpd_out=None,
                         **kw) -> "WindowResult":
        """_result from the window's ``batch`` (Pipeline.batch): the OFPD (or its output
        ``ofpd_out``, where the batch's OFPD input stayed in split.py's second process), the plane
        fit, the faint objects and the tracker, in window order."""
        if self.ones_history is not None:
            self.ones_history.push(t0, volume.idx, (volume.bc, volume.pix))
        tracker = self.tracker
        t_track, faint = None if tracker is None else t0, None if self.faint is None else (t0, pixels)
        ks, x, n_events, ones = batch
        objects = (self.objects_of_batch(ks, x, n_events, ones, t_track, faint) if ofpd_out is None else
                   self.objects_of_ofpd(ks, ofpd_out, n_events, ones, t_track, faint))
        return WindowResult(t0, t0 + self.config.dt_us, objects,
                            coasting=None if tracker is None else tracker.coasting(), **kw)

    @property
    def fast_path(self) -> bool:
        """The cpu and cuda targets' fast path: a sparse target, a pooled OFS grid, grouping
        "blobs" (ofpd_settings, worked out once in __init__) and no kept stages."""
        return (self.sparse and self.config.ofs_pool > 1 and not self.keep_stages
                and self._batch[0]["grouping"] == "blobs")

    def warm_groups(self):
        """The compiled.warm_up groups this Pipeline's windows call (None: all of them). The cpu
        and cuda targets' fast path (pooled OFS grid, "blobs" grouping, no kept stages) calls the
        binning, the front end, pooled_cascade and one form of window_objects: loading only those
        halves start-up (~1.6 -> ~0.7 s); every other path loads all, as before. With temporal
        support the last three are one kernel, runtime/window_front.py's (its own warm-up): the
        binning alone here."""
        if not self.fast_path:
            return None
        if self._window_front is not None:
            return ("binning",)
        recent = self.support is not None and self._batch[0].get("recent_events") is not None
        return ("binning", "front_end", "pooled", "objects_recent" if recent else "objects")

    def __enter__(self) -> "Pipeline":
        if self.processes == 2:
            from .split import SplitHost

            self._split = SplitHost(self)        # it loads its kernels while this process loads its own
        try:
            return self._enter()
        except BaseException:
            if self._split is not None:
                self._split.close()
                self._split = None
            raise

    def _enter(self) -> "Pipeline":
        groups = self.warm_groups()
        half = self.half
        if half == "back" and groups is not None:
            groups = ("binning",)                # the rest of the fast path runs in the second process
        if isinstance(self.cascade, CpuCascade):
            self.cascade.warm_groups = groups   # its __enter__ below loads them (once, not here and there)
        else:
            warm_up(groups)          # the compiled kernels (every target de-duplicates pixels with them)
        if self.support is not None and half != "back":
            support_warm_up()
        if self._window_front is not None and half != "back":
            window_front_warm_up(self._window_front.recent)
        if half != "front":                  # the steps after the OFPD
            if self.ones_history is not None:
                history_warm_up()
            elif self._fusion.on:            # the one-window plane fit
                plane_fit_warm_up()
            if self._outline is not None:
                outline_warm_up()
            if self.faint is not None:
                faint_warm_up()
        self.cascade.__enter__()
        if self._split is not None:
            try:
                self._split.wait_ready()
            except BaseException:
                self.cascade.__exit__(None, None, None)
                raise
        self._entered = True
        return self

    def __exit__(self, *exc) -> None:
        if self._entered:
            self._entered = False
            try:
                if self._split is not None:
                    self._split.close()
                    self._split = None
            finally:
                self.cascade.__exit__(*exc)

    def close(self) -> None:
        self.__exit__(None, None, None)

    @property
    def _scratch(self) -> np.ndarray:
        """The all -1 (H * W,) scratch of ofpd_input's O(n) de-duplication: the front end's own
        (events.frontend.slots_for, this thread's; the kernels leave it all -1), so that the
        grouping's lookups land on the cache lines the front end touched at the same pixels
        (~3 us a window less than a scratch of its own, measured in-process on the sample)."""
        return slots_for(self.sensor_size[0] * self.sensor_size[1])

    @property
    def sparse(self) -> bool:
        """Whether the backend takes windows as coordinates (cpu, cuda) or dense (Lava)."""
        return isinstance(self.cascade, CpuCascade)

    def _check(self, x: Window) -> Window:
        """``x`` (a SpikeVolume, or an array-like made an array) when it has the window's shape
        (B, 2, H, W); a dense one's values are event counts (nonzero = event): a negative or
        non-finite value, or values that are no numbers, are a ValueError, not dropped."""
        if not isinstance(x, SpikeVolume):
            x = np.asarray(x)
            if x.dtype.kind not in "biuf":
                raise ValueError(f"window values must be event counts or 0/1 (bool, int or float), got dtype {x.dtype}")
            if x.dtype.kind in "if" and x.size and (x.min() < 0 or x.dtype.kind == "f" and not np.isfinite(x).all()):
                raise ValueError("window values must be event counts >= 0 (nonzero = event; polarity is the channel, "
                                 "not the sign), got a negative or non-finite value")
        w, h = self.sensor_size
        want = (self.config.n_bins, 2, h, w)
        if tuple(x.shape) != want:
            raise ValueError(f"window must be {want} (B, 2, H, W), got {tuple(x.shape)}")
        return x

    def objects_of(self, volume: SpikeVolume, frames: list[np.ndarray], t0_us: int | None = None,
                   recent=None, faint=None) -> list[ObjectFlow]:
        """Object flow of one window from its ones and its stage frames (bool masks over
        volume.idx, index k - 1): ofpd_io's object grouping, then one batched OFPD call. t0_us
        (with a tracker): the window's start; the objects come back tracked (the tracker takes
        the decoded columns, and ids and states go into the objects' constructor: reading the
        fields back off the objects and setting them afterwards cost more than the tracking).
        recent: the front end's SupportHistory after this window (ofpd.recent_events). faint:
        (t0, the window's event pixels before the front end) for ofpd.faint_objects (this
        window's faint slow objects follow the others; toffe_deploy/faint_objects.py)."""
        return self.objects_of_batch(*self.batch(volume, frames, recent), t0_us, faint=faint)

    def objects_of_batch(self, ks: np.ndarray, x: np.ndarray, n_events: np.ndarray, ones: tuple,
                         t0_us: int | None = None, faint=None) -> list[ObjectFlow]:
        """objects_of from the window's batch (Pipeline.batch): the OFPD call and what follows it."""
        return self.objects_of_ofpd(ks, self.ofpd.run(x) if ks.size else None, n_events, ones, t0_us, faint)

    def objects_of_ofpd(self, ks: np.ndarray, out, n_events: np.ndarray, ones: tuple,
                        t0_us: int | None = None, faint=None) -> list[ObjectFlow]:
        """objects_of_batch from the OFPD's (pose, direction, speed) ``out`` of the batch."""
        if not ks.size:
            fx = self._faint_columns(faint, ones, [], [], [])
            if fx is None:
                if t0_us is not None:
                    self.tracker.columns(_NO_DETECTIONS, t0_us)
                return []
            return self._with_faint([], fx, t0_us)
        pose, direction, speed = out
        speed, direction = self.fuse(speed, direction, ones, ks.size)          # plane_fit
        dec = self.place(self._decode.columns(pose, direction, speed, ks), ones)   # lists: no numpy scalar per field
        px_ms, mps, bin_mps = speeds_of(dec, self.config, self.speed_scale)
        px_s = [v * 1000.0 for v in px_ms]
        fx = self._faint_columns(faint, ones, dec["speed_bin"], dec["x_px"], dec["y_px"])
        n_events = n_events.tolist()
        # track_id and track per object; the tracker takes raw_detections' columns: x, y, direction_rad, speed_px_s,
        # bin, n_events (with faint objects, _with_faint tracks them all)
        ids, states = ((repeat(None), repeat(None)) if t0_us is None or fx is not None else self.tracker.columns(
            np.array([*dec["x_px"], *dec["y_px"], *dec["direction_rad"], *px_s, *dec["speed_bin"], *n_events],
                     np.float64), t0_us))
        objects = [ObjectFlow(sb, k, v, vb, v_px, cx, cy, d, n, c, tid, st)
                   for sb, k, v, vb, v_px, cx, cy, d, n, c, tid, st in zip(
                       dec["speed_bin"], ks.tolist(), mps, bin_mps, px_s, dec["x_px"], dec["y_px"], dec["direction_rad"],
                       n_events, dec["speed_clipped"], ids, states)]
        return objects if fx is None else self._with_faint(objects, fx, t0_us)

    def _faint_columns(self, faint, ones, bins, xs, ys):
        """This window's faint objects (x, y, direction, n_events arrays) when ofpd.faint_objects
        is on and found any, else None (the window is added to the density either way)."""
        if faint is None:
            return None
        t0, pixels = faint
        fx = self.faint.step(t0, np.zeros(0, np.int64) if pixels is None else pixels, ones, bins, xs, ys)
        return fx if fx[0].size else None

    def _with_faint(self, objects: list, fx, t0_us) -> list[ObjectFlow]:
        """``objects`` with the faint ones appended (speed bin 1 at its representative speed, the
        density's drift as direction, ``faint`` true), all tracked when t0_us is given (a faint
        object's position only: its direction goes to the tracker as NaN, tracking.Detections)."""
        rep = [float(self.config.representative_speeds[0])]
        (px_ms,), (mps,), (bin_mps,) = speeds_of({"speed_mps": rep, "speed_bin_mps": rep}, self.config, self.speed_scale)
        for x, y, d, n in zip(*(a.tolist() for a in fx)):
            objects.append(ObjectFlow(1, 1, mps, bin_mps, px_ms * 1000.0, x, y, d, int(round(n)), False, faint=True))
        if t0_us is not None:
            ids, states = self.tracker.columns(raw_detections(objects), t0_us)
            for o, tid, st in zip(objects, ids, states):
                o.track_id, o.track = tid, st
        return objects

    def place(self, dec: dict, ones) -> dict:
        """Decoded columns ``dec`` with slow objects' positions from their outlines over the
        windows before (ofpd.outline_centre; toffe_deploy/outline_centre.py), or as they are."""
        if self._outline is not None:
            x, y = outline_positions(self._outline, self.ones_history, ones, dec["x_px"], dec["y_px"],
                                     dec["speed_px_ms"], dec["direction_rad"], self.config.dt_us)
            dec["x_px"], dec["y_px"] = x.tolist(), y.tolist()
        return dec

    def fuse(self, speed, direction, ones, n_obj: int):
        """The OFPD's (speed, direction) with the plane fit blended in (plane_fit.PlaneFusion.apply):
        over each object's time surface of its K latest windows (time_surface.fuse_history, one
        compiled call) or over its ones of this window (object_planes_flow)."""
        if self.ones_history is not None:
            return fuse_history(self._fusion, self.ones_history, speed, direction, ones)
        return self._fusion.apply(speed, direction, lambda want, _k: object_planes_flow(*ones, n_obj, want))

    def front(self, t0: int, x: Window) -> tuple:
        """The host's first steps on one raw window of a sparse target (cpu, cuda), in time order:
        (volume after the front end, stage frames over its ones, the dense stages with
        keep_stages else None, the window's event pixels before the front end for the faint
        objects else None). Moves the front end's history (``self.support``) on."""
        x = self._check(x)
        vol = x if isinstance(x, SpikeVolume) else SpikeVolume.from_dense(x > 0)
        vol = front_end(vol, self.config, self.support, int(t0))
        pixels = self.support.latest_pixels if self.faint is not None else None
        pool = self.config.ofs_pool
        if pool > 1 and not self.keep_stages:       # pool, cascade and Up_p in one compiled call
            return vol, self.cascade.pooled_frames(vol, pool), None, pixels
        grid, inverse = vol.pool(pool)               # the OFS grid (cascade.py)
        res = self.cascade.cascade_sparse(grid)
        stages = _stage_arrays(res.to_dense()) if self.keep_stages else None
        return vol, up_frames(res.frames, inverse), stages, pixels

    def front_batch(self, t0: int, x: Window) -> tuple:
        """``front`` then ``batch`` of one raw window of a sparse target: (volume after the front
        end, batch (stage_k, OFPD input, n_events, ones), the dense stages with keep_stages else
        None, the window's event pixels before the front end for the faint objects else None).
        On the fast path one compiled call (runtime/window_front.py), the same bits."""
        if self._window_front is None:
            vol, frames, stages, pixels = self.front(t0, x)
            return vol, self.batch(vol, frames, self.support), stages, pixels
        x = self._check(x)
        vol, batch, pixels = self._window_front(int(t0), x if isinstance(x, SpikeVolume) else
                                                SpikeVolume.from_dense(x > 0), self.support)
        return vol, batch, None, pixels if self.faint is not None else None

    def process_stream(self, windows: Iterable[tuple[int, Window]]) -> Iterator[WindowResult]:
        """(t0_us, window) pairs in, WindowResult per window out, in order, streaming. Windows are
        raw (the front end runs here); with ``input_support`` they come in time order, and the
        Pipeline keeps the windows before over calls (``self.support``: a gap resets it). The
        lower-level form: t0_us is taken as given, its order not checked (api.FlowStream checks
        it, and cuts events into windows)."""
        if not self._entered:
            with self:
                yield from self.process_stream(windows)
            return
        cfg, hist = self.config, self.support
        pool = self.config.ofs_pool
        if self.sparse:
            if self._split is not None:
                yield from self._split.stream(self, _pairs(windows))
                return
            for t0, x in _pairs(windows):
                t0 = int(t0)
                vol, batch, stages, pixels = self.front_batch(t0, x)
                yield self._result_of_batch(t0, vol, batch, pixels, stages=stages)
            return
        # Lava backends take dense windows and may pipeline them: remember each window's t0 (and,
        # for ofpd.recent_events, a copy of the front end's history after it: the next windows move it on).
        starts: collections.deque = collections.deque()
        keep_recent = hist is not None and ofpd_settings(cfg).get("recent_events") is not None

        def dense():
            for t0, x in _pairs(windows):
                x = self._check(x)
                vol = (front_end(x, cfg, hist, int(t0)) if isinstance(x, SpikeVolume)
                       else SpikeVolume.from_dense(front_end(x, cfg, hist, int(t0))))
                grid, inverse = vol.pool(pool)               # the OFS grid (cascade.py)
                starts.append((int(t0), vol, grid, inverse, hist.latest() if keep_recent else None,
                               hist.latest_pixels if self.faint is not None else None))
                yield grid.to_dense(np.uint8)

        for res in self.cascade.cascade_stream(dense()):
            t0, vol, grid, inverse, recent, pixels = starts.popleft()
            frames = up_frames([np.asarray(f).reshape(-1)[grid.idx] for f in res.frames], inverse)
            yield self._result(t0, vol, frames, recent, pixels, cascade=res,
                               stages=_stage_arrays(res) if self.keep_stages else None)


def _pairs(windows: Iterable) -> Iterator[tuple]:
    """process_stream's items as (t0_us, window) pairs: a bare window is a one-line ValueError
    (unpacking it said "too many values to unpack")."""
    for item in windows:
        if not (isinstance(item, (tuple, list)) and len(item) == 2):
            raise ValueError(f"Pipeline.process_stream takes (t0_us, window) pairs, got a {type(item).__name__}"
                             + (f" of shape {item.shape}" if hasattr(item, "shape") else ""))
        yield item


def _stage_arrays(res) -> tuple[np.ndarray, np.ndarray]:
    """(stage_input (N, B, 2, H, W), stage_output (N, B, H, W)) bool of a dense CascadeResult,
    index k - 1 = OFS_k: what `run --dump-spikes` writes."""
    return (np.stack([np.asarray(x) > 0 for x in res.inputs]),
            np.stack([np.asarray(s) > 0 for s in res.spikes]))
