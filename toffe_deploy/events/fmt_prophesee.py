"""Prophesee RAW (EVT 2.0, EVT 3.0) and DAT files: what Metavision / OpenEB and EVK cameras record.

Decoded here (a compiled word loop, evt_compiled, one chunk of words at a time, the decoder state
carried from chunk to chunk; DAT in numpy), because the permissive Python packages only decode
EVT3 and the one that also writes every format is GPL. Checked against files written by
``faery`` and decoded by ``evt3`` (tests/test_events_formats.py).

Both start with ASCII header lines ``% key value`` (ending at ``% end`` or the first line that
does not start with ``%``). The sensor size comes from ``% geometry WxH``, ``% format
EVT3;height=H;width=W`` or DAT's ``% Width W`` / ``% Height H``; a file with none needs
``sensor_size``.

- EVT 2.0 (``% evt 2.0``): little-endian 32-bit words, type in bits 28-31: CD_OFF 0 / CD_ON 1
  (timestamp bits 0-5 in 22-27, x in 11-21, y in 0-10), EVT_TIME_HIGH 8 (timestamp bits 6-33 in
  0-27); triggers (10) and vendor words (14, 15) are skipped.
- EVT 3.0 (``% evt 3.0``): little-endian 16-bit words, type in bits 12-15: EVT_ADDR_Y 0 (y),
  EVT_ADDR_X 2 (one event: x, polarity bit 11), VECT_BASE_X 3 (x base, polarity), VECT_12 4 /
  VECT_8 5 (a mask of events at base, base + 1, ...; base += 12 / 8), EVT_TIME_LOW 6 and
  EVT_TIME_HIGH 8 (timestamp bits 0-11 and 12-23); triggers and vendor words (7, 10, 14, 15)
  are skipped.
- DAT: after the header, a byte event type (0 or 12: CD events) and a byte event size (8), then
  records of uint32 t (us) and uint32 x | y << 14 | p << 28 (``% Version 2``), or
  x | y << 9 | p << 17 (version 1, and files that name no version, as Prophesee's loader reads them).

Timestamps are in microseconds; a counter that wraps (EVT3's 24 bits every 16.8 s, EVT2's 34
bits, DAT's 32 bits) is unwrapped: a drop of more than half the counter's range is a wrap, a
smaller one is reported as decreasing timestamps (evt_compiled.EVT3_HALF_RANGE, _Unwrap).
Events before the first time base (EVT_TIME_HIGH) are dropped, as Prophesee's decoders do. A word type that the encoding does not define, or a truncated last
word or record, is an InputError naming the byte offset.
"""
from __future__ import annotations

import re

import numpy as np

from ..errors import InputError
from . import evt_compiled
from .convert import to_events
from .core import EVENT_DTYPE
from .sequential import SequentialSource
from .validate import check_sensor_size

#: Bytes decoded per packet: 4 MiB (1 Mi EVT2 words, ~2 Mi EVT3 words).
CHUNK_BYTES = 1 << 22
#: A header longer than this is not a Prophesee header (a binary file starting with '%').
MAX_HEADER_BYTES = 1 << 20


def _header_line(line: bytes) -> bool:
    """Whether ``line`` is a ``% ...`` header line: '%', then printable ASCII text (not empty),
    ending at a newline. A file without ``% end`` (faery writes none) goes straight from its
    last header line to binary data, whose first byte may be '%' (0x25): an EVT 2.0 file whose
    first time stamp has (t >> 6) & 0xFF = 0x25, about 1 in 256; that word is data."""
    if not (line.startswith(b"%") and line.endswith(b"\n")):
        return False
    text = line[1:].rstrip(b"\r\n")
    return bool(text.strip()) and all(32 <= c < 127 or c == 9 for c in text)


def read_header(path, fh) -> tuple[dict[str, str], int]:
    """The ``% key value`` header lines (keys lower-cased) and the byte offset where data starts
    (the first line that is not a header line, _header_line, or the one after ``% end``)."""
    fields: dict[str, str] = {}
    pos = 0
    fh.seek(0)
    while True:
        line = fh.readline(MAX_HEADER_BYTES)
        if not _header_line(line):
            if line.startswith(b"%") and len(line) >= MAX_HEADER_BYTES:
                raise InputError(path, "header of '%' lines longer than 1 MiB: not a Prophesee file")
            if not line.endswith(b"\n") and _header_line(line + b"\n") and not fh.read(1):
                # the file ends inside a header line (a copy cut short): not an empty recording
                raise InputError(path, f"ends inside its header, at byte {pos + len(line)} (truncated?)")
            break
        pos += len(line)
        if pos > MAX_HEADER_BYTES:
            raise InputError(path, "header of '%' lines longer than 1 MiB: not a Prophesee file")
        text = line[1:].decode("ascii", "replace").strip()
        if text == "end":
            break
        key, _, value = text.partition(" ")
        if key:
            fields.setdefault(key.lower(), value.strip())
    fh.seek(pos)
    return fields, pos


def header_geometry(fields: dict[str, str]) -> tuple[int, int] | None:
    """(width, height) from ``geometry``, ``format ...;width=;height=`` or DAT ``width``/``height``."""
    m = re.fullmatch(r"\s*(\d+)\s*x\s*(\d+)\s*", fields.get("geometry", ""))
    if m:
        return int(m.group(1)), int(m.group(2))
    opts = dict(kv.split("=", 1) for kv in fields.get("format", "").split(";")[1:] if "=" in kv)
    for src in (opts, fields):
        if src.get("width", "").strip().isdigit() and src.get("height", "").strip().isdigit():
            return int(src["width"]), int(src["height"])
    return None


def raw_encoding(fields: dict[str, str]) -> str | None:
    """'evt2', 'evt2.1' or 'evt3' from ``% evt 3.0`` or ``% format EVT3;...``; None when absent."""
    evt = fields.get("evt", "").strip()
    if evt:
        return {"2.0": "evt2", "2": "evt2", "2.1": "evt2.1", "3.0": "evt3", "3": "evt3"}.get(evt, f"evt {evt}")
    fmt = fields.get("format", "").split(";")[0].strip().upper()
    return {"EVT2": "evt2", "EVT21": "evt2.1", "EVT3": "evt3"}.get(fmt, fmt.lower() or None)


class _Unwrap:
    """Unwraps a counter of ``bits`` bits that counts up and wraps: a drop of more than half the
    period adds a period (a smaller drop stays, for the time-order check to report)."""

    def __init__(self, bits: int):
        self.period = 1 << bits
        self.last = None
        self.loops = 0

    def __call__(self, raw: np.ndarray) -> np.ndarray:
        if raw.shape[0] == 0:
            return raw.astype(np.int64)
        raw = raw.astype(np.int64)
        prev = np.concatenate([[raw[0] if self.last is None else self.last], raw])
        loops = self.loops + np.cumsum(np.diff(prev) < -(self.period // 2))
        self.last, self.loops = int(raw[-1]), int(loops[-1])
        return raw + self.period * loops


class _WordDecoder:
    """Bytes -> (x, y, t, p) columns through a compiled word loop (evt_compiled), keeping a
    partial word and the decoder state between calls."""

    word_dtype = np.dtype("<u2")

    def __init__(self):
        self._rest = b""
        self._state = evt_compiled.new_state()
        self.offset = 0          # bytes consumed so far (for error messages)

    def feed(self, data: bytes) -> tuple[np.ndarray, ...]:
        data = self._rest + bytes(data)
        size = self.word_dtype.itemsize
        cut = len(data) - len(data) % size
        self._rest = data[cut:]
        words = np.frombuffer(data, self.word_dtype, cut // size)
        cap = self._bound(words)
        x, y, p = np.empty(cap, np.uint16), np.empty(cap, np.uint16), np.empty(cap, np.uint8)
        t = np.empty(cap, np.int64)
        n = self._kernel(words, self._state, x, y, t, p)
        bad = int(self._state[evt_compiled.BAD])
        if bad >= 0:
            typ = int(words[bad]) >> (8 * size - 4)
            raise ValueError(f"word type {typ:#x} at byte {self.offset + bad * size} is not "
                             f"{self.name} data (corrupt file?)")
        self.offset += cut
        return x[:n], y[:n], t[:n], p[:n]

    def finish(self) -> None:
        if self._rest:
            n = len(self._rest)
            raise ValueError(f"ends inside an {self.name} word ({n} trailing byte{'s' if n != 1 else ''}: truncated?)")


class Evt2Decoder(_WordDecoder):
    name = "EVT 2.0"
    word_dtype = np.dtype("<u4")
    _kernel = staticmethod(evt_compiled.evt2_decode)

    @staticmethod
    def _bound(words):
        return words.shape[0]


class Evt3Decoder(_WordDecoder):
    name = "EVT 3.0"
    word_dtype = np.dtype("<u2")
    _kernel = staticmethod(evt_compiled.evt3_decode)
    _bound = staticmethod(evt_compiled.evt3_bound)


class PropheseeRawSource(SequentialSource):
    """A Prophesee .raw file (EVT 2.0 or EVT 3.0), decoded chunk by chunk."""

    def __init__(self, path, sensor_size=None):
        with _open(path) as fh:
            self._fields, self._data_start = read_header(path, fh)
        enc = raw_encoding(self._fields)
        if enc is None:
            raise InputError(path, "RAW header names no event encoding (expected '% evt 3.0' or "
                                   "'% format EVT3')")
        if enc not in ("evt2", "evt3"):
            raise InputError(path, f"RAW event encoding {enc!r} is not supported (EVT 2.0 and EVT 3.0 are)")
        self.encoding = enc
        self.format_name = f"raw-{enc}"
        own = header_geometry(self._fields)
        if sensor_size is None and own is None:
            raise InputError(path, "RAW header gives no sensor size ('% geometry WxH'); pass --sensor-size W H")
        super().__init__(path, check_sensor_size(path, sensor_size or own))

    def _packets(self, resume=None):
        """Packets of CHUNK_BYTES; restart point: (file position, decoder state, partial word,
        events before)."""
        dec = Evt3Decoder() if self.encoding == "evt3" else Evt2Decoder()
        pos, n = self._data_start, 0
        if resume is not None:
            pos, state, dec._rest, n = resume
            dec._state = state.copy()
        with _open(self.path) as fh:
            fh.seek(pos)
            while True:
                self._cursor = (pos, dec._state.copy(), dec._rest, n)
                data = fh.read(CHUNK_BYTES)
                dec.offset = pos - len(dec._rest)     # byte offsets in errors count from the file start
                try:
                    if not data:
                        dec.finish()
                        return
                    x, y, t, p = dec.feed(data)
                except ValueError as exc:
                    raise InputError(self.path, str(exc)) from None
                pos += len(data)
                if x.shape[0]:
                    yield to_events(self.path, x, y, t, p, n)
                    n += int(x.shape[0])

    @property
    def attrs(self):
        return {"encoding": self.encoding, "header": dict(self._fields)}


class PropheseeDatSource(SequentialSource):
    """A Prophesee .dat file of CD events (DAT versions 1 and 2)."""

    format_name = "dat"

    def __init__(self, path, sensor_size=None):
        with _open(path) as fh:
            self._fields, pos = read_header(path, fh)
            pair = fh.read(2)
        if len(pair) < 2:
            raise InputError(path, "DAT file ends after its header (no event type and size bytes)")
        ev_type, self._size = pair[0], pair[1]
        if ev_type not in (0, 12):
            raise InputError(path, f"DAT event type {ev_type} is not CD events (0 or 12)")
        if self._size < 8:
            raise InputError(path, f"DAT event size {self._size} bytes is less than 8 (corrupt header?)")
        self._data_start = pos + 2
        version = self._fields.get("version", "0").strip()
        self.version = int(version) if version.isdigit() else 0
        if self.version > 2:
            raise InputError(path, f"DAT version {self.version} is not supported (1 and 2 are)")
        own = header_geometry(self._fields)
        if sensor_size is None and own is None:
            raise InputError(path, "DAT header gives no sensor size ('% Width W', '% Height H'); "
                                   "pass --sensor-size W H")
        super().__init__(path, check_sensor_size(path, sensor_size or own))

    def _packets(self, resume=None):
        """Packets of whole records; restart point: (file position, time unwrap state, events before)."""
        size = self._size
        unwrap = _Unwrap(32)
        pos, offset = self._data_start, 0
        if resume is not None:
            pos, (unwrap.last, unwrap.loops), offset = resume
        with _open(self.path) as fh:
            fh.seek(pos)
            while True:
                self._cursor = (pos, (unwrap.last, unwrap.loops), offset)
                data = fh.read(CHUNK_BYTES - CHUNK_BYTES % size)
                pos += len(data)
                if not data:
                    return
                if len(data) % size:
                    n = len(data) % size
                    raise InputError(self.path, f"ends inside an event record ({n} trailing "
                                                f"byte{'s' if n != 1 else ''}: truncated?)")
                rec = np.frombuffer(data, np.dtype([("t", "<u4"), ("d", "<u4"), ("pad", f"V{size - 8}")])
                                    if size > 8 else np.dtype([("t", "<u4"), ("d", "<u4")]))
                d = rec["d"].astype(np.int64)
                if self.version >= 2:
                    x, y, p = d & 0x3FFF, (d >> 14) & 0x3FFF, d >> 28
                else:
                    x, y, p = d & 0x1FF, (d >> 9) & 0xFF, d >> 17
                yield to_events(self.path, x, y, unwrap(rec["t"]), p, offset)
                offset += rec.shape[0]

    @property
    def attrs(self):
        return {"header": dict(self._fields)}


def _open(path):
    try:
        return open(path, "rb")
    except OSError as exc:
        raise InputError(path, f"cannot read: {exc.strerror or exc}") from None


def decode_evt3(path, decoder: Evt3Decoder, data: bytes, offset: int = 0) -> np.ndarray:
    """EVENT_DTYPE events of one more piece of an EVT 3.0 stream (ROS event_camera_msgs packets)."""
    try:
        x, y, t, p = decoder.feed(data)
    except ValueError as exc:
        raise InputError(path, str(exc)) from None
    return to_events(path, x, y, t, p, offset) if x.shape[0] else np.empty(0, EVENT_DTYPE)


def prophesee_kind(path) -> str | None:
    """'raw' or 'dat' for a file starting with '%' header lines: by its header (a RAW file names
    its encoding, ``% evt`` / ``% format``; a DAT file has ``% Version`` and no encoding), then by
    the extension, so that a renamed file is still read as what it is."""
    with _open(path) as fh:
        fields, _ = read_header(path, fh)
    if raw_encoding(fields):
        return "raw"
    if "version" in fields:
        return "dat"
    suffix = str(path).lower().rsplit(".", 1)[-1]
    if suffix in ("raw", "dat"):
        return suffix
    return "dat" if header_geometry(fields) else None
