"""Open any supported event file by its content: one entry point for every command.

Formats, recognised by magic bytes first and extension second (a file named .h5 that is not
HDF5 is reported as corrupt, not guessed at):

- our HDF5 layout (root attr format = "toffe-events", see fmt_toffe): read and written;
- DSEC-style HDF5 (/events/{x,y,t,p} + /t_offset [+ /ms_to_idx]), default sensor 640x480;
- MVSEC-style HDF5 (/davis/{left,right}/events, N x 4 float: x, y, t [s], p [+-1]), 346x260;
- .npz (arrays x, y, t, p [+ sensor_size]) and .npy (structured array with x, y, t, p, or
  N x 4: x, y, t, p); written by ``write_events_npz``;
- AEDAT4 (iniVation DV) through the ``aedat`` package;
- Prophesee RAW (EVT 2.0 / 3.0) and DAT (header lines starting with ``%``; fmt_prophesee),
  Metavision HDF5 (/CD/events; fmt_metavision), ROS1 bags and ROS2 bag directories of
  dvs_msgs/EventArray or event_camera_msgs/EventPacket (fmt_rosbag, through ``rosbags``).

Refused for every format: a path that is not a regular file (a FIFO or device would block or
never end), timestamps beyond 2**53 us or a span over 7 days (validate.MAX_TIME_US,
MAX_DURATION_US: a corrupt timestamp, which would otherwise make window loops run for ever),
polarities other than 0/1, -1/+1 or bool. A ``sensor_size`` argument overrides the file's (or
the format's default). ``sort=True`` loads
the whole file and sorts it by time (stable) instead of rejecting decreasing timestamps.
"""
from __future__ import annotations

import contextlib
import os
import stat
from pathlib import Path

import numpy as np

from ..errors import InputError
from .core import Events
from .fmt_toffe import FORMAT_NAME, ToffeH5Source, write_events_h5
from .sequential import SequentialSource
from .source import ArraySource, EventSource
from .validate import check_event_ends, check_time_span

#: what h5py and numpy raise on a file whose structure or attributes are not what its layout
#: says (a corrupt heap, an attribute of the wrong type, a dataset of the wrong kind): bad input
_MALFORMED = (RuntimeError, OSError, KeyError, ValueError, TypeError, IndexError, AttributeError)


def _malformed(path: Path, exc: BaseException) -> InputError:
    """The one-line error for a file whose reader failed on its content (_MALFORMED)."""
    line = (str(exc).splitlines() or [type(exc).__name__])[0]
    return InputError(path, f"malformed or corrupt file ({type(exc).__name__}: {line})")

__all__ = ["open_events", "read_events", "write_events_h5", "write_events_npz", "EventSource",
           "detect_format", "FORMATS"]

HDF5_MAGIC = b"\x89HDF\r\n\x1a\n"
NPY_MAGIC = b"\x93NUMPY"
ZIP_MAGIC = b"PK\x03\x04"
AEDAT4_MAGIC = b"#!AER-DAT4.0"
ROSBAG1_MAGIC = b"#ROSBAG V2.0"
#: Formats ``detect_format`` can answer, for ``--help`` texts.
FORMATS = (FORMAT_NAME, "dsec", "mvsec", "npz", "npy", "aedat4", "raw", "dat", "metavision", "rosbag")


def _sniff(path: Path) -> bytes:
    if not path.exists():
        raise InputError(path, "no such file")
    if path.is_dir():
        raise InputError(path, "is a directory, not an event file")
    if not stat.S_ISREG(path.stat().st_mode):
        raise InputError(path, "is not a regular file (a FIFO, socket or device would block or never end; "
                               "save the events to a file first)")
    try:
        with open(path, "rb") as fh:
            head = fh.read(16)
    except OSError as exc:
        raise InputError(path, f"cannot read: {exc.strerror or exc}") from None
    if not head:
        raise InputError(path, "empty file")
    return head


def _open_h5(path: Path):
    import h5py

    try:
        return h5py.File(path, "r")
    except OSError as exc:
        raise InputError(path, f"not a readable HDF5 file (truncated or corrupt?): {exc}") from None


def _h5_kind(path: Path, h5) -> str:
    if h5.attrs.get("format") in (FORMAT_NAME, FORMAT_NAME.encode()):
        return FORMAT_NAME
    if "events" in h5 and hasattr(h5["events"], "keys") and "t" in h5["events"]:
        return "dsec"          # /t_offset and /ms_to_idx are optional
    if "davis" in h5:
        return "mvsec"
    if "CD" in h5 and hasattr(h5["CD"], "keys") and "events" in h5["CD"]:
        return "metavision"
    raise InputError(path, "HDF5 file without an event layout we know (expected our "
                           "toffe-events layout, DSEC /events/{x,y,t,p}, MVSEC /davis/left/events "
                           "or Metavision /CD/events)")


def detect_format(path: str | os.PathLike) -> str:
    """The format name of an event file (one of FORMATS), from its content."""
    path = Path(path)
    if (path.is_dir() and (path / "metadata.yaml").is_file()) or \
            (path.suffix.lower() in (".db3", ".mcap") and (path.parent / "metadata.yaml").is_file()):
        return "rosbag"           # a ROS2 bag is a directory (or named by one of its files)
    head = _sniff(path)
    if head.startswith(HDF5_MAGIC) or (path.suffix.lower() in (".h5", ".hdf5", ".hdf") and _is_h5(path)):
        h5 = _open_h5(path)
        with _reading(path, h5.close):
            kind = _h5_kind(path, h5)
        h5.close()
        return kind
    if head.startswith(NPY_MAGIC):
        return "npy"
    if head.startswith(ZIP_MAGIC):
        return "npz"
    if head.startswith(AEDAT4_MAGIC):
        return "aedat4"
    if head.startswith(ROSBAG1_MAGIC):
        return "rosbag"
    if head.startswith(b"#!AER-DAT"):
        version = head[len(b"#!AER-DAT"):].split(b"\r")[0].split(b"\n")[0].decode("ascii", "replace").strip()
        raise InputError(path, f"AEDAT {version or '?'} (jAER / cAER) is not read: only AEDAT 4.0 (DV's); save it as "
                               "AEDAT4 or as a .npy / .npz of x, y, t, p")
    if head.startswith(b"%"):
        from .fmt_prophesee import prophesee_kind
        kind = prophesee_kind(path)
        if kind:
            return kind
    suffix = path.suffix.lower()
    if suffix in (".h5", ".hdf5", ".hdf", ".npz", ".npy", ".aedat4", ".aedat", ".raw", ".dat", ".bag"):
        raise InputError(path, f"does not look like a {suffix} file (truncated or corrupt?)")
    raise InputError(path, f"unknown event file format (supported: {', '.join(FORMATS)})")


def _is_h5(path: Path) -> bool:
    import h5py

    try:
        return bool(h5py.is_hdf5(path))   # HDF5 with a user block: magic at 512, 1024, ...
    except OSError:
        return False


@contextlib.contextmanager
def _reading(path: Path, on_error=None):
    """Reading a user's file: what its reader raised on the content (_MALFORMED) becomes a
    one-line InputError naming the file; ``on_error`` (a close) runs on any exception."""
    try:
        yield
    except BaseException as exc:
        if on_error is not None:
            on_error()
        if isinstance(exc, _MALFORMED) and not isinstance(exc, InputError):
            raise _malformed(path, exc) from None
        raise


def open_events(path: str | os.PathLike, sensor_size: tuple[int, int] | None = None,
                sort: bool = False) -> EventSource:
    """Open an event file of any supported format for chunked reading (see module docstring).

    Every problem with the file raises InputError naming it. ``sort=True`` loads the whole
    file into memory (the only way to sort); without it decreasing timestamps are an error.
    """
    path = Path(path)
    kind = detect_format(path)
    if kind in (FORMAT_NAME, "dsec", "mvsec", "metavision"):
        h5 = _open_h5(path)
        with _reading(path, h5.close):
            if kind == FORMAT_NAME:
                src = ToffeH5Source(path, h5, sensor_size)
            elif kind == "dsec":
                from .fmt_dsec import DsecSource
                src = DsecSource(path, h5, sensor_size)
            elif kind == "metavision":
                from .fmt_metavision import MetavisionH5Source
                src = MetavisionH5Source(path, h5, sensor_size)
            else:
                from .fmt_mvsec import MvsecSource
                src = MvsecSource(path, h5, sensor_size)
    elif kind in ("npz", "npy"):
        from .fmt_numpy import open_numpy
        with _reading(path):                     # a dtype or array of the wrong kind inside
            src = open_numpy(path, kind, sensor_size)
    elif kind in ("raw", "dat"):
        from .fmt_prophesee import PropheseeDatSource, PropheseeRawSource
        src = (PropheseeRawSource if kind == "raw" else PropheseeDatSource)(path, sensor_size)
    elif kind == "rosbag":
        from .fmt_rosbag import RosbagSource
        src = RosbagSource(path, sensor_size)
    else:
        from .fmt_aedat import AedatSource
        src = AedatSource(path, sensor_size)
    if sort:
        src = _sorted_source(src)
    with _reading(path, src.close):
        if not sort and not isinstance(src, SequentialSource):
            check_event_ends(path, src)
        check_time_span(path, src.t_start_us, src.t_end_us)
        if not sort and isinstance(src, SequentialSource) and src.disorder is not None:
            raise src.disorder                   # found by the metadata pass over the whole file (above)
    return src


def _sorted_source(src: EventSource) -> EventSource:
    """Load every event (coordinates and signs checked, order not), sort stably by t: an in-memory source."""
    with src:
        gt, attrs = src.ground_truth, src.attrs
        ev = src.read_unordered()
        n = int(ev.shape[0])
        ev = ev[np.argsort(ev["t"], kind="stable")]
        span = (min(src.t_start_us, int(ev["t"][0])) if n else src.t_start_us,
                max(src.t_end_us, int(ev["t"][-1]) + 1) if n else src.t_end_us)
        out = ArraySource(src.path, ev, src.sensor_size, gt, attrs, t_range=span, validated=True)
        out.format_name = src.format_name
        return out


def read_events(path: str | os.PathLike, sensor_size: tuple[int, int] | None = None,
                sort: bool = False) -> Events:
    """The whole file as Events (validated; sorted by time when ``sort``)."""
    with open_events(path, sensor_size=sensor_size, sort=sort) as src:
        return src.read_all()


def write_events_npz(path: str | os.PathLike, events: np.ndarray, sensor_size: tuple[int, int]) -> None:
    """Write events as an uncompressed-columns .npz (x, y, t, p, sensor_size), atomically."""
    from .fmt_numpy import write_npz
    write_npz(path, events, sensor_size)
