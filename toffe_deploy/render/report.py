"""``run --report FILE.html``: one self-contained page about a run, for people.

Built from the run's JSON lines (what ``--out`` holds) and its summary (what ``--summary-json``
holds); nothing external is referenced (inline SVG and CSS, no scripts, no URLs), so the file can
be mailed or archived as is. Sections (element ids):

- ``summary``: the summary figures (windows, objects, throughput, real-time factor, latency
  percentiles, start-up, camera, skipped windows, bridge traffic, accuracy vs ground truth);
- ``bins``: per speed bin: detections, their share, tracks (that had a detection in the bin: a
  track that changed bin counts in each), mean and max speed (m/s), median
  image-plane speed (px/s), mean events per object (and the confusion matrix with ground truth);
- ``tracks``: tracks over time (one lane per track, a dot per window it was seen, hue = its
  direction) and their paths on the sensor;
- ``speed``: speed (m/s) over time per track, and a table per track (its windows: those it was
  detected in; a bin series holds several objects a window, so its windows are counted once).

Tracks are the objects' ``track_id`` of confirmed tracks (the tracker; a tentative track's id
is provisional and its objects count as detections only); without tracking, each speed bin is
one series and the page says so. Memory: one small tuple per detected object (about 100 bytes).
Charts show at most ``MAX_SERIES`` tracks (the longest) and ``MAX_POINTS`` points per series.
"""
from __future__ import annotations

import html
import math
import os
from collections import Counter, defaultdict
from datetime import datetime, timezone

import numpy as np

from ..fileio import atomic_path
from .draw import flow_color, hex_colour, shown_track_id

MAX_SERIES = 40
MAX_POINTS = 1500
MAX_TABLE_ROWS = 100
GOLDEN_DEG = 137.508

CSS = """body{font:14px/1.4 system-ui,sans-serif;margin:1.5em auto;max-width:1100px;color:#222;background:#fff}
h1{font-size:1.4em}h2{font-size:1.15em;margin-top:1.6em;border-bottom:1px solid #ccc}
table{border-collapse:collapse;margin:.5em 0}td,th{border:1px solid #ccc;padding:2px 8px;text-align:right}
th{background:#f2f2f2}td.l,th.l{text-align:left}.note{color:#666;font-size:.9em}
svg{background:#fafafa;border:1px solid #ddd;margin:.3em 0}svg text{font:11px sans-serif;fill:#333}"""


def _fmt(v, digits: int = 3) -> str:
    if v is None:
        return "-"
    if isinstance(v, bool):
        return str(v)
    if isinstance(v, int):
        return f"{v:,}"
    if isinstance(v, float):
        return "-" if not math.isfinite(v) else f"{v:.{digits}g}" if abs(v) < 1000 else f"{v:,.0f}"
    return html.escape(str(v))


def _table(header: list[str], rows: list[list], left: int = 1) -> str:
    th = "".join(f'<th class="l">{html.escape(h)}</th>' if i < left else f"<th>{html.escape(h)}</th>"
                 for i, h in enumerate(header))
    body = "".join("<tr>" + "".join(f'<td class="l">{c}</td>' if i < left else f"<td>{c}</td>"
                                    for i, c in enumerate(r)) + "</tr>" for r in rows)
    return f"<table><tr>{th}</tr>{body}</table>"


def series_colour(i: int) -> str:
    """A distinct colour per series: the flow wheel stepped by the golden angle."""
    return hex_colour(flow_color(math.radians(GOLDEN_DEG * i)))


class _Axes:
    """Maps data (x, y) into an SVG plot box of w x h px with margins, y up unless ``flip``."""

    def __init__(self, w, h, xr, yr, flip=False, m=(46, 12, 14, 30)):
        self.w, self.h, self.m, self.flip = w, h, m, flip
        self.x0, self.x1 = xr if xr[1] > xr[0] else (xr[0], xr[0] + 1)
        self.y0, self.y1 = yr if yr[1] > yr[0] else (yr[0], yr[0] + 1)

    def px(self, x, y):
        ml, mr, mt, mb = self.m
        u = ml + (np.asarray(x, float) - self.x0) / (self.x1 - self.x0) * (self.w - ml - mr)
        f = (np.asarray(y, float) - self.y0) / (self.y1 - self.y0)
        v = mt + (f if self.flip else 1 - f) * (self.h - mt - mb)
        return u, v

    def frame(self, xlabel, ylabel, yticks=None) -> str:
        ml, mr, mt, mb = self.m
        out = [f'<rect x="{ml}" y="{mt}" width="{self.w - ml - mr}" height="{self.h - mt - mb}" fill="none" '
               'stroke="#999"/>']
        for t in np.linspace(self.x0, self.x1, 6):
            u, _ = self.px(t, self.y0)
            out.append(f'<text x="{u:.1f}" y="{self.h - mb + 13}" text-anchor="middle">{t:.4g}</text>')
        ticks = yticks if yticks is not None else [(t, f"{t:.4g}") for t in np.linspace(self.y0, self.y1, 5)]
        for t, lab in ticks:
            _, v = self.px(self.x0, t)
            out.append(f'<text x="{ml - 4}" y="{v + 4:.1f}" text-anchor="end">{html.escape(lab)}</text>')
        out.append(f'<text x="{(ml + self.w - mr) / 2:.0f}" y="{self.h - 3}" text-anchor="middle">'
                   f'{html.escape(xlabel)}</text>')
        out.append(f'<text x="11" y="{(mt + self.h - mb) / 2:.0f}" text-anchor="middle" '
                   f'transform="rotate(-90 11 {(mt + self.h - mb) / 2:.0f})">{html.escape(ylabel)}</text>')
        return "".join(out)


def _svg(w: int, h: int, body: str, title: str) -> str:
    return (f'<svg width="{w}" height="{h}" viewBox="0 0 {w} {h}" role="img"><title>{html.escape(title)}</title>'
            f"{body}</svg>")


def _thin(idx: np.ndarray) -> np.ndarray:
    return idx if idx.size <= MAX_POINTS else idx[np.linspace(0, idx.size - 1, MAX_POINTS).astype(int)]


class RunReport:
    """Collects the windows of a run (``add``) and writes the page (``write``, module doc)."""

    def __init__(self, sensor_size: tuple[int, int], source: str = ""):
        self.sensor = tuple(int(v) for v in sensor_size)
        self.source = source
        self.windows = 0
        self.t_first = self.t_last = None
        # per object: t0_us, confirmed track id (None: untracked or tentative), bin, speed_mps,
        # speed_px_s, x, y, direction_rad, n_events
        self.rows: list[tuple] = []
        self.ids_seen = False            # whether the run tracked (any object carried a track_id)

    def add(self, window: dict) -> None:
        """One window's JSON dict ({t0_us, t1_us, objects}); objects may carry ``track_id``."""
        t0 = int(window["t0_us"])
        self.windows += 1
        self.t_first = t0 if self.t_first is None else min(self.t_first, t0)
        self.t_last = t0 if self.t_last is None else max(self.t_last, t0)
        for o in window.get("objects", []):
            self.ids_seen |= o.get("track_id") is not None
            tid = shown_track_id(o.get("track_id"), o.get("track"))
            self.rows.append((t0, tid, int(o["speed_bin"]), o.get("speed_mps"),
                              o.get("speed_px_s"), float(o["x"]), float(o["y"]), float(o["direction_rad"]),
                              o.get("n_events")))

    # -- data ---------------------------------------------------------------------------------
    def _columns(self) -> dict[str, np.ndarray]:
        def col(i, fill=np.nan):
            return np.array([fill if r[i] is None else r[i] for r in self.rows], dtype=np.float64)

        return {"t_ms": col(0) / 1000.0, "bin": col(2).astype(int), "mps": col(3), "pxs": col(4), "x": col(5),
                "y": col(6), "dir": col(7), "nev": col(8)}

    def _series(self) -> tuple[dict, bool]:
        """series key -> row indices; keys are track ids, or 'bin k' when no object has one."""
        tracked = self.ids_seen
        groups: dict = defaultdict(list)
        for i, r in enumerate(self.rows):
            if tracked:
                if r[1] is not None:
                    groups[r[1]].append(i)
            else:
                groups[f"bin {r[2]}"].append(i)
        return {k: np.asarray(v) for k, v in groups.items()}, tracked

    # -- sections -----------------------------------------------------------------------------
    def _summary(self, s: dict) -> str:
        lat = s.get("latency_ms") or {}
        rows = [["target", _fmt(s.get("target"))], ["windows", _fmt(s.get("windows"))],
                ["objects", _fmt(s.get("objects"))], ["wall time (s)", _fmt(s.get("wall_s"))],
                ["windows/s", _fmt(s.get("windows_per_s"))], ["real-time factor", _fmt(s.get("realtime_factor"))],
                ["start-up (s)", _fmt(s.get("startup_s"))]]
        what = s.get("latency_kind") or "latency per window"      # the simulator's is its wall time, said so
        rows += [[f"{html.escape(what)}, {q} (ms)", _fmt(lat.get(q))] for q in ("p50", "p90", "p99") if q in lat]
        if s.get("tag") and str(s.get("target", "")).startswith("loihi"):     # cpu and cuda run no Lava process
            rows.append(["Lava process models", html.escape(str(s["tag"]))])
        cam = s.get("camera")
        if isinstance(cam, dict):
            rows.append(["camera", ", ".join(f"{html.escape(str(k))} {_fmt(v)}" for k, v in cam.items()
                                             if not isinstance(v, (dict, list)))])
        sk = s.get("skipped") or {}
        if sk.get("windows"):
            rows.append(["skipped empty windows", f"{_fmt(sk['windows'])} in {_fmt(sk.get('gaps'))} gap(s)"])
        tr = s.get("bridge_traffic")
        if isinstance(tr, dict):
            rows += [[f"bridge {html.escape(str(k))}", _fmt(v)] for k, v in tr.items() if isinstance(v, (int, float))]
            per = tr.get("per_window")
            if isinstance(per, dict):
                rows += [[f"bridge per window: {html.escape(str(k).replace('_', ' '))}", _fmt(v)]
                         for k, v in per.items() if isinstance(v, (int, float))]
        e = s.get("errors")
        if isinstance(e, dict):
            rows += [["recall vs ground truth", _fmt(e.get("recall"))],
                     ["false positives per window", _fmt(e.get("fp_per_window"))],
                     ["bin accuracy", _fmt(e.get("bin_accuracy"))], ["pixE (px)", _fmt(e.get("pixE"))],
                     ["dirE (deg)", _fmt(e.get("dirE"))], ["speedE (m/s)", _fmt(e.get("speedE"))]]
        span = "-" if self.t_first is None else f"{self.t_first / 1000:.1f} - {self.t_last / 1000:.1f} ms"
        rows.append(["window starts", span])
        return '<section id="summary"><h2>Summary</h2>' + _table(["figure", "value"], rows) + "</section>"

    def _bins(self, c: dict, s: dict) -> str:
        n = len(self.rows)
        rows = []
        for k in sorted(set(c["bin"].tolist())):
            sel = c["bin"] == k
            tracks = {self.rows[i][1] for i in np.flatnonzero(sel)} - {None}
            mps, pxs, nev = c["mps"][sel], c["pxs"][sel], c["nev"][sel]
            rows.append([f"bin {k}", _fmt(int(sel.sum())), f"{100 * sel.sum() / n:.1f}%",
                         _fmt(len(tracks)) if tracks else "-",
                         _fmt(float(np.nanmean(mps))) if np.isfinite(mps).any() else "-",
                         _fmt(float(np.nanmax(mps))) if np.isfinite(mps).any() else "-",
                         _fmt(float(np.nanmedian(pxs))) if np.isfinite(pxs).any() else "-",
                         _fmt(float(np.nanmean(nev))) if np.isfinite(nev).any() else "-"])
        out = '<section id="bins"><h2>Per speed bin</h2>'
        if rows:
            out += _table(["bin", "detections", "share", "tracks", "mean m/s", "max m/s", "median px/s",
                           "mean events"], rows)
        else:
            out += '<p class="note">No object was detected.</p>'
        e = s.get("errors")
        conf = e.get("confusion") if isinstance(e, dict) else None
        if isinstance(conf, dict) and conf.get("labels"):
            labels = [str(v) for v in conf["labels"]]
            out += "<p>Ground-truth bin (rows) against the reported bin (columns), matched objects:</p>"
            out += _table(["true \\ reported"] + labels,
                          [[f"bin {lab}"] + [_fmt(int(v)) for v in row] for lab, row in zip(labels, conf["matrix"])])
        return out + "</section>"

    def _tracks(self, c: dict, series: dict, tracked: bool) -> str:
        out = '<section id="tracks"><h2>Tracks over time</h2>'
        if not tracked:
            out += ('<p class="note">The results carry no track ids (run without the tracker): one lane per '
                    "speed bin.</p>")
        if not series:
            return out + '<p class="note">Nothing to show: no object was detected.</p></section>'
        keys = sorted(series, key=lambda k: -len(series[k]))[:MAX_SERIES]
        if len(series) > len(keys):
            out += f'<p class="note">The {len(keys)} longest of {len(series)} tracks are shown.</p>'
        order = sorted(keys, key=lambda k: (c["t_ms"][series[k]].min(), str(k)))
        t0 = float(np.nanmin(c["t_ms"])) if c["t_ms"].size else 0.0
        t1 = float(np.nanmax(c["t_ms"])) if c["t_ms"].size else 1.0
        h = 40 + 18 * len(order)
        ax = _Axes(900, h, (t0, t1), (-0.5, len(order) - 0.5), flip=True, m=(70, 12, 10, 30))
        body = [ax.frame("window start (ms)", "", yticks=[(i, f"#{k}" if tracked else str(k))
                                                          for i, k in enumerate(order)])]
        for lane, k in enumerate(order):
            idx = _thin(series[k])
            u, v = ax.px(c["t_ms"][idx], np.full(idx.size, lane))
            cols = [hex_colour(cc) for cc in flow_color(c["dir"][idx])]
            body += [f'<circle cx="{a:.1f}" cy="{b:.1f}" r="3" fill="{cl}"/>' for a, b, cl in zip(u, v, cols)]
        lane = "track" if tracked else "speed bin"
        out += f"<p>One lane per {lane}, a dot per window it was seen in; hue = direction (flow colour wheel).</p>"
        out += _svg(900, h, "".join(body), "tracks over time")
        w, hh = self.sensor
        sc = min(900 / w, 500 / hh)
        ax2 = _Axes(int(w * sc) + 60, int(hh * sc) + 44, (0, w), (0, hh), flip=True, m=(46, 14, 14, 30))
        body = [ax2.frame("x (px)", "y (px, down)")]
        for i, k in enumerate(order):
            idx = _thin(series[k])
            u, v = ax2.px(c["x"][idx], c["y"][idx])
            colour = series_colour(i)
            if tracked:
                pts = " ".join(f"{a:.1f},{b:.1f}" for a, b in zip(u, v))
                body.append(f'<polyline points="{pts}" fill="none" stroke="{colour}" stroke-width="1.5"/>')
            else:                               # a bin holds several objects: positions, not a path
                body += [f'<circle cx="{a:.1f}" cy="{b:.1f}" r="1.5" fill="{colour}"/>' for a, b in zip(u, v)]
            body.append(f'<circle cx="{u[-1]:.1f}" cy="{v[-1]:.1f}" r="3" fill="{colour}"/>')
            body.append(f'<text x="{u[-1] + 4:.1f}" y="{v[-1] - 4:.1f}">{"#" if tracked else ""}{html.escape(str(k))}'
                        "</text>")
        out += ("<p>Paths on the sensor (the larger dot marks the last position).</p>" if tracked
                else "<p>Positions on the sensor per speed bin.</p>")
        out += _svg(ax2.w, ax2.h, "".join(body), "paths on the sensor")
        return out + "</section>"

    def _speed(self, c: dict, series: dict, tracked: bool) -> str:
        what = "track" if tracked else "speed bin"
        out = f'<section id="speed"><h2>Speed per {what}</h2>'
        if not series:
            return out + '<p class="note">Nothing to show: no object was detected.</p></section>'
        keys = sorted(series, key=lambda k: -len(series[k]))
        shown = keys[:MAX_SERIES]
        speed = c["mps"] if np.isfinite(c["mps"]).any() else c["pxs"]
        unit = "m/s" if speed is c["mps"] else "px/s"
        fin = speed[np.isfinite(speed)]
        ax = _Axes(900, 300, (float(np.nanmin(c["t_ms"])), float(np.nanmax(c["t_ms"]))),
                   (0.0, float(fin.max()) * 1.05 if fin.size else 1.0))
        body = [ax.frame("window start (ms)", f"speed ({unit})")]
        order = sorted(shown, key=lambda k: (c["t_ms"][series[k]].min(), str(k)))
        for i, k in enumerate(order):
            idx = _thin(series[k])
            ok = np.isfinite(speed[idx])
            u, v = ax.px(c["t_ms"][idx][ok], speed[idx][ok])
            if u.size:
                pts = " ".join(f"{a:.1f},{b:.1f}" for a, b in zip(u, v))
                body.append(f'<polyline points="{pts}" fill="none" stroke="{series_colour(i)}" stroke-width="1.5"/>')
                body.append(f'<text x="{min(u[-1] + 3, ax.w - 40):.1f}" y="{v[-1] - 3:.1f}" '
                            f'style="fill:{series_colour(i)}">{"#" if tracked else ""}{html.escape(str(k))}</text>')
        out += _svg(900, 300, "".join(body), f"speed per {what}")
        rows = []
        for k in keys[:MAX_TABLE_ROWS]:
            idx = series[k]
            sp = speed[idx]
            bins = Counter(c["bin"][idx].tolist()).most_common(1)[0][0]
            d = c["dir"][idx]
            mean_dir = math.degrees(math.atan2(np.sin(d).mean(), np.cos(d).mean())) % 360
            rows.append([(f"#{k}" if tracked else html.escape(str(k))), f"{c['t_ms'][idx].min():.1f}",
                         f"{c['t_ms'][idx].max():.1f}", _fmt(int(np.unique(c["t_ms"][idx]).size)), f"bin {bins}",
                         _fmt(float(np.nanmean(sp))) if np.isfinite(sp).any() else "-",
                         _fmt(float(np.nanmax(sp))) if np.isfinite(sp).any() else "-", f"{mean_dir:.0f}"])
        if len(keys) > MAX_TABLE_ROWS:
            out += f'<p class="note">The {MAX_TABLE_ROWS} longest of {len(keys)} tracks are listed.</p>'
        out += _table(["track" if tracked else "series", "first (ms)", "last (ms)", "windows", "most common bin",
                       f"mean {unit}", f"max {unit}", "mean direction (deg)"], rows)
        return out + "</section>"

    def html(self, summary: dict) -> str:
        c = self._columns()
        series, tracked = self._series()
        stamp = datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
        head = (f"<p>{html.escape(self.source)} &middot; sensor {self.sensor[0]}x{self.sensor[1]} &middot; "
                f"{_fmt(self.windows)} windows &middot; {_fmt(len(self.rows))} objects &middot; written {stamp}</p>")
        return ("<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><title>toffe-deploy run report"
                f"</title><style>{CSS}</style></head><body><h1>toffe-deploy run report</h1>{head}"
                + self._summary(summary) + self._bins(c, summary) + self._tracks(c, series, tracked)
                + self._speed(c, series, tracked) + "</body></html>\n")

    def write(self, path: str | os.PathLike, summary: dict) -> None:
        """The page, written atomically (a refused write is one InputError naming ``path``)."""
        page = self.html(summary)
        with atomic_path(path, suffix=".html") as tmp:
            tmp.write_text(page, encoding="utf-8")
