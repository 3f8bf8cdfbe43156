"""The TOFFE configuration carried by a checkpoint (config.json) and by a deploy bundle.

Speed bins follow the paper's Table "Speed ranges for the four speed bins" (m/s):
1: 1-18, 2: 18-42, 3: 42-84, 4: 84-500 (max programmed object speed 144 m/s).
What the network separates is image-plane speed: the bins in m/s hold for an object at
``depth_m`` seen with ``focal_px`` (camera.SpeedScale); ``speed_bins_px_ms`` are the same bins
in px/ms, the camera-independent statement.
"""
from __future__ import annotations

import dataclasses
import math
import os
from dataclasses import dataclass, field
from typing import Any

from .camera import REFERENCE_DEPTH_M, REFERENCE_FOCAL_PX, SpeedScale
from .errors import InputError
from .events.frontend import INPUT_NORMS, check_support
from .events.validate import whole_number
from .fileio import read_json

#: Keys a config.json on disk (checkpoint or bundle) must state: a trained network is only valid
#: for the values it was trained with, so a missing one is an error, never a default.
REQUIRED_KEYS = ("sensor_size", "n_bins", "dt_us", "speed_bins", "representative_speeds", "ofs_kernel",
                 "ofs_in_channels", "mask_kernel")
SPEED_BINS_MPS: tuple[tuple[float, float], ...] = ((1.0, 18.0), (18.0, 42.0), (42.0, 84.0), (84.0, 500.0))
CONFIG_FORMAT_VERSION = 1
#: OFS neuron reset rules (fixed_point module docstring): "subtract" is the paper's eq. (1),
#: "zero" Loihi 2's stock CUBA LIF (v = 0 after a spike), which netx, NIR and NeuroCores run.
RESETS = ("subtract", "zero")




#: the largest sensor the runtime takes (4096 x 4096 px): its per-pixel buffers (a scratch of
#: int64 per pixel, the front end's counts, the closings) grow with W x H, and a 65535 x 65535
#: sensor (what uint16 coordinates allow) asked for tens of GiB and was killed for memory
MAX_SENSOR_PIXELS = 4096 * 4096
#: the largest closing kernel (OFS-grid cells); 100,001 asked for 9 GiB in training
MAX_MASK_KERNEL = 255
#: the longest window (us), 1000 s: longer than any recording a window is cut from, and far
#: enough from int64's range that the window arithmetic on microseconds (t0 + dt_us, n x dt_us)
#: cannot overflow (any whole number was taken, 1e20 too)
MAX_DT_US = 10 ** 9


def sensor_too_large(sensor_size) -> str:
    """The one-line reason a W x H sensor is refused (MAX_SENSOR_PIXELS)."""
    w, h = (int(v) for v in sensor_size)
    return (f"sensor {w}x{h} ({w * h / 1e6:,.1f} M pixels) is larger than toffe-deploy runs "
            f"(at most {MAX_SENSOR_PIXELS / 1e6:.1f} M pixels, e.g. 4096x4096)")

@dataclass(frozen=True)
class ToffeConfig:
    """Everything a trained TOFFE needs besides its weights.

    sensor_size is (width, height) in pixels. A window of ``dt_us`` microseconds is split into
    ``n_bins`` (the paper's B) equal time bins. OFS stage k (1-based) fires for objects at speed
    bin k or faster; the cascade runs k = N..1 and masks with a closing of ``mask_kernel``.

    ``ofs_pool`` p: the OFS cascade runs on the window OR-pooled over p x p pixel blocks (its grid
    is ceil(W / p) x ceil(H / p), see ``ofs_grid``); its closed masks come back to the sensor grid
    by repeating each cell p x p times, so the OFPD still sees every pixel (toffe_deploy/cascade.py).
    p = 2 puts the four 640x480 stages on one Loihi 2 chip (40 of 128 cores, issue 13).
    """

    sensor_size: tuple[int, int] = (640, 480)
    n_bins: int = 5
    dt_us: int = 500
    speed_bins: tuple[tuple[float, float], ...] = SPEED_BINS_MPS
    representative_speeds: tuple[float, ...] = (9.5, 30.0, 63.0, 114.0)
    ofs_kernel: int = 3
    ofs_in_channels: int = 2
    mask_kernel: int = 5                   # closing kernel, in OFS-grid cells
    ofs_pool: int = 1                      # OFS grid = sensor pooled over ofs_pool x ofs_pool blocks
    focal_px: float = REFERENCE_FOCAL_PX   # the camera the speed bins in m/s are stated for
    depth_m: float = REFERENCE_DEPTH_M     # ... and the object depth
    input_norm: str = "none"               # OFS/OFPD input front end (events/frontend.py)
    input_min_cluster: int = 1             # ... then keep pixels in 8-connected clusters of >= this many (1: all)
    input_support: tuple[int, int, int, int] | None = None   # ... and dropped pixels with temporal support:
                                           # (K, r, m, c) of events/support.py; None: off (configs without it)
    reset: str = "subtract"                # OFS neuron reset (RESETS); configs without it: subtract
    ofpd: dict[str, Any] = field(default_factory=dict)
    dataset: dict[str, Any] = field(default_factory=dict)
    format_version: int = CONFIG_FORMAT_VERSION

    @property
    def n_speed_bins(self) -> int:
        return len(self.speed_bins)

    @property
    def untrained(self) -> list[str]:
        """The parts a checkpoint holds without training, as its training run recorded them in
        ``dataset["untrained"]`` (model.train.with_untrained); [] for a trained one."""
        return list((self.dataset or {}).get("untrained") or [])

    @property
    def speed_scale(self) -> SpeedScale:
        """m/s <-> px/ms at the depth and focal length the bins are stated for."""
        return SpeedScale(self.focal_px, self.depth_m)

    @property
    def speed_bins_px_ms(self) -> tuple[tuple[float, float], ...]:
        """The speed bins as image-plane speeds (px/ms): what the OFS stages separate."""
        sc = self.speed_scale
        return tuple((sc.to_px_ms(lo), sc.to_px_ms(hi)) for lo, hi in self.speed_bins)

    def speed_bin_of_px_ms(self, speed_px_ms: float) -> int:
        """1-based speed bin of an image-plane speed (px/ms); 0 below the first bin, N above the last."""
        return self.speed_bin_of(self.speed_scale.to_mps(speed_px_ms))

    def ofs_grid(self, sensor_size: tuple[int, int] | None = None) -> tuple[int, int]:
        """(width, height) of the OFS stages' neuron grid for a sensor (default: the config's):
        ceil(W / ofs_pool) x ceil(H / ofs_pool)."""
        w, h = self.sensor_size if sensor_size is None else sensor_size
        p = int(self.ofs_pool)
        return (-(-int(w) // p), -(-int(h) // p))

    @property
    def width(self) -> int:
        return int(self.sensor_size[0])

    @property
    def height(self) -> int:
        return int(self.sensor_size[1])

    def to_dict(self) -> dict[str, Any]:
        d = dataclasses.asdict(self)
        d["sensor_size"] = list(self.sensor_size)
        d["speed_bins"] = [list(b) for b in self.speed_bins]
        d["representative_speeds"] = list(self.representative_speeds)
        if self.input_support is None:     # off: absent, so configs written before it stay byte for byte
            del d["input_support"]
        else:
            d["input_support"] = list(self.input_support)
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any], path: str | os.PathLike = "config.json") -> "ToffeConfig":
        if not isinstance(d, dict):
            raise InputError(path, "config is not a JSON object")
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(d) - known)
        if unknown:
            raise InputError(path, f"unknown config keys: {', '.join(unknown)}")
        try:
            kw = dict(d)
            if "sensor_size" in kw:
                kw["sensor_size"] = tuple(whole_number("sensor_size", v) for v in kw["sensor_size"])
            if "speed_bins" in kw:
                kw["speed_bins"] = tuple((float(a), float(b)) for a, b in kw["speed_bins"])
            if "representative_speeds" in kw:
                kw["representative_speeds"] = tuple(float(v) for v in kw["representative_speeds"])
            for k in ("n_bins", "dt_us", "ofs_kernel", "ofs_in_channels", "mask_kernel", "format_version",
                      "input_min_cluster", "ofs_pool"):
                if k in kw:
                    kw[k] = whole_number(k, kw[k])
            for k in ("focal_px", "depth_m"):
                if k in kw:
                    kw[k] = float(kw[k])
            if kw.get("input_support") is not None:
                kw["input_support"] = check_support(kw["input_support"])
            cfg = cls(**kw)
        except (TypeError, ValueError, OverflowError) as exc:   # OverflowError: float() of a 400-digit number
            raise InputError(path, f"malformed config: {exc}") from None
        cfg.validate(path)
        return cfg

    def validate(self, path: str | os.PathLike = "config.json") -> None:
        def bad(msg: str) -> None:
            raise InputError(path, msg)

        if self.format_version != CONFIG_FORMAT_VERSION:
            bad(f"config format_version {self.format_version} is not supported (expected {CONFIG_FORMAT_VERSION})")
        if len(self.sensor_size) != 2 or min(self.sensor_size) <= 0:
            bad(f"sensor_size must be [width, height] > 0, got {list(self.sensor_size)}")
        if self.sensor_size[0] * self.sensor_size[1] > MAX_SENSOR_PIXELS:
            bad(sensor_too_large(self.sensor_size))
        if self.n_bins < 1:
            bad(f"n_bins must be >= 1, got {self.n_bins}")
        if self.dt_us < self.n_bins:
            bad(f"dt_us must be >= n_bins, got dt_us={self.dt_us}")
        if self.dt_us > MAX_DT_US:
            bad(f"dt_us must be <= {MAX_DT_US} ({MAX_DT_US / 1e6:g} s), got {self.dt_us}")
        if not self.speed_bins:
            bad("speed_bins is empty")
        lo_prev = -math.inf
        for lo, hi in self.speed_bins:
            if not (lo < hi) or lo < lo_prev:
                bad(f"speed_bins must be increasing [lo, hi) ranges, got {[list(b) for b in self.speed_bins]}")
            lo_prev = lo
        if len(self.representative_speeds) != len(self.speed_bins):
            bad("representative_speeds must have one entry per speed bin")
        if not all(math.isfinite(v) and v >= 0 for v in self.representative_speeds):
            bad(f"representative_speeds must be finite and >= 0, got {list(self.representative_speeds)}")
        if self.ofs_kernel % 2 != 1 or self.ofs_kernel < 1:
            bad(f"ofs_kernel must be odd, got {self.ofs_kernel}")
        if not 1 <= self.mask_kernel <= MAX_MASK_KERNEL:
            bad(f"mask_kernel must be 1..{MAX_MASK_KERNEL}, got {self.mask_kernel}")
        if self.ofs_pool < 1 or self.ofs_pool > 16:
            bad(f"ofs_pool must be an integer 1..16, got {self.ofs_pool}")
        if not (self.focal_px > 0 and math.isfinite(self.focal_px)):
            bad(f"focal_px must be > 0, got {self.focal_px}")
        if not (self.depth_m > 0 and math.isfinite(self.depth_m)):
            bad(f"depth_m must be > 0, got {self.depth_m}")
        if self.reset not in RESETS:
            bad(f"reset must be one of {', '.join(RESETS)}, got {self.reset!r}")
        if self.input_norm not in INPUT_NORMS:
            bad(f"input_norm must be one of {', '.join(INPUT_NORMS)}, got {self.input_norm!r}")
        if not 1 <= self.input_min_cluster <= 2 ** 31 - 1:
            bad(f"input_min_cluster must be 1..2**31 - 1, got {self.input_min_cluster}")
        if self.input_support is not None:
            try:
                check_support(self.input_support)
            except ValueError as exc:
                bad(str(exc))
        if self.ofpd is not None and not isinstance(self.ofpd, dict):
            bad(f"ofpd must be an object of settings, got {type(self.ofpd).__name__}")
        from .ofpd_io import _ofpd_settings                 # imported here: ofpd_io imports this module
        from .outline_centre import outline_settings
        from .plane_fit import fit_settings
        try:
            _ofpd_settings(self)
            fit_settings(self)
            outline_settings(self)
        except (TypeError, ValueError) as exc:
            bad(str(exc))

    def speed_bin_of(self, speed_mps: float) -> int:
        """1-based speed bin of a speed; 0 below the first bin, N above the last."""
        if speed_mps < self.speed_bins[0][0]:
            return 0
        for k, (_lo, hi) in enumerate(self.speed_bins, start=1):
            if speed_mps < hi:
                return k
        return len(self.speed_bins)


def load_config(path: str | os.PathLike) -> ToffeConfig:
    """config.json of a checkpoint or bundle; every key of REQUIRED_KEYS must be present."""
    d = read_json(path)
    missing = [k for k in REQUIRED_KEYS if isinstance(d, dict) and k not in d]
    if missing:
        raise InputError(path, f"config lacks {', '.join(missing)} (a trained checkpoint's config states "
                               "every one; defaults would not match the weights)")
    return ToffeConfig.from_dict(d, path)
