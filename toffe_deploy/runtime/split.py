"""Two host processes for the cpu and cuda targets: ``Pipeline(..., processes=2)``, ``run --processes 2``.

Why: a window's host work splits in two halves of about the same size. The first half turns the
raw window into the OFPD's output: the front end, the OFS cascade, the grouping and the crops
(``Pipeline.front_batch``: one compiled call on the fast path, runtime/window_front.py) and
onnxruntime. The second runs the plane fit, the faint objects and the tracker
(``Pipeline._result_of_batch``), and `run` reads the events, bins them and writes the JSON line.
The OFPD's input (a quarter MB a window) stays in the worker. The first half of window n + 1
needs only the front end's own history, the second half of window n only what came before it,
so a second process runs the first half one window ahead while this one runs the second half.
Python threads cannot do this: with both halves holding the GIL between their compiled calls,
two threads gave 1.1-1.2x the throughput for 1.2x the CPU time; two processes give 1.38-1.53x
for 1.24-1.28x (`run` on a 2-core VM; docs/speed-log.md).

Bit exact: each half runs the same code on the same state in the same order as one process does
(tests/test_split.py compares every line). When the stream yields window n it has read window
n + 1 (the worker runs it meanwhile) and reads n + 2 when asked for the next result, so that a
live source's wait for n + 2 does not hold n back. A consumer that stops early has had n + 1 read
and run through the first half; its second half runs too (its result dropped), so the state of
both halves stays that of the windows read. An error from the input (a bad event in a
file, a live source that fails) is raised after the windows read before it are yielded, as with
one process. ``reset_tracks`` and a second stream are refused while a stream is running.

The second process is this module's ``main`` under ``sys.executable`` with this process's
``sys.path`` (no multiprocessing start method: nothing of the caller's ``__main__`` is imported
again, nor anything from the working directory). It talks over a socket pair (a
``multiprocessing.connection.Connection``: pickled tuples between our own two processes, never
a user's file) and hands the arrays over in a memfd shared by both (two slots of SLOT_BYTES each
way; a window too large for its slot goes through the socket instead, after the answers on the
way are taken, so that two large writes never wait on each other):

    main -> worker   ("init", bundle root, config dict, target, sensor size, OFPD variant, its file, threads)
                     ("window", slot, t0, layout | payload)   the window's ones (SpikeVolume.idx)
                     ("reset",)   ("stop",)
    worker -> main   ("ready",)   ("batch", slot, layout | payload, has_pixels)   ("error", message)
    batch arrays     idx, bc, pix of the window after the front end, then stage_k, n_events and
                     the 4 ones arrays (Pipeline.batch), the OFPD's pose, direction and speed, then
                     the event pixels (with ofpd.faint_objects)

It ignores SIGINT (Ctrl-C is the main process's, which stops it) and exits when the socket
closes, so a main process that is killed leaves no orphan (once the worker has loaded its
kernels: it notices at its first message). A window unanswered for WINDOW_S is an error.
"""
from __future__ import annotations

import collections
import json
import mmap
import os
import signal
import socket
import subprocess
import sys
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Iterator

import numpy as np

from ..errors import ToffeError

#: Bytes per slot and direction (2 slots: the window being prepared and the one being finished).
SLOT_BYTES = 8 << 20
SLOTS = 2
#: Seconds to wait for the worker to start (it loads the compiled kernels: minutes on a first run,
#: which compiles them), for one window's answer, and for it to stop after "stop" and SIGTERM.
START_S, WINDOW_S, STOP_S = 600.0, 60.0, 2.0
#: The worker's bootstrap: this process's sys.path, then split.main(argv).
_BOOT = ("import json, sys; sys.path[:] = json.loads(sys.argv[1]); "
         "from toffe_deploy.runtime.split import main; sys.exit(main(sys.argv[2:]))")


def pack(arrays: list[np.ndarray], buf: memoryview | None) -> tuple[tuple, bytes | None]:
    """(layout, payload): the arrays written back to back into ``buf``, each at a 16-byte
    boundary (layout: (dtype, shape, offset, bytes) each, then the total; payload None), or,
    when they do not fit or there is no buffer, in the payload bytes at those offsets."""
    layout, off = [], 0
    for a in arrays:
        layout.append((a.dtype.str, a.shape, off, a.nbytes))
        off += -(-a.nbytes // 16) * 16
    target = buf if buf is not None and off <= len(buf) else bytearray(off)
    for a, (_, _, at, n) in zip(arrays, layout):
        target[at:at + n] = np.ascontiguousarray(a).view(np.uint8).reshape(-1).data
    return (tuple(layout), off), (None if target is buf else bytes(target))


def unpack(layout: tuple, payload: bytes | None, buf: memoryview | None) -> list[np.ndarray]:
    """The arrays of ``pack``, in one copy of the bytes (the slot is written again two windows
    later): writable, aligned views into it."""
    fields, total = layout
    data = bytearray(payload if payload is not None else buf[:total])
    return [np.frombuffer(data, dtype, n // np.dtype(dtype).itemsize, at).reshape(shape)
            for dtype, shape, at, n in fields]


class _Slots:
    """SLOTS x 2 regions of a memfd mapped here (None where memfd_create is missing: the
    arrays then go through the socket)."""

    def __init__(self, fd: int | None, slot_bytes: int):
        self.fd, self.slot_bytes = fd, slot_bytes
        self.map = mmap.mmap(fd, 2 * SLOTS * slot_bytes) if fd is not None else None
        self.view = memoryview(self.map) if self.map is not None else None

    def region(self, slot: int, back: bool) -> memoryview | None:
        if self.view is None:
            return None
        start = (2 * slot + int(back)) * self.slot_bytes
        return self.view[start:start + self.slot_bytes]

    def close(self) -> None:
        if self.view is not None:
            try:
                self.view.release()
                self.map.close()
            except BufferError:                   # a slice still held (an exception's frame): the
                pass                              # mapping goes with its last reference
            self.view = self.map = None


def _memfd(size: int) -> int | None:
    if not hasattr(os, "memfd_create"):
        return None
    fd = os.memfd_create("toffe-split")          # close-on-exec: only pass_fds hands it on
    os.ftruncate(fd, size)
    return fd


class SplitHost:
    """The second host process of a Pipeline (see module docstring): started by
    ``Pipeline.__enter__`` with ``processes=2`` (``wait_ready`` once this process is warm),
    stopped by its ``__exit__``."""

    def __init__(self, pipe, slot_bytes: int | None = None, ahead: int = SLOTS):
        if not 1 <= ahead <= SLOTS:
            raise ValueError(f"ahead must be 1..{SLOTS}, got {ahead}")
        slot_bytes = SLOT_BYTES if slot_bytes is None else int(slot_bytes)
        ours, theirs = socket.socketpair()
        fd = None
        try:
            fd = _memfd(2 * SLOTS * slot_bytes)
            keep = [theirs.fileno()] + ([fd] if fd is not None else [])
            self.proc = subprocess.Popen(
                [sys.executable, "-c", _BOOT, json.dumps(sys.path), str(theirs.fileno()),
                 str(-1 if fd is None else fd), str(slot_bytes)], pass_fds=keep, stdin=subprocess.DEVNULL,
                stdout=subprocess.DEVNULL,                # a library's print must not land in `--out -`
                start_new_session=True)                   # out of the terminal's group: a Ctrl-C is ours to
                                                          # handle (it stops the worker); one during the
                                                          # worker's imports printed their traceback
            self.slots = _Slots(fd, slot_bytes)
        except OSError as exc:
            ours.close()
            raise ToffeError(f"cannot start the second host process (--processes 2): {exc.strerror or exc}") from None
        finally:
            theirs.close()
            if fd is not None:
                os.close(fd)                              # the child has its copy, the mapping keeps ours
        self.conn = Connection(ours.detach())
        self.broken: str | None = None
        self.ahead = int(ahead)                           # windows sent before the first result (<= SLOTS)
        self.active = False                               # a stream is running (between its windows)
        self._early: dict = {}                            # answers taken before a window sent whole
        self.shape = (pipe.config.n_bins, 2, pipe.sensor_size[1], pipe.sensor_size[0])
        try:
            self.conn.send(("init", str(pipe.bundle.root), pipe.config.to_dict(), pipe.target,
                            tuple(pipe.sensor_size), pipe.ofpd_variant, str(pipe.ofpd.path), pipe.ofpd_threads))
        except BaseException:
            self.close()
            raise

    def wait_ready(self) -> None:
        """Wait until the worker has loaded its compiled kernels (it starts while this process
        loads its own)."""
        try:
            self._expect("ready", START_S)
        except BaseException:
            self.close()
            raise

    # ---- protocol --------------------------------------------------------------------
    def _recv(self, timeout: float):
        if not self.conn.poll(timeout):
            raise self._broken(f"no answer in {timeout:g} s")
        try:
            msg = self.conn.recv()
        except (EOFError, OSError):
            try:
                code = self.proc.wait(STOP_S)
            except subprocess.TimeoutExpired:
                code = None
            raise self._broken(f"it stopped (exit code {code})") from None
        if msg[0] == "error":
            raise self._broken(msg[1])
        return msg

    def _expect(self, kind: str, timeout: float):
        msg = self._recv(timeout)
        if msg[0] != kind:
            raise self._broken(f"expected {kind!r}, got {msg[0]!r}")
        return msg

    def _broken(self, why: str) -> ToffeError:
        self.broken = why
        return ToffeError(f"the second host process (--processes 2) failed: {why}")

    def _send_window(self, slot: int, t0: int, vol, inflight) -> None:
        layout, payload = pack([vol.idx], self.slots.region(slot, False))
        if payload is not None:               # through the socket: first take every answer on the way,
            for s, _ in inflight:             # which may be as large (two blocked writers: a deadlock)
                if s not in self._early:
                    self._early[s] = self._expect("batch", WINDOW_S)
        self.conn.send(("window", slot, int(t0), layout, payload))

    def _batch(self, slot: int):
        """(volume after the front end, batch without the OFPD input, pixels, the OFPD's output or
        None without objects) of the window in ``slot``."""
        from .spikes import SpikeVolume

        msg = self._early.pop(slot, None) or self._expect("batch", WINDOW_S)
        _, got, layout, payload, has_pixels = msg
        if got != slot:
            raise self._broken(f"answered slot {got} for slot {slot}")
        idx, bc, pix, ks, n_ev, o0, o1, o2, o3, pose, direction, speed, *pixels = unpack(
            layout, payload, self.slots.region(slot, True))
        vol = SpikeVolume(idx, self.shape)
        vol.__dict__["bc"], vol.__dict__["pix"] = bc, pix      # as the front end left them (cached_property)
        out = (pose, direction, speed) if ks.size else None
        return vol, (ks, None, n_ev, (o0, o1, o2, o3)), (pixels[0] if has_pixels else None), out

    # ---- the stream ------------------------------------------------------------------
    def stream(self, pipe, pairs) -> Iterator:
        """Pipeline.process_stream's windows, the first half one window ahead in the worker."""
        from .spikes import SpikeVolume

        if self.broken:
            raise ToffeError(f"the second host process (--processes 2) failed earlier: {self.broken}")
        if self.active:
            raise ToffeError("Pipeline(processes=2) runs one process_stream at a time: finish or close the "
                             "running one first")
        inflight: collections.deque = collections.deque()     # (slot, t0)
        it = iter(pairs)
        held: list[BaseException] = []             # the input's error, raised after the windows before it
        n = 0

        def send_next() -> None:
            nonlocal n
            if held:
                return
            try:
                t0, x = next(it)
                x = pipe._check(x)                 # its errors here, as with one process
            except StopIteration:
                held.append(StopIteration())
                return
            except BaseException as exc:           # noqa: BLE001 (raised once the windows read are done)
                held.append(exc)
                return
            vol = x if isinstance(x, SpikeVolume) else SpikeVolume.from_dense(x > 0)
            slot = n % SLOTS
            self._send_window(slot, int(t0), vol, inflight)
            inflight.append((slot, int(t0)))
            n += 1

        self.active = True
        try:
            while len(inflight) < self.ahead and not held:
                send_next()
            while inflight:
                slot, t0 = inflight[0]
                vol, batch, pixels, out = self._batch(slot)
                inflight.popleft()
                yield pipe._result_of_batch(t0, vol, batch, pixels, out)
                send_next()                        # after the yield: a live source's read of the next
                                                   # window does not hold this one back (the worker has
                                                   # the window after this one meanwhile)
            if held and not isinstance(held[0], StopIteration):
                raise held[0]
        except GeneratorExit:                      # left early: finish what was read, drop its results
            if sys.is_finalizing():                # a stream left open at the interpreter's exit: no
                self.broken = "closed at the interpreter's exit"   # state to keep (and imports fail)
                raise
            while inflight and not self.broken:
                slot, t0 = inflight.popleft()
                vol, batch, pixels, out = self._batch(slot)
                pipe._result_of_batch(t0, vol, batch, pixels, out)
            raise
        except BaseException:                      # an error or Ctrl-C inside a window: its answers are
            if inflight and not self.broken:       # still on the way, so this worker is done with
                self.broken = "a stream stopped by an error with windows in the worker"
            raise
        finally:
            self.active = False

    def reset(self) -> None:
        if self.active:
            raise ToffeError("reset_tracks() inside a running process_stream of Pipeline(processes=2): the "
                             "windows read ahead went through the front end already; call it between streams")
        if not self.broken:
            self.conn.send(("reset",))

    def close(self) -> None:
        """Stop the worker (a "stop" message, then SIGTERM, then SIGKILL) and free the slots."""
        try:
            if self.proc.poll() is None:
                try:
                    self.conn.send(("stop",))
                except OSError:
                    pass
                try:
                    self.proc.wait(STOP_S)
                except subprocess.TimeoutExpired:
                    self.proc.terminate()
                    try:
                        self.proc.wait(STOP_S)
                    except subprocess.TimeoutExpired:
                        self.proc.kill()
                        self.proc.wait()
        finally:
            self.conn.close()
            self.slots.close()


# ---- the worker ----------------------------------------------------------------------
def _serve(conn: Connection, slots: _Slots) -> None:
    import dataclasses

    from ..config import ToffeConfig
    from ..deploy.bundle import load_bundle
    from .pipeline import Pipeline
    from .spikes import SpikeVolume

    try:
        _, root, cfg, target, sensor, variant, model, threads = conn.recv()
        bundle = load_bundle(root)
        bundle = dataclasses.replace(bundle, config=ToffeConfig.from_dict(cfg),     # the caller's, as given
                                     ofpd_variants={**getattr(bundle, "ofpd_variants", {}), variant: Path(model)})
        pipe = Pipeline(bundle, target, sensor_size=sensor, track=False, ofpd_variant=variant, ofpd_threads=threads)
        pipe.half = "front"
        pipe.__enter__()                                    # the compiled kernels of its half
    except (EOFError, OSError):
        return
    except BaseException as exc:                            # noqa: BLE001 (said to the main process)
        conn.send(("error", f"{type(exc).__name__}: {exc}".splitlines()[0]))
        return
    shape = (pipe.config.n_bins, 2, pipe.sensor_size[1], pipe.sensor_size[0])
    try:
        conn.send(("ready",))
        while True:
            msg = conn.recv()
            if msg[0] == "stop":
                return
            if msg[0] == "reset":
                pipe.reset_tracks()
                continue
            _, slot, t0, layout, payload = msg
            try:
                (idx,) = unpack(layout, payload, slots.region(slot, False))
                vol, (ks, x, n_ev, ones), _stages, pixels = pipe.front_batch(t0, SpikeVolume(idx, shape))
                out = pipe.ofpd.run(x)                      # (empty arrays for a window without objects)
                arrays = [vol.idx, vol.bc, vol.pix, ks, n_ev, *ones, *out] + ([] if pixels is None else [pixels])
                out_layout, out_payload = pack(arrays, slots.region(slot, True))
            except Exception as exc:                        # noqa: BLE001 (said to the main process)
                conn.send(("error", f"{type(exc).__name__}: {exc}".splitlines()[0]))
                return
            conn.send(("batch", slot, out_layout, out_payload, pixels is not None))
    except (EOFError, OSError):                             # the main process went away
        return
    finally:
        pipe.__exit__(None, None, None)


def main(argv: list[str]) -> int:
    signal.signal(signal.SIGINT, signal.SIG_IGN)            # Ctrl-C is the main process's: it stops us
    sock_fd, mem_fd, slot_bytes = (int(a) for a in argv)
    conn = Connection(sock_fd)
    slots = _Slots(None if mem_fd < 0 else mem_fd, slot_bytes)
    try:
        _serve(conn, slots)
    finally:
        slots.close()
        conn.close()
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
