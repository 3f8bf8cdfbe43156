"""Two host processes (runtime/split.py; `run --processes 2`): the same lines as one process,
bit for bit, on a real tiny bundle with the shipped checkpoint's host features and a generated
recording; a worker that dies, a stream left early, bad requests; no process left behind."""
from __future__ import annotations

import json
import os
import signal
from pathlib import Path

import numpy as np
import pytest

from toffe_deploy.cli import main
from toffe_deploy.errors import ToffeError
from toffe_deploy.events.io import read_events
from toffe_deploy.runtime import split
from toffe_deploy.runtime.pipeline import Pipeline
from toffe_deploy.runtime.spikes import SpikeVolume

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def shipped_tiny(tmp_path_factory, make_bundle, make_recording):
    """(bundle, windows): the shipped ckpt/'s settings (faint objects, plane fit over the windows
    before, outline positions, temporal support, pooled OFS) on a 64x48 sensor, and the binned
    windows of a generated multi-object recording."""
    tmp = tmp_path_factory.mktemp("split")
    shipped = json.loads((ROOT / "ckpt" / "config.json").read_text())
    ofpd = dict(shipped["ofpd"], crop_px=32, pool=2, min_events=4)
    extra = {k: shipped[k] for k in ("input_norm", "input_min_cluster", "input_support")}
    bundle = make_bundle(tmp, ofs_pool=2, ofpd=ofpd, reset=shipped["reset"], **extra)
    rec = make_recording(tmp / "rec.h5", duration=0.03)
    ev = read_events(rec).events
    cfg = bundle.config
    windows = [(t0, SpikeVolume.from_events(ev, t0, cfg.dt_us, cfg.n_bins, (64, 48)))
               for t0 in range(0, 30_000, cfg.dt_us)]
    return bundle, rec, windows


def _lines(results) -> list[str]:
    return [json.dumps(r.to_json(), sort_keys=True) for r in results]


def test_two_processes_give_the_lines_of_one_bit_for_bit(shipped_tiny):
    bundle, _, windows = shipped_tiny
    with Pipeline(bundle, "cpu") as one:
        want = _lines(one.process_stream(windows))
    assert sum(len(json.loads(line)["objects"]) for line in want) > 10     # objects and tracks to compare
    with Pipeline(bundle, "cpu", processes=2) as two:
        assert _lines(two.process_stream(windows)) == want
        two.reset_tracks()                           # the worker's front-end history too: the same again
        assert _lines(two.process_stream(windows)) == want
        worker = two._split.proc
    assert worker.poll() is not None                 # stopped with the Pipeline


def test_windows_too_large_for_a_slot_go_through_the_socket(shipped_tiny, monkeypatch):
    bundle, _, windows = shipped_tiny
    with Pipeline(bundle, "cpu") as one:
        want = _lines(one.process_stream(windows))
    monkeypatch.setattr(split, "SLOT_BYTES", 256)    # every window's arrays overflow it
    with Pipeline(bundle, "cpu", processes=2) as two:
        assert two._split.slots.slot_bytes == 256
        assert _lines(two.process_stream(windows)) == want
    with Pipeline(bundle, "cpu") as one:               # a window larger than the socket's buffer both
        dense = [(t0, np.ones((bundle.config.n_bins, 2, 48, 64), np.uint8)) for t0 in range(0, 3000, 500)]
        want = _lines(one.process_stream(dense))       # ways (~250 KB of ones, a MB of answer): no deadlock
    with Pipeline(bundle, "cpu", processes=2) as two:
        assert _lines(two.process_stream(dense)) == want


def test_a_stream_left_early_keeps_both_halves_in_step(shipped_tiny):
    """The windows read ahead are finished when the consumer stops (their results dropped): a
    later stream goes on with both processes' state as one process that ran them has it."""
    bundle, _, windows = shipped_tiny
    with Pipeline(bundle, "cpu") as one:
        head = _lines(one.process_stream(windows[:7]))[:6]     # 6: read ahead below
        tail = _lines(one.process_stream(windows[8:]))
    with Pipeline(bundle, "cpu", processes=2) as two:
        given = iter(windows[:8])
        stream = two.process_stream(given)
        got = [json.dumps(next(stream).to_json(), sort_keys=True) for _ in range(6)]
        stream.close()                                # 6 was read: finished, dropped
        assert got == head and [t0 for t0, _ in given] == [windows[7][0]]     # 7 was not read
        assert _lines(two.process_stream(windows[8:])) == tail


def test_a_worker_that_dies_is_a_one_line_error_and_nothing_is_left(shipped_tiny):
    bundle, _, windows = shipped_tiny
    with pytest.raises(ToffeError, match=r"the second host process \(--processes 2\) failed: it stopped"):
        with Pipeline(bundle, "cpu", processes=2) as two:
            worker = two._split.proc
            stream = two.process_stream(windows)
            next(stream)
            os.kill(worker.pid, signal.SIGKILL)
            list(stream)
    assert worker.poll() == -signal.SIGKILL


def test_bad_requests_are_refused_before_any_process_starts(shipped_tiny, capsys, tmp_path):
    bundle, rec, _ = shipped_tiny
    for bad in (0, 3, True):
        with pytest.raises(ValueError, match="processes must be 1 or 2"):
            Pipeline(bundle, "cpu", processes=bad)
    with pytest.raises(ValueError, match="cpu and cuda targets"):
        Pipeline(bundle, "loihi-sim", processes=2)
    with pytest.raises(ValueError, match="keep_stages"):
        Pipeline(bundle, "cpu", processes=2, keep_stages=True)
    assert main(["run", str(bundle.root), "--events", str(rec), "--processes", "2", "--target", "loihi-sim",
                 "--no-progress"]) == 2
    assert "--processes 2 splits the host steps of --target cpu and cuda" in capsys.readouterr().err


def test_run_with_two_processes_writes_the_same_file(shipped_tiny, tmp_path, capsys):
    bundle, rec, _ = shipped_tiny
    outs = []
    for n in (1, 2):
        out = tmp_path / f"p{n}.jsonl"
        assert main(["run", str(bundle.root), "--events", str(rec), "--processes", str(n), "--no-progress",
                     "--out", str(out)]) == 0
        outs.append(out.read_text().splitlines())
    capsys.readouterr()
    assert len(outs[0]) > 50 and outs[0] == outs[1]
    assert np.all([json.loads(line).get("type") != "error" for line in outs[1]])


def test_bench_processes_reports_identical_lines_and_both_rates(shipped_tiny, tmp_path, capsys):
    import importlib.util
    import sys

    bench = ROOT / "benchmarks"
    sys.path.insert(0, str(bench))
    spec = importlib.util.spec_from_file_location("bench_processes_t", bench / "bench_processes.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    bundle, rec, _ = shipped_tiny
    out = tmp_path / "bp.json"
    assert mod.main(["--bundle", str(bundle.root), "--events", str(rec), "--seconds", "0.06", "--rounds", "1",
                     "--out", str(out)]) == 0
    res = json.loads(out.read_text())
    (r,) = res["rounds"]
    assert res["identical_lines"] and r["identical_lines"] and r["one"]["windows"] == r["two"]["windows"] == 120
    assert r["one"]["windows_per_s"] > 0 and r["two"]["windows_per_s"] > 0 and r["two"]["cpu_s"] > 0
    assert json.loads(capsys.readouterr().out) == res


def test_an_input_error_comes_after_the_windows_read_before_it(shipped_tiny):
    """A bad window (or a failing source) mid-stream: every window before it is yielded first,
    as with one process (two lines had been lost with the windows in flight)."""
    bundle, _, windows = shipped_tiny

    def with_bad(n):
        yield from windows[:n]
        yield windows[n][0], np.zeros((2, 2))           # not a (B, 2, H, W) window

    got = {}
    for procs in (1, 2):
        with Pipeline(bundle, "cpu", processes=procs) as pipe:
            out = []
            with pytest.raises(ValueError, match="window must be"):
                for r in pipe.process_stream(with_bad(9)):
                    out.append(json.dumps(r.to_json(), sort_keys=True))
            got[procs] = out
    assert len(got[1]) == 9 and got[2] == got[1]


def test_reset_or_a_second_stream_inside_a_running_stream_is_refused(shipped_tiny):
    bundle, _, windows = shipped_tiny
    with Pipeline(bundle, "cpu", processes=2) as two:
        stream = two.process_stream(windows)
        next(stream)
        with pytest.raises(ToffeError, match="between streams"):
            two.reset_tracks()
        with pytest.raises(ToffeError, match="one process_stream at a time"):
            next(two.process_stream(windows))
        stream.close()
        two.reset_tracks()                                 # between streams: fine
        assert len(_lines(two.process_stream(windows[:3]))) == 3


def test_the_ofpd_variant_runs_in_the_second_process_too(shipped_tiny, tmp_path):
    pytest.importorskip("onnx")
    import dataclasses

    from toffe_deploy.deploy.onnx_export import make_variant

    bundle, _, windows = shipped_tiny
    fp16 = make_variant("fp16", bundle.ofpd_onnx, tmp_path / "ofpd_fp16.onnx")
    bundle16 = dataclasses.replace(bundle, ofpd_variants={"fp16": fp16})
    lines = {}
    for procs in (1, 2):
        with Pipeline(bundle16, "cpu", processes=procs, ofpd_variant="fp16", track=False) as pipe:
            lines[procs] = _lines(pipe.process_stream(windows))
    with Pipeline(bundle, "cpu", track=False) as pipe:
        fp32 = _lines(pipe.process_stream(windows))
    assert lines[2] == lines[1] != fp32


def test_the_worker_is_out_of_the_terminals_reach(shipped_tiny):
    """A terminal's Ctrl-C goes to its foreground process group; the worker, in that group, got
    it too, and during its imports (before it ignores SIGINT) printed their traceback under `run`'s
    one line. It runs in a session of its own: the Ctrl-C is this process's, which stops it."""
    bundle, _, _ = shipped_tiny
    with Pipeline(bundle, "cpu", processes=2) as two:
        worker = two._split.proc.pid
        assert os.getsid(worker) == worker != os.getsid(0) and os.getpgid(worker) != os.getpgid(0)


_LEFT_OPEN = r"""
import sys
from toffe_deploy.runtime.pipeline import Pipeline
from toffe_deploy.runtime.spikes import SpikeVolume
from toffe_deploy.events.io import read_events
from toffe_deploy.deploy.bundle import load_bundle
b = load_bundle(sys.argv[1])
ev = read_events(sys.argv[2]).events
cfg = b.config
p = Pipeline(b, "cpu", processes=2)
g = p.process_stream((t0, SpikeVolume.from_events(ev, t0, cfg.dt_us, cfg.n_bins, (64, 48))) for t0 in range(0, 10_000, 500))
print(next(g).t0_us)
"""


def test_a_stream_left_open_at_exit_ends_quietly(shipped_tiny):
    """A script that takes one window of a processes=2 stream and exits: the generator is closed
    while the interpreter shuts down, and finishing the windows in the worker then failed on an
    import ("Exception ignored in ... sys.meta_path is None"). Nothing to keep there: it stops."""
    import subprocess
    import sys

    bundle, rec, _ = shipped_tiny
    p = subprocess.run([sys.executable, "-c", _LEFT_OPEN, str(bundle.root), str(rec)], capture_output=True,
                       text=True, timeout=300, cwd=ROOT)
    assert p.returncode == 0 and p.stdout.split() == ["0"] and p.stderr == "", p.stderr
