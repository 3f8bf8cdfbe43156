"""TOFFE checkpoint directory: config.json + ofs.safetensors + ofpd.safetensors (torch-free).

    config.json        ToffeConfig.to_dict()
    ofs.safetensors    stage{k}.weight (1, C, K, K) f32, stage{k}.threshold (), stage{k}.leak (), k = 1..N
    ofpd.safetensors   OFPD state dict (shapes: ofpd_io.ofpd_param_shapes(config))

safetensors holds raw tensors only, so loading never executes code from the file (no pickle).
Every inconsistency (missing file, corrupt file, shape against config.json, NaN/inf) is one
InputError naming the file.
"""
from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from .config import ToffeConfig, load_config
from .errors import InputError
from .fileio import atomic_dir

CONFIG_FILE = "config.json"
OFS_FILE = "ofs.safetensors"
OFPD_FILE = "ofpd.safetensors"


@dataclass
class Checkpoint:
    """A loaded checkpoint; ofs[k-1] = dict(weight (1,C,K,K) f32, threshold float, leak float)."""

    config: ToffeConfig
    ofs: list[dict[str, Any]]
    ofpd_state: dict[str, np.ndarray]
    root: Path | None = None


def ofs_shape(config: ToffeConfig) -> tuple[int, int, int, int]:
    return (1, config.ofs_in_channels, config.ofs_kernel, config.ofs_kernel)


def dotie_ofs(config: ToffeConfig) -> list[dict[str, Any]]:
    """DOTIE's hand-set layer per stage (0.15, centre 0.2, leak 0.3), threshold 1.0 + 0.5 (k-1).

    DOTIE sums ON and OFF counts into one channel: the same weight on both polarity channels is
    that. The rising threshold makes an untrained cascade already separate something (faster
    objects make denser spikes), which keeps other engineers' tests non-trivial.
    """
    w = np.full(ofs_shape(config), 0.15, dtype=np.float32)
    c = config.ofs_kernel // 2
    w[:, :, c, c] = 0.2
    return [dict(weight=w.copy(), threshold=1.0 + 0.5 * (k - 1), leak=0.3) for k in range(1, config.n_speed_bins + 1)]


def random_ofpd_state(config: ToffeConfig, seed: int = 0) -> dict[str, np.ndarray]:
    """Untrained OFPD weights (PyTorch's default uniform(+-1/sqrt(fan_in)) init), numpy only."""
    from .ofpd_io import ofpd_param_shapes

    rng = np.random.default_rng(seed)
    shapes = ofpd_param_shapes(config)
    state = {}
    for name, shape in shapes.items():
        wshape = shapes[name.rsplit(".", 1)[0] + ".weight"]
        fan_in = int(np.prod(wshape[1:]))
        bound = 1.0 / np.sqrt(fan_in)
        state[name] = rng.uniform(-bound, bound, size=shape).astype(np.float32)
    return state


def save_checkpoint(path: str | os.PathLike, config: ToffeConfig, ofs_params: list[dict[str, Any]],
                    ofpd_state: dict[str, Any]) -> Path:
    """Write a checkpoint directory atomically (a crash never leaves a half checkpoint)."""
    from safetensors.numpy import save_file

    config.validate()
    if len(ofs_params) != config.n_speed_bins:
        raise ValueError(f"{len(ofs_params)} OFS stages for {config.n_speed_bins} speed bins")
    ofs_t = {}
    for k, p in enumerate(ofs_params, start=1):
        ofs_t[f"stage{k}.weight"] = np.ascontiguousarray(np.asarray(p["weight"], dtype=np.float32))
        ofs_t[f"stage{k}.threshold"] = np.asarray(float(p["threshold"]), dtype=np.float32)
        ofs_t[f"stage{k}.leak"] = np.asarray(float(p["leak"]), dtype=np.float32)
    ofpd_t = {k: np.ascontiguousarray(_to_numpy(v), dtype=np.float32) for k, v in ofpd_state.items()}
    path = Path(path)
    with atomic_dir(path) as tmp:
        with open(tmp / CONFIG_FILE, "w", encoding="utf-8") as f:
            json.dump(config.to_dict(), f, indent=2)
            f.write("\n")
        save_file(ofs_t, str(tmp / OFS_FILE))
        save_file(ofpd_t, str(tmp / OFPD_FILE))
        for name in (CONFIG_FILE, OFS_FILE, OFPD_FILE):
            os.chmod(tmp / name, 0o644)                 # temp files are private; a checkpoint is not
        os.chmod(tmp, 0o755)
        _keep_extra_files(path, tmp)
    return path


def _keep_extra_files(old: Path, new: Path) -> None:
    """Carry files we do not write (README.md, .train_state/, logs, per-dt sub-checkpoints) into
    the new directory, so re-saving a checkpoint never drops them."""
    if not old.is_dir():
        return
    import shutil

    for p in old.iterdir():
        if p.name not in (CONFIG_FILE, OFS_FILE, OFPD_FILE) and not (new / p.name).exists():
            if p.is_dir():
                shutil.copytree(p, new / p.name)
            else:
                shutil.copy2(p, new / p.name)


def _to_numpy(v: Any) -> np.ndarray:
    if hasattr(v, "detach"):
        v = v.detach().cpu().numpy()
    return np.asarray(v)


def init_checkpoint(path: str | os.PathLike, config: ToffeConfig, seed: int = 0) -> Path:
    """Write an untrained checkpoint: DOTIE OFS stages (see dotie_ofs) and a random OFPD."""
    return save_checkpoint(path, config, dotie_ofs(config), random_ofpd_state(config, seed))


def _read_safetensors(path: Path) -> dict[str, np.ndarray]:
    from safetensors.numpy import load_file

    if not path.is_file():
        raise InputError(path, "missing file")
    try:
        return load_file(str(path))
    except Exception as exc:  # safetensors raises SafetensorError / ValueError / OSError
        raise InputError(path, f"not a valid safetensors file ({type(exc).__name__}: {str(exc).splitlines()[0][:120]})") from None


def _check_finite(path: Path, name: str, a: np.ndarray) -> None:
    if not np.issubdtype(a.dtype, np.floating):
        raise InputError(path, f"tensor {name} has dtype {a.dtype}, expected float")
    if not np.all(np.isfinite(a)):
        raise InputError(path, f"tensor {name} holds NaN or infinite values")


def load_checkpoint(path: str | os.PathLike) -> Checkpoint:
    """Load and validate a checkpoint directory (see module docstring)."""
    root = Path(path)
    if not root.exists():
        raise InputError(root, "checkpoint directory does not exist")
    if root.is_dir() and (root / "manifest.json").is_file() and not (root / OFS_FILE).exists():
        raise InputError(root, "a deploy bundle (export's output), not a checkpoint: give the checkpoint "
                               "directory it was exported from (e.g. ckpt/)")
    if not root.is_dir() or not any((root / f).exists() for f in (CONFIG_FILE, OFS_FILE, "ofpd.safetensors")):
        unfinished = root.is_dir() and (root / ".train_state").is_dir()     # model.train.STATE_DIR
        raise InputError(root, "not a checkpoint directory (expected config.json, ofs.safetensors, ofpd.safetensors)"
                               + ("; it holds a stopped training run's progress: finish it with `toffe-deploy train "
                                  "... --resume` and the same options" if unfinished else ""))
    config = load_config(root / CONFIG_FILE)
    try:
        from .ofpd_io import ofpd_param_shapes
        expected_ofpd = ofpd_param_shapes(config)
    except (ValueError, KeyError, TypeError) as exc:
        raise InputError(root / CONFIG_FILE, f"bad ofpd settings: {exc}") from None

    ofs_path = root / OFS_FILE
    t = _read_safetensors(ofs_path)
    ofs = []
    wshape = ofs_shape(config)
    for k in range(1, config.n_speed_bins + 1):
        p = {}
        for part, shape in (("weight", wshape), ("threshold", ()), ("leak", ())):
            name = f"stage{k}.{part}"
            if name not in t:
                raise InputError(ofs_path, f"missing tensor {name} ({config.n_speed_bins} stages in config.json)")
            a = t[name]
            if tuple(a.shape) != tuple(shape):
                raise InputError(ofs_path, f"tensor {name} has shape {list(a.shape)}, config.json implies {list(shape)}")
            _check_finite(ofs_path, name, a)
            p[part] = a.astype(np.float32) if part == "weight" else float(a)
        if p["threshold"] <= 0:
            raise InputError(ofs_path, f"stage{k}.threshold must be > 0, got {p['threshold']}")
        if not 0.0 <= p["leak"] <= 1.0:
            raise InputError(ofs_path, f"stage{k}.leak must be in [0, 1], got {p['leak']}")
        ofs.append(p)
    extra = sorted(set(t) - {f"stage{k}.{q}" for k in range(1, config.n_speed_bins + 1) for q in ("weight", "threshold", "leak")})
    if extra:
        raise InputError(ofs_path, f"unexpected tensors {', '.join(extra[:4])} (config.json has {config.n_speed_bins} stages)")

    ofpd_path = root / OFPD_FILE
    st = _read_safetensors(ofpd_path)
    missing = sorted(set(expected_ofpd) - set(st))
    if missing:
        raise InputError(ofpd_path, f"missing tensors {', '.join(missing[:4])}")
    unexpected = sorted(set(st) - set(expected_ofpd))
    if unexpected:
        raise InputError(ofpd_path, f"unexpected tensors {', '.join(unexpected[:4])}")
    for name, shape in expected_ofpd.items():
        if tuple(st[name].shape) != tuple(shape):
            raise InputError(ofpd_path, f"tensor {name} has shape {list(st[name].shape)}, config.json implies {list(shape)}")
        _check_finite(ofpd_path, name, st[name])
    return Checkpoint(config=config, ofs=ofs, ofpd_state={k: st[k].astype(np.float32) for k in expected_ofpd}, root=root)
