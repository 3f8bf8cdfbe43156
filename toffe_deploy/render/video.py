"""Frame sinks of ``run --render``: a folder of PNG frames, or one H.264 MP4 that browsers play.

The MP4 is encoded by PyAV (``av``, BSD-3-Clause; its binary wheels bundle FFmpeg with the
libx264 encoder, which is GPL-2.0-or-later: see README "Rendering"): H.264 High profile,
``avc1`` in an MP4 (ISO BMFF) container, yuv420p, constant frame rate, ``movflags=+faststart``
(the index comes first, so a browser starts playing before the whole file arrived). yuv420p
needs even sides: an odd frame is padded by one row / column of its border pixels.

Nothing partial is left: frames go to a hidden stage directory inside the output directory and
are moved into place by ``close(ok=True)``; the MP4 is re-opened first and must decode as h264
with every frame written, else the run fails naming it. ``close(ok=False)`` (or any error)
removes the stage, and a directory the sink created stays only when something was kept.
"""
from __future__ import annotations

import contextlib
import fractions
import os
import re
import shutil
import tempfile
from pathlib import Path

import numpy as np

from ..errors import InputError, ToffeError
from ..fileio import write_errors

VIDEO_NAME = "object_flow.mp4"
#: x264 quality (constant rate factor; 23 is x264's default, lower = better) and speed preset
CRF = 23
PRESET = "veryfast"
MAX_FPS = 1000


def even(frame: np.ndarray) -> np.ndarray:
    """The frame padded (edge pixels repeated) to even width and height, as yuv420p needs."""
    h, w = frame.shape[:2]
    if h % 2 == 0 and w % 2 == 0:
        return frame
    return np.pad(frame, ((0, h % 2), (0, w % 2), (0, 0)), mode="edge")


def video_info(path: str | os.PathLike) -> tuple[str, str, int]:
    """(codec name, pixel format, decoded frame count) of a video file's first video stream."""
    import av

    with av.open(str(path)) as c:
        st = c.streams.video[0]
        n = sum(1 for _ in c.decode(st))
        return st.codec_context.name, st.codec_context.pix_fmt, n


class H264Writer:
    """Frames (BGR uint8, all one size) -> an H.264 MP4 at ``path`` (module doc)."""

    def __init__(self, path: Path, fps: float):
        try:
            import av
        except ImportError:
            raise ToffeError("--video needs PyAV for H.264: pip install 'toffe-deploy[video]' (or av); "
                             "drop --video to write PNG frames") from None
        self._av = av
        self.path = path
        self.fps = fractions.Fraction(fps).limit_denominator(1001)
        self._c = None
        self._s = None

    def _open(self, w: int, h: int) -> None:
        av = self._av
        self._c = av.open(str(self.path), "w", format="mp4", options={"movflags": "+faststart"})
        try:
            self._s = self._c.add_stream("libx264", rate=self.fps)
        except (av.error.FFmpegError, ValueError) as exc:
            raise ToffeError(f"this PyAV build has no libx264 H.264 encoder ({exc}); drop --video") from None
        self._s.width, self._s.height, self._s.pix_fmt = w, h, "yuv420p"
        self._s.options = {"crf": str(CRF), "preset": PRESET}

    def write(self, frame: np.ndarray) -> None:
        frame = even(frame)
        if self._c is None:
            self._open(frame.shape[1], frame.shape[0])
        vf = self._av.VideoFrame.from_ndarray(np.ascontiguousarray(frame), format="bgr24")
        for pkt in self._s.encode(vf):
            self._c.mux(pkt)

    def close(self) -> None:
        """Flush the encoder and write the index (first, faststart)."""
        if self._c is None:
            return
        try:
            if self._s is not None:
                for pkt in self._s.encode():
                    self._c.mux(pkt)
        finally:
            c, self._c = self._c, None
            c.close()


FRAME_NAME = re.compile(r"frame_(\d{6})\.png")


class FrameSink:
    """One frame per window into ``out_dir``: ``frame_NNNNNN.png`` files (those of an earlier,
    longer run past this one's last are removed), or with ``video`` one ``object_flow.mp4``
    (staged and checked, module doc)."""

    def __init__(self, out_dir: str | os.PathLike, video: bool = False, fps: float = 10.0):
        self.out_dir = Path(out_dir)
        self._created = not self.out_dir.exists()
        if video and not 0 < fps <= MAX_FPS:
            raise ToffeError(f"--fps must be in (0, {MAX_FPS}], got {fps:g}")
        try:
            self.out_dir.mkdir(parents=True, exist_ok=True)
            self._stage = Path(tempfile.mkdtemp(prefix=".frames-", suffix=".tmp", dir=self.out_dir))
        except OSError as exc:
            raise InputError(self.out_dir, f"cannot create the render directory: {exc.strerror or exc}") from None
        self.video = video
        self.n = 0
        self._writer = None
        if video:
            try:
                self._writer = H264Writer(self._stage / VIDEO_NAME, fps)
            except BaseException:
                self._drop()
                raise

    def add(self, frame: np.ndarray) -> None:
        if self._writer is None:
            import cv2

            ok, png = cv2.imencode(".png", frame)   # encoded in memory: imwrite reports success on a full disk
            if not ok:
                raise ToffeError("this OpenCV build cannot encode PNG")
            with write_errors(self.out_dir), open(self._stage / f"frame_{self.n:06d}.png", "wb") as fh:
                fh.write(png.tobytes())
        else:
            with self._video_errors():
                self._writer.write(frame)
        self.n += 1

    def _video_errors(self):
        """FFmpeg's own I/O failing (a full disk) as one InputError naming the video."""
        av = self._writer._av

        @contextlib.contextmanager
        def ctx():
            try:
                yield
            except (av.error.FFmpegError, OSError) as exc:
                raise InputError(self.out_dir / VIDEO_NAME, f"the video writer failed: "
                                                            f"{getattr(exc, 'strerror', None) or exc} (disk full?); "
                                                            "nothing written") from None
        return ctx()

    def close(self, ok: bool = True) -> None:
        """Move the frames (or the checked video) into ``out_dir`` when ``ok``; always drop the stage."""
        try:
            if self._writer is not None:
                if ok:
                    with self._video_errors():
                        self._writer.close()
                    self._check_video(self._stage / VIDEO_NAME)
                else:                   # the run failed: its error (or signal) is the one to report
                    with contextlib.suppress(Exception):
                        self._writer.close()
            if ok:
                with write_errors(self.out_dir):
                    for f in sorted(self._stage.iterdir()):
                        os.replace(f, self.out_dir / f.name)
                    if self._writer is None:
                        self._drop_stale_frames()
        finally:
            self._drop()

    def _drop_stale_frames(self) -> None:
        """Frames ``frame_NNNNNN.png`` numbered past this run's last, left by a longer run into
        the same directory: DIR holds one run's frames (they sat beside the new ones)."""
        for f in self.out_dir.glob("frame_*.png"):
            m = FRAME_NAME.fullmatch(f.name)
            if m and int(m.group(1)) >= self.n:
                f.unlink()

    def _drop(self) -> None:
        shutil.rmtree(self._stage, ignore_errors=True)
        if self._created and self.out_dir.is_dir() and not any(self.out_dir.iterdir()):
            self.out_dir.rmdir()       # a failed run leaves no trace, not even an empty DIR

    def _check_video(self, path: Path) -> None:
        if self.n == 0:
            return
        av = self._writer._av
        try:
            codec, _fmt, frames = video_info(path)
        except (av.error.FFmpegError, OSError, IndexError):   # unreadable or no video stream: broken file
            codec, frames = "unreadable", 0
        if codec != "h264" or frames != self.n:
            raise InputError(self.out_dir / VIDEO_NAME, f"the video writer stored {frames} of {self.n} frames "
                                                         f"({codec}; disk full?); nothing written")
