"""Write a synthetic data set: one HDF5 file per sequence (events + ground truth + generator
parameters, through events.io.write_events_h5) and an index.json that lists every sequence.

Layout::

    DIR/index.json              {"format": "toffe-synth-index", "version": 1, "seed": ...,
                                 "sequences": [{file, name, split, sensor_size, duration_s,
                                 n_events, seed, digest, shape, trajectory, speed_bin,
                                 orientation_deg, direction, objects: [...],
                                 appearance: {...}}, ...]}
    DIR/<split>/<name>.h5       one sequence

Re-running skips files whose stored digest (generator version + spec + seed) matches, so an
interrupted run resumes and a finished one is a no-op; ``force`` regenerates everything.
"""
from __future__ import annotations

import json
import os
import reprlib
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any, Iterable

import numpy as np

from ..errors import InputError, ToffeError
from ..fileio import atomic_path, read_json
from .splits import SPLITS, sequence_seed
from .synth import (GENERATOR_NAME, GENERATOR_VERSION, SequenceSpec, appearance_summary, generate_sequence,
                    object_tracks)

INDEX_FORMAT = "toffe-synth-index"
INDEX_VERSION = 1


def sequence_attrs(spec: SequenceSpec, seed: int) -> dict[str, Any]:
    """The JSON attrs stored in a sequence file (interface: objects, generator, seed)."""
    return {
        "objects": [o.to_dict() for o in spec.objects],
        "generator": {"name": GENERATOR_NAME, "version": GENERATOR_VERSION, "spec": spec.to_dict()},
        "seed": int(seed),
        "digest": spec.digest(seed),
        "split": spec.split,
        "name": spec.name,
        "appearance": appearance_summary(spec),
    }


def index_entry(spec: SequenceSpec, seed: int, file: str, n_events: int) -> dict[str, Any]:
    """One index.json row; the single-object columns repeat object 0 for easy filtering."""
    t_s = np.arange(spec.n_samples) * (spec.sample_us * 1e-6)
    _, gt = object_tracks(spec, t_s)
    objs = []
    for i, o in enumerate(spec.objects):
        sel = gt["object_id"] == i
        sp, spx = gt["speed"][sel], gt["speed_px_ms"][sel]
        tr = o.trajectory
        objs.append({"object_id": i, "shape": o.shape, "trajectory": tr.curve, "speed_bin": o.target_bin,
                     "orientation_deg": tr.orientation_deg, "direction": "cw" if tr.clockwise else "ccw",
                     "lap_time_s": tr.lap_time_s, "speed_min_mps": round(float(sp.min()), 3),
                     "speed_max_mps": round(float(sp.max()), 3), "speed_min_px_ms": round(float(spx.min()), 4),
                     "speed_max_px_ms": round(float(spx.max()), 4), "size_m": o.size_m,
                     "polarity": "bright" if o.intensity > spec.background else "dark"})
    first = objs[0]
    return {"file": file, "name": spec.name, "split": spec.split, "sensor_size": list(spec.camera.sensor_size),
            "duration_s": spec.duration_s, "n_events": int(n_events), "seed": int(seed),
            "digest": spec.digest(seed), "n_objects": len(objs),
            **{k: first[k] for k in ("shape", "trajectory", "speed_bin", "orientation_deg", "direction")},
            "objects": objs, "appearance": appearance_summary(spec)}


def _existing_events(path: Path, digest: str) -> int | None:
    """num_events of an up-to-date file at path, None if absent, stale or unreadable."""
    if not path.exists():
        return None
    from ..events.io import open_events

    try:
        with open_events(path) as src:
            if src.attrs.get("digest") == digest:
                return int(src.num_events)
    except ToffeError:
        return None
    return None


def build_sequence(spec: SequenceSpec, seed: int, root: Path, force: bool = False) -> dict[str, Any]:
    """Generate and write one sequence (or reuse an up-to-date file); return its index row."""
    from ..events.io import write_events_h5

    rel = f"{spec.split}/{spec.name}.h5"
    path = root / rel
    n = None if force else _existing_events(path, spec.digest(seed))
    if n is None:
        events, gt, sensor_size = generate_sequence(spec, seed)
        write_events_h5(path, events, sensor_size, ground_truth=gt, attrs=sequence_attrs(spec, seed),
                        t_range=(0, spec.n_samples * spec.sample_us))
        n = int(events.shape[0])
    return index_entry(spec, seed, rel, n)


def _build_star(args):
    return build_sequence(*args)


def read_index(root: str | os.PathLike) -> dict[str, Any] | None:
    """The index of a data-set directory, None when it has none; InputError when it is broken."""
    path = Path(root) / "index.json"
    if not path.exists():
        return None
    d = read_json(path)
    if not isinstance(d, dict) or d.get("format") != INDEX_FORMAT or not isinstance(d.get("sequences"), list):
        raise InputError(path, f"not a {INDEX_FORMAT} file")
    for i, row in enumerate(d["sequences"]):
        check_index_row(path, i, row)
    return d


#: the fields of an index row that its readers use (the split's files, a rebuild's kept rows)
ROW_FIELDS = ("file", "name", "split", "n_events")


def check_index_row(path: Path, i: int, row: Any) -> None:
    """InputError naming index.json for a row its readers would fail on with a TypeError or
    KeyError: not an object, or a field of ROW_FIELDS missing or of the wrong type."""
    if not isinstance(row, dict):
        raise InputError(path, f"sequences[{i}] is {reprlib.repr(row)}, expected an object")
    for key in ROW_FIELDS:
        if key not in row:
            raise InputError(path, f"sequences[{i}] lacks {key!r}")
        v = row[key]
        if key == "n_events":
            ok, want = isinstance(v, int) and not isinstance(v, bool) and v >= 0, "a whole number >= 0"
        else:
            ok, want = isinstance(v, str) and v != "", "a non-empty string"
        if not ok:
            raise InputError(path, f"sequences[{i}].{key} is {reprlib.repr(v)}, expected {want}")


def build_dataset(root: str | os.PathLike, specs_by_split: dict[str, list[SequenceSpec]], seed: int,
                  jobs: int = 1, force: bool = False, progress: bool = True) -> dict[str, Any]:
    """Write every spec's sequence under root and (re)write root/index.json atomically.

    Rows of splits not regenerated now are kept from an existing index, so splits can be built
    one at a time into one directory.
    """
    from tqdm import tqdm

    root = Path(root)
    if root.exists() and not root.is_dir():
        raise InputError(root, "exists and is not a directory")
    old = read_index(root) if root.exists() else None
    check_one_camera(root, old, {(int(s.camera.width), int(s.camera.height))
                                 for specs in specs_by_split.values() for s in specs}, specs_by_split)
    todo = [(spec, sequence_seed(seed, "dvs:" + spec.name), root, force)
            for split in specs_by_split for spec in specs_by_split[split]]
    bar = tqdm(total=len(todo), desc="synth", unit="seq", file=sys.stderr, disable=not progress)
    rows: list[dict[str, Any]] = []
    try:
        if jobs > 1:
            with ProcessPoolExecutor(max_workers=jobs) as pool:
                for row in pool.map(_build_star, todo):
                    rows.append(row)
                    bar.update(1)
        else:
            for args in todo:
                rows.append(build_sequence(*args))
                bar.update(1)
    finally:
        bar.close()
    kept = [r for r in (old or {}).get("sequences", []) if r.get("split") not in specs_by_split]
    order = {s: i for i, s in enumerate(SPLITS)}
    seqs = sorted(kept + rows, key=lambda r: (order.get(r.get("split"), 99), r.get("name", "")))
    index = {"format": INDEX_FORMAT, "version": INDEX_VERSION, "generator": GENERATOR_NAME,
             "generator_version": GENERATOR_VERSION, "seed": int(seed),
             "splits": {s: sum(1 for r in seqs if r["split"] == s) for s in SPLITS},
             "n_events": int(sum(r["n_events"] for r in seqs)), "sequences": seqs}
    with atomic_path(root / "index.json", suffix=".json") as tmp:
        tmp.write_text(json.dumps(index, indent=1) + "\n", encoding="utf-8")
    _warn_unlisted(root, specs_by_split, seqs)
    return index


def check_one_camera(root: Path, old: dict | None, new: set, splits) -> None:
    """InputError when the splits kept from the index ``old`` (those not in ``splits``, the ones
    regenerated) were made with another sensor size than ``new`` (the sizes now generated): one
    data set is one camera (train and eval read one size; a run wrote train at 346x260 and test
    at 640x480 into one index, exit 0). `dataset synth` asks before its other checks too."""
    kept = {}
    for r in (old or {}).get("sequences", []):
        if r.get("split") not in splits and isinstance(r.get("sensor_size"), list) and len(r["sensor_size"]) == 2:
            kept.setdefault(tuple(int(v) for v in r["sensor_size"]), set()).add(r.get("split"))
    other = {size: held for size, held in kept.items() if size not in new}
    if new and other:
        (w, h), held = next(iter(other.items()))
        nw, nh = next(iter(new))
        raise InputError(root, f"holds {', '.join(sorted(map(str, held)))} at {w}x{h}; these splits would be "
                               f"{nw}x{nh}: a data set is one camera (train and eval read one sensor size): "
                               "generate into another --out, or regenerate every split (--split all)")


def _warn_unlisted(root: Path, specs_by_split: dict, seqs: list) -> None:
    """Warn of .h5 files in a regenerated split's folder that the index no longer lists (an
    earlier run with more sequences, or a larger --limit): `eval --split DIR/SPLIT/` would read
    them. They are left in place: the folder may hold the user's own files."""
    from ..errors import warn

    listed = {str(r.get("file")) for r in seqs}
    for split in specs_by_split:
        folder = root / split
        extra = sorted(p.name for p in folder.glob("*.h5") if f"{split}/{p.name}" not in listed) \
            if folder.is_dir() else []
        if extra:
            warn(f"{folder}: {len(extra)} .h5 file(s) the index does not list (e.g. {extra[0]}; from an earlier, "
                 "larger run): training reads the index, but `eval --split` on that folder would read them too; "
                 "delete them")


def iter_split_files(root: str | os.PathLike, split: str | None = None) -> Iterable[Path]:
    """Paths of the sequence files an index lists (optionally one split), in index order."""
    index = read_index(root)
    if index is None:
        raise InputError(Path(root) / "index.json", "missing file (generate with `toffe-deploy dataset synth`)")
    for row in index["sequences"]:
        if split is None or row["split"] == split:
            yield Path(root) / row["file"]
