"""The camera a run reports metric speeds for: the recording's sensor, a focal length and a depth.

The OFS separates image-plane speeds (px/ms) and OFPD regresses one, so a run needs only the
sensor size to work; metres per second need a focal length f (px) and the object depth Z (m):

    v_mps = v_px_per_ms * 1000 * Z / f                         (camera.SpeedScale)

Defaults, in order: ``--focal-px`` / ``--hfov-deg``; for a synthetic recording the generator's
camera; the bundle's focal length when the recording is as wide as the bundle's sensor; else the
bundle's horizontal field of view spread over the recording's width (f = W_rec / W_bundle * f_bundle,
the same lens on a sensor of another size). Depth: ``--depth-m``, else the bundle's.
"""
from __future__ import annotations

from dataclasses import dataclass

from ..camera import DEPTH_RANGE_M, FOCAL_RANGE_PX, HFOV_RANGE_DEG, SpeedScale, focal_px_from_hfov, hfov_deg_from_focal, speed_text
from ..config import ToffeConfig
from ..errors import ToffeError


@dataclass(frozen=True)
class RunCamera:
    """The recording's ``sensor_size`` (W, H) and the ``scale`` (focal px, depth m) its m/s use;
    ``sensor_from`` / ``focal_from`` / ``depth_from`` say where each value came from (for the summary)."""

    sensor_size: tuple[int, int]
    scale: SpeedScale
    focal_from: str
    depth_from: str
    sensor_from: str = "the recording's"

    def describe(self, config: ToffeConfig) -> str:
        """One summary line: the camera, where its numbers came from, the bins at this camera."""
        w, h = self.sensor_size
        px = ", ".join(f"{lo * 1000:.0f}-{hi * 1000:.0f}" for lo, hi in config.speed_bins_px_ms)
        mps = ", ".join(f"{speed_text(self.scale.to_mps(lo))}-{speed_text(self.scale.to_mps(hi))}"
                        for lo, hi in config.speed_bins_px_ms)
        return (f"camera: {w}x{h} sensor ({self.sensor_from}), focal {_focal_text(self.scale.focal_px)} px ({self.focal_from}), depth "
                f"{self.scale.depth_m:g} m ({self.depth_from}); speeds in m/s assume that depth and focal length. "
                f"Speed bins in px/s: {px}; in m/s here: {mps}")

    def to_json(self, config: ToffeConfig) -> dict:
        return {"sensor_size": list(self.sensor_size), "sensor_from": self.sensor_from, "focal_px": self.scale.focal_px, "focal_from": self.focal_from,
                "depth_m": self.scale.depth_m, "depth_from": self.depth_from,
                "speed_bins_px_ms": [list(b) for b in config.speed_bins_px_ms],
                "speed_bins_mps": [[self.scale.to_mps(lo), self.scale.to_mps(hi)] for lo, hi in config.speed_bins_px_ms]}


def _focal_text(f: float) -> str:
    """A focal length for the summary: one decimal, 3 significant digits below 1 px (a 0.01 px
    focal length read "0.0 px")."""
    return f"{f:.1f}" if f >= 1.0 else f"{f:.3g}"


#: what --depth-m (m), --focal-px (px) and --hfov-deg (deg) may be (camera.DEPTH_RANGE_M,
#: FOCAL_RANGE_PX, HFOV_RANGE_DEG)
OPTION_RANGE = {"--depth-m": DEPTH_RANGE_M, "--focal-px": FOCAL_RANGE_PX, "--hfov-deg": HFOV_RANGE_DEG}


def _positive(name: str, v: float | None) -> None:
    if v is None:
        return
    lo, hi = OPTION_RANGE[name]
    if not (v > 0 and v < float("inf")):
        raise ToffeError(f"{name} must be a positive number, got {v:g}")
    if not lo <= v <= hi:
        raise ToffeError(f"{name} must be in [{lo:g}, {hi:g}], got {v:.12g}")


def resolve_camera(config: ToffeConfig, sensor_size: tuple[int, int], *, depth_m: float | None = None,
                   focal_px: float | None = None, hfov_deg: float | None = None,
                   synthetic_focal_px: float | None = None, sensor_from: str = "the recording's") -> RunCamera:
    """The run's camera from the bundle's config, the recording's sensor and the options (module doc)."""
    _positive("--depth-m", depth_m)
    _positive("--focal-px", focal_px)
    _positive("--hfov-deg", hfov_deg)
    w = int(sensor_size[0])
    if focal_px is not None:
        f, f_from = float(focal_px), "--focal-px"
    elif hfov_deg is not None:
        f, f_from = focal_px_from_hfov(w, hfov_deg), f"--hfov-deg {hfov_deg:g} over {w} px"
    elif synthetic_focal_px is not None:
        f, f_from = float(synthetic_focal_px), "the synthetic recording's camera"
    elif w == config.width:
        f, f_from = float(config.focal_px), "the bundle's"
    else:
        hfov = hfov_deg_from_focal(config.width, config.focal_px)
        f = focal_px_from_hfov(w, hfov)
        f_from = f"the bundle's {hfov:.1f} deg horizontal FoV over {w} px; set --focal-px or --hfov-deg for your lens"
    d, d_from = (float(depth_m), "--depth-m") if depth_m is not None else (float(config.depth_m), "the bundle's")
    return RunCamera((w, int(sensor_size[1])), SpeedScale(f, d), f_from, d_from, sensor_from)
