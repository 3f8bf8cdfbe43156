"""The ``toffe-deploy`` command line: dispatch to sub-commands, turn user errors into one line."""
from __future__ import annotations

import argparse
import importlib
import os
import re
import sys

from . import __version__
from .commands import COMMAND_MODULES
from .errors import ToffeError
from .signals import Terminated, exceptions_on_signals, signal_behind


PROG = "toffe-deploy"


class OneLineParser(argparse.ArgumentParser):
    """argparse with its errors on one line (``PROG: error: MESSAGE (PROG --help for usage)``,
    exit 2), like every other error of the command line, instead of the usage block first."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {message} ({self.prog} --help for usage)\n")

    def parse_known_args(self, args=None, namespace=None):
        """A command's parser (``toffe-deploy run``, ``toffe-deploy events info``) refuses what it
        does not know itself, so that the error names the command and its --help (argparse hands
        the leftovers up to the top-level parser, whose line named neither)."""
        ns, extras = super().parse_known_args(args, namespace)
        if extras and self.prog != PROG:
            self.error(f"unrecognized arguments: {' '.join(extras)}")
        return ns, extras


#: a negative number or range (``-1.5,-0.3``) that argparse would take for an option
_NEGATIVE_VALUE = re.compile(r"-(\d|\.\d)[\d.eE+-]*(,[-+]?[\d.eE+-]+)?")


def join_negative_values(argv: list[str]) -> list[str]:
    """``--opt -1.5,-0.3`` as ``--opt=-1.5,-0.3`` (argparse reads a lone negative number as a
    value but a negative range as an unknown option), and ``--sensor-size W H`` as ``WxH``."""
    out: list[str] = []
    for tok in argv:
        if (out and out[-1].startswith("--") and "=" not in out[-1] and _NEGATIVE_VALUE.fullmatch(tok)
                and "," in tok):
            out[-1] = f"{out[-1]}={tok}"
        elif len(out) >= 2 and out[-2] == "--sensor-size" and out[-1].isdigit() and tok.isdigit():
            out[-1] = f"{out[-1]}x{tok}"          # --sensor-size W H, the older spelling of WxH
        else:
            out.append(tok)
    return out


def build_parser() -> argparse.ArgumentParser:
    parser = OneLineParser(
        prog=PROG,
        description="Deploy TOFFE object flow (OFS spiking cascade + OFPD CNN) on Loihi 2 "
        "(Lava) and an edge GPU (onnxruntime); train, export, run and measure it.",
    )
    parser.add_argument("--version", action="version", version=f"toffe-deploy {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in COMMAND_MODULES:
        importlib.import_module(f"toffe_deploy.commands.{name}").register(sub)
    return parser


def os_error_line(exc: OSError) -> str:
    """``PATH: reason`` for an OSError, without the library noise some wrappers add."""
    reason = os.strerror(exc.errno) if exc.errno else (str(exc).splitlines() or ["I/O error"])[0]
    return f"{exc.filename}: {reason}" if exc.filename else reason


def entry() -> int:
    """The ``toffe-deploy`` program (pyproject's script, ``python -m toffe_deploy.cli``): main,
    with the signals left ignored after a signal ended the command, so that a second Ctrl-C
    during the interpreter's exit cannot turn exit status 130 into a traceback."""
    return main(process=True)


def main(argv: list[str] | None = None, process: bool = False) -> int:
    """Run one command. Signals raise from the start (toffe_deploy.signals), so a Ctrl-C or a
    kill at any stage unwinds through the clean-ups: exit 130 (SIGINT) or 128 + n (SIGTERM 143,
    SIGHUP 129) with one line on stderr. ``process``: this is the program, about to exit (entry)."""
    with exceptions_on_signals(ignore_after_signal=process):
        try:
            parser = build_parser()
            args = parser.parse_args(join_negative_values(sys.argv[1:] if argv is None else list(argv)))
            if not getattr(args, "func", None):
                parser.print_help()
                return 2
            return int(args.func(args) or 0)
        except (Exception, KeyboardInterrupt, Terminated) as exc:
            return exit_status(exc)


def exit_status(exc: BaseException) -> int:
    """The one line on stderr and the exit status of an error that ended a command; an error
    that is a bug (none of these) goes on as a traceback."""
    sig = signal_behind(exc)
    if sig is not None:
        # Ctrl-C or a kill, also one that landed in compiled code or in a C extension's import
        # (signals.signal_behind): the clean-ups ran
        if isinstance(sig, KeyboardInterrupt):
            print("toffe-deploy: interrupted", file=sys.stderr)
            return 130
        print(f"toffe-deploy: {sig}", file=sys.stderr)
        return sig.exit_code
    if isinstance(exc, ToffeError):
        print(f"toffe-deploy: error: {exc}", file=sys.stderr)
        return exc.exit_code
    if isinstance(exc, MemoryError):
        # numpy's "Unable to allocate 16.0 GiB for an array ...": a size in the input (a
        # sensor, a kernel, a noise rate, a frame count) beyond this machine
        line = (str(exc).splitlines() or [""])[0]
        print(f"toffe-deploy: error: out of memory{': ' + line if line else ''} (a size in the input or the "
              "options larger than this machine holds?)", file=sys.stderr)
        return 2
    if isinstance(exc, BrokenPipeError):
        # the reader of our stdout went away (`| head`): stop quietly, and point stdout at
        # /dev/null so the interpreter's final flush does not report the closed pipe
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
    if isinstance(exc, OSError):
        # A write (or read) the system refused: full disk (ENOSPC, EDQUOT), read-only file
        # system (EROFS), permissions (EACCES). Writers are atomic, so nothing partial is left.
        print(f"toffe-deploy: error: {os_error_line(exc)}", file=sys.stderr)
        return 2
    raise exc


if __name__ == "__main__":
    sys.exit(entry())
