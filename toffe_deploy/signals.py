"""Signals as exceptions, so that a kill unwinds through the same ``finally`` blocks as an error.

The CLI enters ``exceptions_on_signals()`` before it does any work: SIGTERM (``kill``,
``timeout``) and SIGHUP (a closed terminal) raise ``Terminated``, SIGINT (Ctrl-C) raises
KeyboardInterrupt, from the first signal on, at any stage, start-up included. Unwinding then
stops the Lava runtime and removes temporary files and directories (fileio.atomic_path /
atomic_dir, the exporter's staging directory). A handler's exception that Python cannot
propagate (raised while an at-fork hook, a ``__del__`` or a weakref callback runs: logging's
fork hook is one, and Lava forks a dozen times at start-up) reaches sys.unraisablehook instead;
there the signal is sent again 10 ms later, from a timer thread, until it lands in ordinary code. A
repeated signal while unwinding is ignored, so it cannot cut a clean-up short; SIGKILL still ends everything (Lava's children die with the
host, see runtime.lava_host). A signal that the parent set to be ignored (``nohup``, a
background job's SIGINT) stays ignored.

Exit status (cli.main; the process ends with it, signals still ignored, through cli.entry): 130 for SIGINT, 128 + n for ``Terminated`` (143 for SIGTERM, 129 for
SIGHUP), with one line on stderr.
"""
from __future__ import annotations

import contextlib
import os
import signal
import sys
import threading
from typing import Iterator

HANDLED = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)


class Terminated(BaseException):
    """The process was asked to stop by a signal (a BaseException: ``except Exception`` lets it
    through, like KeyboardInterrupt). ``exit_code`` is 128 + the signal number."""

    def __init__(self, signum: int):
        self.signum = int(signum)
        self.exit_code = 128 + self.signum
        super().__init__(f"terminated by {signal.Signals(self.signum).name}")


_DEFER = {"depth": 0, "pending": None}
#: the signal's exception that the innermost active exceptions_on_signals block raised, if any
_RAISED: dict = {"exc": None}


@contextlib.contextmanager
def signals_deferred() -> Iterator[None]:
    """Within this block a signal that exceptions_on_signals handles is held, and raised as the
    block ends: a window's bookkeeping (its JSON line, the summary's counts) is done whole, so a
    live run's summary always counts the lines its output holds. An error in the block goes on
    as it is."""
    _DEFER["depth"] += 1
    try:
        yield
    finally:
        _DEFER["depth"] -= 1
    if not _DEFER["depth"] and _DEFER["pending"] is not None:
        exc, _DEFER["pending"] = _DEFER["pending"], None
        raise exc


def _send_again(signum: int) -> None:
    """Send ``signum`` to this process 10 ms from now, from a timer thread: a signal whose
    exception Python swallowed lands again, in ordinary code this time."""
    timer = threading.Timer(0.01, os.kill, (os.getpid(), signum))
    timer.daemon = True
    timer.start()


@contextlib.contextmanager
def exceptions_on_signals(ignore_after_signal: bool = False) -> Iterator[None]:
    """Within this block (main thread only), SIGINT, SIGTERM and SIGHUP raise once, then are ignored.
    With ``ignore_after_signal`` (the command line's process, cli.entry) they stay ignored after
    a block that a signal ended: only the interpreter's exit is left (its atexit hooks stop any
    Lava runtime still open, bounded by timeouts), and a second Ctrl-C there raised in an atexit
    hook (a traceback) or killed the process by the signal instead of its exit status 130."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    fired: list[int] = []             # the signal this block took (its exception: _RAISED["exc"])

    def handler(signum, frame):
        if fired:
            return
        fired.append(signum)
        exc = KeyboardInterrupt() if signum == signal.SIGINT else Terminated(signum)
        _RAISED["exc"] = exc
        if _DEFER["depth"]:                 # signals_deferred: raised when that block ends
            _DEFER["pending"] = exc
            return
        raise exc

    prev_hook = sys.unraisablehook

    def unraisable(info):           # (marked: redeliver_swallowed leaves a swallowed signal to it)
        if info.exc_value is not None and info.exc_value is _RAISED["exc"]:   # swallowed: deliver it again
            signum = fired.pop()
            _RAISED["exc"] = None
            _send_again(signum)
            return
        prev_hook(info)

    prev_excepthook = sys.excepthook

    def excepthook(etype, value, tb):
        # A C extension's init that PyErr_Print()s the error of a nested import (numba's
        # _dispatcher does, for numba._devicearray): our own signal's exception is not printed
        # there; the ImportError that follows carries it up (signal_behind).
        if value is not None and value is _RAISED["exc"]:
            return
        prev_excepthook(etype, value, tb)

    outer_raised, _RAISED["exc"] = _RAISED["exc"], None     # (before the handlers: they set it)
    old = {}
    for sig in HANDLED:
        if signal.getsignal(sig) is not signal.SIG_IGN:
            old[sig] = signal.signal(sig, handler)
    unraisable.redelivers_signals = True
    sys.unraisablehook = unraisable
    sys.excepthook = excepthook
    try:
        yield
    finally:
        signalled = bool(fired)
        fired.append(0)                   # a signal from here on must not raise outside the caller's try
        sys.unraisablehook = prev_hook
        sys.excepthook = prev_excepthook
        _RAISED["exc"] = outer_raised
        for sig, prev in old.items():
            signal.signal(sig, signal.SIG_IGN if ignore_after_signal and signalled else prev)


@contextlib.contextmanager
def redeliver_swallowed() -> Iterator[None]:
    """For library use without exceptions_on_signals (the Python API around a Lava start-up):
    Python's own SIGINT handler (KeyboardInterrupt) and the runtime's SIGTERM one (SystemExit
    143) raise wherever the main thread is, also inside an at-fork hook (logging's: Lava forks a
    dozen times at start-up), where Python swallows the exception (sys.unraisablehook) and the
    signal is lost: the script ran on to the end, exit 0. Within this block such an exception
    sends its signal again 10 ms later, as exceptions_on_signals does (which, when active,
    handles it itself)."""
    prev = sys.unraisablehook
    if threading.current_thread() is not threading.main_thread() or getattr(prev, "redelivers_signals", False):
        yield
        return

    def hook(info):
        exc = info.exc_value
        sig = (signal.SIGINT if isinstance(exc, KeyboardInterrupt) else exc.signum if isinstance(exc, Terminated)
               else signal.SIGTERM if isinstance(exc, SystemExit) and exc.code == 128 + signal.SIGTERM else None)
        if sig is None:
            prev(info)
            return
        _send_again(sig)

    sys.unraisablehook = hook
    try:
        yield
    finally:
        sys.unraisablehook = prev


def signal_behind(exc: BaseException | None) -> BaseException | None:
    """The KeyboardInterrupt or ``Terminated`` that ``exc`` is, or that it wraps; else None.

    A signal that lands while compiled code (numba's dispatcher) calls back into Python comes out
    as a SystemError ("returned a result with an exception set") with the signal's exception as
    its cause, at the end of a chain of such SystemErrors, one per compiled frame. One that lands
    while a C extension initialises (onnxruntime's, numba's: an import in the first second of a
    command) comes out as an ImportError ("initialization failed", "numba._devicearray failed to
    import"), sometimes with no link to it. So any error that ends a block of
    exceptions_on_signals after its signal was raised is that signal: the unwinding ran the
    clean-ups all the same, and callers treat it as the signal."""
    seen = 0
    first = exc
    while isinstance(exc, SystemError) and seen < 100:
        exc, seen = exc.__cause__ or exc.__context__, seen + 1
    if isinstance(exc, (KeyboardInterrupt, Terminated)):
        return exc
    if isinstance(first, Exception) and _RAISED["exc"] is not None:
        return _RAISED["exc"]
    return None
