"""The deploy bundle on disk: layout, manifest with sha256 of every file, reader and writer.

Layout (export/README.md, written into every bundle, documents every field)::

    manifest.json          format, versions, config summary, camera, quantization report, sha256 of all files
    config.json            the ToffeConfig (same form as a checkpoint's config.json)
    ofs_loihi.json         the quantized OFS, one entry per speed bin k = 1..N (lava_procs builds from it)
    ofpd.onnx              OFPD, input ``events`` (N, C, h, w) float32, outputs pose, direction, speed
    README.md              this layout, with every field explained
    ...                    optional: netx/, ofs.nir, ofpd_fp16.onnx, ofpd_int8.onnx, parity.json

The quantized stage k holds exactly what one Loihi 2 OFS neuron population needs (see
``toffe_deploy.fixed_point``): spike where v > vth_mant << 6 with

    v[t] = clip24(trunc0(v[t-1] * (4096 - dv) / 4096) + (conv(w, s_in[t]) << 6) - (vth_mant << 6) * o[t-1])

The manifest's ``camera`` section states what the speed bins mean: image-plane speeds (px/ms),
and the m/s they equal for the camera (sensor, focal length) and object depth of the config.
Bundles written before it carry neither the section nor config.focal_px / depth_m: they load with
the reference camera (camera.REFERENCE_FOCAL_PX, REFERENCE_DEPTH_M), what they were trained on.

This module is torch- and Lava-free: the runtime on an edge device reads bundles with it.
``load_bundle`` refuses a bundle whose files do not match the sha256 in its manifest.
"""
from __future__ import annotations

import datetime as _dt
import hashlib
import json
import os
import shutil
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath
from typing import Any, Mapping, Sequence, Union

import numpy as np

from .. import __version__
from ..config import ToffeConfig, load_config
from ..errors import InputError
from ..fileio import JSON_ERRORS, atomic_dir, read_json
from ..fixed_point import DECAY_UNITY, STATE_SHIFT, VTH_MANT_MAX, WEIGHT_MAX, LoihiOFSParams

BUNDLE_FORMAT = "toffe-deploy-bundle"
BUNDLE_FORMAT_VERSION = 1
OFS_FORMAT = "toffe-ofs-loihi"
OFS_FORMAT_VERSION = 1

MANIFEST = "manifest.json"
CONFIG = "config.json"
OFS_FILE = "ofs_loihi.json"
OFPD_ONNX = "ofpd.onnx"
README = "README.md"
REQUIRED_FILES = (CONFIG, OFS_FILE, OFPD_ONNX)

#: Dependency versions recorded in the manifest (None where a package is not installed).
RECORDED_PACKAGES = ("numpy", "opencv-python-headless", "onnx", "onnxruntime", "torch", "lava-nc", "lava-dl",
                     "nir", "h5py", "safetensors")

FileSource = Union[bytes, str, os.PathLike]


@dataclass
class Bundle:
    """A loaded (and, by default, hash-verified) deploy bundle.

    ofs[k-1] is speed bin k's quantized OFS stage; ofpd_onnx the fp32 OFPD model;
    ofpd_variants maps "fp16"/"int8" to their ONNX files when the bundle carries them.
    """

    root: Path
    config: ToffeConfig
    ofs: list[LoihiOFSParams]
    ofpd_onnx: Path
    manifest: dict
    ofpd_variants: dict[str, Path] = field(default_factory=dict)

    @property
    def parity(self) -> dict | None:
        """parity.json's content when the bundle has one (export always writes it)."""
        p = self.root / "parity.json"
        if not p.is_file():
            return None
        return read_json(p)


# ----------------------------------------------------------------------------- hashing

def sha256_file(path: str | os.PathLike) -> str:
    """Hex sha256 of a file, read in 1 MiB chunks."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def package_versions(names: Sequence[str] = RECORDED_PACKAGES) -> dict[str, str | None]:
    """Installed versions of the given distributions (None when absent), for the manifest."""
    from importlib import metadata

    out: dict[str, str | None] = {}
    for n in names:
        try:
            out[n] = metadata.version(n)
        except metadata.PackageNotFoundError:
            out[n] = None
    return out


# ----------------------------------------------------------------------------- OFS stages as JSON

def ofs_to_json(ofs: Sequence[LoihiOFSParams], float_params: Sequence[Mapping[str, Any]] | None = None) -> dict:
    """The documented JSON form of the quantized OFS (ofs_loihi.json).

    float_params (optional, index k-1): the float threshold/leak each stage was quantized from,
    recorded for reference only; readers use the integers.
    """
    stages = []
    for k, p in enumerate(ofs, start=1):
        st = {
            "stage": k,
            "weight": np.asarray(p.weight, dtype=np.int64).tolist(),
            "vth_mant": int(p.vth_mant),
            "dv": int(p.dv),
            "du": int(p.du),
            "weight_scale": float(p.weight_scale),
            "notes": list(p.notes),
        }
        if float_params is not None:
            fp = float_params[k - 1]
            st["float"] = {"threshold": float(fp["threshold"]), "leak": float(fp["leak"])}
        stages.append(st)
    return {
        "format": OFS_FORMAT,
        "format_version": OFS_FORMAT_VERSION,
        "weight_layout": "(1, C_in, K, K), cross-correlation (torch Conv2d layout), zero padding K//2, stride 1",
        "state_shift": STATE_SHIFT,
        "reset_mode": _reset_mode(ofs),
        "reset": RESET_TEXT[_reset_mode(ofs)],
        "input": "binary spikes per polarity channel (count > 0), one time step per bin",
        "stages": stages,
    }


def _reset_mode(ofs: Sequence[LoihiOFSParams]) -> str:
    modes = {p.reset for p in ofs}
    if len(modes) != 1:
        raise ValueError(f"OFS stages disagree on the reset rule: {sorted(modes)}")
    return modes.pop()


#: ofs_loihi.json ``reset``: the rule of each ``reset_mode`` in words (toffe_deploy.fixed_point).
RESET_TEXT = {
    "subtract": "subtraction of (vth_mant << 6) * o[t-1] at step t, undecayed (paper eq. 1); "
                "state zero at each window start",
    "zero": "v = 0 after a spike (Loihi 2's stock CUBA LIF, lava.proc.lif); u and v zeroed at each "
            "window start (LIFReset, reset_interval = n_bins)",
}


def ofs_from_json(d: Any, path: str | os.PathLike, expect_channels: int | None = None,
                  expect_kernel: int | None = None, expect_stages: int | None = None,
                  expect_reset: str | None = None) -> list[LoihiOFSParams]:
    """Parse and range-check ofs_loihi.json. Every problem is an InputError naming the field.

    ``reset_mode`` ("subtract" or "zero") is absent from files written before it existed: they
    hold subtract-reset stages."""
    if not isinstance(d, dict) or d.get("format") != OFS_FORMAT:
        raise InputError(path, f"not a quantized OFS file (format is not {OFS_FORMAT!r})")
    if d.get("format_version") != OFS_FORMAT_VERSION:
        raise InputError(path, f"OFS format_version {d.get('format_version')!r} is not supported "
                               f"(expected {OFS_FORMAT_VERSION})")
    if d.get("state_shift", STATE_SHIFT) != STATE_SHIFT:
        raise InputError(path, f"state_shift = {d.get('state_shift')!r} is not supported: every runtime "
                               f"(cpu fixed point, Lava) scales by 2**{STATE_SHIFT} (state_shift {STATE_SHIFT})")
    reset = d.get("reset_mode", "subtract")
    if reset not in RESET_TEXT:
        raise InputError(path, f"reset_mode {reset!r} is not one of {', '.join(RESET_TEXT)}")
    if expect_reset is not None and reset != expect_reset:
        raise InputError(path, f"reset_mode {reset!r} but config.json says reset {expect_reset!r}")
    stages = d.get("stages")
    if not isinstance(stages, list) or not stages:
        raise InputError(path, "no OFS stages")
    if expect_stages is not None and len(stages) != expect_stages:
        raise InputError(path, f"{len(stages)} OFS stages but config has {expect_stages} speed bins")
    out = []
    for k, st in enumerate(stages, start=1):
        where = f"stage {k}"
        try:
            if int(st["stage"]) != k:
                raise InputError(path, f"{where}: stages out of order (found stage {st['stage']})")
            w = np.asarray(st["weight"], dtype=np.float64)
            vth, dv, du, scale = st["vth_mant"], st["dv"], st["du"], float(st["weight_scale"])
            notes = tuple(str(n) for n in st.get("notes", ()))
        except InputError:
            raise
        except (KeyError, TypeError, ValueError) as exc:
            raise InputError(path, f"{where}: malformed entry ({exc.__class__.__name__}: {exc})") from None
        if w.ndim != 4 or w.shape[0] != 1 or w.shape[2] != w.shape[3]:
            raise InputError(path, f"{where}: weight shape {list(w.shape)} is not (1, C, K, K)")
        if expect_channels is not None and w.shape[1] != expect_channels:
            raise InputError(path, f"{where}: weight has {w.shape[1]} input channels, config says {expect_channels}")
        if expect_kernel is not None and w.shape[2] != expect_kernel:
            raise InputError(path, f"{where}: kernel {w.shape[2]} but config says {expect_kernel}")
        if not np.all(w == np.rint(w)) or np.abs(w).max(initial=0) > WEIGHT_MAX:
            raise InputError(path, f"{where}: weights must be integers in [-{WEIGHT_MAX}, {WEIGHT_MAX}]")
        for name, val, lo, hi in (("vth_mant", vth, 1, VTH_MANT_MAX), ("dv", dv, 0, DECAY_UNITY - 1),
                                  ("du", du, 0, DECAY_UNITY - 1)):
            if not isinstance(val, int) or isinstance(val, bool) or not lo <= val <= hi:
                raise InputError(path, f"{where}: {name} = {val!r} is not an integer in [{lo}, {hi}]")
        if du != DECAY_UNITY - 1:
            raise InputError(path, f"{where}: du = {du} is not supported: the OFS current is memoryless "
                                   f"(du = {DECAY_UNITY - 1}), which is what every runtime implements")
        if not np.isfinite(scale) or scale <= 0:
            raise InputError(path, f"{where}: weight_scale {scale!r} must be finite and > 0")
        out.append(LoihiOFSParams(weight=w.astype(np.int32), vth_mant=vth, dv=dv, du=du, weight_scale=scale,
                                  notes=notes, reset=reset))
    return out


# ----------------------------------------------------------------------------- output directory

def is_bundle_dir(path: str | os.PathLike) -> bool:
    """True when ``path`` holds a manifest.json of our bundle format (any version)."""
    return _bundle_manifest(path) is not None


def _bundle_manifest(path: str | os.PathLike) -> dict | None:
    """``path``'s manifest.json when it is one of our bundle format (any version), else None."""
    try:
        d = json.loads((Path(path) / MANIFEST).read_text(encoding="utf-8"))
    except (OSError, *JSON_ERRORS):
        return None
    return d if isinstance(d, dict) and d.get("format") == BUNDLE_FORMAT else None


def check_output_dir(path: str | os.PathLike, force: bool = False) -> None:
    """Refuse to replace a directory that holds anything not ours (unless force): the bundle is
    written beside it and replaces it whole, so whatever else it holds would be deleted.

    Accepted: a missing path, an empty directory, an existing bundle holding only its own files
    (manifest.json and those its manifest lists), or a directory holding only this project's
    bundle README (export/README.md as shipped in the repository).
    """
    p = Path(path)
    if not p.exists():
        return
    if not p.is_dir():
        raise InputError(p, "output exists and is not a directory")
    if force:
        return
    manifest = _bundle_manifest(p)
    if manifest is not None:
        others = foreign_files(p, manifest)
        if others:
            shown = ", ".join(others[:3]) + (f" and {len(others) - 3} more" if len(others) > 3 else "")
            raise InputError(p, f"the bundle directory also holds {len(others)} file(s) that are not the bundle's "
                                f"({shown}): writing the new bundle replaces the directory whole and would delete "
                                "them; move them out, choose another -o, or pass --force to replace it all")
        return
    entries = [e for e in p.iterdir()]
    if not entries:
        return
    if len(entries) == 1 and entries[0].name == README and entries[0].is_file():
        from .readme import README_TITLE
        try:
            if entries[0].read_text(encoding="utf-8").startswith(README_TITLE):
                return
        except (OSError, UnicodeDecodeError):
            pass
    names = sorted(e.name + ("/" if e.is_dir() else "") for e in entries)
    shown = ", ".join(names[:3]) + (f" and {len(names) - 3} more" if len(names) > 3 else "")
    raise InputError(p, f"output directory exists and is not a toffe-deploy bundle (holds {shown}): writing "
                        "the bundle replaces the directory whole and would delete them; choose another -o or "
                        "pass --force to replace it")


def foreign_files(path: str | os.PathLike, manifest: dict) -> list[str]:
    """The files under bundle directory ``path`` (relative, sorted) that are neither its
    manifest.json nor listed in its ``manifest``: a run's --out, a user's notes."""
    root = Path(path)
    listed = manifest.get("files")
    own = set(listed if isinstance(listed, dict) else ()) | {MANIFEST}
    found = []
    for d, dirs, files in os.walk(root):          # symlinked directories are listed, not followed
        rel = Path(d).relative_to(root)
        found += [(rel / n).as_posix() for n in files + [x for x in dirs if (Path(d) / x).is_symlink()]]
    return sorted(f for f in found if f not in own)


# ----------------------------------------------------------------------------- writer

def camera_section(config: ToffeConfig) -> dict[str, Any]:
    """The manifest's ``camera``: the sensor and lens the bundle was trained for and its speed bins
    in px/ms and in m/s at ``depth_m`` (v_px_per_ms = v_mps * focal_px / (1000 * depth_m))."""
    from ..camera import hfov_deg_from_focal

    return {
        "sensor_size": list(config.sensor_size),
        "focal_px": float(config.focal_px),
        "hfov_deg": hfov_deg_from_focal(config.width, config.focal_px),
        "depth_m": float(config.depth_m),
        "speed_bins_px_ms": [list(b) for b in config.speed_bins_px_ms],
        "speed_bins_mps": [list(b) for b in config.speed_bins],
        "note": "the OFS separates image-plane speeds (px/ms); the m/s hold for an object at depth_m seen "
                "with focal_px. `run` works on any sensor size and re-expresses m/s with --depth-m / "
                "--focal-px / --hfov-deg",
    }


def _put(dst: Path, src: FileSource) -> None:
    dst.parent.mkdir(parents=True, exist_ok=True)
    if isinstance(src, (bytes, bytearray)):
        dst.write_bytes(bytes(src))
    else:
        shutil.copyfile(src, dst)


def _json_bytes(d: Any) -> bytes:
    return (json.dumps(d, indent=2, sort_keys=False) + "\n").encode("utf-8")


def write_bundle(path: str | os.PathLike, config: ToffeConfig, ofs: Sequence[LoihiOFSParams],
                 ofpd_onnx: FileSource, *, files: Mapping[str, FileSource] | None = None,
                 manifest: Mapping[str, Any] | None = None, float_params: Sequence[Mapping[str, Any]] | None = None,
                 force: bool = False) -> Bundle:
    """Write a bundle directory atomically and return it loaded (and verified).

    ofpd_onnx: the OFPD ONNX model (a path to copy, or the serialized bytes).
    files: extra files, relative path -> bytes or a path to copy (netx, NIR, variants, parity.json).
    manifest: extra top-level manifest sections (quantization report, parity summary, ...).
    force: replace an existing directory that is not a bundle.
    Nothing is visible at ``path`` until everything, manifest last, has been written.
    """
    path = Path(path)
    check_output_dir(path, force=force)
    if len(ofs) != config.n_speed_bins:
        raise ValueError(f"{len(ofs)} OFS stages for {config.n_speed_bins} speed bins")
    from .readme import bundle_readme

    with atomic_dir(path) as tmp:
        _put(tmp / CONFIG, _json_bytes(config.to_dict()))
        _put(tmp / OFS_FILE, _json_bytes(ofs_to_json(ofs, float_params)))
        _put(tmp / OFPD_ONNX, ofpd_onnx)
        _put(tmp / README, bundle_readme().encode("utf-8"))
        for rel, src in (files or {}).items():
            rel_p = Path(rel)
            if rel_p.is_absolute() or ".." in rel_p.parts or rel in (MANIFEST, CONFIG, OFS_FILE, OFPD_ONNX):
                raise ValueError(f"bad extra bundle file name {rel!r}")
            _put(tmp / rel_p, src)
        hashes = {}
        for f in sorted(q for q in tmp.rglob("*") if q.is_file()):
            rel = f.relative_to(tmp).as_posix()
            hashes[rel] = {"sha256": sha256_file(f), "bytes": f.stat().st_size}
        m: dict[str, Any] = {
            "format": BUNDLE_FORMAT,
            "format_version": BUNDLE_FORMAT_VERSION,
            "created_utc": _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ"),
            "tool": {"name": "toffe-deploy", "version": __version__},
            "dependencies": package_versions(),
            "config_summary": {
                "sensor_size": list(config.sensor_size), "n_bins": config.n_bins, "dt_us": config.dt_us,
                "speed_bins_mps": [list(b) for b in config.speed_bins],
                "representative_speeds_mps": list(config.representative_speeds),
                "speed_bins_px_ms": [list(b) for b in config.speed_bins_px_ms],
                "focal_px": float(config.focal_px), "depth_m": float(config.depth_m),
                "ofs_kernel": config.ofs_kernel, "ofs_in_channels": config.ofs_in_channels,
                "mask_kernel": config.mask_kernel,
            },
            "camera": camera_section(config),
            "config": config.to_dict(),
            "ofs": {"file": OFS_FILE, "n_stages": len(ofs),
                    "stages": [{"stage": k, "vth_mant": int(p.vth_mant), "dv": int(p.dv), "du": int(p.du),
                                "weight_scale": float(p.weight_scale), "clamps": list(p.notes)}
                               for k, p in enumerate(ofs, start=1)]},
            "ofpd": {"file": OFPD_ONNX},
        }
        for key, val in (manifest or {}).items():
            if key in ("format", "format_version", "files"):
                raise ValueError(f"manifest key {key!r} is reserved")
            if isinstance(val, dict) and isinstance(m.get(key), dict):
                m[key] = {**m[key], **val}
            else:
                m[key] = val
        m["files"] = hashes
        _put(tmp / MANIFEST, _json_bytes(m))
    return load_bundle(path)


# ----------------------------------------------------------------------------- reader

def read_manifest(root: str | os.PathLike) -> dict:
    """manifest.json of a bundle directory, format-checked (InputError otherwise)."""
    root = Path(root)
    if not root.exists():
        raise InputError(root, "bundle directory does not exist (run `toffe-deploy export CKPT -o DIR` first)")
    if not root.is_dir():
        raise InputError(root, "not a directory (a bundle is a directory with manifest.json)")
    mpath = root / MANIFEST
    if not mpath.exists():
        raise InputError(root, "not a deploy bundle (no manifest.json)")
    m = read_json(mpath)
    if not isinstance(m, dict) or m.get("format") != BUNDLE_FORMAT:
        raise InputError(mpath, f"not a toffe-deploy bundle manifest (format is not {BUNDLE_FORMAT!r})")
    if m.get("format_version") != BUNDLE_FORMAT_VERSION:
        raise InputError(mpath, f"bundle format_version {m.get('format_version')!r} is not supported "
                                f"(expected {BUNDLE_FORMAT_VERSION}); re-export with this toffe-deploy")
    if not isinstance(m.get("files"), dict):
        raise InputError(mpath, "manifest has no 'files' table")
    return m


def bundle_file(root: str | os.PathLike, rel: Any, what: str) -> Path:
    """``root / rel`` for a path named in the manifest, refused unless it stays inside the bundle.

    Refused: non-strings, empty names, absolute paths, '..' components, backslashes, and paths
    whose resolved location (symlinks followed) leaves the bundle directory. Nothing outside the
    bundle is ever opened, so an error can never reveal anything about such a file.
    """
    root = Path(root)
    mpath = root / MANIFEST
    if not isinstance(rel, str) or not rel.strip() or "\\" in rel or "\0" in rel:
        raise InputError(mpath, f"{what}: {rel!r} is not a relative file name")
    p = PurePosixPath(rel)
    if p.is_absolute() or ".." in p.parts:
        raise InputError(mpath, f"{what}: {rel!r} points outside the bundle (absolute or '..' path)")
    f = root / p
    if not Path(os.path.realpath(f)).is_relative_to(Path(os.path.realpath(root))):
        raise InputError(mpath, f"{what}: {rel!r} resolves outside the bundle (symbolic link)")
    return f


def _listed(rel: str) -> str:
    return PurePosixPath(rel).as_posix()


def verify_bundle(root: str | os.PathLike, manifest: dict | None = None) -> None:
    """Check every file listed in the manifest lies inside the bundle, exists and matches its
    sha256 (InputError if not)."""
    root = Path(root)
    m = manifest if manifest is not None else read_manifest(root)
    files = m["files"]
    listed = {_listed(k) for k in files if isinstance(k, str)}
    for req in REQUIRED_FILES:
        if req not in listed:
            raise InputError(root / MANIFEST, f"manifest does not list required file {req}")
    for rel, entry in sorted(files.items()):
        f = bundle_file(root, rel, "files")
        if not isinstance(entry, dict) or not isinstance(entry.get("sha256"), str):
            raise InputError(root / MANIFEST, f"malformed files entry for {rel}")
        if not f.is_file():
            raise InputError(f, "missing file (listed in manifest.json)")
        got = sha256_file(f)
        if got != entry["sha256"]:
            raise InputError(f, f"sha256 mismatch (bundle file modified or corrupt: manifest "
                                f"{entry['sha256'][:12]}..., file {got[:12]}...); re-export the bundle")


def ofpd_variant_files(root: str | os.PathLike, manifest: dict, verify: bool = True) -> dict[str, Path]:
    """manifest.ofpd.variants as {precision: path}, each path inside the bundle and (verify)
    listed in manifest.files, hence hash-checked by verify_bundle; variants whose file is
    absent are left out (``run --ofpd`` then says the bundle has no such variant)."""
    root = Path(root)
    mpath = root / MANIFEST
    ofpd = manifest.get("ofpd", {})
    if not isinstance(ofpd, dict):
        raise InputError(mpath, "manifest 'ofpd' section must be an object")
    variants = ofpd.get("variants") or {}
    if not isinstance(variants, dict):
        raise InputError(mpath, "manifest ofpd.variants must be an object {precision: {\"file\": NAME}}")
    listed = {_listed(k) for k in manifest.get("files", {}) if isinstance(k, str)}
    out = {}
    for name, entry in variants.items():
        rel = entry.get("file") if isinstance(entry, dict) else entry
        fp = bundle_file(root, rel, f"ofpd.variants.{name}")
        if verify and _listed(rel) not in listed:
            raise InputError(mpath, f"ofpd.variants.{name}: {rel} is not listed in 'files' with a sha256, "
                                    "so it cannot be verified; re-export the bundle")
        if fp.is_file():
            out[str(name)] = fp
    return out


def check_manifest_config(root: Path, m: dict, config: ToffeConfig) -> None:
    """The manifest's ``config`` and ``camera`` must say what config.json (hash-checked) says:
    the manifest is the one file no hash covers, and users read the camera and bins from it, so
    an edited one is refused rather than read beside a config that runs otherwise."""
    mpath = root / MANIFEST
    if "config" in m and m["config"] != read_json(root / CONFIG):
        raise InputError(mpath, "its 'config' differs from config.json (edited after export?): re-export the bundle")
    if "camera" in m and m["camera"] != json.loads(json.dumps(camera_section(config))):
        raise InputError(mpath, "its 'camera' differs from what config.json gives (edited after export?): "
                                "re-export the bundle")


def load_bundle(path: str | os.PathLike, verify: bool = True) -> Bundle:
    """Read a bundle directory; with verify (default) refuse any file whose sha256 differs,
    and any file the runtime would open that the manifest does not list."""
    root = Path(path)
    m = read_manifest(root)
    if verify:
        verify_bundle(root, m)
    config = load_config(root / CONFIG)
    if verify:
        check_manifest_config(root, m, config)
    ofs_path = root / OFS_FILE
    ofs_d = read_json(ofs_path)
    ofs = ofs_from_json(ofs_d, ofs_path, expect_channels=config.ofs_in_channels, expect_kernel=config.ofs_kernel,
                        expect_stages=config.n_speed_bins, expect_reset=config.reset)
    onnx_path = root / OFPD_ONNX
    ofpd = m.get("ofpd")                # not an object: ofpd_variant_files below says so
    named = ofpd.get("file", OFPD_ONNX) if isinstance(ofpd, dict) else OFPD_ONNX
    if named != OFPD_ONNX:              # the fp32 model's name is fixed (it was read whatever this said)
        raise InputError(root / MANIFEST, f"ofpd.file is {named!r}, but a bundle's fp32 OFPD is always "
                                          f"{OFPD_ONNX} (variants go in ofpd.variants); re-export the bundle")
    if not onnx_path.is_file():
        raise InputError(onnx_path, "missing file")
    variants = ofpd_variant_files(root, m, verify)
    return Bundle(root=root, config=config, ofs=ofs, ofpd_onnx=onnx_path, manifest=m, ofpd_variants=variants)
