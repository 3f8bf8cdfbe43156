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
