"""Frames of ``run --render``: a window's events with each object's flow as a coloured arrow.

Colour = the paper's object-flow colour wheel (Fig. 1a), the optical-flow convention: hue encodes
the direction of motion, hue = direction in degrees (image plane, y down, 0 = moving right,
90 = moving down the image), full saturation and value. Arrow: from the object's centre along
its direction, 20 px per speed bin long, labelled with its speed; a small wheel in the corner
is the legend. Events: ON white, OFF grey, on black. Frames go to DIR/frame_NNNNNN.png, or with
``video`` to DIR/object_flow.mp4 (OpenCV's mp4v writer); every file is written atomically.
"""
from __future__ import annotations

import math
import os
import shutil
import tempfile
from pathlib import Path
from typing import Sequence

import cv2
import numpy as np

from ..errors import InputError, ToffeError
from ..fileio import write_errors
from .pipeline import ObjectFlow
from .spikes import SpikeVolume

ARROW_PX_PER_BIN = 20
WHEEL_RADIUS = 24
VIDEO_NAME = "object_flow.mp4"


def flow_color(direction_rad: np.ndarray | float) -> np.ndarray:
    """BGR uint8 colour(s) of direction(s) on the flow colour wheel (hue = direction)."""
    deg = np.mod(np.degrees(np.asarray(direction_rad, dtype=np.float64)), 360.0)
    hsv = np.stack([np.round(deg / 2.0) % 180, np.full_like(deg, 255), np.full_like(deg, 255)], axis=-1)
    return cv2.cvtColor(hsv.astype(np.uint8).reshape(-1, 1, 3), cv2.COLOR_HSV2BGR).reshape(hsv.shape)


def colour_wheel(radius: int = WHEEL_RADIUS) -> tuple[np.ndarray, np.ndarray]:
    """(BGR image, mask) of a disk whose hue at each point is the angle of that point."""
    yy, xx = np.mgrid[-radius:radius + 1, -radius:radius + 1]
    img = flow_color(np.arctan2(yy, xx))
    return img, (xx ** 2 + yy ** 2) <= radius ** 2


def draw_window(volume: SpikeVolume, objects: Sequence[ObjectFlow], t0_us: int | None = None) -> np.ndarray:
    """(H, W, 3) BGR frame: the window's accumulated events and its objects' flow arrows."""
    _b, _c, h, w = volume.shape
    img = np.zeros((h * w, 3), dtype=np.uint8)
    on = volume.c == 1
    img[volume.pix[~on]] = 110
    img[volume.pix[on]] = 255                      # ON drawn last: wins where both polarities fired
    img = img.reshape(h, w, 3)
    wheel, mask = colour_wheel(min(WHEEL_RADIUS, max(4, min(h, w) // 8)))
    r = wheel.shape[0]
    if r + 4 <= min(h, w):
        roi = img[h - r - 2:h - 2, w - r - 2:w - 2]
        roi[mask] = wheel[mask]
    scale = max(0.3, min(h, w) / 800)
    for o in objects:
        colour = tuple(int(v) for v in flow_color(o.direction_rad))
        length = ARROW_PX_PER_BIN * max(o.speed_bin, 1)
        p0 = (int(round(o.x)), int(round(o.y)))
        p1 = (int(round(o.x + length * math.cos(o.direction_rad))), int(round(o.y + length * math.sin(o.direction_rad))))
        cv2.arrowedLine(img, p0, p1, colour, 2, cv2.LINE_AA, tipLength=0.3)
        cv2.putText(img, f"{o.speed_mps:.0f} m/s", (p0[0] + 4, p0[1] - 4), cv2.FONT_HERSHEY_SIMPLEX, scale, colour, 1,
                    cv2.LINE_AA)
    if t0_us is not None:
        cv2.putText(img, f"t = {t0_us / 1000:.1f} ms", (4, int(14 * scale / 0.5)), cv2.FONT_HERSHEY_SIMPLEX, scale,
                    (200, 200, 200), 1, cv2.LINE_AA)
    return img


class FrameRenderer:
    """Writes one frame per window to ``out_dir`` (PNG files, or one MP4 with ``video``).

    Nothing partial is left: PNG frames go to a hidden temp directory inside ``out_dir`` and are
    moved into place by ``close(ok=True)``; the MP4 is written to a temp file, re-opened to check
    it holds every frame (OpenCV's writer drops frames silently on a full disk), then renamed.
    On failure (``close(ok=False)``, or an exception here) the temp files are removed.
    """

    def __init__(self, out_dir: str | Path, video: bool = False, fps: float = 10.0):
        self.out_dir = Path(out_dir)
        self._created = not self.out_dir.exists()
        try:
            self.out_dir.mkdir(parents=True, exist_ok=True)
            self._stage = Path(tempfile.mkdtemp(prefix=".frames-", suffix=".tmp", dir=self.out_dir))
        except OSError as exc:
            raise InputError(self.out_dir, f"cannot create the render directory: {exc.strerror or exc}") from None
        self.video = video
        self.fps = fps
        self.n = 0
        self._writer = None

    def add(self, volume: SpikeVolume, objects: Sequence[ObjectFlow], t0_us: int | None = None) -> None:
        frame = draw_window(volume, objects, t0_us)
        if not self.video:
            ok, png = cv2.imencode(".png", frame)   # encoded in memory: imwrite reports success on a full disk
            if not ok:
                raise ToffeError("this OpenCV build cannot encode PNG")
            with write_errors(self.out_dir), open(self._stage / f"frame_{self.n:06d}.png", "wb") as fh:
                fh.write(png.tobytes())
        else:
            if self._writer is None:
                h, w = frame.shape[:2]
                self._writer = cv2.VideoWriter(str(self._stage / VIDEO_NAME), cv2.VideoWriter_fourcc(*"mp4v"),
                                               self.fps, (w, h))
                if not self._writer.isOpened():
                    self._writer = None
                    raise ToffeError("this OpenCV build cannot write MP4 (mp4v); drop --video to write PNG frames")
            self._writer.write(frame)
        self.n += 1

    def close(self, ok: bool = True) -> None:
        """Move the frames (or the checked video) into ``out_dir`` when ``ok``; always drop the temp dir."""
        try:
            if self._writer is not None:
                self._writer.release()
                self._writer = None
                if ok:
                    self._check_video(self._stage / VIDEO_NAME)
            if ok:
                with write_errors(self.out_dir):
                    for f in sorted(self._stage.iterdir()):
                        os.replace(f, self.out_dir / f.name)
        finally:
            shutil.rmtree(self._stage, ignore_errors=True)
            if self._created and not any(self.out_dir.iterdir()):
                self.out_dir.rmdir()       # a failed run leaves no trace, not even an empty DIR

    def _check_video(self, path: Path) -> None:
        cap = cv2.VideoCapture(str(path))
        try:
            frames = int(cap.get(cv2.CAP_PROP_FRAME_COUNT)) if cap.isOpened() else 0
        finally:
            cap.release()
        if frames != self.n:
            raise InputError(self.out_dir / VIDEO_NAME, f"the video writer stored {frames} of {self.n} frames "
                                                         "(disk full?); nothing written")
