"""Fault sweep: signals at every stage of `toffe-deploy run` and `export`, and what they leave.

Each scenario starts the CLI in a session of its own, waits for a stage (the host has N
children, the run is streaming: its first JSON line is written), does one thing (SIGTERM to the
host, Ctrl-C to the process group as a terminal sends it, SIGKILL to the host or to the whole
group as ``timeout -k`` does, SIGKILL to Lava's shared-memory manager), then records the exit
status, how long the host took to exit, and what is left 10 s later: processes of the session
(and the run's shm reaper),
/dev/shm bytes and segments of the run (named toffe_lava_<host pid>_..., or the stdlib's psm_...
created during the run by the code before segment naming), temp files and directories.
Everything left is removed afterwards (the sweep's own processes and segments only).

    python benchmarks/fault_sweep.py                  # the full matrix, a table on stdout
    python benchmarks/fault_sweep.py --pythonpath /work/main --only run-loihi   # another checkout

Exit status: 0 when every scenario run left nothing behind and its host exited; 1 when one
hung (did not exit within its wait), printed a traceback, or left processes, /dev/shm segments
or temp files (the table says which); 2 for bad options (an unknown --only group, a --pythonpath without
toffe_deploy/, a --match that selects nothing). The exit codes of the killed runs themselves
are reported, not judged.

The tests (tests/test_faults_signals.py) run a few of these scenarios with the same helpers.
"""
from __future__ import annotations

import argparse
import contextlib
import glob
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

ROOT = Path(__file__).resolve().parents[1]
SHM = "/dev/shm"
GROUPS = ("run-loihi", "run-cpu", "export")       # matrix()'s groups, for --only


# ----------------------------------------------------------------------------- /proc observation
def stat(pid: int) -> tuple[int, int, int] | None:
    """(ppid, session id, start ticks) of a live process (zombies count as gone); None if gone."""
    try:
        with open(f"/proc/{pid}/stat", "rb") as f:
            rest = f.read().rsplit(b")", 1)[1].split()
    except (FileNotFoundError, ProcessLookupError):
        return None
    if rest[0] in (b"Z", b"X"):
        return None
    return int(rest[1]), int(rest[3]), int(rest[19])


def _pids() -> list[int]:
    return [int(d) for d in os.listdir("/proc") if d.isdigit()]


def session_pids(sid: int) -> list[int]:
    """Live processes of session ``sid`` (the host, its children, and their orphans)."""
    out = []
    for pid in _pids():
        st = stat(pid)
        if st is not None and st[1] == sid:
            out.append(pid)
    return out


def run_pids(host: int) -> list[int]:
    """Live processes of a run: its session (the host started in a session of its own, its
    children and their orphans) and its shm reaper (a session of its own, named after the host)."""
    tag = f"toffe_lava_{host}_"
    return sorted(set(session_pids(host)) | {p for p in _pids() if tag in cmdline(p) and stat(p) is not None})


def children(pid: int) -> list[int]:
    """Live children of ``pid``, oldest first."""
    kids = []
    for p in _pids():
        st = stat(p)
        if st is not None and st[0] == pid:
            kids.append((st[2], p))
    return [p for _, p in sorted(kids)]


def cmdline(pid: int) -> str:
    try:
        with open(f"/proc/{pid}/cmdline", "rb") as f:
            return f.read().replace(b"\0", b" ").decode(errors="replace")
    except OSError:
        return ""


def manager_pid(host: int) -> int | None:
    """Lava's shared-memory manager: the host's first forked child (same command line as the host;
    the resource tracker and the shm reaper are exec'd)."""
    me = cmdline(host)
    for p in children(host):
        if cmdline(p) == me:
            return p
    return None


def shm_sizes() -> dict[str, int]:
    out = {}
    for name in os.listdir(SHM):
        try:
            out[name] = os.stat(os.path.join(SHM, name)).st_size
        except OSError:
            pass
    return out


def _maps(pid: int) -> set[str]:
    """Names of the /dev/shm files process ``pid`` maps."""
    used = set()
    try:
        with open(f"/proc/{pid}/maps") as f:
            for line in f:
                i = line.find("/dev/shm/")
                if i >= 0:
                    used.add(line[i + 9:].split()[0])
    except OSError:
        pass
    return used


def mapped_shm() -> set[str]:
    """Names of /dev/shm files some live process maps (segments in use)."""
    used = set()
    for pid in _pids():
        used |= _maps(pid)
    return used


# ----------------------------------------------------------------------------- one scenario
@dataclass
class Outcome:
    name: str
    rc: int | None                 # None: the host did not exit within the wait
    exit_s: float                  # from the action to the host's exit
    procs_left: int                # processes of the session 10 s after the action
    shm_segments_left: int
    shm_bytes_left: int
    temp_left: list[str] = field(default_factory=list)
    stderr: str = ""
    triggered: bool = True         # False: the run ended before the stage was reached
    pid: int = 0                   # the host's


def _run_shm(before: dict[str, int], host: int, t_start: float, count_psm: bool = True) -> dict[str, int]:
    """Segments of this run: named after the host, or (code before segment naming) stdlib psm_
    names created since the run started that no process outside its session maps."""
    out, psm = {}, {}
    for name, size in shm_sizes().items():
        if name.startswith(f"toffe_lava_{host}_"):
            out[name] = size
        elif count_psm and name.startswith("psm_") and name not in before:
            with contextlib.suppress(OSError):
                if os.stat(os.path.join(SHM, name)).st_mtime >= t_start - 1:
                    psm[name] = size
    if psm:
        ours = set(session_pids(host))
        foreign = set()
        for pid in _pids():
            if pid not in ours:
                foreign |= _maps(pid)
        out.update({n: s for n, s in psm.items() if n not in foreign})
    return out


def _default_sigint() -> None:
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def run_scenario(name: str, argv: list[str], trigger: Callable[[subprocess.Popen], bool],
                 action: Callable[[subprocess.Popen], None], temp_globs: list[str], env: dict | None = None,
                 settle_s: float = 10.0, exit_wait_s: float = 60.0, trigger_wait_s: float = 180.0,
                 cleanup: bool = True, count_psm: bool = False) -> Outcome:
    """Start ``argv`` in its own session, wait for ``trigger``, do ``action``, measure what is left.

    The working directory is the checkout on PYTHONPATH (``python -m`` puts the working directory
    first on sys.path). ``count_psm``: also count stdlib-named segments (code before naming).
    """
    before = shm_sizes()
    t_start = time.time()
    err = tempfile.TemporaryFile()
    # SIGINT as in a terminal's foreground job: a sweep started in the background (`cmd &` in a
    # script) would hand its ignored SIGINT down to the CLI, which keeps an ignored signal ignored
    cwd = (env or {}).get("PYTHONPATH", str(ROOT))
    p = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=err, env=env, cwd=cwd, start_new_session=True,
                         preexec_fn=_default_sigint)
    sid = p.pid
    triggered = False
    deadline = time.monotonic() + trigger_wait_s
    while p.poll() is None and time.monotonic() < deadline:
        if trigger(p):
            triggered = True
            break
        time.sleep(0.005)
    t_act = time.monotonic()
    if triggered and p.poll() is None:
        action(p)
    try:
        rc = p.wait(exit_wait_s)
    except subprocess.TimeoutExpired:
        rc = None
    exit_s = time.monotonic() - t_act
    if rc is None:                                  # hung: end it to measure the rest
        os.killpg(sid, signal.SIGKILL)
        p.wait()
    settle = time.monotonic() + settle_s
    while time.monotonic() < settle:
        if not run_pids(sid) and not _run_shm(before, p.pid, t_start, count_psm):
            break
        time.sleep(0.1)
    left = run_pids(sid)
    shm = _run_shm(before, p.pid, t_start, count_psm)
    temp = sorted(x for g in temp_globs for x in glob.glob(g))
    err.seek(0)
    out = Outcome(name, rc, round(exit_s, 2), len(left), len(shm), sum(shm.values()), temp,
                  err.read().decode(errors="replace"), triggered, p.pid)
    if cleanup:
        for pid in left:
            try:
                os.kill(pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
        time.sleep(0.5)
        used = mapped_shm()
        for n in _run_shm(before, p.pid, t_start, count_psm):
            if n not in used:
                try:
                    os.unlink(os.path.join(SHM, n))
                except OSError:
                    pass
        for x in temp:
            shutil.rmtree(x, ignore_errors=True) if os.path.isdir(x) else os.unlink(x)
    return out


# ----------------------------------------------------------------------------- triggers and actions
def n_children(n: int, after_s: float = 0.0) -> Callable[[subprocess.Popen], bool]:
    """The host has at least n children (then waits after_s); n = 0: right after the start."""
    state: dict = {}

    def trig(p):
        if len(children(p.pid)) < n:
            return False
        state.setdefault("t", time.monotonic())
        return time.monotonic() - state["t"] >= after_s
    return trig


def after(seconds: float) -> Callable[[subprocess.Popen], bool]:
    """``seconds`` after the start: a stage by time (the imports of the first second, where a
    signal can land inside a C extension's initialisation)."""
    state: dict = {}

    def trig(p):
        return time.monotonic() - state.setdefault("t", time.monotonic()) >= seconds
    return trig


def catching(sig: int = signal.SIGTERM) -> Callable[[subprocess.Popen], bool]:
    """The host has a handler for ``sig`` (/proc/PID/status SigCgt) and no child yet: the CLI is
    past interpreter start-up (before that, a signal takes its default action)."""
    def trig(p):
        try:
            with open(f"/proc/{p.pid}/status") as f:
                caught = next(int(line.split()[1], 16) for line in f if line.startswith("SigCgt:"))
        except (OSError, StopIteration):
            return False
        return bool(caught >> (sig - 1) & 1) and not children(p.pid)
    return trig


def file_exists(pattern: str, min_bytes: int = 0) -> Callable[[subprocess.Popen], bool]:
    def trig(p):
        return any(os.path.getsize(x) >= min_bytes for x in glob.glob(pattern) if os.path.isfile(x))
    return trig


def lines_written(path: str | Path, n: int = 1) -> Callable[[subprocess.Popen], bool]:
    """The run has streamed at least n whole window lines to ``path`` (`run --out` writes the
    header line, then each window's line as it is done); a file older than the trigger's first
    look is a previous run's."""
    state: dict = {}

    def trig(p):
        t = state.setdefault(p.pid, time.time())          # one trigger serves several runs
        try:
            if os.stat(path).st_mtime < t:
                return False
            with open(path, "rb") as f:
                return f.read().count(b"\n") >= n + 1             # + the header line
        except OSError:
            return False
    return trig


def whole_lines(path: str | Path) -> list[dict]:
    """The window lines a (possibly killed) run left, after its header line: ValueError on a
    partial or broken line, or on a header that is not the first line."""
    data = Path(path).read_bytes()
    if data and not data.endswith(b"\n"):
        raise ValueError(f"{path} ends inside a line")
    rows = [json.loads(line) for line in data.splitlines()]
    if any(r.get("type") == "header" for r in rows[1:]):
        raise ValueError(f"{path}: a header line after the first line")
    return rows[1:] if rows and rows[0].get("type") == "header" else rows


def to_host(sig: int) -> Callable[[subprocess.Popen], None]:
    return lambda p: os.kill(p.pid, sig)


def to_group(sig: int) -> Callable[[subprocess.Popen], None]:
    return lambda p: os.killpg(p.pid, sig)


def kill_manager(p: subprocess.Popen) -> None:
    pid = manager_pid(p.pid)
    if pid is not None:
        os.kill(pid, signal.SIGKILL)


ACTIONS = {"SIGTERM host": to_host(signal.SIGTERM), "Ctrl-C group": to_group(signal.SIGINT),
           "SIGKILL host": to_host(signal.SIGKILL), "SIGKILL group": to_group(signal.SIGKILL),
           "SIGKILL shm manager": kill_manager}


# ----------------------------------------------------------------------------- fixtures and matrix
def make_env(root: Path, sensor=(32, 24)) -> dict:
    """A small real bundle, its checkpoint and a recording (tests/conftest.py's factories)."""
    sys.path.insert(0, str(ROOT / "tests"))
    from conftest import _make_bundle, _make_recording

    bundle = _make_bundle(root, sensor=sensor)
    rec = _make_recording(root / "rec.h5", sensor=sensor, duration=0.02)
    return {"root": root, "bundle": bundle.root, "ckpt": root / "ckpt", "rec": rec}


def cli(pythonpath: str, *args) -> tuple[list[str], dict]:
    env = dict(os.environ, PYTHONPATH=pythonpath)
    return [sys.executable, "-m", "toffe_deploy.cli", *map(str, args)], env


def matrix(e: dict, pythonpath: str, out: Path):
    """(group, name, argv, env, trigger, action, temp globs, exit wait s) of every scenario."""
    run_lava, env = cli(pythonpath, "run", e["bundle"], "--target", "loihi-sim", "--synthetic",
                        "multi:0,duration=5", "--no-progress", "--out", out / "lava.jsonl")
    lava_tmp = [str(out / ".lava.jsonl.*")]
    stages = [("0 children", catching()), ("2 children", n_children(2)), ("6 children", n_children(6)),
              ("streaming", lines_written(out / "lava.jsonl"))]
    for act in ("SIGTERM host", "Ctrl-C group", "SIGKILL host", "SIGKILL group"):
        for stage, trig in stages:
            yield "run-loihi", f"{act} @ {stage}", run_lava, env, trig, ACTIONS[act], lava_tmp, 30.0
    # a run that ends by itself in a few seconds: not exiting within 60 s after the kill is a hang
    short = run_lava[:run_lava.index("--no-progress")] + ["--max-windows", "100", "--no-progress", "--out",
                                                          str(out / "lava.jsonl")]
    for stage, trig in stages[1:]:
        yield "run-loihi", f"SIGKILL shm manager @ {stage}", short, env, trig, kill_manager, lava_tmp, 60.0
    run_cpu, env = cli(pythonpath, "run", e["bundle"], "--target", "cpu", "--synthetic", "multi:0,duration=3",
                       "--no-progress", "--out", out / "cpu.jsonl")
    yield "run-cpu", "SIGTERM host @ writing output", run_cpu, env, lines_written(out / "cpu.jsonl"), \
        ACTIONS["SIGTERM host"], [str(out / ".cpu.jsonl.*")], 30.0
    # Ctrl-C through start-up by time, two processes (more imports in flight): one landing inside
    # onnxruntime's or numba's C initialisation came out as an ImportError traceback, exit 1
    two = run_cpu[:run_cpu.index("--no-progress")] + ["--processes", "2", "--no-progress", "--out", str(out / "two.jsonl")]
    for ms in range(200, 1500, 100):
        yield "run-cpu", f"Ctrl-C group @ {ms} ms, 2 processes", two, env, after(ms / 1000), ACTIONS["Ctrl-C group"], \
            [str(out / ".two.jsonl.*")], 30.0
    exp, env = cli(pythonpath, "export", e["ckpt"], "-o", out / "bundle", "--checks", "lava_vs_fixed",
                   "--windows", "2", "--lava-windows", "1", "--quiet")
    exp_tmp = [str(out / ".bundle.*")]
    for act, stage, trig in (("SIGTERM host", "2 children", n_children(2)), ("SIGTERM host", "6 children", n_children(6)),
                             ("SIGKILL host", "6 children", n_children(6))):
        yield "export", f"{act} @ {stage}", exp, env, trig, ACTIONS[act], exp_tmp, 30.0


def main(argv: list[str] | None = None) -> int:
    sys.path.insert(0, str(ROOT / "benchmarks"))
    from _args import OneLineParser, comma_list, existing_dir, nonneg_float

    def group(text: str) -> str:
        if text not in GROUPS:
            raise argparse.ArgumentTypeError(f"unknown group {text!r} (groups: {', '.join(GROUPS)})")
        return text

    ap = OneLineParser(prog="fault_sweep.py", description=__doc__.splitlines()[0] + " Exit 1 when a scenario "
                       "hung, printed a traceback, or left processes, /dev/shm segments or temp files; 2 for bad "
                       "options.")
    ap.add_argument("--pythonpath", type=existing_dir, default=str(ROOT),
                    help="checkout whose toffe_deploy runs (default: this one)")
    ap.add_argument("--only", type=comma_list(group), default=[], help=f"comma-separated groups: {', '.join(GROUPS)}")
    ap.add_argument("--match", default="", help="only scenarios whose name contains this text")
    ap.add_argument("--settle", type=nonneg_float, default=10.0,
                    help="seconds to wait for leftovers to go (default: 10)")
    a = ap.parse_args(argv)
    if not (a.pythonpath / "toffe_deploy" / "__init__.py").is_file():
        ap.error(f"argument --pythonpath: {a.pythonpath}: no toffe_deploy/ package in it")
    a.pythonpath = str(a.pythonpath)
    groups = set(a.only)

    def chosen(group_name: str, name: str) -> bool:
        return (not groups or group_name in groups) and a.match in name

    names = matrix(dict.fromkeys(("bundle", "ckpt", "rec"), Path("-")), a.pythonpath, Path("-"))
    if not any(chosen(g, n) for g, n, *_ in names):      # before the bundle is built (a minute)
        print(f"fault_sweep.py: error: no scenario matches --only {','.join(a.only) or '(all)'} --match {a.match!r}",
              file=sys.stderr)
        return 2
    failed = ran = 0
    with tempfile.TemporaryDirectory(prefix="fault-sweep-") as tmp:
        e = make_env(Path(tmp))
        out = Path(tmp) / "out"
        out.mkdir()
        print(f"code: {a.pythonpath}")
        print(f"{'group':10} {'scenario':40} {'rc':>5} {'exit s':>7} {'procs':>5} {'shm seg':>7} {'shm bytes':>10} temp")
        named = (Path(a.pythonpath) / "toffe_deploy" / "runtime" / "lava_host.py").is_file()
        for group_name, name, args, env, trig, act, globs, wait in matrix(e, a.pythonpath, out):
            if not chosen(group_name, name):
                continue
            ran += 1
            o = run_scenario(name, args, trig, act, globs, env=env, settle_s=a.settle, exit_wait_s=wait,
                             count_psm=not named)
            rc = "hung" if o.rc is None else str(o.rc)
            tb = "Traceback" in o.stderr
            bad = o.rc is None or o.procs_left or o.shm_segments_left or o.temp_left or tb
            failed += bool(bad)
            note = ("" if o.triggered else "  (ended before the stage)") + ("  traceback" if tb else "") + (
                "  FAILED" if bad else "")
            print(f"{group_name:10} {name:40} {rc:>5} {o.exit_s:7.2f} {o.procs_left:5d} {o.shm_segments_left:7d} "
                  f"{o.shm_bytes_left:10d} {len(o.temp_left)}{note}", flush=True)
    if failed:
        print(f"fault_sweep.py: {failed} of {ran} scenarios hung, printed a traceback or left something behind",
              file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
