"""ROS1 bags (.bag) and ROS2 bag directories (metadata.yaml + .db3 / .mcap, or one of those files,
which names its directory) of event camera messages, through ``rosbags`` (Apache-2.0, pure Python; no ROS installation needed).

Messages read (the first topic, by name, of one of these types; ``attrs`` names it):

- ``dvs_msgs/EventArray`` (rpg_dvs_ros, ROS1 and ROS2): header, height, width, events[] of
  (x u16, y u16, ts time, polarity bool); t = ts in us (nanoseconds floored).
- ``event_camera_msgs/EventPacket`` (ros-event-camera's metavision_driver / libcaer_driver; also
  under its earlier name ``event_array_msgs/EventArray``):
  header, height, width, seq, time_base, encoding, is_bigendian, events (bytes). Encodings:
  ``mono`` (64-bit words: dt in bits 0-31, x 32-47, y 48-62, polarity 63; t = (time_base + dt)
  ns, floored to us) and ``evt3`` (a Prophesee EVT 3.0 stream continued from packet to packet,
  decoded by fmt_prophesee; t = sensor time in us). Other encodings (``trigger``, ``libcaer``)
  are refused.

The sensor size is the first message's width x height. dvs_msgs events are parsed from the
serialized bytes with numpy (their ROS1 and CDR layouts are fixed; a message laid out otherwise
is deserialized by rosbags, an object per event, ~100x slower); EventPacket bags decode in numpy.
Both ROS1 and ROS2 bags carry their message definitions, which ``rosbags`` uses; the two types
above are also registered, for ROS2 bags written without definitions.
"""
from __future__ import annotations

import contextlib
import functools
import tempfile
from pathlib import Path

import numpy as np

from ..errors import InputError
from .convert import to_events
from .core import EVENT_DTYPE
from .sequential import SequentialSource
from .validate import check_sensor_size

DVS_ARRAY = "dvs_msgs/msg/EventArray"
EVENT_PACKET = "event_camera_msgs/msg/EventPacket"
#: The same message under its earlier package name (event_array_msgs, 2022-2023 drivers).
EVENT_ARRAY_LEGACY = "event_array_msgs/msg/EventArray"
PACKET_TYPES = (EVENT_PACKET, EVENT_ARRAY_LEGACY)
#: Public message definitions (ROS2 syntax) of the message types read here.
MSG_DEFS = {
    "dvs_msgs/msg/Event": "uint16 x\nuint16 y\nbuiltin_interfaces/Time ts\nbool polarity\n",
    DVS_ARRAY: "std_msgs/Header header\nuint32 height\nuint32 width\ndvs_msgs/Event[] events\n",
    EVENT_PACKET: ("std_msgs/Header header\nuint32 height\nuint32 width\nuint64 seq\nuint64 time_base\n"
                   "string encoding\nbool is_bigendian\nuint8[] events\n"),
}
MSG_DEFS[EVENT_ARRAY_LEGACY] = MSG_DEFS[EVENT_PACKET]
ENCODINGS = ("mono", "evt3")


@functools.lru_cache(maxsize=4)
def typestore(store: str = "ROS2_HUMBLE"):
    """A rosbags typestore with the standard ROS types plus the event messages of MSG_DEFS."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    ts = get_typestore(getattr(Stores, store))
    types = {}
    for name, text in MSG_DEFS.items():
        types.update(get_types_from_msg(text, name))
    ts.register(types)
    return ts


def bag_root(path) -> Path:
    """The bag to open: a ROS2 bag's directory when ``path`` names one of its .db3 / .mcap files."""
    path = Path(path)
    if path.suffix.lower() in (".db3", ".mcap") and (path.parent / "metadata.yaml").is_file():
        return path.parent
    return path


@contextlib.contextmanager
def _reader(bag, path):
    """An open rosbags AnyReader of ``bag``; one it cannot open is an InputError naming ``path``."""
    try:
        from rosbags.highlevel import AnyReader
    except ImportError:
        raise InputError(path, "reading ROS bags needs the rosbags package (pip install rosbags)") from None
    with contextlib.ExitStack() as stack:
        bag = Path(bag)
        try:
            if bag.is_file() and bag.suffix != ".bag":
                # found by its content (#ROSBAG V2.0); rosbags picks its reader by the name's suffix, and
                # `rosbag record` leaves a killed recording as NAME.bag.active: open it through a .bag link
                tmp = Path(stack.enter_context(tempfile.TemporaryDirectory(prefix="toffe-bag-")))
                (tmp / "recording.bag").symlink_to(bag.resolve())
                bag = tmp / "recording.bag"
            reader = AnyReader([bag], default_typestore=typestore())
            reader.open()
        except Exception as exc:   # rosbags raises its own errors (and struct/sqlite ones) on bad bags
            raise InputError(path, f"cannot read ROS bag (truncated or corrupt?): {_msg(exc)}") from None
        try:
            yield reader
        finally:
            reader.close()


def _msg(exc: BaseException) -> str:
    return " ".join(str(exc).split()) or type(exc).__name__


_ROS1_EVENT = np.dtype([("x", "<u2"), ("y", "<u2"), ("sec", "<u4"), ("nsec", "<u4"), ("p", "u1")])


def _cdr_event(endian: str, offsets) -> np.dtype:
    return np.dtype({"names": ["x", "y", "sec", "nsec", "p"],
                     "formats": [endian + "u2", endian + "u2", endian + "i4", endian + "u4", "u1"],
                     "offsets": list(offsets), "itemsize": 16})


def _after_header(raw: bytes, is2: bool) -> tuple[str, int]:
    """(byte order, offset of the field after std_msgs/Header) of a serialized message; ROS2
    offsets count from byte 4 (the CDR encapsulation header), where its alignment starts."""
    import struct

    if not is2:
        (flen,) = struct.unpack_from("<I", raw, 12)
        return "<", 16 + flen
    e = "<" if raw[1] == 1 else ">"
    (flen,) = struct.unpack_from(e + "I", raw, 4 + 8)
    rel = 12 + flen
    return e, 4 + rel + (-rel % 4)


def _raw_size(raw: bytes, is2: bool) -> tuple[int, int] | None:
    """(width, height) of a serialized EventArray / EventPacket (both: header, height, width)."""
    import struct

    try:
        e, off = _after_header(raw, is2)
        h, w = struct.unpack_from(e + "II", raw, off)
    except (struct.error, IndexError):
        return None
    return w, h


def _dvs_raw(raw: bytes, is2: bool) -> tuple[np.ndarray, ...] | None:
    """x, y, t (us), p of a serialized dvs_msgs/EventArray, straight from its bytes (numpy: ~100x
    faster than deserializing an object per event); None when the bytes are not laid out as
    expected (the caller then deserializes the message).

    ROS1: header (seq u32, stamp 2 x u32, frame_id u32 length + bytes), height, width, count
    (u32), then packed 13-byte events (x u2, y u2, sec u4, nsec u4, polarity u1). ROS2 (CDR,
    aligned from byte 4): stamp (i4, u4), frame_id, height, width, count; event 0 at a 4-aligned
    offset s0 (fields at +0, 2, 4, 8, 12), event i >= 1 at s0 + 14 + 16 (i - 1) (fields at +0, 2,
    6, 10, 14: its time is realigned to 4 bytes).
    """
    import struct

    try:
        e, off = _after_header(raw, is2)
        _, _, n = struct.unpack_from(e + "III", raw, off)
        if not is2:
            off += 12
            if off + 13 * n != len(raw):
                return None
            rec = np.frombuffer(raw, _ROS1_EVENT, n, off)
        else:
            s0 = off - 4 + 12
            if n == 0:
                return (np.empty(0, np.int64),) * 3 + (np.empty(0, np.uint8),)
            end = 4 + s0 + (13 if n == 1 else 14 + 16 * (n - 2) + 15)
            if end > len(raw) or len(raw) - end > 3:
                return None
            first = np.frombuffer(raw, _cdr_event(e, (0, 2, 4, 8, 12)), 1, 4 + s0)
            rest = np.frombuffer(raw + b"\0", _cdr_event(e, (0, 2, 6, 10, 14)), n - 1, 4 + s0 + 14)
            rec = np.concatenate([first.astype(_ROS1_EVENT), rest.astype(_ROS1_EVENT)])
    except (struct.error, ValueError, IndexError):
        return None
    if rec.shape[0] and int(rec["p"].max()) > 1:
        return None
    t = rec["sec"].astype(np.int64) * 1_000_000 + rec["nsec"].astype(np.int64) // 1000
    return rec["x"].astype(np.int64), rec["y"].astype(np.int64), t, rec["p"]


def _dvs_columns(msg) -> tuple[np.ndarray, ...]:
    evs = msg.events
    n = len(evs)
    x = np.fromiter((e.x for e in evs), np.int64, n)
    y = np.fromiter((e.y for e in evs), np.int64, n)
    t = np.fromiter((e.ts.sec * 1_000_000 + e.ts.nanosec // 1000 for e in evs), np.int64, n)
    p = np.fromiter((e.polarity for e in evs), np.uint8, n)
    return x, y, t, p


def _mono_columns(msg) -> tuple[np.ndarray, ...]:
    data = np.asarray(msg.events, np.uint8)
    if data.shape[0] % 8:
        raise ValueError(f"mono packet of {data.shape[0]} bytes is not a whole number of 8-byte events")
    w = data.view(">u8" if msg.is_bigendian else "<u8").astype(np.uint64)
    t_ns = np.uint64(msg.time_base) + (w & np.uint64(0xFFFFFFFF))
    return ((w >> np.uint64(32)) & np.uint64(0xFFFF)).astype(np.int64), \
        ((w >> np.uint64(48)) & np.uint64(0x7FFF)).astype(np.int64), \
        (t_ns // np.uint64(1000)).astype(np.int64), (w >> np.uint64(63)).astype(np.uint8)


class RosbagSource(SequentialSource):
    """Events of one event topic of a ROS1 or ROS2 bag, decoded message by message."""

    format_name = "rosbag"
    _encoding = None

    def __init__(self, path, sensor_size=None):
        self.path = path
        self._bag = bag_root(path)
        with self._open() as reader:
            conns = sorted((c for c in reader.connections if c.msgtype in (DVS_ARRAY,) + PACKET_TYPES),
                           key=lambda c: c.topic)
            if not conns:
                found = ", ".join(sorted({f"{c.topic} ({c.msgtype})" for c in reader.connections})) or "none"
                raise InputError(path, f"no event topic ({', '.join((DVS_ARRAY,) + PACKET_TYPES)}) in the bag; "
                                       f"topics: {found}")
            self._topic, self._msgtype = conns[0].topic, conns[0].msgtype
            first = next(self._raw_messages(reader), None)
            own = _raw_size(first, reader.is2) if first is not None else (0, 0)
            if own is None or (self._msgtype in PACKET_TYPES and first is not None):
                msg = self._deserialize(reader, first)
                own = (int(msg.width), int(msg.height))
                self._encoding = msg.encoding if self._msgtype in PACKET_TYPES else None
        if sensor_size is None and 0 in own:
            what = (f"has no messages, so nothing gives the sensor size" if first is None else
                    f"messages give no sensor size (width x height {own[0]}x{own[1]})")
            raise InputError(path, f"{self._topic}: {what}; pass --sensor-size W H")
        super().__init__(path, check_sensor_size(path, sensor_size or own))

    def _open(self):
        return _reader(self._bag, self.path)

    def _raw_messages(self, reader):
        """The serialized messages of our topic, in bag order."""
        conns = [c for c in reader.connections if c.topic == self._topic and c.msgtype == self._msgtype]
        try:
            for _, _, raw in reader.messages(connections=conns):
                yield bytes(raw)
        except Exception as exc:
            raise InputError(self.path, f"cannot read ROS bag message on {self._topic} (truncated or "
                                        f"corrupt?): {_msg(exc)}") from None

    def _messages(self, reader, raw_dvs: bool = False):
        """Deserialized messages of our topic; with ``raw_dvs``, dvs_msgs events as columns
        parsed from the bytes where their layout allows it."""
        for raw in self._raw_messages(reader):
            cols = _dvs_raw(raw, reader.is2) if raw_dvs else None
            yield cols if cols is not None else self._deserialize(reader, raw)

    def _deserialize(self, reader, raw: bytes):
        try:
            return reader.deserialize(raw, self._msgtype)
        except Exception as exc:   # struct / index / value errors of a short or garbled message
            raise InputError(self.path, f"cannot deserialize a {self._msgtype} message on {self._topic} "
                                        f"(corrupt?): {_msg(exc)}") from None

    def _packets(self, resume=None):
        from .fmt_prophesee import Evt3Decoder, decode_evt3

        evt3 = Evt3Decoder()
        offset = 0
        with self._open() as reader:
            for msg in self._messages(reader, raw_dvs=self._msgtype == DVS_ARRAY):
                if isinstance(msg, tuple):
                    cols = msg
                elif self._msgtype == DVS_ARRAY:
                    cols = _dvs_columns(msg)
                elif msg.encoding == "mono":
                    try:
                        cols = _mono_columns(msg)
                    except ValueError as exc:
                        raise InputError(self.path, f"{self._topic}: {exc}") from None
                elif msg.encoding == "evt3":
                    ev = decode_evt3(self.path, evt3, np.asarray(msg.events, np.uint8).tobytes(), offset)
                    offset += int(ev.shape[0])
                    yield ev
                    continue
                else:
                    raise InputError(self.path, f"{self._topic}: event encoding {msg.encoding!r} is not "
                                                f"supported ({', '.join(ENCODINGS)} are)")
                ev = to_events(self.path, *cols, offset) if cols[0].shape[0] else np.empty(0, EVENT_DTYPE)
                offset += int(ev.shape[0])
                yield ev

    @property
    def attrs(self):
        out = {"topic": self._topic, "msgtype": self._msgtype}
        if self._encoding is not None:
            out["encoding"] = self._encoding
        return out
