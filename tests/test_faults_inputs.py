"""Fault injection: inputs that used to give wrong results with exit 0, destroy a file, bypass the
bundle check, crash on a full disk, hang, or end in a traceback.

Every case asserts the guarantee README.md ("Guarantees") states: exit code 2, one line on
stderr without a traceback, and every input file and bundle file byte-identical afterwards.
Real files in tmp dirs, a real small bundle (64x48), real onnxruntime; the full and read-only
disks are real tmpfs mounts (skipped where this process cannot mount).
"""
import contextlib
import hashlib
import json
import os
import shutil
import subprocess
import sys
import time

import h5py
import numpy as np
import pytest

from toffe_deploy.cli import main
from toffe_deploy.events.fmt_toffe import ms_index
from toffe_deploy.events.io import read_events, write_events_npz

SENSOR = (64, 48)


@pytest.fixture(scope="module")
def env(tmp_path_factory, make_bundle, make_recording):
    root = tmp_path_factory.mktemp("faults")
    bundle = make_bundle(root)
    rec = make_recording(root / "rec.h5", duration=0.006)
    return {"root": root, "bundle": bundle.root, "ckpt": root / "ckpt", "rec": rec}


def cli(capsys, *argv):
    rc = main([str(a) for a in argv])
    cap = capsys.readouterr()
    return rc, cap.out, cap.err


def one_line_error(rc, err, *needles):
    """Exit 2, exactly one stderr line 'toffe-deploy: error: ...' holding every needle."""
    assert rc == 2, err
    assert err.startswith("toffe-deploy: error: ") and err.count("\n") == 1 and "Traceback" not in err, err
    for n in needles:
        assert n in err, err
    return err


def digest(*paths):
    """sha256 of every file under the given files / directories (what must stay unchanged)."""
    out = {}
    for p in paths:
        files = sorted(f for f in p.rglob("*") if f.is_file()) if p.is_dir() else [p]
        for f in files:
            out[str(f)] = hashlib.sha256(f.read_bytes()).hexdigest()
    return out


@contextlib.contextmanager
def unchanged(*paths):
    before = digest(*paths)
    yield
    assert digest(*paths) == before


def copy_bundle(env, tmp_path):
    b = tmp_path / "b"
    shutil.copytree(env["bundle"], b)
    return b


def edit_manifest(b, fn):
    m = json.loads((b / "manifest.json").read_text())
    fn(m)
    (b / "manifest.json").write_text(json.dumps(m))


def rehash(b, rel):
    """Make manifest.json agree with an edited bundle file (so the file's own checks are reached)."""
    def fn(m):
        m["files"][rel] = {"sha256": hashlib.sha256((b / rel).read_bytes()).hexdigest(),
                           "bytes": (b / rel).stat().st_size}
    edit_manifest(b, fn)


def run_args(env, *extra, bundle=None, events=None):
    return ["run", bundle or env["bundle"], "--events", events or env["rec"], "--no-progress", *extra]


# ------------------------------------------------------------------ 1. a seek index that lies

def _dsec_copy(env, path):
    ev = read_events(env["rec"]).events
    with h5py.File(path, "w") as f:
        for n in ("x", "y", "t", "p"):
            f[f"events/{n}"] = ev[n]
        f["ms_to_idx"] = ms_index(ev["t"], 0)
        f["t_offset"] = np.int64(0)
    return path


def test_reversed_ms_to_idx_is_refused_not_miscounted(env, capsys, tmp_path):
    n = len(read_events(env["rec"]))
    good = tmp_path / "good.h5"
    shutil.copy(env["rec"], good)
    rc, out, _ = cli(capsys, "events", "info", good, "--json", "--no-progress")
    assert rc == 0 and json.loads(out)["events"] == n                 # control: the intact index
    for path, key in ((tmp_path / "rev.h5", "events/ms_to_idx"), (tmp_path / "dsec.h5", "ms_to_idx")):
        if key == "ms_to_idx":
            _dsec_copy(env, path)
        else:
            shutil.copy(env["rec"], path)
        with h5py.File(path, "r+") as f:
            f[key][...] = f[key][()][::-1]
        with unchanged(path, env["bundle"]):
            one_line_error(*cli(capsys, "events", "info", path, "--no-progress")[::2], "seek index")
            one_line_error(*cli(capsys, *run_args(env, events=path))[::2], "ms_to_idx")


def test_ms_to_idx_off_by_some_events_is_refused(env, capsys, tmp_path):
    """Entries shifted past the answer (still monotone, in range): only the check against t catches them."""
    path = tmp_path / "shift.h5"
    shutil.copy(env["rec"], path)
    with h5py.File(path, "r+") as f:
        idx = f["events/ms_to_idx"]
        idx[...] = np.minimum(idx[()] + 100, f["events/t"].shape[0])
    with unchanged(path):
        rc, _, err = cli(capsys, *run_args(env, "--start-us", 2000, events=path))   # a seek through the index
        one_line_error(rc, err, "disagrees with the timestamps")


# ------------------------------------------------------------------ 2. outputs that would destroy inputs

@pytest.mark.parametrize("case", ["out=events", "summary=events", "out=bundle-onnx", "out=manifest",
                                  "out=summary", "render=bundle", "out=bundle-dir", "out=hardlink", "out=dir"])
def test_run_never_overwrites_its_inputs(env, capsys, tmp_path, case):
    ev = tmp_path / "rec.npz"
    write_events_npz(ev, read_events(env["rec"]).events, SENSOR)
    b = copy_bundle(env, tmp_path)
    os.link(ev, tmp_path / "link.npz")
    (tmp_path / "d").mkdir()
    extra = {"out=events": ["--out", ev], "summary=events": ["--summary-json", ev],
             "out=bundle-onnx": ["--out", b / "ofpd.onnx"], "out=manifest": ["--out", b / "manifest.json"],
             "out=summary": ["--out", tmp_path / "o.json", "--summary-json", tmp_path / "o.json"],
             "render=bundle": ["--render", b], "out=bundle-dir": ["--out", b],
             "out=hardlink": ["--out", tmp_path / "link.npz"], "out=dir": ["--out", tmp_path / "d"]}[case]
    with unchanged(ev, b):
        rc, out, err = cli(capsys, *run_args(env, *extra, bundle=b, events=ev))
        one_line_error(rc, err)
    assert out == "" and not (tmp_path / "o.json").exists()


@pytest.mark.parametrize("option", ["--out", "--report", "--summary-json", "--dump-spikes"])
def test_run_without_events_never_overwrites_the_shipped_sample(env, capsys, option):
    """No --events reads the shipped sample: it is an input like a given file (an HTML report
    was written over it, and --out wiped it)."""
    from toffe_deploy.commands.run import SAMPLE

    with unchanged(SAMPLE):
        rc, out, err = cli(capsys, "run", env["bundle"], "--no-progress", "--max-windows", 1, option, SAMPLE)
        one_line_error(rc, err, "would overwrite the input events")
    assert out == ""


def test_a_run_failing_in_its_first_window_leaves_an_existing_out_file(env, capsys, tmp_path):
    """--out replaces a file with its first line, not when the run starts: events outside the
    sensor found in the first window leave yesterday's results as they were, and no temp file."""
    ev = read_events(env["rec"]).events.copy()
    ev["x"][:50] = SENSOR[0] + 3
    bad = tmp_path / "bad.npz"
    write_events_npz(bad, ev, (SENSOR[0] + 8, SENSOR[1]))
    out = tmp_path / "o.jsonl"
    out.write_text("precious\n")
    rc, _, err = cli(capsys, *run_args(env, "--out", out, "--sensor-size", f"{SENSOR[0]}x{SENSOR[1]}", events=bad))
    one_line_error(rc, err, "outside the")
    assert out.read_text() == "precious\n" and sorted(p.name for p in tmp_path.iterdir()) == ["bad.npz", "o.jsonl"]
    assert cli(capsys, *run_args(env, "--out", out, "--max-windows", 2))[0] == 0      # a good run replaces it
    lines = out.read_text().splitlines()
    assert len(lines) == 3 and json.loads(lines[0])["type"] == "header"
    assert oct(out.stat().st_mode & 0o777) == oct(0o644 & ~_umask())


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def test_other_commands_never_overwrite_their_inputs(env, capsys, tmp_path):
    ev = tmp_path / "rec.npz"
    write_events_npz(ev, read_events(env["rec"]).events, SENSOR)
    ck = tmp_path / "ck"
    shutil.copytree(env["ckpt"], ck)
    h5 = tmp_path / "rec.h5"
    shutil.copy(env["rec"], h5)
    with unchanged(ev, ck, h5):
        one_line_error(*cli(capsys, "events", "convert", ev, ev, "--force")[::2], "input file")
        one_line_error(*cli(capsys, "export", ck, "-o", ck, "--force", "--checks", "none", "--quiet")[::2],
                       "overlaps the checkpoint")
        one_line_error(*cli(capsys, "export", ck, "-o", tmp_path, "--force", "--checks", "none", "--quiet")[::2],
                       "overlaps the checkpoint")
        one_line_error(*cli(capsys, "eval", ck, "--data", tmp_path, "--json", ck / "config.json")[::2],
                       "checkpoint file")
        one_line_error(*cli(capsys, "dataset", "show", h5, "--out", h5)[::2], "input file")
        one_line_error(*cli(capsys, "dataset", "synth", "--out", h5, "--split", "test", "--limit", "1")[::2],
                       "not a directory")


# ------------------------------------------------------------------ 3. bundle paths and unverified files

def test_variant_not_in_files_is_refused_even_untampered(env, capsys, tmp_path):
    b = copy_bundle(env, tmp_path)
    shutil.copy(b / "ofpd.onnx", b / "ofpd_fp16.onnx")
    with open(b / "ofpd_fp16.onnx", "ab") as f:
        f.write(b"tampered")
    edit_manifest(b, lambda m: m["ofpd"].update(variants={"fp16": {"file": "ofpd_fp16.onnx"}}))
    with unchanged(b):
        one_line_error(*cli(capsys, *run_args(env, "--ofpd", "fp16", bundle=b))[::2], "not listed in 'files'")
        one_line_error(*cli(capsys, *run_args(env, bundle=b))[::2], "not listed in 'files'")


@pytest.mark.parametrize("where", ["variant-dotdot", "variant-abs", "files-dotdot", "files-abs", "files-symlink"])
def test_paths_leaving_the_bundle_are_refused_without_leaking(env, capsys, tmp_path, where):
    b = copy_bundle(env, tmp_path)
    secret = tmp_path / "secret.onnx"
    secret.write_bytes(b"not yours " * 100)
    leak = hashlib.sha256(secret.read_bytes()).hexdigest()[:12]
    rel = {"variant-dotdot": "../secret.onnx", "variant-abs": str(secret), "files-dotdot": "../secret.onnx",
           "files-abs": str(secret), "files-symlink": "link.onnx"}[where]
    if where == "files-symlink":
        (b / "link.onnx").symlink_to(secret)
    if where.startswith("variant"):
        edit_manifest(b, lambda m: m["ofpd"].update(variants={"fp16": {"file": rel}}))
    else:
        edit_manifest(b, lambda m: m["files"].update({rel: {"sha256": "0" * 64, "bytes": 1}}))
    with unchanged(b, secret):
        err = one_line_error(*cli(capsys, *run_args(env, "--ofpd", "fp16", bundle=b))[::2], "outside the bundle")
    assert leak not in err


@pytest.mark.parametrize("section", [{"ofpd": "x"}, {"ofpd": {"variants": [1, 2]}},
                                     {"ofpd": {"variants": {"fp16": {"nofile": 1}}}}])
def test_malformed_manifest_sections_are_one_line_errors(env, capsys, tmp_path, section):
    b = copy_bundle(env, tmp_path)
    edit_manifest(b, lambda m: m.update(section))
    with unchanged(b):
        one_line_error(*cli(capsys, *run_args(env, bundle=b))[::2], "manifest.json")


@pytest.mark.parametrize("edit", ["camera", "config"])
def test_a_manifest_that_contradicts_config_json_is_refused(env, capsys, tmp_path, edit):
    """The manifest is the one file no hash covers, and the README sends users to its camera:
    a focal length of -3 there (or a changed config copy) ran silently with config.json's."""
    b = copy_bundle(env, tmp_path)
    if edit == "camera":
        edit_manifest(b, lambda m: m["camera"].update(focal_px=-3))
    else:
        edit_manifest(b, lambda m: m["config"].update(dt_us=1000))
    with unchanged(b):
        one_line_error(*cli(capsys, *run_args(env, bundle=b))[::2], "manifest.json", f"its '{edit}' differs")


# ------------------------------------------------------------------ 8. full and read-only disks

@contextlib.contextmanager
def tmpfs(path, opts):
    path.mkdir()
    r = subprocess.run(["mount", "-t", "tmpfs", "-o", opts, "tmpfs", str(path)], capture_output=True)
    if r.returncode:
        pytest.skip(f"cannot mount a tmpfs here ({r.stderr.decode().strip() or 'not root'})")
    try:
        yield path
    finally:
        subprocess.run(["umount", "-l", str(path)], check=False)


def fill(disk, leave=0):
    """Fill a tmpfs, leaving ``leave`` bytes (page-rounded) free."""
    free = shutil.disk_usage(disk).free - leave
    with open(disk / "filler", "ab") as f:
        with contextlib.suppress(OSError):
            f.write(b"\0" * free)


@pytest.fixture
def full_disk(tmp_path):
    with tmpfs(tmp_path / "full", "size=1m") as d:
        yield d


def test_full_disk_is_one_line_error_and_leaves_nothing(env, capsys, tmp_path, full_disk):
    sample = tmp_path / "in.h5"
    shutil.copy(os.path.join(os.path.dirname(__import__("toffe_deploy").__file__), "samples", "sample_multi.h5"),
                sample)
    fill(full_disk, leave=300_000)                   # the sample's HDF5 (~600 kB) cannot fit
    with unchanged(sample, env["bundle"]):
        one_line_error(*cli(capsys, "events", "convert", sample, full_disk / "x.h5")[::2],
                       "x.h5: cannot write: No space left on device")
        fill(full_disk, leave=8192)
        one_line_error(*cli(capsys, "events", "convert", sample, full_disk / "x.npz")[::2], "No space left")
        rc, _, err = cli(capsys, "dataset", "synth", "--out", full_disk / "ds", "--split", "test", "--limit", "2",
                         "--duration-s", "0.02")
        one_line_error(rc, err.split("\r")[-1].split("\n", 1)[-1] if "\r" in err else err, "No space left")
        one_line_error(*cli(capsys, *run_args(env, "--render", full_disk / "r"))[::2], "No space left")
        one_line_error(*cli(capsys, *run_args(env, "--render", full_disk / "v", "--video"))[::2], "disk full")
        fill(full_disk)
        one_line_error(*cli(capsys, *run_args(env, "--out", full_disk / "o.jsonl"))[::2], "o.jsonl: cannot write")
    assert sorted(p.name for p in full_disk.iterdir()) == ["filler"] or \
        sorted(p.name for p in full_disk.iterdir()) == ["ds", "filler"] and not any((full_disk / "ds").rglob("*.*"))


def test_disk_full_mid_stream_leaves_whole_lines(full_disk):
    """run --out appends one line per window: a write the disk refuses half-way is cut back to
    the last whole line before the one-line error."""
    from toffe_deploy.errors import InputError
    from toffe_deploy.runtime.output import LineFile, write_line

    fill(full_disk, leave=8192)
    sink = LineFile(full_disk / "o.jsonl")
    n = 0
    with pytest.raises(InputError, match="o.jsonl: cannot write: No space left on device"):
        while n < 10_000:
            write_line(sink, {"t0_us": 500 * n, "objects": [{"pad": "x" * 300}]})
            n += 1
    sink.close()
    data = (full_disk / "o.jsonl").read_bytes()
    assert n > 5 and data.endswith(b"\n") and len(data.splitlines()) == n
    assert all(json.loads(line)["t0_us"] == 500 * i for i, line in enumerate(data.splitlines()))


def test_read_only_destination_is_one_line_error(env, capsys, tmp_path):
    with tmpfs(tmp_path / "ro", "ro,size=1m") as ro, unchanged(env["rec"], env["bundle"]):
        one_line_error(*cli(capsys, *run_args(env, "--out", ro / "o.jsonl"))[::2], "Read-only file system")
        one_line_error(*cli(capsys, *run_args(env, "--summary-json", ro / "s.json"))[::2], "Read-only file system")
        one_line_error(*cli(capsys, "events", "convert", env["rec"], ro / "x.npz")[::2], "Read-only file system")


def test_full_stdout_is_one_line_error():
    """JSON lines to a full stdout (/dev/full): a subprocess, since the stream is the process's own."""
    if not os.path.exists("/dev/full"):
        pytest.skip("no /dev/full here")
    sample = os.path.join(os.path.dirname(__import__("toffe_deploy").__file__), "samples", "sample_multi.h5")
    with open("/dev/full", "w") as full:
        r = subprocess.run([sys.executable, "-m", "toffe_deploy.cli", "events", "info", sample, "--json",
                            "--no-progress"], stdout=full, stderr=subprocess.PIPE, text=True, timeout=120)
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and "No space left on device" in r.stderr, r.stderr


# ------------------------------------------------------------------ 9. odd recordings

def _events(env):
    return read_events(env["rec"]).events.copy()


def test_three_hour_gap_is_skipped_quickly_and_reported(env, capsys, tmp_path):
    ev = _events(env)
    ev["t"][len(ev) // 2:] += 3 * 3600 * 10 ** 6
    path = tmp_path / "gap.npz"
    write_events_npz(path, ev, SENSOR)
    t = time.perf_counter()
    with unchanged(path, env["bundle"]):
        rc, out, err = cli(capsys, *run_args(env, "--out", tmp_path / "o.jsonl", "--summary-json",
                                             tmp_path / "s.json", "--skip-empty-after", "50", events=path))
    assert rc == 0, err
    assert time.perf_counter() - t < 60
    lines = (tmp_path / "o.jsonl").read_text().splitlines()[1:]         # after the header
    s = json.loads((tmp_path / "s.json").read_text())["skipped"]
    dt = 500
    assert s["gaps"] == 1 and s["windows"] > 3 * 3600 * 10 ** 6 // dt - 100 and s["longest_gap_s"] > 10_000
    assert len(lines) + s["windows"] == (int(ev["t"][-1]) + 1 - int(ev["t"][0])) // dt    # whole windows
    assert "skipped" in out and "empty windows" in out


@pytest.mark.parametrize("t_last", [np.iinfo(np.int64).max, 2 ** 53 + 1, 8 * 24 * 3600 * 10 ** 6])
def test_absurd_timestamps_are_refused(env, capsys, tmp_path, t_last):
    ev = _events(env)
    path = tmp_path / "big.npz"
    np.savez(path, x=ev["x"], y=ev["y"], t=np.append(ev["t"][:-1], t_last), p=ev["p"],
             sensor_size=np.array(SENSOR))
    with unchanged(path):
        one_line_error(*cli(capsys, "events", "info", path, "--no-progress")[::2], str(path))
        one_line_error(*cli(capsys, *run_args(env, events=path))[::2], str(path))


def test_fifo_as_events_is_refused_not_waited_on(env, capsys, tmp_path):
    fifo = tmp_path / "ev.fifo"
    os.mkfifo(fifo)
    fd = os.open(fifo, os.O_RDWR | os.O_NONBLOCK)     # a writer with data: a regression errors, never hangs
    try:
        os.write(fd, b"\x93NUMPY" + b"\0" * 64)
        one_line_error(*cli(capsys, *run_args(env, events=fifo))[::2], "not a regular file")
        one_line_error(*cli(capsys, "events", "info", fifo)[::2], "not a regular file")
    finally:
        os.close(fd)


def test_out_into_a_fifo_streams_into_it_and_whole_file_outputs_refuse_it(env, capsys, tmp_path):
    """`--out FIFO` (or /dev/null, bash's >(...)) replaced the pipe with a regular file, exit 0,
    and its reader got nothing (as root, `--out /dev/null` replaced /dev/null). Now the lines go
    into the pipe; outputs written whole and renamed into place (--summary-json, events convert)
    refuse a pipe, one line, and it stays a pipe."""
    import stat
    import threading

    fifo = tmp_path / "lines.fifo"
    os.mkfifo(fifo)
    got = []
    reader = threading.Thread(target=lambda: got.append(open(fifo, "rb").read()), daemon=True)
    reader.start()
    rc, _out, err = cli(capsys, *run_args(env), "--max-windows", "4", "--out", fifo)
    reader.join(timeout=60)
    assert rc == 0, err
    assert stat.S_ISFIFO(os.stat(fifo).st_mode)
    lines = got[0].decode().splitlines()
    assert len(lines) == 5 and json.loads(lines[0])["type"] == "header" and json.loads(lines[-1])["t0_us"] >= 0
    one_line_error(*cli(capsys, *run_args(env), "--max-windows", "1", "--summary-json", fifo)[::2],
                   "--summary-json", "not a file")
    conv = tmp_path / "conv.h5"
    os.mkfifo(conv)
    one_line_error(*cli(capsys, "events", "convert", "--force", env["rec"], conv)[::2], "not a file")
    assert stat.S_ISFIFO(os.stat(fifo).st_mode) and stat.S_ISFIFO(os.stat(conv).st_mode)
    assert not list(tmp_path.glob(".*.tmp"))


def test_out_into_a_fifo_whose_reader_goes_away_ends_quietly(env, tmp_path):
    """`--out FIFO` whose reader reads a line and goes: exit 0 and no error, as `> FIFO` and
    `| head -1` end (it was "cannot write: Broken pipe", exit 2)."""
    import threading

    fifo = tmp_path / "lines.fifo"
    os.mkfifo(fifo)
    got = []

    def first_line():
        with open(fifo, "rb") as fh:
            got.append(fh.readline())

    reader = threading.Thread(target=first_line, daemon=True)
    reader.start()
    r = subprocess.run([sys.executable, "-m", "toffe_deploy.cli", *map(str, run_args(env)), "--out", str(fifo)],
                       stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, timeout=300)
    reader.join(timeout=60)
    assert r.returncode == 0 and b"error" not in r.stderr and b"Traceback" not in r.stderr, r.stderr
    assert json.loads(got[0])["type"] == "header"


def test_a_reader_closing_stdout_at_the_summary_costs_no_output_file(env, tmp_path):
    """The summary was printed before --summary-json and --report were written: a reader that
    went away then (`| (sleep; exit)`) left the old summary file in place and no report, exit 0
    (or, buffered, exit 120 with 'Exception ignored ... BrokenPipeError'). Now the files come
    first and the closed pipe is a quiet exit 0."""
    summary, report = tmp_path / "s.json", tmp_path / "r.html"
    summary.write_text('{"old": true}')
    for unbuffered in ("1", ""):
        p = subprocess.Popen([sys.executable, "-m", "toffe_deploy.cli", *map(str, run_args(env)), "--max-windows", "3",
                              "--out", tmp_path / "o.jsonl", "--summary-json", summary, "--report", report],
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                             env=dict(os.environ, PYTHONUNBUFFERED=unbuffered))
        p.stdout.close()                                   # the reader is gone before the summary
        err = p.stderr.read().decode()
        assert p.wait(timeout=300) == 0 and "Traceback" not in err and "Exception ignored" not in err, err
        assert json.loads(summary.read_text()).get("windows") == 3 and report.stat().st_size > 0
        summary.write_text('{"old": true}')
        report.unlink()


def test_live_source_options_on_a_file_are_refused(env, capsys):
    """--queue-events 0 on a file was silently ignored (as --fps without --video is refused)."""
    for opt, val in (("--queue-events", "0"), ("--idle-timeout", "2"), ("--window-grace-ms", "1")):
        one_line_error(*cli(capsys, *run_args(env), opt, val)[::2], opt, "live sources")


def test_out_naming_stdout_is_out_dash(env, tmp_path):
    """`--out /proc/self/fd/1` (as /dev/stdout) is `--out -`: the lines on stdout, the summary on
    stderr (it went through a temp file renamed over the link, or, written through it, under
    the summary's own writes). /proc/self/fd/1 rather than /dev/stdout: a regression fails to
    rename there instead of replacing the container's /dev/stdout."""
    out = tmp_path / "stdout.txt"
    with open(out, "wb") as fh:
        r = subprocess.run([sys.executable, "-m", "toffe_deploy.cli", *map(str, run_args(env)), "--max-windows", "3",
                            "--out", "/proc/self/fd/1"], stdout=fh, stderr=subprocess.PIPE, timeout=300)
    assert r.returncode == 0, r.stderr
    lines = out.read_text().splitlines()
    assert len(lines) == 4 and all(ln.startswith("{") for ln in lines) and b"windows" in r.stderr


# ------------------------------------------------------------------ 10. validation gaps

def test_nan_coordinate_in_float_hdf5_column(env, capsys, tmp_path):
    path = tmp_path / "nan.h5"
    shutil.copy(env["rec"], path)
    with h5py.File(path, "r+") as f:
        x = f["events/x"][()].astype("f4")
        x[7] = np.nan
        del f["events/x"]
        f["events/x"] = x
    with unchanged(path):
        one_line_error(*cli(capsys, "events", "info", path, "--no-progress")[::2], "x = nan at event 7")
        one_line_error(*cli(capsys, *run_args(env, events=path))[::2], "x = nan at event 7")


@pytest.mark.parametrize("fmt", ["npz", "h5"])
def test_polarities_other_than_on_off_are_refused(env, capsys, tmp_path, fmt):
    ev = _events(env)
    p = ev["p"].astype(np.int8)
    p[3], p[5] = 7, -3
    path = tmp_path / f"pol.{fmt}"
    if fmt == "npz":
        np.savez(path, x=ev["x"], y=ev["y"], t=ev["t"], p=p, sensor_size=np.array(SENSOR))
    else:
        shutil.copy(env["rec"], path)
        with h5py.File(path, "r+") as f:
            del f["events/p"]
            f["events/p"] = p.astype(np.uint8)         # 7 and 253 in our uint8 column
    with unchanged(path):
        one_line_error(*cli(capsys, "events", "info", path, "--no-progress")[::2], "polarity p = 7 at event 3")


def test_a_polarity_of_both_minus_one_and_zero_is_refused(env, capsys, tmp_path):
    """-1 and 0 in one column is neither encoding: both read as OFF, silently (events info,
    convert and run went ahead); -1/+1 alone still reads."""
    ev = _events(env)
    p = ev["p"].astype(np.int8)
    p[p == 1] = 0
    p[4], p[9] = -1, -1                                     # -1 and 0, no +1
    path = tmp_path / "mixed.npz"
    np.savez(path, x=ev["x"], y=ev["y"], t=ev["t"], p=p, sensor_size=np.array(SENSOR))
    with unchanged(path):
        one_line_error(*cli(capsys, "events", "info", path, "--no-progress")[::2],
                       "polarity holds both -1 (event 4) and 0 (event 0)")
        one_line_error(*cli(capsys, *run_args(env, events=path))[::2], "neither the 0/1 nor the -1/+1 encoding")
    pm = tmp_path / "pm.npz"
    np.savez(pm, x=ev["x"], y=ev["y"], t=ev["t"], p=np.where(ev["p"] > 0, 1, -1).astype(np.int8),
             sensor_size=np.array(SENSOR))
    code, _out, _err = cli(capsys, "events", "info", pm, "--no-progress")
    assert code == 0


def test_short_ground_truth_column(env, capsys, tmp_path):
    path = tmp_path / "gt.h5"
    shutil.copy(env["rec"], path)
    with h5py.File(path, "r+") as f:
        v = f["ground_truth/x"][()][:-5]
        del f["ground_truth/x"]
        f["ground_truth/x"] = v
    with unchanged(path):
        one_line_error(*cli(capsys, *run_args(env, events=path))[::2], "/ground_truth columns")


@pytest.mark.parametrize("edit, needle", [
    (lambda c: [c.pop("n_bins"), c.pop("speed_bins")], "config lacks n_bins, speed_bins"),
])
def test_config_missing_trained_keys(env, capsys, tmp_path, edit, needle):
    b = copy_bundle(env, tmp_path)
    c = json.loads((b / "config.json").read_text())
    edit(c)
    (b / "config.json").write_text(json.dumps(c))
    rehash(b, "config.json")
    one_line_error(*cli(capsys, *run_args(env, bundle=b))[::2], needle)


@pytest.mark.parametrize("key, value, needle", [("du", 0, "du = 0 is not supported"),
                                                ("state_shift", 60, "state_shift = 60 is not supported")])
def test_unsupported_ofs_arithmetic_is_refused(env, capsys, tmp_path, key, value, needle):
    b = copy_bundle(env, tmp_path)
    o = json.loads((b / "ofs_loihi.json").read_text())
    if key == "du":
        o["stages"][0]["du"] = value
    else:
        o[key] = value
    (b / "ofs_loihi.json").write_text(json.dumps(o))
    rehash(b, "ofs_loihi.json")
    one_line_error(*cli(capsys, *run_args(env, bundle=b))[::2], needle)


@pytest.mark.parametrize("extra, needle", [
    (["--start-us", "-1"], "--start-us"),
    (["--skip-empty-after", "-1"], "--skip-empty-after"),
])
def test_bad_run_numbers(env, capsys, extra, needle):
    one_line_error(*cli(capsys, *run_args(env, *extra))[::2], needle)


def test_huge_synthetic_duration_is_bounded(env, capsys, tmp_path):
    one_line_error(*cli(capsys, "run", env["bundle"], "--synthetic", "multi,duration=1e9", "--no-progress")[::2],
                   "duration must be in (0, 10] s")
    one_line_error(*cli(capsys, "dataset", "synth", "--out", tmp_path / "ds", "--duration-s", "1e9")[::2],
                   "longer than 10 s")
    assert not (tmp_path / "ds").exists()


# ------------------------------------------------------------------ 11. camera recordings (RAW, DAT)

def _faery_copy(env, path, **kw):
    faery = pytest.importorskip("faery", reason="faery (test extra) writes Prophesee RAW / DAT files")
    ev = _events(env)
    arr = np.zeros(len(ev), faery.EVENTS_DTYPE)
    arr["t"], arr["x"], arr["y"], arr["on"] = ev["t"], ev["x"], ev["y"], ev["p"].astype(bool)
    faery.events_stream_from_array(arr, SENSOR).to_file(str(path), zero_t0=False, **kw)
    return path


@pytest.mark.parametrize("name, kw", [("rec.raw", {"version": "evt3"}), ("rec.dat", {})])
def test_run_on_a_camera_file_matches_run_on_the_same_events(env, capsys, tmp_path, name, kw):
    path = _faery_copy(env, tmp_path / name, **kw)
    outs = []
    for events in (env["rec"], path):
        out = tmp_path / f"{len(outs)}.jsonl"
        rc, _, err = cli(capsys, *run_args(env, "--target", "cpu", "--start-us", "0", "--max-windows", "10",
                                           "--out", out, events=events))
        assert rc == 0, err
        outs.append(out.read_text())
    assert outs[0] == outs[1] and outs[0].count("\n") == 1 + 10          # the header, then 10 windows


@pytest.mark.parametrize("cut", [1, 3])
def test_run_on_a_truncated_raw_file_is_one_line(env, capsys, tmp_path, cut):
    path = _faery_copy(env, tmp_path / "rec.raw", version="evt3")
    path.write_bytes(path.read_bytes()[:-cut])
    with unchanged(path, env["bundle"]):
        one_line_error(*cli(capsys, *run_args(env, "--out", tmp_path / "o.jsonl", events=path))[::2],
                       str(path), "truncated")
    assert not (tmp_path / "o.jsonl").exists()


# ------------------------------------------- a 2026-11-24 fault sweep: no traceback, no lost output

def _npy(path, t):
    ev = np.zeros(len(t), [("x", "<u2"), ("y", "<u2"), ("t", "<i8"), ("p", "u1")])
    ev["x"], ev["y"], ev["t"], ev["p"] = np.arange(len(t)) % 64, np.arange(len(t)) % 48, t, np.arange(len(t)) % 2
    np.save(path, ev)
    return path


@pytest.mark.parametrize("where", ["last", "first"])
def test_time_going_back_at_an_end_is_refused_and_keeps_the_old_output(env, capsys, tmp_path, where):
    """The span came from the first and last event: a last before the first made it empty, and
    run read 0 windows, exit 0, over the old --out and --summary-json."""
    t = 100 + 10 * np.arange(2000)
    t[-1 if where == "last" else 0] = 0 if where == "last" else 10 ** 9
    path = _npy(tmp_path / "back.npy", t)
    out, summ = tmp_path / "flow.jsonl", tmp_path / "s.json"
    out.write_text("old\n")
    summ.write_text("old\n")
    with unchanged(path, out, summ):
        one_line_error(*cli(capsys, *run_args(env, "--out", out, "--summary-json", summ, events=path))[::2],
                       "back.npy", "timestamps decrease", "before the first")


def test_a_recorded_span_shorter_than_the_events_is_refused(env, capsys, tmp_path):
    path = tmp_path / "short.h5"
    shutil.copy(env["rec"], path)
    with h5py.File(path, "r+") as f:
        f.attrs["t_end_us"] = int(f.attrs["t_start_us"]) + 100
    for cmd in (["events", "info", path], ["events", "convert", path, tmp_path / "c.h5"], run_args(env, events=path)):
        one_line_error(*cli(capsys, *cmd)[::2], "short.h5", "does not hold its events")
    assert not (tmp_path / "c.h5").exists()


def test_malformed_files_are_one_line_errors(env, capsys, tmp_path):
    """h5py's and numpy's own errors on a corrupt structure or a column of the wrong kind."""
    bad_heap = tmp_path / "heap.h5"
    with h5py.File(bad_heap, "w") as f:
        for n, d in (("x", "u2"), ("y", "u2"), ("t", "i8"), ("p", "u1")):
            f[f"events/{n}"] = np.arange(100).astype(d) % 2
    raw = bytearray(bad_heap.read_bytes())
    i = raw.find(b"HEAP")
    raw[i + 16:i + 24] = b"\xff" * 8
    bad_heap.write_bytes(bytes(raw))
    attr = tmp_path / "attr.h5"
    shutil.copy(env["rec"], attr)
    with h5py.File(attr, "r+") as f:
        f.attrs["format_version"] = "abc"
    sub = tmp_path / "sub.npy"
    np.save(sub, np.zeros(10, [("x", "<u2", (2,)), ("y", "<u2"), ("t", "<i8"), ("p", "u1")]))
    zero_d = tmp_path / "size.npz"
    z = np.zeros(5, int)
    np.savez(zero_d, x=z, y=z, t=np.arange(5), p=z, sensor_size=np.array(64))
    for path, needle in ((bad_heap, "malformed or corrupt"), (attr, "malformed or corrupt"),
                         (sub, "column x has shape (10, 2)"), (zero_d, "malformed or corrupt")):
        one_line_error(*cli(capsys, "events", "info", path)[::2], path.name, needle)


def _edit_config(env, tmp_path, fn):
    b = copy_bundle(env, tmp_path)
    c = json.loads((b / "config.json").read_text())
    fn(c)
    (b / "config.json").write_text(json.dumps(c))
    rehash(b, "config.json")
    edit_manifest(b, lambda m: m.__setitem__("config", c) if "config" in m else None)
    return b


@pytest.mark.parametrize("edit, needle", [
    (lambda c: c["ofpd"].__setitem__("crop_px", 0), "ofpd.crop_px must be a whole number"),   # hung, deaf to SIGTERM
    (lambda c: c["ofpd"].__setitem__("pool", 0), "ofpd.pool must be a whole number"),         # ZeroDivisionError
    (lambda c: c.__setitem__("mask_kernel", 100001), "mask_kernel must be 1..255"),           # tens of GiB
    (lambda c: c.__setitem__("input_min_cluster", 10 ** 30), "input_min_cluster must be"),    # OverflowError
    (lambda c: c.__setitem__("n_bins", 4), "do not belong together"),                         # onnxruntime's error
    # out of range, accepted silently before:
    (lambda c: c["ofpd"].__setitem__("min_events", 0), "ofpd.min_events must be a whole number 1.."),
    (lambda c: c["ofpd"].__setitem__("min_events", "12"), "ofpd.min_events must be a whole number 1.."),
    (lambda c: c["ofpd"].__setitem__("min_events", True), "ofpd.min_events must be a whole number 1.."),
    (lambda c: c["ofpd"].__setitem__("link_px", 0), "ofpd.link_px must be a whole number 1..4096"),
    (lambda c: c["ofpd"].__setitem__("dedupe_px", -3), "ofpd.dedupe_px must be a whole number 1..4096"),
    (lambda c: c["ofpd"].__setitem__("merge_frac", -0.1), "ofpd.merge_frac must be a finite number >= 0"),
    (lambda c: c["ofpd"].__setitem__("edge_merge_frac", float("nan")), "ofpd.edge_merge_frac must be a finite"),
    (lambda c: c["ofpd"].__setitem__("split_frac", float("inf")), "ofpd.split_frac must be a finite number >= 0"),
    (lambda c: c["ofpd"].__setitem__("merge_frac", 10 ** 400), "ofpd.merge_frac must be a finite number >= 0"),
    (lambda c: c.__setitem__("focal_px", 10 ** 400), "malformed config: int too large to convert to float"),
    (lambda c: c["ofpd"].__setitem__("split_waist", 0), "ofpd.split_waist must be a finite number > 0"),
    (lambda c: c["ofpd"].__setitem__("pool_min", 32), "ofpd.pool_min 32 must not exceed ofpd.pool_max 16"),
    (lambda c: c["ofpd"].__setitem__("pool_max", 0), "ofpd.pool_max must be a whole number 1..4096"),
    (lambda c: c.__setitem__("dt_us", 10 ** 10), "dt_us must be <= 1000000000"),
    (lambda c: c["representative_speeds"].__setitem__(1, -1.0), "representative_speeds must be finite and >= 0"),
    (lambda c: c["representative_speeds"].__setitem__(1, float("inf")), "representative_speeds must be finite"),
])
def test_edited_bundle_configs_are_one_line_errors(env, capsys, tmp_path, edit, needle):
    b = _edit_config(env, tmp_path, edit)
    rc, _out, err = cli(capsys, *run_args(env, "--max-windows", "2", bundle=b))
    one_line_error(rc, err, needle)


@pytest.mark.parametrize("extra, needle", [
    (["--sensor-size", "65535x65535"], "larger than toffe-deploy runs"),
    (["--depth-m", "1e308"], "--depth-m must be in"),
    (["--focal-px", "5e-324"], "--focal-px must be in"),
    (["--hfov-deg", "1e-300"], "--hfov-deg must be in [0.1, 179], got 1e-300"),            # a focal of 3.7e304 px
    (["--hfov-deg", "179.99999999"], "--hfov-deg must be in [0.1, 179], got 179.99999999"),  # ... of 3e-8 px
])
def test_sizes_beyond_any_camera_are_refused(env, capsys, tmp_path, extra, needle):
    ev = _npy(tmp_path / "ok.npy", 100 + 10 * np.arange(200))
    out = tmp_path / "o.jsonl"
    one_line_error(*cli(capsys, *run_args(env, "--out", out, *extra, events=ev))[::2], needle)
    assert not out.exists() and not list(tmp_path.glob(".o.jsonl*"))


@pytest.mark.parametrize("spec, needle", [("multi:2,seed=-1", "seed must be >= 0"),
                                          ("multi:2,hfov=1e-300", "hfov must be in [0.1, 179] degrees"),
                                          ("multi:2,sensor=65535x65535", "larger than toffe-deploy runs")])
def test_bad_synthetic_seeds_and_sizes(env, capsys, spec, needle):
    one_line_error(*cli(capsys, "run", env["bundle"], "--synthetic", spec, "--max-windows", "1", "--no-progress")[::2],
                   needle)


@pytest.mark.parametrize("col, value, needle", [("direction", np.inf, "not a finite number"),
                                                ("speed_bin", 9, "speed bin 9, but the bundle has 4"),
                                                ("visible", 7, "expected whole numbers 0..1")])
def test_ground_truth_values_are_checked(env, capsys, tmp_path, col, value, needle):
    """A NaN / inf direction gave dirE nan with exit 0 and an IndexError in dataset show."""
    path = tmp_path / "gt.h5"
    shutil.copy(env["rec"], path)
    with h5py.File(path, "r+") as f:
        g = f["ground_truth"]
        v = np.array(g[col][()])
        v = v.astype({"direction": np.float32, "visible": np.int8}.get(col, v.dtype))
        v[0] = value
        del g[col]
        g[col] = v
    one_line_error(*cli(capsys, *run_args(env, events=path))[::2], "gt.h5", needle)
    if col != "speed_bin":                   # a bin the file's format holds: dataset show draws it
        one_line_error(*cli(capsys, "dataset", "show", path, "--out", tmp_path / "g.png")[::2],
                       f"/ground_truth/{col}", needle)


@pytest.mark.parametrize("kind", ["float", "uint64"])
def test_times_beyond_int64s_range_are_named_not_wrapped(capsys, tmp_path, kind):
    """1e30 (float) and 2**64 - 1 (uint64) were reported as 'negative timestamp t = -9223372036854775808'."""
    if kind == "float":
        a = np.zeros((5, 4))
        a[:, 2] = np.arange(5)
        a[4, 2] = 1e30
    else:
        a = np.zeros(5, [("x", "<u2"), ("y", "<u2"), ("t", "<u8"), ("p", "u1")])
        a["t"] = np.arange(5)
        a["t"][4] = 2 ** 64 - 1
    np.save(tmp_path / "t.npy", a)
    one_line_error(*cli(capsys, "events", "info", tmp_path / "t.npy")[::2], "beyond 2**53 us", "at event 4",
                   "nanoseconds?")


def test_nanosecond_timestamps_get_a_hint_in_info_and_run(env, capsys, tmp_path):
    """A recording in ns read as us (ROS stamps, many loggers) ran with no word: near-empty windows.
    Every timestamp a multiple of 1000 now gets a hint in `events info` and, once, in `run`
    (stderr at once, the summary and its JSON); a us recording gets none."""
    ev = read_events(env["rec"]).events
    ns = ev.copy()
    ns["t"] = (ev["t"] - ev["t"][0]) * 1000
    write_events_npz(tmp_path / "ns.npz", ns, SENSOR)
    write_events_npz(tmp_path / "us.npz", ev, SENSOR)
    rc, out, _ = cli(capsys, "events", "info", tmp_path / "ns.npz")
    assert rc == 0 and "note:" in out and "multiple of 1000 us: if they are nanoseconds, divide t by 1000" in out
    rc, out, _ = cli(capsys, "events", "info", tmp_path / "us.npz", "--json")
    assert rc == 0 and json.loads(out)["time_unit_note"] is None
    rc, _, err = cli(capsys, *run_args(env, "--target", "cpu", "--out", tmp_path / "f.jsonl",    # ~11,000 windows
                                       "--summary-json", tmp_path / "s.json", events=tmp_path / "ns.npz"))
    assert rc == 0 and err.count("divide t by 1000") == 2, err      # at once, and the summary's warning line
    assert "multiple of 1000 us" in json.loads((tmp_path / "s.json").read_text())["time_unit_note"]
    rc, _, err = cli(capsys, *run_args(env, "--target", "cpu", "--max-windows", "8", "--out", tmp_path / "g.jsonl",
                                       events=tmp_path / "us.npz"))
    assert rc == 0 and "nanoseconds" not in err, err


def test_small_option_slips_are_refused(env, capsys, tmp_path):
    """dataset show past the end drew blank frames (exit 0) and --frames 5000 ran out of memory;
    export --checks '' ran no check."""
    one_line_error(*cli(capsys, "dataset", "show", env["rec"], "--out", tmp_path / "s.png",
                        "--t0-us", "999999999999")[::2], "outside the recording")
    with pytest.raises(SystemExit) as exc:                  # argparse's usage error
        main(["dataset", "show", str(env["rec"]), "--out", str(tmp_path / "s.png"), "--frames", "5000"])
    err = capsys.readouterr().err
    assert exc.value.code == 2 and "1..64" in err and "Traceback" not in err
    assert not (tmp_path / "s.png").exists()
    one_line_error(*cli(capsys, "export", env["ckpt"], "-o", tmp_path / "b", "--checks", "")[::2], "--checks is empty")
    assert not (tmp_path / "b").exists()


def test_a_fractional_sensor_size_is_refused_not_truncated(env, capsys, tmp_path):
    """sensor_width 64.7 in our HDF5, or [64.7, 48.2] in an .npz, was read as 64 x 48."""
    h5 = tmp_path / "w.h5"
    shutil.copy(env["rec"], h5)
    with h5py.File(h5, "r+") as f:
        f.attrs["sensor_width"] = 64.7
    z = np.zeros(5, int)
    npz = tmp_path / "w.npz"
    np.savez(npz, x=z, y=z, t=np.arange(5), p=z, sensor_size=np.array([64.7, 48.2]))
    for path in (h5, npz):
        one_line_error(*cli(capsys, "events", "info", path)[::2], path.name, "in whole pixels")


def test_an_ofpd_model_giving_nan_is_one_line_error(env, capsys, tmp_path):
    """An ofpd.onnx with NaN weights (manifest re-hashed) wrote "x": null ... with exit 0, which
    the output schema refuses: now the model is named, exit 2, and --out keeps only the whole
    lines of the windows before (none with an object)."""
    onnx = pytest.importorskip("onnx")
    from onnx import numpy_helper

    b = copy_bundle(env, tmp_path)
    model = onnx.load(str(b / "ofpd.onnx"))
    (fc,) = [t for t in model.graph.initializer if t.name == "fc.weight"]
    fc.CopyFrom(numpy_helper.from_array(np.full_like(numpy_helper.to_array(fc), np.nan), fc.name))
    onnx.save(model, str(b / "ofpd.onnx"))
    rehash(b, "ofpd.onnx")
    out = tmp_path / "o.jsonl"
    one_line_error(*cli(capsys, *run_args(env, "--out", out, bundle=b))[::2],
                   "ofpd.onnx: produced non-finite output (NaN or inf)")
    lines = [json.loads(line) for line in out.read_text().splitlines()]
    assert lines[0]["type"] == "header" and not any(line.get("objects") for line in lines)


def test_the_finite_check_of_the_ofpd_output_is_exact():
    """OFPDRunner.run's fast check (one float64 sum of the outputs) is True exactly when every
    float32 value is finite; for float64 outputs it may say False on huge finite values, which
    the runner then confirms with np.isfinite before it refuses anything."""
    from toffe_deploy.runtime.ofpd_runner import _finite_sum

    big = np.finfo(np.float32).max
    assert _finite_sum(np.full((64, 2), big, np.float32), np.full((64, 2), -big, np.float32), np.zeros((64, 1), np.float32))
    assert _finite_sum(np.zeros((0, 2), np.float32))
    for bad in (np.nan, np.inf, -np.inf):
        x = np.ones((3, 2), np.float32)
        x[2, 1] = bad
        assert not _finite_sum(np.ones((3, 2), np.float32), x)
    assert not _finite_sum(np.array([1e308, 1e308]))          # finite, so the runner's np.isfinite decides


def test_ground_truth_time_running_backwards_is_refused(env, capsys, tmp_path):
    """A /ground_truth/t that runs backwards for an object gave wrong truth per window with exit 0;
    rows grouped by object (each object's in time order) stay fine."""
    grouped, back = tmp_path / "grouped.h5", tmp_path / "back.h5"
    for path in (grouped, back):
        shutil.copy(env["rec"], path)
    with h5py.File(grouped, "r+") as f:
        g = f["ground_truth"]
        order = np.argsort(g["object_id"][()], kind="stable")
        for k in list(g):
            g[k][...] = g[k][()][order]
    assert cli(capsys, "events", "info", grouped)[0] == 0
    with h5py.File(back, "r+") as f:
        f["ground_truth/t"][...] = f["ground_truth/t"][()][::-1]
    with unchanged(back):
        one_line_error(*cli(capsys, *run_args(env, "--max-windows", "2", events=back))[::2], "back.h5",
                       "/ground_truth/t runs backwards at row")
        one_line_error(*cli(capsys, "dataset", "show", back, "--out", tmp_path / "g.png")[::2],
                       "/ground_truth/t runs backwards")
    assert not (tmp_path / "g.png").exists()


def test_a_deeply_nested_manifest_is_one_line_error(env, capsys, tmp_path):
    """JSON nested deeper than the parser's stack raised RecursionError with a traceback."""
    b = copy_bundle(env, tmp_path)
    (b / "manifest.json").write_text("[" * 3000 + "]" * 3000)
    one_line_error(*cli(capsys, *run_args(env, bundle=b))[::2], "manifest.json: not valid JSON (nested too deeply)")
