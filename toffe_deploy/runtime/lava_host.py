"""Keeping Lava's OS processes and shared memory tied to the host process that started them.

Lava's multiprocessing backend forks one process per process model, plus a SharedMemoryManager
process, and allocates its port buffers as POSIX shared memory (/dev/shm). Left alone, these
outlive a host killed by SIGKILL (the OOM killer, ``timeout -k``) for as long as nobody kills
them, and the segments for as long as the machine runs. ``spawning(prefix)`` wraps the start of
one runtime so that:

* every process forked inside it dies with the host: PR_SET_PDEATHSIG = SIGKILL, set in the
  child right after fork (with a getppid check for a host that died before that), ignores SIGINT
  (Ctrl-C reaches the host, which stops the network) and takes SIGTERM's and SIGHUP's default
  action. Signals are not blocked around the fork: a handler that raises inside an at-fork hook
  would have its exception swallowed, losing the signal in the host (the child's window between
  fork and its hook is a few microseconds);
* every segment Lava allocates is named ``toffe_lava_<pid>_<start>_<n>_<token>``: the host's
  pid and its start time (clock ticks since boot, /proc/PID/stat field 22, which tells a reused
  pid apart), the runtime's number in that host, and a random token.

When the host dies, Python's resource tracker (a child of the host) unlinks the segments once
the last process holding its pipe is gone. A SIGKILL of the whole process group (``timeout -k``,
``kill -9 -PGID``) kills the tracker too, so ``ensure_reaper()`` starts, once per host, a small
process in a session of its own that waits for the end of a pipe held by the host and everything
forked from it, unlinks the host's segments and exits. ``reclaim()`` removes the segments whose
named host is gone (no process with that pid and start time), for when even the reaper was
killed; each Lava start calls it. Segments with other names (other programs, Lava used
directly) are never touched.
"""
from __future__ import annotations

import contextlib
import ctypes
import itertools
import multiprocessing.managers as managers
import os
import secrets
import signal
import subprocess
import sys
import threading
from dataclasses import dataclass
from multiprocessing import shared_memory
from typing import Iterator

SHM_DIR = "/dev/shm"
PREFIX = "toffe_lava_"
PR_SET_PDEATHSIG = 1

_armed = threading.local()            # set on the thread that starts a runtime, read by the fork hooks
_fork_state: dict = {}                # the host's pid, handed from the before hook to the child
_registered = False
_prctl = None                         # libc's prctl, looked up before any fork
_counter = itertools.count(1)
_reaper: tuple[int, int, subprocess.Popen] | None = None   # (host pid, pipe write end, process)

REAPER = """
import os, sys
fd, shm_dir, prefix = int(sys.argv[1]), sys.argv[2], sys.argv[3]
while os.read(fd, 4096):
    pass
for name in os.listdir(shm_dir):
    if name.startswith(prefix):
        try:
            os.unlink(os.path.join(shm_dir, name))
        except OSError:
            pass
"""


def start_ticks(pid: int) -> int | None:
    """A process's start time in clock ticks since boot (/proc/PID/stat field 22); None if gone."""
    try:
        with open(f"/proc/{pid}/stat", "rb") as f:
            return int(f.read().rsplit(b")", 1)[1].split()[19])
    except (FileNotFoundError, ProcessLookupError, IndexError, ValueError):
        return None


def host_prefix(n: int | None = None) -> str:
    """Segment name prefix of this process (and of its runtime number ``n`` when given)."""
    pid = os.getpid()
    base = f"{PREFIX}{pid}_{start_ticks(pid)}_"
    return base if n is None else f"{base}{n}_"


def next_runtime_prefix() -> str:
    """The prefix for the next runtime this process starts."""
    return host_prefix(next(_counter))


def _owner(name: str) -> tuple[int, int] | None:
    """(pid, start ticks) encoded in one of our segment names; None for any other name."""
    if not name.startswith(PREFIX):
        return None
    parts = name[len(PREFIX):].split("_")
    if len(parts) != 4 or not (parts[0].isdigit() and parts[1].isdigit()):
        return None
    return int(parts[0]), int(parts[1])


@dataclass
class Reclaimed:
    """Segments of dead hosts removed by one ``reclaim()`` call."""

    segments: int = 0
    bytes: int = 0


def reclaim(shm_dir: str = SHM_DIR) -> Reclaimed:
    """Unlink our segments whose host (pid and start time in the name) no longer runs."""
    out = Reclaimed()
    try:
        names = os.listdir(shm_dir)
    except OSError:
        return out
    for name in names:
        owner = _owner(name)
        if owner is None or start_ticks(owner[0]) == owner[1]:
            continue
        path = os.path.join(shm_dir, name)
        with contextlib.suppress(OSError):
            size = os.stat(path).st_size
            os.unlink(path)
            out.segments += 1
            out.bytes += size
    return out


def unlink_prefix(prefix: str, shm_dir: str = SHM_DIR) -> int:
    """Unlink this process's segments that start with ``prefix`` (a runtime that was force-stopped);
    they are also dropped from Python's resource tracker, which would otherwise warn at exit.

    Only a segment this call unlinked is unregistered: the segment manager's process may unlink
    (and unregister) the same one at the same moment, and a second UNREGISTER of a name makes the
    tracker print a KeyError traceback on the shared stderr. Whoever's unlink succeeds
    unregisters; the other's unlink fails before its unregister (SharedMemory.unlink). The
    UNREGISTER follows a REGISTER of the same name: a Ctrl-C can land in SharedMemory(create=True)
    between shm_open and its REGISTER, leaving a segment the tracker never saw (its UNREGISTER
    alone was the same traceback, once in CI); the tracker keeps a set, so a second REGISTER of a
    registered name changes nothing."""
    from multiprocessing import resource_tracker

    n = 0
    with contextlib.suppress(OSError):
        for name in os.listdir(shm_dir):
            if not name.startswith(prefix):
                continue
            try:
                os.unlink(os.path.join(shm_dir, name))
            except OSError:
                continue                      # gone already: its unlinker unregistered it
            n += 1
            with contextlib.suppress(Exception):
                resource_tracker.register("/" + name, "shared_memory")
                resource_tracker.unregister("/" + name, "shared_memory")
    return n


def ensure_reaper(shm_dir: str = SHM_DIR) -> int:
    """Start this host's reaper unless it runs; returns its pid.

    The reaper reads a pipe whose write end only this process and its forks hold (close-on-exec);
    end of file means all of them are gone, however they died: it then unlinks the segments named
    after this host. It lives in its own session, out of reach of signals to the host's group.
    """
    global _reaper
    if _reaper is not None and _reaper[0] == os.getpid() and _reaper[2].poll() is None:
        return _reaper[2].pid
    r, w = os.pipe()
    try:
        proc = subprocess.Popen([sys.executable, "-I", "-S", "-c", REAPER, str(r), shm_dir, host_prefix()],
                                pass_fds=(r,), start_new_session=True, stdin=subprocess.DEVNULL,
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    except BaseException:
        os.close(w)
        raise
    finally:
        os.close(r)
    _reaper = (os.getpid(), w, proc)
    return proc.pid


class NamedSegmentManager(managers.SharedMemoryManager):
    """The stdlib SharedMemoryManager, creating segments named ``<prefix><token>``.

    The segment is created in the calling process (as the stdlib does) and handed to the manager
    process, which unlinks it on shutdown.
    """

    def __init__(self, prefix: str, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.prefix = prefix

    def SharedMemory(self, size):  # noqa: N802 - the stdlib's method name
        with self._Client(self._address, authkey=self._authkey) as conn:
            sms = shared_memory.SharedMemory(self.prefix + secrets.token_hex(6), create=True, size=size)
            try:
                managers.dispatch(conn, None, "track_segment", (sms.name,))
            except BaseException:
                sms.unlink()
                raise
        return sms


def _before_fork() -> None:
    if getattr(_armed, "on", False):
        _fork_state["parent"] = os.getpid()


def _after_fork_parent() -> None:
    _fork_state.pop("parent", None)


def _after_fork_child() -> None:
    parent = _fork_state.pop("parent", None)
    if parent is None:
        return
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    signal.signal(signal.SIGHUP, signal.SIG_DFL)
    _armed.on = False
    if _prctl is not None:
        _prctl(PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0)
    if os.getppid() != parent:          # the host died before prctl took effect
        os._exit(128 + signal.SIGKILL)


@contextlib.contextmanager
def spawning(prefix: str) -> Iterator[None]:
    """Start a Lava runtime inside this block: its processes die with the host thread that forks
    them (PR_SET_PDEATHSIG follows the forking *thread*: start and use a runtime on one thread)
    and its shared memory carries ``prefix``."""
    global _registered, _prctl
    from lava.magma.runtime.message_infrastructure import multiprocessing as lava_mp
    from lava.magma.runtime.message_infrastructure.shared_memory_manager import SharedMemoryManager

    if not _registered:
        with contextlib.suppress(OSError, AttributeError):     # Linux only; elsewhere no death signal
            _prctl = ctypes.CDLL(None, use_errno=True).prctl
        os.register_at_fork(before=_before_fork, after_in_parent=_after_fork_parent,
                            after_in_child=_after_fork_child)
        _registered = True

    class _Named(SharedMemoryManager):
        def __init__(self) -> None:
            super().__init__()
            self._manager = NamedSegmentManager(prefix)

    old = lava_mp.SharedMemoryManager
    lava_mp.SharedMemoryManager = _Named
    _armed.on = True
    try:
        yield
    finally:
        _armed.on = False
        lava_mp.SharedMemoryManager = old
