"""Drawing primitives on a BGR uint8 image, shared by ``run --render`` and ``dataset show``.

Palette: the paper's object-flow colour wheel (Fig. 1a, the optical-flow convention): hue =
direction of motion in degrees on the image plane, y down (0 = moving right, 90 = moving down the
image, 180 = left, 270 = up), at fixed saturation ``PALETTE_SAT`` and full value. At full
saturation blue (hue 240) has a luma of 29/255 and vanishes on black; at 0.7 the darkest hue has
97 and the brightest (yellow) 235, and every coloured stroke and label gets a dark halo, so the
palette reads on black (``dark`` theme) and white (``light`` theme) alike. Events are grey levels
(ON brighter than OFF on dark, darker on light), so colour only ever means direction.

Marks: a detected object is a thick arrow from its centre along its direction (``unit`` px per
speed bin, unit = min(W, H) / 24 sensor px, 20 px on 640x480), a dot at the centre, an optional
trail (its last centres; no segment longer than TRAIL_JUMP units) and a label "#id b<bin> <speed>
m/s" placed beside it (the free side among four, away from its arrow, other labels and objects).
A faint object (``ofpd.faint_objects``: its position measured, its direction a guess and its
speed bin 1's) is a neutral grey ring and dot with no arrow, labelled "#id faint", and its
trail's segment to it is grey.
Ground truth is a dashed outline in its direction's colour, 2 px + 1.5 sensor px outside the
object (not over its edge events), and a thin arrow. Frames of small sensors are upscaled by an integer factor
(``frame_scale``) so labels stay legible.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Iterable, Sequence

import cv2
import numpy as np

#: saturation of every direction colour (see module doc: readable on black and white)
PALETTE_SAT = 0.7
#: frames are upscaled until their shorter side is at least this many pixels (integer factor)
MIN_SIDE_PX = 360
MAX_SCALE = 16
#: trail segments longer than this many units (min(W, H) / 24 px) are not drawn (an id switch)
TRAIL_JUMP = 6
#: clearance (px) a label keeps from other labels, objects and its arrow
LABEL_PAD = 3
FONT = cv2.FONT_HERSHEY_SIMPLEX
HALO = (24, 24, 24)
#: a faint object's colour: neutral grey (colour means direction, and its direction is a guess)
FAINT = (190, 190, 190)


@dataclass(frozen=True)
class Theme:
    """Background, event (ON / OFF) and foreground colours, BGR; ``text_halo`` rims foreground text."""

    bg: tuple[int, int, int]
    on: tuple[int, int, int]
    off: tuple[int, int, int]
    fg: tuple[int, int, int]
    text_halo: tuple[int, int, int]


THEMES = {"dark": Theme(bg=(0, 0, 0), on=(225, 225, 225), off=(115, 115, 115), fg=(250, 250, 250), text_halo=HALO),
          "light": Theme(bg=(255, 255, 255), on=(40, 40, 40), off=(160, 160, 160), fg=(10, 10, 10),
                         text_halo=(255, 255, 255))}


def theme_of(name: str) -> Theme:
    return THEMES[name]


def _wheel_table(saturation: float) -> np.ndarray:
    """(180, 3) BGR of OpenCV's 180 hue steps (2 deg each) at ``saturation``, full value."""
    hsv = np.stack([np.arange(180), np.full(180, round(255 * saturation)), np.full(180, 255)], axis=-1)
    return cv2.cvtColor(hsv.astype(np.uint8).reshape(-1, 1, 3), cv2.COLOR_HSV2BGR).reshape(180, 3)


_TABLE = _wheel_table(PALETTE_SAT)
_TUPLES = [tuple(int(v) for v in c) for c in _TABLE]


def _hue_step(direction_rad) -> np.ndarray:
    deg = np.mod(np.degrees(np.asarray(direction_rad, dtype=np.float64)), 360.0)
    return (np.round(deg / 2.0) % 180).astype(np.intp)


def flow_color(direction_rad: np.ndarray | float, saturation: float = PALETTE_SAT) -> np.ndarray:
    """BGR uint8 colour(s) of direction(s) on the flow colour wheel: hue = direction (module doc)."""
    table = _TABLE if saturation == PALETTE_SAT else _wheel_table(saturation)
    return table[_hue_step(direction_rad)]


def bgr(direction_rad: float) -> tuple[int, int, int]:
    """One direction's colour as the int tuple OpenCV draws with."""
    return _TUPLES[int(_hue_step(direction_rad))]


def hex_colour(c: Sequence[int]) -> str:
    """'#rrggbb' of a BGR colour (for SVG / HTML)."""
    return f"#{int(c[2]):02x}{int(c[1]):02x}{int(c[0]):02x}"


def colour_wheel(radius: int) -> tuple[np.ndarray, np.ndarray]:
    """(BGR image, mask) of a disk whose hue at each point is the angle of that point (y down)."""
    yy, xx = np.mgrid[-radius:radius + 1, -radius:radius + 1]
    return flow_color(np.arctan2(yy, xx)), (xx ** 2 + yy ** 2) <= radius ** 2


def frame_scale(sensor_size: tuple[int, int]) -> int:
    """Integer upscale of a W x H sensor so the shorter side reaches MIN_SIDE_PX (1 for >= 360 px):
    the smallest factor that does (rounding gave a DAVIS346's 260 px x1)."""
    return int(min(MAX_SCALE, max(1, -(-MIN_SIDE_PX // max(1, min(sensor_size))))))


def font_scale(img: np.ndarray) -> float:
    return float(np.clip(min(img.shape[:2]) / 900.0, 0.38, 0.7))


def event_image(pix: np.ndarray, on: np.ndarray, sensor_size: tuple[int, int], theme: Theme,
                scale: int = 1) -> np.ndarray:
    """(H*scale, W*scale, 3) image of a window's events: ``pix`` flat pixel indices (y * W + x),
    ``on`` their polarity; ON wins where both fired."""
    w, h = sensor_size
    img = np.zeros((h * w, 3), dtype=np.uint8) if not any(theme.bg) else np.tile(np.uint8(theme.bg), (h * w, 1))
    pix = np.asarray(pix, dtype=np.int64)
    on = np.asarray(on, dtype=bool)
    img[pix[~on]] = theme.off
    img[pix[on]] = theme.on
    img = img.reshape(h, w, 3)
    if scale > 1:
        img = np.repeat(np.repeat(img, scale, axis=0), scale, axis=1)
    return img


def to_px(x: float, y: float, scale: int) -> tuple[int, int]:
    """Sensor coordinates (pixel centres at integers) -> pixel of a frame upscaled by ``scale``."""
    return int(round((x + 0.5) * scale - 0.5)), int(round((y + 0.5) * scale - 0.5))


def tip_of(c: tuple[int, int], length: float, direction_rad: float) -> tuple[int, int]:
    """The end of an arrow of ``length`` px from ``c`` along ``direction_rad`` (y down)."""
    return int(round(c[0] + length * math.cos(direction_rad))), int(round(c[1] + length * math.sin(direction_rad)))


def text(img: np.ndarray, s: str, org: tuple[int, int], colour, halo, fs: float) -> None:
    """Text with a rim of ``halo`` around every glyph (readable on any background)."""
    cv2.putText(img, s, org, FONT, fs, halo, 3, cv2.LINE_AA)
    cv2.putText(img, s, org, FONT, fs, colour, 1, cv2.LINE_AA)


def arrow(img: np.ndarray, p0, p1, colour, thickness: int = 2) -> None:
    """An arrow with a dark halo (visible on light and dark backgrounds)."""
    cv2.arrowedLine(img, p0, p1, HALO, thickness + 2, cv2.LINE_AA, tipLength=0.3)
    cv2.arrowedLine(img, p0, p1, colour, thickness, cv2.LINE_AA, tipLength=0.3)


def dashed(img: np.ndarray, pts: np.ndarray, colour, dash: float = 5.0, closed: bool = True,
           thickness: int = 1) -> None:
    """A dashed polyline through (n, 2) points: on for ``dash`` px, off for ``dash`` px."""
    pts = np.asarray(pts, dtype=np.float64).reshape(-1, 2)
    if closed:
        pts = np.vstack([pts, pts[:1]])
    seg = np.hypot(*np.diff(pts, axis=0).T)
    total = float(seg.sum())
    if total <= 0:
        return
    s = np.arange(0.0, total, 1.0)                       # one sample per pixel of arc length
    cum = np.concatenate([[0.0], np.cumsum(seg)])
    xy = np.stack([np.interp(s, cum, pts[:, 0]), np.interp(s, cum, pts[:, 1])], axis=1)
    on = (s // dash) % 2 == 0
    idx = np.flatnonzero(on)
    if idx.size < 2:
        return
    breaks = np.flatnonzero(np.diff(idx) > 1) + 1
    lines = [np.round(xy[g]).astype(np.int32) for g in np.split(idx, breaks) if g.size > 1]
    cv2.polylines(img, lines, False, colour, thickness, cv2.LINE_AA)


def _overlap(a, b) -> float:
    """Area shared by two boxes (x0, y0, x1, y1)."""
    return max(0, min(a[2], b[2]) - max(a[0], b[0])) * max(0, min(a[3], b[3]) - max(a[1], b[1]))


def place_label(size: tuple[int, int], centre: tuple[int, int], gap: int, tip: tuple[int, int] | None,
                taken: list, frame: tuple[int, int]) -> tuple[int, int]:
    """Top-left corner of a (w, h) label beside ``centre``: the first of right, left, above, below
    (``gap`` px from the centre, then twice that) with the least overlap with ``taken`` boxes (labels placed so far,
    objects) and the object's arrow (to ``tip``), kept inside the frame (W, H)."""
    w, h = size
    cx, cy = centre
    cands = [c for g in (gap, 2 * gap) for c in
             ((cx + g, cy - h // 2), (cx - g - w, cy - h // 2), (cx - w // 2, cy - g - h), (cx - w // 2, cy + g))]
    arrow_box = None
    if tip is not None:
        arrow_box = (min(cx, tip[0]) - 2, min(cy, tip[1]) - 2, max(cx, tip[0]) + 2, max(cy, tip[1]) + 2)
    best, best_cost = None, math.inf
    for x0, y0 in cands:
        x0 = int(np.clip(x0, 2, max(2, frame[0] - w - 2)))
        y0 = int(np.clip(y0, 2, max(2, frame[1] - h - 2)))
        box = (x0 - LABEL_PAD, y0 - LABEL_PAD, x0 + w + LABEL_PAD, y0 + h + LABEL_PAD)
        cost = sum(_overlap(box, t) for t in taken) + (2 * _overlap(box, arrow_box) if arrow_box else 0)
        if cost < best_cost:
            best, best_cost = (x0, y0), cost
            if cost == 0:
                break
    return best


@dataclass
class Mark:
    """One object to draw, in sensor pixels: centre, direction (rad, y down), speed bin, speed
    (m/s, or None), track id (None when the run has no tracker), and whether it is a faint object
    (position only: drawn without direction or speed)."""

    x: float
    y: float
    direction_rad: float
    speed_bin: int
    speed_mps: float | None = None
    track_id: int | None = None
    faint: bool = False

    @classmethod
    def of(cls, obj) -> "Mark":
        """From a JSON object dict of ``run`` (or anything with those attributes)."""
        get = obj.get if isinstance(obj, dict) else (lambda k, d=None: getattr(obj, k, d))
        tid = shown_track_id(get("track_id"), get("track"))
        sp = get("speed_mps")
        return cls(float(get("x")), float(get("y")), float(get("direction_rad")), int(get("speed_bin")),
                   None if sp is None else float(sp), tid, bool(get("faint", False)))

    def label(self) -> str:
        who = f"#{self.track_id} " if self.track_id is not None else ""
        if self.faint:
            return f"{who}faint"
        speed = f" {self.speed_mps:.0f} m/s" if self.speed_mps is not None else ""
        return f"{who}b{self.speed_bin}{speed}"


def shown_track_id(track_id, track) -> int | None:
    """The track id a picture shows for an object (its ``track_id`` and ``track`` state): None
    without one, and for a tentative track, whose id is provisional (README) and no track yet."""
    if track_id is None or (track is not None and track.get("confirmed", True) is False):
        return None
    return int(track_id)


@dataclass
class TruthMark:
    """A ground-truth object: centre, direction, bin, speed (m/s), id and, when the recording says
    its shape and size, the outline (``shape``, ``radius_px`` half-size in sensor px)."""

    x: float
    y: float
    direction_rad: float
    speed_bin: int
    speed_mps: float
    object_id: int
    shape: str | None = None
    radius_px: float | None = None

    def label(self) -> str:
        return f"#{self.object_id} b{self.speed_bin} {self.speed_mps:.1f} m/s"


def shape_outline(shape: str, cx: float, cy: float, r: float, margin: float = 0.0) -> np.ndarray | None:
    """(n, 2) outline of a data-set shape of half-size ``r`` px centred at (cx, cy), grown by
    ``margin`` px: the level ``margin`` of its signed distance (dataset.shapes.sdf) traced by
    OpenCV (the margin keeps the outline off the object's own edge events)."""
    from ..dataset.shapes import sdf

    if not r > 0.5:
        return None
    n = int(math.ceil(r + margin)) + 2
    yy, xx = np.mgrid[-n:n + 1, -n:n + 1].astype(np.float64)
    inside = (sdf(shape, xx, yy, r) <= margin).astype(np.uint8)
    contours, _ = cv2.findContours(inside, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    if not contours:
        return None
    c = max(contours, key=len).reshape(-1, 2).astype(np.float64)
    return c - n + np.array([cx, cy])


def draw_truth(img: np.ndarray, truths: Iterable[TruthMark], scale: int, unit: float, theme: Theme,
               labels: bool, taken: list) -> None:
    """Ground truth: dashed outline in the direction's colour (on a dark rim on light backgrounds),
    2 px + 1.5 sensor px outside the object's edge (a circle of ``unit`` px when the shape is unknown), thin arrow,
    and with ``labels`` "#id b<bin> <speed> m/s" beside it."""
    h, w = img.shape[:2]
    fs = font_scale(img)
    for t in truths:
        c = to_px(t.x, t.y, scale)
        margin = 2.0 + 1.5 * scale               # screen px: clear of the edge's own event pixels
        r = (t.radius_px if t.radius_px else unit) * scale
        pts = shape_outline(t.shape, c[0], c[1], r, margin) if t.shape and t.radius_px else None
        r += margin
        if pts is None:
            ang = np.linspace(0, 2 * np.pi, 48, endpoint=False)
            pts = np.stack([c[0] + r * np.cos(ang), c[1] + r * np.sin(ang)], axis=1)
        colour = bgr(t.direction_rad)
        if sum(theme.bg) > 382:                  # light background: a dark rim under the light hues
            cv2.polylines(img, [np.round(pts).astype(np.int32)], True, HALO, 3, cv2.LINE_AA)
        dashed(img, pts, colour, dash=5.0 * max(1, scale // 2), thickness=2)
        length = unit * scale * max(t.speed_bin, 1)
        tip = tip_of(c, length, t.direction_rad)
        arrow(img, c, tip, colour, 1)
        rr = int(r)
        taken.append((c[0] - rr, c[1] - rr, c[0] + rr, c[1] + rr))
        if labels:
            s = t.label()
            (tw, th), base = cv2.getTextSize(s, FONT, fs, 1)
            x0, y0 = place_label((tw, th + base), c, rr + 4, tip, taken, (w, h))
            text(img, s, (x0, y0 + th), theme.fg, theme.text_halo, fs)
            taken.append((x0, y0, x0 + tw, y0 + th + base))


def draw_marks(img: np.ndarray, marks: Sequence[Mark], scale: int, unit: float, theme: Theme,
               trails: dict[int, list[tuple[float, float, float]]] | None, taken: list) -> None:
    """Detected objects: trail (oldest to newest centre, each segment in its direction's colour),
    thick arrow, centre dot and the label beside the object (module doc)."""
    h, w = img.shape[:2]
    fs = font_scale(img)
    thick = 2 if scale < 3 else 3
    for m in marks:
        pts = (trails or {}).get(m.track_id) if m.track_id is not None else None
        if pts and len(pts) > 1:
            for (xa, ya, _), (xb, yb, db) in zip(pts[:-1], pts[1:]):
                if math.hypot(xb - xa, yb - ya) > TRAIL_JUMP * unit:
                    continue                      # a jump of a whole object or more: an id switch, not motion
                pa, pb = to_px(xa, ya, scale), to_px(xb, yb, scale)
                cv2.line(img, pa, pb, HALO, thick + 1, cv2.LINE_AA)
                cv2.line(img, pa, pb, FAINT if math.isnan(db) else bgr(db), thick - 1, cv2.LINE_AA)
    heads = []
    for m in marks:
        c = to_px(m.x, m.y, scale)
        if m.faint:                               # no measured direction or speed: a ring, no arrow
            colour, tip = FAINT, None
            rr = int(unit * scale * 0.6)
            cv2.circle(img, c, rr, HALO, thick + 2, cv2.LINE_AA)
            cv2.circle(img, c, rr, colour, thick, cv2.LINE_AA)
        else:
            length = unit * scale * max(m.speed_bin, 1)
            tip = tip_of(c, length, m.direction_rad)
            colour = bgr(m.direction_rad)
            arrow(img, c, tip, colour, thick)
        cv2.circle(img, c, thick + 1, HALO, -1, cv2.LINE_AA)
        cv2.circle(img, c, thick, colour, -1, cv2.LINE_AA)
        heads.append((m, c, tip, colour))
    r = int(unit * scale * 0.75)
    taken.extend((c[0] - r, c[1] - r, c[0] + r, c[1] + r) for _m, c, _t, _c in heads)
    for m, c, tip, colour in heads:
        s = m.label()
        (tw, th), base = cv2.getTextSize(s, FONT, fs, 1)
        x0, y0 = place_label((tw, th + base), c, r + 3, tip, taken, (w, h))
        text(img, s, (x0, y0 + th), colour, HALO, fs)
        taken.append((x0, y0, x0 + tw, y0 + th + base))


def draw_legend(img: np.ndarray, theme: Theme) -> tuple[int, int, int, int] | None:
    """Colour-wheel legend in the bottom-right corner: the wheel with its angles 0 / 90 / 180 /
    270 (deg, y down: 90 = moving down) on a translucent panel; omitted when the frame is too small.
    Returns its box (x0, y0, x1, y1), or None."""
    h, w = img.shape[:2]
    fs = font_scale(img) * 0.85
    rad = int(np.clip(min(h, w) / 16, 12, 36))
    (tw, th), _ = cv2.getTextSize("180", FONT, fs, 1)
    pw, ph = 2 * rad + 2 * tw + 16, 2 * rad + 2 * th + 18
    if pw + 4 > w or ph + 4 > h:
        return None
    x0, y0 = w - pw - 4, h - ph - 4
    roi = img[y0:y0 + ph, x0:x0 + pw]
    roi[:] = (0.3 * roi + 0.7 * np.array(theme.bg)).astype(np.uint8)
    cx, cy = x0 + pw // 2, y0 + ph // 2
    wheel, mask = colour_wheel(rad)
    sub = img[cy - rad:cy + rad + 1, cx - rad:cx + rad + 1]
    sub[mask] = wheel[mask]
    cv2.circle(img, (cx, cy), rad, HALO, 1, cv2.LINE_AA)
    for s, (dx, dy) in (("0", (1, 0)), ("90", (0, 1)), ("180", (-1, 0)), ("270", (0, -1))):
        (sw, sh), _ = cv2.getTextSize(s, FONT, fs, 1)
        px = cx + dx * (rad + 4) + (0 if dx > 0 else -sw if dx < 0 else -sw // 2)
        py = cy + dy * (rad + 4) + (sh if dy > 0 else 0 if dy < 0 else sh // 2)
        text(img, s, (int(px), int(py)), theme.fg, theme.text_halo, fs)
    return x0, y0, x0 + pw, y0 + ph


def compose(img: np.ndarray, marks: Sequence[Mark] = (), truths: Sequence[TruthMark] = (), *, scale: int,
            unit: float, theme: Theme, header: str | None = None,
            trails: dict[int, list[tuple[float, float, float]]] | None = None, truth_labels: bool = False,
            legend: bool = True) -> np.ndarray:
    """Draw a whole frame onto an event image in place: the legend first (objects and arrows are
    drawn over it, labels are placed off it: drawn last, it covered an object in its corner),
    ground truth under the detections, then detections with labels and a header line; returns ``img``."""
    taken: list = []
    box = draw_legend(img, theme) if legend else None
    if box is not None:
        taken.append(box)
    draw_truth(img, truths, scale, unit, theme, truth_labels, taken)
    draw_marks(img, marks, scale, unit, theme, trails, taken)
    if header:
        fs = font_scale(img)
        (_tw, th), _ = cv2.getTextSize(header, FONT, fs, 1)
        text(img, header, (4, th + 5), theme.fg, theme.text_halo, fs)
    return img


def unit_px(sensor_size: tuple[int, int]) -> float:
    """Arrow length per speed bin and nominal object radius, in sensor px: min(W, H) / 24, >= 4."""
    return max(4.0, min(sensor_size) / 24.0)


class Trails:
    """Each track's last ``length`` centres and directions, for trails across windows; a track
    not seen for ``length`` windows is dropped (objects without ``track_id`` get no trail)."""

    def __init__(self, length: int = 12):
        self.length = length
        self.points: dict[int, list[tuple[float, float, float]]] = {}
        self._seen: dict[int, int] = {}
        self._n = 0

    def update(self, marks: Sequence[Mark]) -> dict[int, list[tuple[float, float, float]]]:
        self._n += 1
        for m in marks:
            if m.track_id is None:
                continue
            pts = self.points.setdefault(m.track_id, [])
            pts.append((m.x, m.y, math.nan if m.faint else m.direction_rad))   # NaN: no direction, a grey segment
            del pts[:-self.length]
            self._seen[m.track_id] = self._n
        for tid in [t for t, n in self._seen.items() if self._n - n >= self.length]:
            del self._seen[tid], self.points[tid]
        return self.points
