"""The JSON-lines format of `run`: a versioned JSON Schema and the header line that opens a run.

Every line validates against ``schemas/object_flow.v1.schema.json`` (shipped in the package):
the first line is the header (``"type": "header"``: schema version, bundle and its manifest
hash, target, sensor, window length, clock, units and the image conventions), every other line
one window (t0_us, t1_us, objects and, with tracking, coasting tracks). README.md's "JSON
lines" section has a table of every field. A consumer that predates the header skips lines
whose ``type`` is ``header``.
"""
from __future__ import annotations

import json
from dataclasses import asdict
from pathlib import Path

from .fileio import json_text

SCHEMA_NAME = "toffe-deploy/object-flow"
SCHEMA_VERSION = 1
SCHEMA_PATH = Path(__file__).resolve().parent / "schemas" / f"object_flow.v{SCHEMA_VERSION}.schema.json"

CLOCK = ("the recording's timestamps in microseconds; window i covers [t0_us, t1_us) = "
         "[t_start + i dt_us, t_start + (i + 1) dt_us); windows skipped over a gap have no line")
UNITS = {"t0_us": "us", "t1_us": "us", "x": "px", "y": "px", "direction_rad": "rad", "direction_deg": "deg",
         "speed_px_s": "px/s (image plane)", "speed_mps": "m/s (at the camera's depth and focal length)",
         "speed_bin_mps": "m/s", "n_events": "count of (time bin, polarity, pixel) ones",
         "age": "windows", "hits": "windows"}
PIXEL_ORIGIN = "top-left: pixel (0, 0) is the top-left pixel, its centre at x = 0, y = 0; x to the right"
DIRECTION = ("atan2(dy, dx) in the image plane with y down: 0 = moving right (+x), +90 deg = moving down (+y), "
             "+-180 deg = moving left")


def load_schema() -> dict:
    """The JSON Schema (draft 2020-12) every line of a run validates against."""
    return json.loads(SCHEMA_PATH.read_text(encoding="utf-8"))


def is_header(line: dict) -> bool:
    return isinstance(line, dict) and line.get("type") == "header"


def header(bundle, *, target: str, sensor_size, camera_json: dict, ofpd_variant: str = "fp32",
           tag: str | None = None, tracking=None) -> dict:
    """The first JSON line of a run (module doc). bundle: the loaded Bundle; camera_json: the
    run camera (runtime.run_camera ``to_json``); tracking: the TrackerConfig, or None when the run
    does not track."""
    from . import __version__
    from .deploy.bundle import sha256_file

    cfg = bundle.config
    out = {"type": "header", "schema": SCHEMA_NAME, "schema_version": SCHEMA_VERSION, "toffe_deploy": __version__,
           "bundle": {"path": str(bundle.root), "manifest_sha256": sha256_file(Path(bundle.root) / "manifest.json")},
           "target": target}
    if tag is not None:
        out["tag"] = tag
    out.update(ofpd_variant=ofpd_variant, sensor_size=[int(v) for v in sensor_size], dt_us=int(cfg.dt_us),
               n_bins=int(cfg.n_bins), n_speed_bins=int(cfg.n_speed_bins),
               speed_bins_px_s=[[lo * 1000.0, hi * 1000.0] for lo, hi in cfg.speed_bins_px_ms],
               camera=camera_json, clock=CLOCK, units=UNITS, pixel_origin=PIXEL_ORIGIN, y_axis="down",
               direction=DIRECTION, tracking=None if tracking is None else asdict(tracking))
    return out


def write_header(stream, line: dict) -> None:
    """The header as the first JSON line of ``stream`` (compact, like the window lines); returns
    None, so that ``head = head and write_header(stream, head)`` writes it once."""
    stream.write(json_text(line, separators=(",", ":")) + "\n")
