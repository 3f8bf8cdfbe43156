"""Faults from outside: signals at each start-up stage of `toffe-deploy run` and `export`, SIGKILL
of the host and of its whole process group, a killed shared-memory manager.

Real CLI subprocesses (each in its own session) on a 32x24 bundle; benchmarks/fault_sweep.py
holds the observation helpers and runs the full matrix. Each case asserts the exit status, that
no process of the run's session is left and none of its /dev/shm segments 10 s after, and that
no temporary file or directory is left.
"""
import importlib.util
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from toffe_deploy.runtime import lava_host
from toffe_deploy.signals import Terminated, exceptions_on_signals

ROOT = Path(__file__).resolve().parents[1]


def _load_sweep():
    spec = importlib.util.spec_from_file_location("fault_sweep", ROOT / "benchmarks" / "fault_sweep.py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod          # its dataclasses look their module up
    spec.loader.exec_module(mod)
    return mod


fs = _load_sweep()


@pytest.fixture(scope="module")
def env(tmp_path_factory):
    pytest.importorskip("lava.magma.core.run_configs")
    root = tmp_path_factory.mktemp("faults")
    e = fs.make_env(root)
    e["out"] = root / "out"
    e["out"].mkdir()
    return e


def run_lava(e):
    return fs.cli(str(ROOT), "run", e["bundle"], "--target", "loihi-sim", "--synthetic", "multi:0,duration=5",
                  "--no-progress", "--out", e["out"] / "lava.jsonl")


def assert_clean(o, rc, message=None):
    assert o.triggered, o.stderr
    assert o.rc == rc, o.stderr
    if message is not None:
        lines = o.stderr.strip().splitlines()
        assert len(lines) == 1 and message in lines[0], o.stderr
    assert o.procs_left == 0, o
    assert o.shm_segments_left == 0 and o.shm_bytes_left == 0, o
    assert o.temp_left == [], o


# ------------------------------------------------------------------------- units: no subprocess
def test_sigterm_and_sigint_raise_once_then_are_ignored():
    before = signal.getsignal(signal.SIGTERM)
    with exceptions_on_signals():
        with pytest.raises(Terminated) as info:
            os.kill(os.getpid(), signal.SIGTERM)
            time.sleep(1)
        assert info.value.exit_code == 143 and "SIGTERM" in str(info.value)
        os.kill(os.getpid(), signal.SIGINT)         # a repeated signal while unwinding: ignored
        time.sleep(0.05)
    with exceptions_on_signals():
        with pytest.raises(KeyboardInterrupt):
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(1)
    assert signal.getsignal(signal.SIGTERM) == before


def test_the_program_ignores_signals_after_a_signal_ended_its_command():
    """cli.entry (the toffe-deploy program) leaves the signals ignored after a signal ended the
    command: a second Ctrl-C during the interpreter's exit raised in an atexit hook (a
    traceback) or killed the process by SIGINT instead of exit 130. Without a signal, and for
    in-process callers (main), the handlers are restored."""
    before = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)}
    try:
        with exceptions_on_signals(ignore_after_signal=True):
            pass
        assert {sig: signal.getsignal(sig) for sig in before} == before
        with exceptions_on_signals(ignore_after_signal=True):
            with pytest.raises(KeyboardInterrupt):
                os.kill(os.getpid(), signal.SIGINT)
                time.sleep(1)
        assert all(signal.getsignal(sig) is signal.SIG_IGN for sig in before if before[sig] is not signal.SIG_IGN)
        os.kill(os.getpid(), signal.SIGINT)                  # ignored: no KeyboardInterrupt
        time.sleep(0.05)
    finally:
        for sig, prev in before.items():
            signal.signal(sig, prev)
    from toffe_deploy import cli
    assert 'toffe-deploy = "toffe_deploy.cli:entry"' in (ROOT / "pyproject.toml").read_text() and callable(cli.entry)


def test_a_signal_inside_signals_deferred_is_raised_when_the_block_ends():
    """A live run's window bookkeeping runs in signals_deferred: a Ctrl-C there lets the block
    finish (the line and the summary's count both happen) and is raised at its end; a second
    signal is ignored as before. (A Ctrl-C between the count and the line once left a summary of
    6 windows over 5 lines.)"""
    from toffe_deploy.signals import signals_deferred

    done = []
    with exceptions_on_signals():
        with pytest.raises(KeyboardInterrupt):
            with signals_deferred():
                os.kill(os.getpid(), signal.SIGINT)
                time.sleep(0.05)
                done.append("line")
                os.kill(os.getpid(), signal.SIGTERM)       # while unwinding: ignored
                time.sleep(0.05)
                done.append("count")
    assert done == ["line", "count"]
    with exceptions_on_signals():                            # no signal: nothing raised
        with signals_deferred():
            done.append("again")
    assert done[-1] == "again"


def test_a_ctrl_c_wrapped_by_compiled_code_still_ends_a_live_run_with_its_summary():
    """A signal that lands while numba's dispatcher calls back into Python arrives as a chain of
    SystemErrors with the KeyboardInterrupt at its end: a live run treats it as the Ctrl-C (it
    once escaped, and the run printed no summary), a file run and other errors unwind."""
    from toffe_deploy.commands.run import live_interrupt
    from toffe_deploy.signals import signal_behind

    def wrapped(sig, depth):
        exc = sig
        for _ in range(depth):
            try:
                raise SystemError("returned a result with an exception set") from exc
            except SystemError as outer:
                exc = outer
        return exc

    ki = KeyboardInterrupt()
    assert signal_behind(wrapped(ki, 3)) is ki and signal_behind(ki) is ki
    term = Terminated(signal.SIGTERM)
    assert signal_behind(wrapped(term, 1)) is term
    assert signal_behind(SystemError("no cause")) is None and signal_behind(ValueError()) is None
    for exc, live, swallowed in [(wrapped(ki, 2), True, True), (ki, True, True), (wrapped(ki, 2), False, False),
                                 (wrapped(term, 1), True, False), (SystemError("x"), True, False)]:
        stop = live_interrupt(live)
        assert stop.__exit__(type(exc), exc, None) is swallowed and stop.interrupted is swallowed


def test_a_ctrl_c_that_a_c_extension_import_turned_into_an_import_error_exits_130(capsys):
    """A Ctrl-C in the first second of `run` can land while onnxruntime's or numba's C extension
    initialises: it came out as "ImportError: initialization failed" (its cause the
    KeyboardInterrupt) or, after numba's C code had printed the KeyboardInterrupt's traceback
    itself (PyErr_Print), as "numba._devicearray failed to import" with no link to it: a
    traceback, exit 1. Both are the Ctrl-C now: one line, exit 130."""
    from toffe_deploy import cli
    from toffe_deploy.signals import signal_behind

    def swallowed_by_an_import():
        try:
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(1)
        except KeyboardInterrupt as exc:
            sys.excepthook(type(exc), exc, exc.__traceback__)      # what PyErr_Print does
        raise ImportError("numba._devicearray failed to import")

    with exceptions_on_signals():
        with pytest.raises(ImportError) as info:
            swallowed_by_an_import()
        assert isinstance(signal_behind(info.value), KeyboardInterrupt)
        assert cli.exit_status(info.value) == 130
    assert signal_behind(info.value) is None             # outside the block: an ImportError is an ImportError
    err = capsys.readouterr().err
    assert err == "toffe-deploy: interrupted\n", err     # no traceback printed by the hook
    with exceptions_on_signals():                          # no signal: an error stays an error
        with pytest.raises(ImportError):
            cli.exit_status(ImportError("no module named x"))


def test_reclaim_removes_only_our_segments_of_dead_hosts(tmp_path):
    dead = subprocess.Popen(["true"])
    dead.wait()
    me = os.getpid()
    ticks = lava_host.start_ticks(me)
    names = {
        f"toffe_lava_{dead.pid}_{ticks}_1_aa": True,          # host gone
        f"toffe_lava_{me}_{ticks + 1}_1_bb": True,           # pid reused by another process
        f"toffe_lava_{me}_{ticks}_1_cc": False,              # host alive
        "psm_0123abcd": False,                               # not ours to judge
        "toffe_lava_x_y": False,                             # not one of our names
    }
    for n in names:
        (tmp_path / n).write_bytes(b"\0" * 100)
    got = lava_host.reclaim(str(tmp_path))
    assert got.segments == 2 and got.bytes == 200
    assert {p.name for p in tmp_path.iterdir()} == {n for n, gone in names.items() if not gone}


def test_named_segments_carry_the_host(tmp_path):
    assert lava_host.host_prefix().startswith(f"toffe_lava_{os.getpid()}_{lava_host.start_ticks(os.getpid())}_")
    a, b = lava_host.next_runtime_prefix(), lava_host.next_runtime_prefix()
    assert a != b and a.startswith(lava_host.host_prefix())


# ------------------------------------------------------------------------- run --target loihi-sim
@pytest.mark.parametrize("action, n, rc, message", [
    ("SIGTERM host", 0, 143, "terminated by SIGTERM"),     # handlers installed, Lava not started
    ("SIGTERM host", 2, 143, "terminated by SIGTERM"),     # resource tracker + shm manager forked
    ("Ctrl-C group", 2, 130, "interrupted"),               # a terminal's Ctrl-C reaches every process
    ("SIGTERM host", 6, 143, "terminated by SIGTERM"),     # half the process models forked
])
def test_signal_during_lava_start_up_stops_everything(env, action, n, rc, message):
    argv, cenv = run_lava(env)
    o = fs.run_scenario(f"{action} @ {n}", argv, fs.catching() if n == 0 else fs.n_children(n), fs.ACTIONS[action],
                        [str(env["out"] / ".lava.jsonl.*")], env=cenv)
    assert_clean(o, rc, message)
    assert o.exit_s < 20


def assert_finished_windows(path, at_least):
    """--out streams: the windows finished before the fault, as whole JSON lines, in order."""
    rows = fs.whole_lines(path)
    assert len(rows) >= at_least, rows
    assert [r["t0_us"] for r in rows] == [rows[0]["t0_us"] + 500 * i for i in range(len(rows))]


def test_sigterm_while_streaming_keeps_the_finished_windows(env):
    argv, cenv = run_lava(env)
    o = fs.run_scenario("SIGTERM streaming", argv, fs.lines_written(env["out"] / "lava.jsonl"),
                        fs.ACTIONS["SIGTERM host"], [str(env["out"] / ".lava.jsonl.*")], env=cenv)
    assert_clean(o, 143, "terminated by SIGTERM")
    assert_finished_windows(env["out"] / "lava.jsonl", 1)


def test_sigkill_of_the_host_takes_its_lava_processes_and_memory(env):
    argv, cenv = run_lava(env)
    o = fs.run_scenario("SIGKILL host", argv, fs.n_children(6), fs.ACTIONS["SIGKILL host"], [], env=cenv)
    assert_clean(o, -signal.SIGKILL)


def test_sigkill_of_the_group_leaves_whole_lines_of_the_finished_windows(env):
    """`timeout -k` kills the whole group, Python's resource tracker included: the host's reaper
    (its own session) unlinks the segments; --out holds every finished window, no partial line."""
    argv, cenv = run_lava(env)
    tmp = str(env["out"] / ".lava.jsonl.*")
    o = fs.run_scenario("SIGKILL group", argv, fs.lines_written(env["out"] / "lava.jsonl", 3),
                        fs.ACTIONS["SIGKILL group"], [tmp], env=cenv)
    assert o.rc == -signal.SIGKILL and o.procs_left == 0 and o.shm_segments_left == 0, o
    assert o.temp_left == [], o           # no temp file: the lines go straight to the target
    assert_finished_windows(env["out"] / "lava.jsonl", 3)


def test_lava_start_reclaims_segments_of_dead_hosts():
    """When even the reaper was killed, the next start removes what a dead host left."""
    pytest.importorskip("lava.magma.core.run_configs")
    import numpy as np

    from toffe_deploy.fixed_point import quantize_ofs
    from toffe_deploy.runtime.loihi import LavaCascade

    dead = subprocess.Popen(["true"])
    dead.wait()
    stale = f"/dev/shm/{lava_host.PREFIX}{dead.pid}_1_1_0123456789ab"
    with open(stale, "wb") as f:
        f.write(b"\0" * 4096)
    params = [quantize_ofs(np.full((1, 2, 3, 3), 0.15), 0.5, 0.3)]
    with LavaCascade(params, n_bins=2, mask_kernel=1, sensor_size=(8, 8)) as lc:
        assert lc.reclaimed.segments >= 1 and lc.reclaimed.bytes >= 4096
        assert not os.path.exists(stale)
        assert lc.shm_names and all(n.startswith(lc.shm_prefix) for n in lc.shm_names)
    assert not [n for n in os.listdir("/dev/shm") if n.startswith(lc.shm_prefix)]


def test_killed_shm_manager_is_a_one_line_error_not_a_hang(env):
    argv, cenv = run_lava(env)
    o = fs.run_scenario("kill manager", argv, fs.lines_written(env["out"] / "lava.jsonl"), fs.kill_manager,
                        [str(env["out"] / ".lava.jsonl.*")], env=cenv, exit_wait_s=30)
    assert_clean(o, 2, "shared-memory manager")
    assert o.exit_s < 20                  # a hang is for ever; this allows a loaded 2-core machine


# ------------------------------------------------------------------------- cpu target, export
def test_sigterm_on_the_cpu_target_keeps_the_finished_windows(env):
    argv, cenv = fs.cli(str(ROOT), "run", env["bundle"], "--target", "cpu", "--synthetic", "multi:0,duration=3",
                        "--no-progress", "--out", env["out"] / "cpu.jsonl")
    tmp = str(env["out"] / ".cpu.jsonl.*")
    o = fs.run_scenario("cpu SIGTERM", argv, fs.lines_written(env["out"] / "cpu.jsonl", 5),
                        fs.ACTIONS["SIGTERM host"], [tmp], env=cenv)
    assert_clean(o, 143, "terminated by SIGTERM")
    assert_finished_windows(env["out"] / "cpu.jsonl", 5)


def test_sigterm_during_the_export_lava_check_leaves_no_hidden_bundle(env):
    argv, cenv = fs.cli(str(ROOT), "export", env["ckpt"], "-o", env["out"] / "bundle", "--checks", "lava_vs_fixed",
                        "--windows", "2", "--lava-windows", "1", "--quiet")
    tmp = str(env["out"] / ".bundle.*")
    o = fs.run_scenario("export SIGTERM", argv, fs.n_children(2), fs.ACTIONS["SIGTERM host"], [tmp], env=cenv)
    assert_clean(o, 143, "terminated by SIGTERM")
    assert not (env["out"] / "bundle").exists()


# ------------------------------------------------------------------------- a live source on loihi-sim
def test_ctrl_c_ends_a_live_loihi_run_with_its_lines_and_summary_and_stops_lava(env):
    """`--events -` (stdin kept open: the stream goes on) on loihi-sim; Ctrl-C to the group as a
    terminal sends it: the finished windows stay, the summary is printed, exit 130, and no process
    or segment of the run is left."""
    from toffe_deploy.events.io import read_events
    from toffe_deploy.events.live import stdin_header

    rec = read_events(env["rec"])
    out = env["out"] / "live.jsonl"
    argv, cenv = fs.cli(str(ROOT), "run", env["bundle"], "--target", "loihi-sim", "--events", "-", "--no-progress",
                        "--out", out)
    t_start = time.time()
    p = subprocess.Popen(argv, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=cenv,
                         cwd=str(ROOT), start_new_session=True, preexec_fn=fs._default_sigint)
    p.stdin.write(stdin_header(rec.sensor_size) + rec.events.tobytes())
    p.stdin.flush()
    trig = fs.lines_written(out, 3)
    deadline = time.monotonic() + 180
    while not trig(p):
        assert p.poll() is None and time.monotonic() < deadline, p.stderr.read()
        time.sleep(0.05)
    os.killpg(p.pid, signal.SIGINT)
    stdout, stderr = (s.decode() for s in p.communicate(timeout=60))
    p.stdin.close()
    assert p.returncode == 130 and stderr.strip().splitlines()[-1] == "toffe-deploy: interrupted", stderr
    assert stderr.strip().splitlines()[:-1] == ["toffe-deploy: reading - (stdin)"]
    assert "live: newest event -> JSON line" in stdout and f"{len(rec)} events in" in stdout
    rows = fs.whole_lines(out)
    assert len(rows) >= 3 and f"target loihi-sim: {len(rows)} windows" in stdout
    settle = time.monotonic() + 10
    while (fs.run_pids(p.pid) or fs._run_shm({}, p.pid, t_start, False)) and time.monotonic() < settle:
        time.sleep(0.1)
    assert fs.run_pids(p.pid) == [] and fs._run_shm({}, p.pid, t_start, False) == {}


# ------------------------------------------------------------------------- the API without `with`
def test_a_signal_swallowed_by_an_at_fork_hook_is_sent_again_in_library_use():
    """Without the CLI's handlers (the Python API) a Ctrl-C raised inside an at-fork hook (here a
    __del__, where Python swallows it too) was lost during a Lava start-up: the script ran on.
    redeliver_swallowed (LavaCascade.start) sends it again."""
    from toffe_deploy.signals import redeliver_swallowed

    class Swallowed:
        def __del__(self):
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        with redeliver_swallowed():
            Swallowed()                               # the exception goes to sys.unraisablehook
            time.sleep(2)


def _api_script(tmp_path, body):
    path = tmp_path / "api_script.py"
    path.write_text("import gc, sys, time\nfrom toffe_deploy.deploy.bundle import load_bundle\n"
                    "from toffe_deploy.runtime.pipeline import Pipeline\n"
                    "b = load_bundle(sys.argv[1])\n" + body)
    return path


def test_an_api_pipeline_never_closed_is_stopped_at_exit_and_when_dropped(env, tmp_path):
    """A script that entered a loihi-sim Pipeline and ended (or dropped it) without closing it
    left Lava's processes running, and the interpreter's exit waited on them forever. Now the
    network is stopped when its object goes and at exit: the script ends at once, nothing left."""
    script = _api_script(tmp_path, "p = Pipeline(b, 'loihi-sim'); p.__enter__()\n"
                                   "if sys.argv[2] == 'drop':\n"
                                   "    del p; gc.collect(); time.sleep(1)\n"
                                   "    import multiprocessing as mp; print(len(mp.active_children()))\n")
    for how in ("exit", "drop"):
        r = subprocess.run([sys.executable, str(script), str(env["bundle"]), how], capture_output=True, text=True,
                           timeout=240, cwd=ROOT, env=dict(os.environ, PYTHONPATH=str(ROOT)))
        assert r.returncode == 0, r.stderr
        if how == "drop":
            assert r.stdout.split() == ["0"], r.stdout           # no Lava child alive after the drop


def test_process_stream_twice_without_with_on_loihi_sim(env):
    """Each process_stream outside a `with` starts and stops its own network; the second one
    waited for a record the fresh network owed later (the period count was not reset): 2 x the
    timeout, then an error."""
    import numpy as np

    from toffe_deploy.deploy.bundle import load_bundle
    from toffe_deploy.events.io import read_events
    from toffe_deploy.runtime.pipeline import Pipeline
    from toffe_deploy.runtime.spikes import SpikeVolume

    b = load_bundle(env["bundle"])
    cfg = b.config
    ev = read_events(env["rec"]).events
    wins = [(t0, SpikeVolume.from_events(ev, t0, cfg.dt_us, cfg.n_bins, cfg.sensor_size)) for t0 in (0, 500, 1000)]
    lava = Pipeline(b, "loihi-sim", track=False)
    lava.cascade.timeout_s = 30
    t = time.monotonic()
    first = [r.to_json() for r in lava.process_stream(wins)]
    second = [r.to_json() for r in lava.process_stream(wins)]
    assert first == second and len(first) == 3 and time.monotonic() - t < 60
    with Pipeline(b, "cpu", track=False) as cpu:
        assert [r.to_json() for r in cpu.process_stream(wins)] == first
    np.testing.assert_equal(lava.cascade._runtime, None)


_KILLED_WRITER = r"""
import os, signal, sys
from pathlib import Path
import toffe_deploy.fileio as fileio
path, where = Path(sys.argv[1]), sys.argv[2]
if where == "between":                      # killed between atomic_dir's two renames
    real = os.replace
    def replace(a, b, calls=[]):
        calls.append(a)
        if len(calls) == 2:
            os.kill(os.getpid(), signal.SIGKILL)
        return real(a, b)
    fileio.os.replace = replace
if where == "file":
    with fileio.atomic_path(path) as tmp:
        tmp.write_bytes(b"half")
        os.kill(os.getpid(), signal.SIGKILL)
with fileio.atomic_dir(path) as tmp:
    (tmp / "a").write_text("new")
    if where == "inside":
        os.kill(os.getpid(), signal.SIGKILL)
"""


@pytest.mark.parametrize("where", ["inside", "between", "file"])
def test_the_next_write_clears_what_a_killed_writer_left(tmp_path, where):
    """SIGKILL gives no chance to clean up: a writer killed inside atomic_dir / atomic_path left its
    temporary directory or file beside the target for good (a killed `dataset synth` or `export`:
    megabytes), and one killed between atomic_dir's two renames left the target missing, its old
    content under a hidden name. The temporary names now carry the writer's pid, and the next
    write of the same path removes a dead writer's leftovers and puts a moved-aside directory
    back; a live writer's are left alone."""
    from toffe_deploy import fileio

    target = tmp_path / ("out.bin" if where == "file" else "out")
    if where != "file":
        target.mkdir()
        (target / "a").write_text("old")
    live = tmp_path / f".{target.name}.{os.getpid()}-abcdefgh.tmp"      # this process: alive
    live.write_text("x")
    users = tmp_path / f".{target.name}.old-2"                           # a backup made by hand: not ours
    users.mkdir()
    stale = tmp_path / f".{target.name}.{os.getpid()}-zzzzzzzz.tmp"     # this pid, before this process: a
    stale.write_text("x")                                                # container's fixed pid, reused
    os.utime(stale, (1e9, 1e9))
    proc = subprocess.run([sys.executable, "-c", _KILLED_WRITER, str(target), where], capture_output=True)
    assert proc.returncode == -signal.SIGKILL, proc.stderr.decode()
    left = sorted(p.name for p in tmp_path.iterdir() if p not in (live, users, stale))
    dead = f".{target.name}."
    if where == "between":                  # the target moved aside, not back, and the new one beside it
        assert len(left) == 2 and sorted(n.rsplit(".", 1)[1] for n in left) == ["old", "tmp"]
        assert not target.exists()
    elif where == "inside":
        assert len(left) == 2 and left[0].startswith(dead) and left[0].endswith(".tmp") and left[1] == target.name
    else:
        assert len(left) == 1 and left[0].startswith(dead) and left[0].endswith(".tmp") and not target.exists()
    if where == "between":                  # a write that fails still finds the old directory put back
        with pytest.raises(RuntimeError):
            with fileio.atomic_dir(target):
                raise RuntimeError
        assert (target / "a").read_text() == "old"
    if where == "file":
        with fileio.atomic_path(target) as tmp:
            tmp.write_bytes(b"whole")
        assert target.read_bytes() == b"whole"
    else:
        with fileio.atomic_dir(target) as tmp:
            (tmp / "a").write_text("newer")
        assert (target / "a").read_text() == "newer"
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([target.name, live.name, users.name])

