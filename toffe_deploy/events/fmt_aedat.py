"""AEDAT4 (iniVation DV) through the ``aedat`` package (MIT/Apache, Rust decoder).

AEDAT4 is a stream of compressed packets with no seek index, so this reader is sequential:
windows stream packet by packet (memory: one packet plus one window), and metadata (event
count, time span) costs one decoding pass, done lazily and cached. The sensor size comes from
the file's event stream description; the first event stream is used. Polarity ``on`` -> p = 1.
"""
from __future__ import annotations

from typing import Iterator

import numpy as np

from ..errors import InputError
from .convert import to_events
from .sequential import SequentialSource
from .validate import check_sensor_size


def _decoder(path):
    try:
        import aedat
    except ImportError:
        raise InputError(path, "reading AEDAT4 needs the aedat package (pip install aedat)") from None

    try:
        return aedat.Decoder(str(path))
    except Exception as exc:  # the Rust decoder raises plain RuntimeError/OSError variants
        raise InputError(path, f"cannot read AEDAT4 file (truncated or corrupt?): {exc}") from None


class AedatSource(SequentialSource):
    format_name = "aedat4"

    def __init__(self, path, sensor_size=None):
        dec = _decoder(path)
        streams = {k: v for k, v in dec.id_to_stream().items() if v.get("type") == "events"}
        if not streams:
            raise InputError(path, "AEDAT4 file has no event stream")
        self._stream = min(streams)
        info = streams[self._stream]
        own = (int(info.get("width", 0)), int(info.get("height", 0)))
        super().__init__(path, check_sensor_size(path, sensor_size or own))

    def _packets(self, resume=None) -> Iterator[np.ndarray]:
        """Converted events of each packet of our stream, in file order (unvalidated)."""
        dec = _decoder(self.path)
        while True:
            try:
                packet = next(dec)
            except StopIteration:
                return
            except Exception as exc:
                raise InputError(self.path, f"cannot decode AEDAT4 packet (truncated or corrupt?): "
                                            f"{exc}") from None
            if packet.get("stream_id") != self._stream or "events" not in packet:
                continue
            e = packet["events"]
            yield to_events(self.path, e["x"], e["y"], e["t"].astype(np.int64), e["on"])
