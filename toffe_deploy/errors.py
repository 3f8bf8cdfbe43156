"""User-facing errors: one line, naming the file and the problem, exit code 2 from the CLI."""
from __future__ import annotations

import os
import sys


class ToffeError(Exception):
    """An error caused by the user's input or environment, reported without a traceback."""

    exit_code = 2


class InputError(ToffeError):
    """A problem with one file (or directory) the user handed us: ``PATH: problem``."""

    def __init__(self, path: str | os.PathLike, problem: str):
        self.path = os.fspath(path)
        self.problem = problem
        super().__init__(f"{self.path}: {problem}")


def warn(message: str) -> None:
    """A one-line warning on stderr (the CLI's form: what was done anyway, and why it may be
    wrong), e.g. an option that applies to part of what was asked only."""
    print(f"toffe-deploy: warning: {message}", file=sys.stderr, flush=True)
