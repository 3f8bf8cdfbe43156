"""Signals as exceptions, so that a kill unwinds through the same ``finally`` blocks as an error.

The CLI enters ``exceptions_on_signals()`` before it does any work: SIGTERM (``kill``,
``timeout``) and SIGHUP (a closed terminal) raise ``Terminated``, SIGINT (Ctrl-C) raises
KeyboardInterrupt, from the first signal on, at any stage, start-up included. Unwinding then
stops the Lava runtime and removes temporary files and directories (fileio.atomic_path /
atomic_dir, the exporter's staging directory). A repeated signal while unwinding is ignored, so
it cannot cut a clean-up short; SIGKILL still ends everything (Lava's children die with the
host, see runtime.lava_host). A signal that the parent set to be ignored (``nohup``, a
background job's SIGINT) stays ignored.

Exit status (cli.main): 130 for SIGINT, 128 + n for ``Terminated`` (143 for SIGTERM, 129 for
SIGHUP), with one line on stderr.
"""
from __future__ import annotations

import contextlib
import signal
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


@contextlib.contextmanager
def exceptions_on_signals() -> Iterator[None]:
    """Within this block (main thread only), SIGINT, SIGTERM and SIGHUP raise once, then are ignored."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    fired: list[int] = []

    def handler(signum, frame):
        if fired:
            return
        fired.append(signum)
        if signum == signal.SIGINT:
            raise KeyboardInterrupt
        raise Terminated(signum)

    old = {}
    for sig in HANDLED:
        if signal.getsignal(sig) is not signal.SIG_IGN:
            old[sig] = signal.signal(sig, handler)
    try:
        yield
    finally:
        for sig, prev in old.items():
            signal.signal(sig, prev)
