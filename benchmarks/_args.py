"""What the benchmark scripts share on their command lines: argparse types that refuse bad values
with one line (exit 2, before any work), the one-line parser, and the handler that turns the
package's user errors (toffe_deploy.errors.ToffeError) into one line on stderr.

The numeric types are toffe_deploy.commands.dataset's (the CLI's own); the scripts import this
module with benchmarks/ on sys.path (``sys.path.insert(0, str(ROOT / "benchmarks"))``). It
changes nothing on sys.path itself: toffe_deploy is whichever the script put first (bench_exact.py
runs the version on PYTHONPATH, possibly an older checkout).
"""
from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

from toffe_deploy.commands.dataset import _number
from toffe_deploy.errors import ToffeError

try:
    from toffe_deploy.cli import OneLineParser, os_error_line
except ImportError:           # a checkout older than the CLI's one-line parser (bench_exact.py compares those)
    OneLineParser = argparse.ArgumentParser
    os_error_line = str

__all__ = ["OneLineParser", "positive_int", "nonneg_int", "at_least_two", "positive_float", "nonneg_float", "share", "int_in",
           "comma_list", "existing_file", "existing_dir", "json_output", "cpu_core", "default_core", "guarded", "key_value",
           "apply_overrides"]

positive_int = _number(int, 1, strict=False)        # an integer >= 1
nonneg_int = _number(int, 0, strict=False)          # an integer >= 0
at_least_two = _number(int, 2, strict=False)        # an integer >= 2
positive_float = _number(float, 0, strict=True)     # a finite number > 0
nonneg_float = _number(float, 0, strict=False)      # a finite number >= 0


def share(text: str) -> float:
    """An argparse type: a finite number in (0, 1] (a share of something, 1 = all of it)."""
    v = positive_float(text)
    if v > 1:
        raise argparse.ArgumentTypeError(f"must be in (0, 1], got {text}")
    return v


def int_in(low: int, high: int):
    """An argparse type: an integer in [low, high]."""
    at_least = _number(int, low, strict=False)

    def parse(text: str) -> int:
        v = at_least(text)
        if v > high:
            raise argparse.ArgumentTypeError(f"must be {low}..{high}, got {text}")
        return v
    return parse


def comma_list(item, min_items: int = 1, max_items: int | None = None):
    """An argparse type: comma-separated values, each through the argparse type ``item``, at
    least ``min_items`` (and at most ``max_items``) of them; returns a list."""
    def parse(text: str) -> list:
        parts = [p.strip() for p in text.split(",") if p.strip()]
        if not min_items <= len(parts) <= (max_items if max_items is not None else len(parts)):
            want = (f"{min_items}" if max_items == min_items else
                    f"{min_items} to {max_items}" if max_items is not None else f"at least {min_items}")
            raise argparse.ArgumentTypeError(f"expected {want} comma-separated value(s), got {text!r}")
        out = []
        for p in parts:
            try:
                out.append(item(p))
            except argparse.ArgumentTypeError as exc:
                raise argparse.ArgumentTypeError(f"{exc} (in {text!r})") from None
        return out
    return parse


def existing_file(text: str) -> Path:
    """An argparse type: a path that exists and is a file (or a device, pipe: not a directory)."""
    p = Path(text)
    if not p.exists():
        raise argparse.ArgumentTypeError(f"{text}: no such file")
    if p.is_dir():
        raise argparse.ArgumentTypeError(f"{text}: is a directory, not a file")
    return p


def existing_dir(text: str) -> Path:
    """An argparse type: a path that exists and is a directory."""
    p = Path(text)
    if not p.exists():
        raise argparse.ArgumentTypeError(f"{text}: no such directory")
    if not p.is_dir():
        raise argparse.ArgumentTypeError(f"{text}: is a file, not a directory")
    return p


def json_output(text: str) -> Path:
    """An argparse type: a file to write (a JSON result): not an existing directory, in a
    directory that exists."""
    p = Path(text)
    if p.is_dir():
        raise argparse.ArgumentTypeError(f"{text}: is a directory (give a file name)")
    parent = p.parent
    if not parent.is_dir():
        raise argparse.ArgumentTypeError(f"{text}: directory {parent} does not exist")
    return p


def cpu_core(text: str) -> int:
    """An argparse type: a CPU core this process may run on (os.sched_getaffinity(0))."""
    v = nonneg_int(text)
    cores = sorted(os.sched_getaffinity(0))
    if v not in cores:
        raise argparse.ArgumentTypeError(f"no CPU core {v} here (cores this process may use: "
                                         f"{', '.join(map(str, cores))})")
    return v


def default_core() -> str:
    """The --core default of bench_parts.py and bench_features.py: core 1, the core the README's
    figures were taken on, or 0 when the highest core this process may use is 0 (one core)."""
    return str(min(1, max(os.sched_getaffinity(0))))


def guarded(prog: str, fn, *args) -> int:
    """``fn(*args)`` as a script's main runs it: a ToffeError (a missing bundle, data directory,
    a malformed file) is one line ``PROG.py: error: ...`` on stderr and its exit code (2), a
    refused read or write (OSError) one line and 2, Ctrl-C one line and 130, a closed stdout
    (``| head``) a quiet 0, as the toffe-deploy CLI does. ``prog``: the script's name without
    ".py"; its lines name the file as argparse's usage errors do (``PROG.py: error: ...``)."""
    prog = f"{prog}.py"
    try:
        return int(fn(*args) or 0)
    except ToffeError as exc:
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return exc.exit_code
    except KeyboardInterrupt:
        print(f"{prog}: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:      # the reader of stdout went away (`| head`): stop quietly, as the CLI does
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
    except OSError as exc:
        print(f"{prog}: error: {os_error_line(exc)}", file=sys.stderr)
        return 2


#: config.ofpd keys read outside ofpd_io's defaults (plane_fit.py, outline_centre.py)
FUSION_KEYS = ("plane_fit_weight", "plane_fit_min_px_ms", "plane_fit_dir_weight", "plane_fit_history",
               "plane_fit_refits", "outline_centre")


def key_value(text: str, option: str) -> tuple[str, object]:
    """(KEY, JSON value) of ``KEY=VALUE``; ValueError naming the option otherwise."""
    k, eq, v = text.partition("=")
    if not eq or not k.strip():
        raise ValueError(f"argument {option}: expected KEY=VALUE (VALUE in JSON), got {text!r}")
    try:
        return k.strip(), json.loads(v)
    except json.JSONDecodeError as exc:
        raise ValueError(f"argument {option}: {k.strip()}: the value is not JSON ({exc.msg}): {v!r}") from None


def apply_overrides(cfg, ofpd: list, top: list):
    """cfg with --ofpd and --config overrides (KEY, value pairs of ``key_value``), checked as a
    config.json is (ToffeConfig.from_dict: one-line errors); an unknown key is refused, listing
    the valid ones. The scripts that take them try a grouping or fusion setting on a trained
    bundle without exporting a new one."""
    import dataclasses

    from toffe_deploy import ofpd_io
    from toffe_deploy.plane_fit import refit_settings

    if not (ofpd or top):
        return cfg
    valid_ofpd = sorted(set(ofpd_io.OFPD_DEFAULTS) | set(FUSION_KEYS) | set(cfg.ofpd or {}))
    valid_top = sorted(f.name for f in dataclasses.fields(cfg) if f.name != "ofpd")
    for option, pairs, valid in (("--ofpd", ofpd, valid_ofpd), ("--config", top, valid_top)):
        unknown = [k for k, _ in pairs if k not in valid]
        if unknown:
            raise ToffeError(f"{option}: unknown key(s) {', '.join(unknown)} (valid: {', '.join(valid)})")
    d = {**cfg.to_dict(), **dict(top)}
    if ofpd:
        d["ofpd"] = {**(cfg.ofpd or {}), **dict(ofpd)}
    out = type(cfg).from_dict(d, path="the --ofpd / --config overrides")
    try:
        refit_settings(out)                              # what from_dict's validate does not read
        ofpd_io.blob_settings(ofpd_io.ofpd_settings(out))  # the grouping's numbers (merge_frac, link_px, ...)
    except (TypeError, ValueError) as exc:
        given = ", ".join(f"{k}={v!r}" for k, v in ofpd)
        raise ToffeError(f"--ofpd {given}: {exc}") from None
    return out
