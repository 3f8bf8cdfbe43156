"""Progress bars follow habit: only on a terminal, one flag name everywhere."""
import argparse
import subprocess
import sys
from pathlib import Path

import pytest

from toffe_deploy.commands import COMMAND_MODULES

SAMPLE = Path(__file__).resolve().parent.parent / "toffe_deploy" / "samples" / "sample_multi.h5"


def _info(stderr):
    return subprocess.run([sys.executable, "-m", "toffe_deploy.cli", "events", "info", str(SAMPLE)],
                          stdout=subprocess.PIPE, stderr=stderr, timeout=120)


def test_redirected_stderr_gets_no_bar_frames():
    p = _info(subprocess.PIPE)
    assert p.returncode == 0 and b"\r" not in p.stderr and b"reading" not in p.stderr


def test_a_terminal_gets_the_bar_unless_asked_not_to(monkeypatch):
    from toffe_deploy.commands import show_progress

    class Terminal:
        def isatty(self):
            return True

    monkeypatch.setattr(sys, "stderr", Terminal())
    assert show_progress(argparse.Namespace(no_progress=False))
    assert not show_progress(argparse.Namespace(no_progress=True))


def test_a_slow_start_is_announced_on_a_terminal_only(monkeypatch):
    """slow_notice: a block still running after after_s prints its message once on a terminal
    (the first run's kernel compile); a quick block, --no-progress or a redirected stderr: nothing."""
    import io
    import time

    from toffe_deploy.commands import slow_notice

    class Terminal(io.StringIO):
        def isatty(self):
            return True

    term = Terminal()
    monkeypatch.setattr(sys, "stderr", term)
    with slow_notice(argparse.Namespace(no_progress=False), "compiling", after_s=0.05):
        time.sleep(0.3)
    with slow_notice(argparse.Namespace(no_progress=False), "quick", after_s=0.5):
        pass
    with slow_notice(argparse.Namespace(no_progress=True), "asked not to", after_s=0.0):
        time.sleep(0.1)
    time.sleep(0.6)                                  # a cancelled timer never fires
    assert term.getvalue() == "compiling\n"
    piped = io.StringIO()
    monkeypatch.setattr(sys, "stderr", piped)
    with slow_notice(argparse.Namespace(no_progress=False), "redirected", after_s=0.0):
        time.sleep(0.1)
    assert piped.getvalue() == ""


@pytest.mark.parametrize("command", ["events info", "events convert", "dataset synth", "dataset show", "train", "eval",
                                     "export", "run"])
def test_every_command_takes_no_progress(command):
    import importlib

    parser = argparse.ArgumentParser()
    sub = parser.add_subparsers()
    for name in COMMAND_MODULES:
        importlib.import_module(f"toffe_deploy.commands.{name}").register(sub)
    words = command.split()
    target = sub.choices[words[0]]
    if len(words) > 1:
        target = next(a for a in target._actions if isinstance(a, argparse._SubParsersAction)).choices[words[1]]
    flags = {s for a in target._actions for s in a.option_strings}
    assert "--no-progress" in flags
    assert "--quiet" in flags                                  # the alias (export's old name), on every command
