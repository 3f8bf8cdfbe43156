"""Atomic writes: nothing half-written is ever left at a user-visible path.

Files are written to a temporary name in the destination directory and renamed over the target
(os.replace is atomic on one file system); directories are built in a sibling temp directory
and renamed into place. The temporary names carry the writer's process id, so that the next write
of the same path removes what a killed writer (SIGKILL, a crash, power) left beside it
(``clear_killed``), and puts back a directory it had moved aside.
"""
from __future__ import annotations

import contextlib
import errno
import json
import math
import os
import re
import secrets
import shutil
import stat
import tempfile
import time
import zipfile
from pathlib import Path
from typing import Any, Iterator, Sequence

from .errors import InputError


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


#: errno values that mean "this destination cannot take the write": reported as PATH: reason.
WRITE_ERRNOS = frozenset(getattr(errno, n) for n in ("ENOSPC", "EDQUOT", "EROFS", "EACCES", "EPERM", "EFBIG")
                         if hasattr(errno, n))


@contextlib.contextmanager
def write_errors(path: str | os.PathLike) -> Iterator[None]:
    """Turn a refused write (full disk, read-only, no permission) into InputError(path, ...)."""
    try:
        yield
    except OSError as exc:
        if exc.errno not in WRITE_ERRNOS:
            raise
        raise InputError(path, f"cannot write: {os.strerror(exc.errno)}") from None


def special_file(path: str | os.PathLike) -> bool:
    """Whether ``path`` names an existing device, pipe (FIFO, /dev/fd/N) or socket, or anything
    named under /dev or /proc (/dev/stdout, a link to whatever fd 1 is): something a rename over
    it would destroy (a file written beside /dev/null and renamed to it replaces /dev/null with
    a regular file; one renamed to /dev/stdout replaces the link), not a file or directory of
    the user's."""
    try:
        mode = os.stat(path).st_mode
    except OSError:
        return False
    if os.path.abspath(path).startswith(("/dev/", "/proc/")):
        return not stat.S_ISDIR(mode)
    return not (stat.S_ISREG(mode) or stat.S_ISDIR(mode))


#: why an output written whole (atomic_path) cannot go to a special_file
SPECIAL_WHY = "is a device, pipe or socket, not a file: this output is written whole and renamed into place; name a file"


def refuse_special(path: str | os.PathLike, name: str = "") -> None:
    """InputError for an output that must be written whole (atomic_path) named at a device or pipe."""
    if special_file(path):
        raise InputError(path, f"{name}: {SPECIAL_WHY}" if name else SPECIAL_WHY)


_STARTED = time.time()     # a leftover named with this process's pid but older than it is an earlier process's


def _alive(pid: int, mtime: float) -> bool:
    """Whether the writer ``pid`` of a leftover last changed at ``mtime`` may still run: process
    ``pid`` exists (one of another user's counts as alive) and is not this process, unless the
    leftover is newer than it (a container's fixed pid, reused by every run)."""
    if pid == os.getpid():
        return mtime >= _STARTED - 1.0
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OverflowError):
        return True
    return True


def temp_prefix(path: Path) -> str:
    """The prefix of a temporary name beside ``path`` (mkstemp / mkdtemp, suffix ``.tmp``):
    ``.NAME.PID-``, which clear_killed recognises."""
    return f".{path.name}.{os.getpid()}-"


def clear_killed(path: Path, suffix: str = ".tmp") -> None:
    """Remove what an earlier writer of ``path`` that no longer runs left beside it: temporary
    files or directories (``.NAME.PID-XXXXXXXX`` + ``suffix``) and a directory it moved aside
    (``.NAME.PID-XXXXXXXX.old``), which is put back when ``path`` is missing (the writer was killed
    between atomic_dir's two renames). A live writer's names are left alone. Limit: the pid is
    this machine's; a writer in another pid namespace (another container or host writing into
    the same directory) looks dead to it."""
    tmp = re.compile(rf"\.{re.escape(path.name)}\.(\d+)-[a-z0-9_]{{8}}{re.escape(suffix)}")
    old = re.compile(rf"\.{re.escape(path.name)}\.(\d+)-[a-z0-9_]{{8}}\.old")
    try:
        names = os.listdir(path.parent)
    except OSError:
        return
    for name in names:
        m = tmp.fullmatch(name) or old.fullmatch(name)
        if m is None:
            continue
        p = path.parent / name
        try:
            mtime = os.lstat(p).st_mtime
        except OSError:
            continue                            # gone meanwhile (another writer cleared it)
        if _alive(int(m.group(1)), mtime):
            continue
        if m.re is old and not os.path.lexists(path):
            with contextlib.suppress(OSError):  # another writer may put it back first
                os.replace(p, path)
            continue                            # put back, or kept: never deleted while path is missing
        if p.is_dir() and not p.is_symlink():
            shutil.rmtree(p, ignore_errors=True)
        else:
            with contextlib.suppress(OSError):
                p.unlink()


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, suffix: str = "") -> Iterator[Path]:
    """Yield a temporary path beside ``path``; rename it to ``path`` if the block succeeds.

    The caller writes the file at the yielded path (any library). On an exception the
    temporary file is removed and ``path`` is untouched; a refused write (WRITE_ERRNOS) is
    reported as InputError naming ``path``, and so is a ``path`` that names a device or pipe
    (refuse_special: the rename would replace it).
    """
    path = Path(path)
    refuse_special(path)
    with write_errors(path):
        path.parent.mkdir(parents=True, exist_ok=True)
        clear_killed(path, suffix or ".tmp")
        fd, tmp = tempfile.mkstemp(prefix=temp_prefix(path), suffix=suffix or ".tmp", dir=path.parent)
        os.close(fd)
        tmp = Path(tmp)
        try:
            yield tmp
            if tmp.exists():
                os.chmod(tmp, 0o666 & ~_umask())   # mkstemp makes 0600; give the usual mode
            os.replace(tmp, path)
        finally:
            if tmp.exists():
                tmp.unlink()


@contextlib.contextmanager
def atomic_dir(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a fresh temporary directory beside ``path``; on success it replaces ``path``.

    An existing ``path`` is moved aside first and deleted only after the rename succeeded; an
    error or Ctrl-C between the two renames puts it back (and a kill there, the next write of
    ``path``: clear_killed).
    A refused write (WRITE_ERRNOS) is reported as InputError naming ``path``, and so is a
    ``path`` that exists and is not a directory (nothing is written: a file there was moved
    aside, never deleted, and the next save into the new directory failed).
    """
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise InputError(path, "exists and is not a directory: a directory is written here; name a new one")
    with write_errors(path):
        path.parent.mkdir(parents=True, exist_ok=True)
        clear_killed(path, ".tmp")
        tmp = Path(tempfile.mkdtemp(prefix=temp_prefix(path), suffix=".tmp", dir=path.parent))
        old = None
        try:
            yield tmp
            os.chmod(tmp, 0o777 & ~_umask())       # mkdtemp makes 0700
            if path.exists():
                aside = path.with_name(f"{temp_prefix(path)}{secrets.token_hex(4)}.old")
                os.replace(path, aside)
                old = aside                        # only once it is there: a failed move leaves nothing to undo
            os.replace(tmp, path)
        finally:
            if old is not None and not path.exists():
                os.replace(old, path)              # stopped between the two renames: the old one back
                old = None
            if tmp.exists():
                shutil.rmtree(tmp, ignore_errors=True)
            if old is not None:
                shutil.rmtree(old, ignore_errors=True)


def finite_json(obj: Any) -> Any:
    """``obj`` with every float that is NaN or infinite replaced by None (JSON null),
    recursively through dicts, lists and tuples: strict JSON has no NaN, and parsers other than
    Python's (JavaScript's JSON.parse, jq, serde) reject Python's bare ``NaN``."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: finite_json(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [finite_json(v) for v in obj]
    return obj


def json_text(obj: Any, **kwargs) -> str:
    """json.dumps(obj, **kwargs) as strict JSON: NaN and infinities become null (finite_json).
    The usual object (all finite) is dumped once: only a refusal walks it."""
    try:
        return json.dumps(obj, allow_nan=False, **kwargs)
    except ValueError:
        return json.dumps(finite_json(obj), allow_nan=False, **kwargs)


#: what json.load / json.loads raise on text that is not usable JSON: ValueError (JSONDecodeError,
#: UnicodeDecodeError) and RecursionError, which the parser raises for nesting deeper than the
#: interpreter's stack ('[' * 2000), not a ValueError
JSON_ERRORS = (ValueError, RecursionError)


def read_json(path: str | os.PathLike) -> Any:
    """A JSON file's content; a missing, unreadable or malformed file is a one-line InputError."""
    try:
        with open(path, "r", encoding="utf-8") as f:
            return json.load(f)
    except FileNotFoundError:
        raise InputError(path, "missing file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(path, f"cannot read: {exc}") from None
    except json.JSONDecodeError as exc:
        msg = exc.msg.removesuffix(" at")        # json's "Invalid control character at"
        raise InputError(path, f"not valid JSON ({msg} at line {exc.lineno})") from None
    except RecursionError:
        raise InputError(path, "not valid JSON (nested too deeply)") from None


def savez_compressed(file, **arrays) -> None:
    """np.savez_compressed's .npz (a deflated zip of NAME.npy members, no pickle) into ``file``
    (a path or a binary file object), the zip closed on every way out: numpy's own leaves its
    ZipFile open when a Ctrl-C lands mid-write, and that object's __del__ later wrote into the
    closed buffer ("Exception ignored ... I/O operation on closed file" after `interrupted`)."""
    import numpy as np

    with zipfile.ZipFile(file, "w", compression=zipfile.ZIP_DEFLATED, allowZip64=True) as zf:
        for name, value in arrays.items():
            with zf.open(f"{name}.npy", "w", force_zip64=True) as member:
                np.lib.format.write_array(member, np.asanyarray(value), allow_pickle=False)


def write_bytes_atomic(path: str | os.PathLike, data, suffix: str = "") -> None:
    """Write an in-memory file image (bytes, bytearray, memoryview) to ``path`` atomically.

    Why: libraries that write through their own C I/O (HDF5) can crash the interpreter when the
    disk fills up; building the file in memory and writing it with Python's I/O turns a full or
    read-only disk into an ordinary OSError, and atomic_path removes the partial temp file.
    """
    with atomic_path(path, suffix=suffix) as tmp:
        with open(tmp, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())


def _real(path: str | os.PathLike) -> Path:
    return Path(os.path.realpath(os.fspath(path)))


def _same_file(a: Path, b: Path) -> bool:
    try:
        return os.path.samefile(a, b)
    except OSError:
        return _real(a) == _real(b)


def _probe_writable(out: Path, is_dir: bool) -> None:
    """Create and drop a temp file where ``out`` will be written (EROFS, EACCES, ENOSPC up front)."""
    d = out if is_dir else out.parent
    while not d.exists() and d != d.parent:
        d = d.parent
    if not d.is_dir():
        raise InputError(out, f"cannot write: {d} is not a directory")
    try:
        with tempfile.TemporaryFile(dir=d) as fh:
            fh.write(b"\0")
            fh.flush()
    except OSError as exc:
        raise InputError(out, f"cannot write in {d}: {exc.strerror or exc}") from None


def check_outputs(files: Sequence[tuple[str, str | os.PathLike | None]] = (),
                  dirs: Sequence[tuple[str, str | os.PathLike | None]] = (),
                  inputs: Sequence[tuple[str, str | os.PathLike | None]] = (),
                  streamed: Sequence[str] = ()) -> None:
    """Refuse, before any work, output paths that would destroy an input or each other.

    files / dirs: (option name, path) of the file / directory outputs (None = not given).
    inputs: (what, path) of the files and directories the command reads, e.g. ("the input
    events", F), ("bundle file", B/ofpd.onnx), ("the bundle", B); no output may be one of them
    (same inode or same resolved path: symlinks and hard links count). Two outputs may not
    resolve to the same path, a file output may not be an existing directory (nor a directory
    output a file), and every output's directory must accept a new file (read-only, full or
    forbidden destinations fail here, before the work). A file output at a device or pipe
    (special_file) is refused too, unless its option is in ``streamed`` (written line by line
    into it, runtime.output.LineFile). Each problem is an InputError naming the output: one
    line, exit 2.
    """
    outs = [(n, Path(p), False) for n, p in files if p is not None] + \
           [(n, Path(p), True) for n, p in dirs if p is not None]
    ins = [(what, Path(p)) for what, p in inputs if p is not None]
    seen: dict[Path, str] = {}
    for name, out, is_dir in outs:
        if out.exists() and out.is_dir() != is_dir:
            raise InputError(out, f"{name}: " + ("exists and is not a directory" if is_dir
                                                 else "is a directory (give a file name)"))
        real = _real(out)
        for what, src in ins:
            if real == _real(src) or (out.exists() and src.exists() and _same_file(out, src)):
                raise InputError(out, f"{name} would overwrite {what} {src}; choose another output")
        if real in seen:
            raise InputError(out, f"given as both {seen[real]} and {name}; choose different outputs")
        seen[real] = name
        if not is_dir and special_file(out):
            if name not in streamed:
                refuse_special(out, name)
            continue                               # written into as it is: nothing to probe beside it
        _probe_writable(out, is_dir)
