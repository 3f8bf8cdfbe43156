"""Summary statistics of an event file, computed in one streaming pass (which also validates
every event: ``events info`` doubles as a file checker)."""
from __future__ import annotations

import os

import numpy as np


def summarize(path: str | os.PathLike, sensor_size=None, sort: bool = False, progress: bool = True) -> dict:
    """events, time span, sensor size, event rate, polarity balance, ground truth summary.

    Rates are events per second over the covered span [t_start_us, t_end_us). Bounded memory:
    the file is read chunk by chunk.
    """
    from tqdm import tqdm

    from .convert import TimeUnitCheck
    from .io import open_events

    unit = TimeUnitCheck()
    with open_events(path, sensor_size=sensor_size, sort=sort) as src:
        n_on = n_total = 0
        x_min = y_min = None
        x_max = y_max = -1
        first = last = None
        with tqdm(total=src.num_events, unit="ev", unit_scale=True, desc="reading", disable=None if progress else True,
                  leave=False) as bar:
            for ev in src.iter_chunks():
                if ev.shape[0] == 0:
                    continue
                n_total += int(ev.shape[0])
                n_on += int(np.count_nonzero(ev["p"]))
                unit.feed(ev["t"])
                first = int(ev["t"][0]) if first is None else first
                last = int(ev["t"][-1])
                x_min = min(int(ev["x"].min()), x_min if x_min is not None else 1 << 16)
                y_min = min(int(ev["y"].min()), y_min if y_min is not None else 1 << 16)
                x_max = max(int(ev["x"].max()), x_max)
                y_max = max(int(ev["y"].max()), y_max)
                bar.update(ev.shape[0])
        t0, t1 = src.t_start_us, src.t_end_us
        duration = t1 - t0
        info = {
            "path": os.fspath(path),
            "format": src.format_name,
            "events": n_total,
            "sensor_width": src.sensor_size[0],
            "sensor_height": src.sensor_size[1],
            "t_start_us": t0,
            "t_end_us": t1,
            "duration_s": duration / 1e6,
            "first_event_us": first,
            "last_event_us": last,
            "event_rate_eps": n_total / (duration / 1e6) if duration > 0 else 0.0,
            "on_events": n_on,
            "off_events": n_total - n_on,
            "on_fraction": n_on / n_total if n_total else None,
            "x_range": [x_min, x_max] if n_total else None,
            "y_range": [y_min, y_max] if n_total else None,
            "ground_truth": _gt_summary(src.ground_truth),
            "time_unit_note": unit.hint(),
            "attrs": src.attrs,
        }
    return info


def _gt_summary(gt: dict | None) -> dict | None:
    if gt is None:
        return None
    out: dict = {"rows": int(len(gt["t"])) if "t" in gt else 0, "columns": sorted(gt)}
    if "object_id" in gt and len(gt["object_id"]):
        ids = np.unique(gt["object_id"])
        out["objects"] = int(ids.size)
        out["object_ids"] = ids.tolist()[:50]
    if "t" in gt and len(gt["t"]) > 1:
        ts = np.unique(gt["t"])
        out["t_range_us"] = [int(ts[0]), int(ts[-1])]
        if ts.size > 1:
            out["sample_period_us"] = int(np.median(np.diff(ts)))
    if "speed_bin" in gt and len(gt["speed_bin"]):
        vis = gt["visible"].astype(bool) if "visible" in gt else np.ones(len(gt["speed_bin"]), bool)
        bins, counts = np.unique(gt["speed_bin"][vis], return_counts=True)
        out["visible_rows_per_speed_bin"] = {int(b): int(c) for b, c in zip(bins, counts)}
    if "speed" in gt and len(gt["speed"]):
        sp = gt["speed"].astype(np.float64)
        out["speed_mps"] = [float(np.nanmin(sp)), float(np.nanmax(sp))]
    return out


def _size_note(attrs: dict) -> str:
    """What the summary says of a sensor size the file does not record (npy: inferred; DSEC and
    MVSEC layouts: the layout's default), else nothing."""
    if attrs.get("sensor_size_inferred"):
        return " (inferred from the coordinates: pass --sensor-size WxH)"
    if attrs.get("sensor_size_default"):
        return f" ({attrs['sensor_size_default']}'s default: the file records none; pass --sensor-size WxH)"
    return ""


def format_info(info: dict) -> str:
    """Human-readable lines for ``toffe-deploy events info``."""
    n = info["events"]
    lines = [
        f"file:            {info['path']} ({info['format']})",
        f"events:          {n:,}",
        f"sensor size:     {info['sensor_width']} x {info['sensor_height']} px" + _size_note(info["attrs"]),
        f"time span:       [{info['t_start_us']}, {info['t_end_us']}) us",
        f"duration:        {info['duration_s']:.6f} s",
        f"event rate:      {info['event_rate_eps'] / 1e6:.4f} Mev/s",
    ]
    if n:
        lines.append(f"polarity:        {info['on_events']:,} ON / {info['off_events']:,} OFF "
                     f"({100 * info['on_fraction']:.1f} % ON)")
        lines.append(f"coordinates:     x {info['x_range'][0]}..{info['x_range'][1]}, "
                     f"y {info['y_range'][0]}..{info['y_range'][1]}")
    gt = info["ground_truth"]
    if gt is None:
        lines.append("ground truth:    none")
    else:
        desc = f"{gt['rows']:,} rows"
        if "objects" in gt:
            desc += f", {gt['objects']} object(s)"
        if "sample_period_us" in gt:
            desc += f", every {gt['sample_period_us']} us"
        lines.append(f"ground truth:    {desc}")
        if "speed_mps" in gt:
            lines.append(f"  speed:         {gt['speed_mps'][0]:.2f} .. {gt['speed_mps'][1]:.2f} m/s")
        if "visible_rows_per_speed_bin" in gt:
            lines.append("  speed bins:    " + ", ".join(f"bin {b}: {c:,}" for b, c in
                                                       gt["visible_rows_per_speed_bin"].items()))
    if "topic" in info["attrs"]:          # a ROS bag: which topic, message type and encoding
        a = info["attrs"]
        lines.append(f"topic:           {a['topic']} ({a['msgtype']}"
                     + (f", encoding {a['encoding']})" if a.get("encoding") else ")"))
    for k in ("generator", "seed"):
        if k in info["attrs"]:
            v = info["attrs"][k]
            lines.append(f"{k + ':':<17}{v if not isinstance(v, (dict, list)) else _short(v)}")
    if info.get("time_unit_note"):
        lines.append(f"note:            {info['time_unit_note']}")
    return "\n".join(lines)


def _short(v) -> str:
    import json

    s = json.dumps(v, sort_keys=True)
    return s if len(s) <= 100 else s[:97] + "..."
