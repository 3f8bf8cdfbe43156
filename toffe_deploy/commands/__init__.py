"""One module per sub-command. Each has ``register(subparsers)``, which adds its parser and sets
``func`` to a handler ``func(args) -> int``. Heavy imports (torch, Lava) live inside handlers so
that ``toffe-deploy --help`` and the lean runtime stay fast and torch-free."""

COMMAND_MODULES = ("events", "dataset", "train", "eval", "export", "run")


def add_progress_flag(parser) -> None:
    """The one progress switch of every command: ``--no-progress`` (``--quiet`` an alias, the name
    `export` had)."""
    names = ("--no-progress", "--quiet")
    parser.add_argument(*names, dest="no_progress", action="store_true",
                        help="no progress bars (they are shown only when stderr is a terminal)")


def show_progress(args) -> bool:
    """Progress bars follow habit: on when stderr is a terminal and --no-progress is not given,
    so a redirected stderr (a log file, CI) gets no bar frames."""
    import sys

    return not getattr(args, "no_progress", False) and sys.stderr.isatty()


class slow_notice:
    """``with slow_notice(args, "..."):`` prints the message once on stderr when the block is
    still running after ``after_s`` seconds and progress is shown (stderr a terminal, no
    --no-progress): the first run on a machine compiles the numba kernels (~2 minutes) before
    its first window, and a silent terminal for that long looks like a hang."""

    def __init__(self, args, message: str, after_s: float = 3.0):
        self.message, self.after_s, self.on = message, float(after_s), show_progress(args)
        self._timer = None

    def __enter__(self):
        if self.on:
            import sys
            import threading

            self._timer = threading.Timer(self.after_s, lambda: print(self.message, file=sys.stderr, flush=True))
            self._timer.daemon = True
            self._timer.start()
        return self

    def __exit__(self, *exc):
        if self._timer is not None:
            self._timer.cancel()
        return False
