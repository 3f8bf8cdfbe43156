"""``run --render DIR [--video]``: one frame per window, drawn in the style of render.draw.

Each frame shows the window's events, each object's arrow (hue = direction, length by bin),
label "#track b<bin> <speed> m/s" beside it and, for objects with a ``track_id`` (the tracker),
a trail through its last centres; the recording's ground truth, when it has some, as dashed
outlines with thin arrows; the colour-wheel legend; and a header with the window's time.
Objects without ``track_id``, or of a tentative track (its id is provisional), are drawn the
same without id and trail.
"""
from __future__ import annotations

import os
from typing import Iterable

from ..errors import ToffeError
from . import draw
from .truth import TruthShapes
from .video import VIDEO_NAME, FrameSink

__all__ = ["FrameRenderer", "VIDEO_NAME"]


#: Timestamps from here on are a clock's (us since 1970: DV cameras, ROS), not a recording's own.
EPOCH_FROM_US = 10 ** 12          # 11.6 days


def time_label(t_us: int) -> str:
    """A frame's time: ms into the recording, or a UTC clock time where the timestamps are a
    clock's (a 16-digit ms figure read "t = 1700000000000005.1 ms")."""
    if t_us < EPOCH_FROM_US:
        return f"{t_us / 1000:.1f} ms"
    import datetime

    clock = datetime.datetime.fromtimestamp(t_us // 10 ** 6, tz=datetime.timezone.utc)
    return f"{clock:%Y-%m-%d %H:%M:%S}.{t_us % 10 ** 6:06d} UTC"


#: the widest or tallest frame PNG takes here (libpng's default user limit, 1,000,000 px): a
#: 65535x1 sensor drawn 16x asked for 1,048,560 px, and libpng and OpenCV refused it with lines
#: of their own on stderr
MAX_FRAME_SIDE_PX = 1_000_000


def check_frame_size(sensor_size: tuple[int, int]) -> None:
    """ToffeError when a W x H sensor's frames (draw.frame_scale) exceed MAX_FRAME_SIDE_PX: checked
    before a run starts, not at its first frame."""
    w, h = (int(v) for v in sensor_size)
    s = draw.frame_scale((w, h))
    if max(w, h) * s > MAX_FRAME_SIDE_PX:
        raise ToffeError(f"--render: a {w}x{h} sensor draws {w * s:,}x{h * s:,} px frames, more than PNG takes "
                         f"({MAX_FRAME_SIDE_PX:,} px a side)")


class FrameRenderer:
    """Draws and writes the frames of a run (module doc); ``close(ok)`` keeps them only when ok."""

    def __init__(self, out_dir: str | os.PathLike, video: bool = False, fps: float = 10.0, theme: str = "dark",
                 attrs: dict | None = None, trail: int = 12):
        self.sink = FrameSink(out_dir, video=video, fps=fps)
        self.theme = draw.theme_of(theme)
        self.shapes = TruthShapes(attrs)
        self.trails = draw.Trails(trail)

    @property
    def n(self) -> int:
        return self.sink.n

    def frame(self, volume, window: dict, truths: Iterable = ()):
        """The BGR frame of one window: ``volume`` its SpikeVolume, ``window`` its JSON dict
        ({t0_us, t1_us, objects: [...]}, objects may carry track_id), ``truths`` its
        dataset.groundtruth.ObjectTruth rows."""
        _b, _c, h, w = volume.shape
        scale = draw.frame_scale((w, h))
        img = draw.event_image(volume.pix, volume.c == 1, (w, h), self.theme, scale)
        marks = [draw.Mark.of(o) for o in window.get("objects", [])]
        truth_marks = self.shapes.marks(truths)
        t0 = window.get("t0_us")
        header = None
        if t0 is not None:
            header = (f"t = {time_label(t0)}, {len(marks)} object{'' if len(marks) == 1 else 's'}"
                      + (", dashed: ground truth" if truth_marks else ""))
        return draw.compose(img, marks, truth_marks, scale=scale, unit=draw.unit_px((w, h)), theme=self.theme,
                            header=header, trails=self.trails.update(marks))

    def add(self, volume, window: dict, truths: Iterable = ()) -> None:
        self.sink.add(self.frame(volume, window, truths))

    def close(self, ok: bool = True) -> None:
        self.sink.close(ok)
