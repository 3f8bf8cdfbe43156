"""The Python API (toffe_deploy.api) and the robot-loop example, on a real tiny bundle and recording."""
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from toffe_deploy import api
from toffe_deploy.cli import main
from toffe_deploy.events.io import read_events

ROOT = Path(__file__).resolve().parent.parent


@pytest.fixture(scope="module")
def env(tmp_path_factory, make_bundle, make_recording):
    root = tmp_path_factory.mktemp("api")
    return {"root": root, "bundle": make_bundle(root), "rec": make_recording(root / "rec.h5")}


def test_feeding_packets_gives_the_json_lines_of_run(env, capsys, tmp_path, rng):
    """Events fed in packets of random length give, window for window, what `run` writes (object
    flow, track ids and track states)."""
    assert main(["run", str(env["bundle"].root), "--events", str(env["rec"]), "--out", str(tmp_path / "o.jsonl"),
                 "--no-progress"]) == 0
    capsys.readouterr()
    want = [json.loads(s) for s in (tmp_path / "o.jsonl").read_text().splitlines()[1:]]
    ev = read_events(env["rec"]).events
    got = []
    with api.FlowStream(str(env["bundle"].root), "cpu", t_start_us=0) as flow:
        cuts = np.sort(rng.integers(0, len(ev), 15))
        for part in np.split(ev, cuts):
            got += [r.to_json() for r in flow.feed(part["x"], part["y"], part["t"], part["p"])]
        got += [r.to_json() for r in flow.flush()]
    assert len(got) >= len(want) - 1 and got == want[:len(got)]
    assert any(o.get("track_id") is not None for w in got for o in w["objects"])
    tracks = flow.tracks()
    assert all(t["track"]["confirmed"] for t in tracks)


def test_feed_window_takes_dense_windows_and_bad_events_are_refused(env):
    b = env["bundle"]
    cfg = b.config
    w, h = cfg.sensor_size
    with api.FlowStream(b, "cpu", track=api.TrackerConfig(confirm_hits=1)) as flow:
        x = np.zeros((cfg.n_bins, 2, h, w), np.uint8)
        x[:, :, 10:20, 10:20] = 1
        res = flow.feed_window(0, x)
        assert res.t0_us == 0 and res.t1_us == cfg.dt_us
        with pytest.raises(ValueError, match="timestamps decrease"):
            flow.feed([1, 2], [1, 2], [50, 10], [0, 1])
        with pytest.raises(ValueError, match="outside"):
            flow.feed([w], [0], [100], [1])
        for cols, msg in ((([1, 2], [0], [60], [1]), "one length"), (([1], [0], [60], [7]), "polarity p = 7"),
                          (([1.7], [0], [60], [1]), "x = 1.7"), (([1], [0], [float("nan")], [1]), "not a finite time")):
            with pytest.raises(ValueError, match=msg):
                flow.feed(*cols)
        assert flow._buf.shape[0] == 0                      # nothing refused got in
        flow.feed([3, 4], [3, 4], [600, 700], [-1, 1])      # -1/+1 as the file readers take it: OFF, ON
        np.testing.assert_array_equal(flow._buf["p"], [0, 1])


def test_robot_loop_example_runs(env):
    p = subprocess.run([sys.executable, str(ROOT / "examples" / "robot_loop.py"), "--bundle", str(env["bundle"].root),
                        "--events", str(env["rec"]), "--packet-us", "1500", "--max-ms", "12"],
                       capture_output=True, text=True, timeout=300, cwd=ROOT)
    assert p.returncode == 0, p.stderr
    lines = p.stdout.splitlines()
    assert lines[0].endswith(" sensor") and lines[1].startswith("t=    0.0 ms:")
    assert len(lines) == 10                                 # the sensor, then one line per 1.5 ms packet
    assert lines[-1].startswith("24 windows, ") and "confirmed tracks" in lines[-1]


def test_robot_loop_example_takes_the_bundle_where_run_does(env, tmp_path):
    """Its default bundle was the repository's export/, wherever it ran; `toffe-deploy export`
    writes export/ in the current directory and `run` reads it there: so does the example now."""
    (tmp_path / "export").symlink_to(env["bundle"].root, target_is_directory=True)
    cmd = [sys.executable, str(ROOT / "examples" / "robot_loop.py"), "--events", str(env["rec"]), "--max-ms", "2"]
    p = subprocess.run(cmd, capture_output=True, text=True, timeout=300, cwd=tmp_path)
    assert p.returncode == 0 and "windows" in p.stdout.splitlines()[-1], p.stderr
    (tmp_path / "export").unlink()
    p = subprocess.run(cmd, capture_output=True, text=True, timeout=300, cwd=tmp_path)
    assert p.returncode == 2 and p.stderr.startswith("robot_loop: error: export: bundle directory does not exist")


def test_robot_loop_example_reads_a_whole_file_without_a_sensor_size(env, tmp_path):
    """--max-ms inf (the whole recording) gave an OverflowError traceback, and a .npy recording
    (no sensor size in it) ran on a sensor guessed from its largest coordinates, unsaid:
    --sensor-size gives it, and the loop prints the sensor it uses."""
    ev = read_events(env["rec"]).events
    npy = tmp_path / "rec.npy"
    np.save(npy, ev)
    w, h = env["bundle"].config.sensor_size
    p = subprocess.run([sys.executable, str(ROOT / "examples" / "robot_loop.py"), "--bundle", str(env["bundle"].root),
                        "--events", str(npy), "--sensor-size", f"{w}x{h}", "--packet-us", "5000", "--max-ms", "inf"],
                       capture_output=True, text=True, timeout=300, cwd=ROOT)
    assert p.returncode == 0, p.stderr
    lines = p.stdout.splitlines()
    assert lines[0] == f"{npy}: {w}x{h} sensor"
    n_win = (int(ev["t"][-1]) + 1 - int(ev["t"][0])) // env["bundle"].config.dt_us     # whole windows, as `run`
    assert lines[-1].startswith(f"{n_win} windows, ")
    bad = subprocess.run([sys.executable, str(ROOT / "examples" / "robot_loop.py"), "--sensor-size", "640"],
                         capture_output=True, text=True, timeout=60, cwd=ROOT)
    assert bad.returncode == 2 and "--sensor-size" in bad.stderr.splitlines()[-1]


def test_the_api_refuses_what_it_would_otherwise_drop_or_cast(env):
    """A new user's mistakes that the API took silently or with an AttributeError: OFF events as
    -1 in a dense window (dropped), NaN values, fractional sizes and starts (cast), events before
    the first window (dropped), track="no" (tracking on), a (focal, depth) tuple for speed_scale,
    an unknown OFPD variant (told to re-export it). A list window and a bundle's directory work."""
    b = env["bundle"]
    cfg = b.config
    w, h = cfg.sensor_size
    x = np.zeros((cfg.n_bins, 2, h, w), np.int8)
    x[:, :, 10:20, 10:20] = 1
    with api.FlowStream(b, "cpu") as flow:
        for bad in (-x, np.where(x > 0, np.nan, 0.0)):
            with pytest.raises(ValueError, match="counts >= 0"):
                flow.feed_window(0, bad)
        with pytest.raises(ValueError, match="dtype"):
            flow.feed_window(0, x.astype(str))
        want = flow.feed_window(0, x).to_json()
    with api.FlowStream(str(b.root), "cpu") as flow:
        assert flow.feed_window(0, x.tolist()).to_json() == want
    for kw, msg in (({"sensor_size": (w + 0.5, h)}, "whole number"), ({"t_start_us": 1.5}, "whole number"),
                    ({"track": "no"}, "track must be"), ({"speed_scale": (554.0, 5.0)}, "SpeedScale"),
                    ({"ofpd_variant": "bogus"}, "unknown OFPD variant")):
        with pytest.raises(ValueError, match=msg):
            api.FlowStream(b, "cpu", **kw)
    with api.FlowStream(b, "cpu", sensor_size=np.array([w, h]), t_start_us=np.array(1000), track=np.True_) as flow:
        assert flow.t_start_us == 1000 and flow.pipeline.tracker is not None     # numpy forms of valid values
        with pytest.raises(ValueError, match="real numbers"):
            flow.feed(np.array([1 + 2j]), [1], [1000], [0])
        with pytest.raises(ValueError, match="before the first window"):
            flow.feed([1, 2], [1, 2], [500, 1500], [0, 1])
        assert [r.t0_us for r in flow.feed([1, 2], [1, 2], [1000, 1500], [0, 1])] == [1000]
    with api.Pipeline(str(b.root), "cpu") as pipe:
        assert [r.to_json() for r in pipe.process_stream([(0, x)])] == [want]


def test_flush_processes_or_drops_the_last_partial_window(env):
    """Three whole windows and half of a fourth fed: flush() drops the partial fourth (its objects
    would come from half a window), as `run` does; flush(partial=True) processes it too."""
    ev = read_events(env["rec"]).events
    dt = env["bundle"].config.dt_us
    cut = ev[ev["t"] < 3 * dt + dt // 2]
    assert cut["t"].max() >= 3 * dt
    for partial, n in ((True, 4), (False, 3)):
        with api.FlowStream(str(env["bundle"].root), "cpu", t_start_us=0) as flow:
            got = flow.feed(cut["x"], cut["y"], cut["t"], cut["p"]) + flow.flush(partial=partial)
            assert flow.flush() == []                   # nothing left buffered either way
        assert [r.t0_us for r in got] == [k * dt for k in range(n)]
    with api.FlowStream(str(env["bundle"].root), "cpu", t_start_us=0) as flow:   # the stream's end given:
        got = flow.feed(cut["x"], cut["y"], cut["t"], cut["p"])                  # the fourth is whole
        for bad in (int(cut["t"][-1]), 1.5 * dt, "x", float("nan")):
            with pytest.raises(ValueError, match="t_end_us must be a whole number"):
                flow.flush(t_end_us=bad)
        got += flow.flush(t_end_us=4 * dt)
    assert [r.t0_us for r in got] == [k * dt for k in range(4)]


def test_flush_to_a_later_end_processes_the_empty_windows_as_run_does(env, capsys, tmp_path):
    """A recording whose stated end lies windows after its last event: flush(t_end_us=end) gives
    run's windows, the empty ones included (it stopped at the last event's window), and with
    skip_empty_after the same jump past the end."""
    from toffe_deploy.events.io import write_events_h5

    ev = read_events(env["rec"]).events
    dt = env["bundle"].config.dt_us
    part = ev[ev["t"] < 2300]
    rec = tmp_path / "quiet_end.h5"
    write_events_h5(rec, part, env["bundle"].config.sensor_size, t_range=(0, 6700))
    for skip in (1000, 2):
        assert main(["run", str(env["bundle"].root), "--events", str(rec), "--out", str(tmp_path / "o.jsonl"),
                     "--skip-empty-after", str(skip), "--no-progress"]) == 0
        capsys.readouterr()
        want = [json.loads(x)["t0_us"] for x in (tmp_path / "o.jsonl").read_text().splitlines()[1:]]
        with api.FlowStream(str(env["bundle"].root), "cpu", t_start_us=0, skip_empty_after=skip) as flow:
            got = flow.feed(part["x"], part["y"], part["t"], part["p"]) + flow.flush(t_end_us=6700)
        assert [r.t0_us for r in got] == want
        assert want[-1] == (12 * dt if skip == 1000 else 2000 + skip * dt)          # 6000: [6500, 7000) is partial


def test_a_stream_refuses_events_of_windows_it_processed_until_reset(env):
    """Feeding the recording again after flush() was a silent loss (one empty window for all of
    it): events in windows already processed are refused, and reset() starts a new recording
    that gives what the first pass gave."""
    ev = read_events(env["rec"]).events
    ev = ev[ev["t"] < 2000]
    with api.FlowStream(str(env["bundle"].root), "cpu", t_start_us=0) as flow:
        first = [r.to_json() for r in flow.feed(ev["x"], ev["y"], ev["t"], ev["p"]) + flow.flush(t_end_us=2000)]
        with pytest.raises(ValueError, match="timestamps decrease|already processed"):
            flow.feed(ev["x"], ev["y"], ev["t"], ev["p"])
        with pytest.raises(ValueError, match="negative timestamp"):
            flow.feed([1], [1], [-5], [1])
        flow.reset()
        again = [r.to_json() for r in flow.feed(ev["x"], ev["y"], ev["t"], ev["p"]) + flow.flush(t_end_us=2000)]
    assert again == first and len(first) == 4


def test_a_gap_is_jumped_on_the_window_grid_of_t_start(env):
    """After a gap longer than skip_empty_after windows the next window starts on the grid from
    t_start_us (as `run`), not on multiples of dt."""
    dt = env["bundle"].config.dt_us
    with api.FlowStream(str(env["bundle"].root), "cpu", t_start_us=50, skip_empty_after=2, track=False) as flow:
        got = flow.feed([1, 2, 3], [1, 2, 3], [60, 100_000, 100_010], [1, 1, 0]) + flow.flush(partial=True)
    starts = [r.t0_us for r in got]
    assert starts[0] == 50 and all((t - 50) % dt == 0 for t in starts) and starts[-1] == 50 + (100_000 - 50) // dt * dt


def test_speeds_in_mps_on_another_sensor_are_runs(env, capsys, tmp_path):
    """On a sensor wider than the bundle's (no camera in the file), the API's m/s are `run`'s:
    the bundle's field of view over the sensor's width (run_camera.resolve_camera), not the
    bundle's focal length as it is (that reported 84.7 m/s where `run` reported 156.6)."""
    from toffe_deploy.events.io import open_events, write_events_npz
    from toffe_deploy.runtime.run_camera import resolve_camera

    cfg = env["bundle"].config
    ev = read_events(env["rec"]).events
    wide = (2 * cfg.sensor_size[0], cfg.sensor_size[1])
    write_events_npz(tmp_path / "wide.npz", ev, wide)
    assert main(["run", str(env["bundle"].root), "--events", str(tmp_path / "wide.npz"), "--out",
                 str(tmp_path / "o.jsonl"), "--summary-json", str(tmp_path / "s.json"), "--no-progress"]) == 0
    capsys.readouterr()
    summary = json.loads((tmp_path / "s.json").read_text())
    camera = summary["camera"]
    assert camera["focal_px"] == pytest.approx(2 * cfg.focal_px)
    head = json.loads((tmp_path / "o.jsonl").read_text().splitlines()[0])
    assert summary["tag"] == head["tag"] == "fixed_pt"           # one answer in both files (null in the summary)
    want = [json.loads(s) for s in (tmp_path / "o.jsonl").read_text().splitlines()[1:]]
    with open_events(tmp_path / "wide.npz") as src:             # the file's own start, as `run` (README)
        start = src.t_start_us
    with api.FlowStream(env["bundle"], "cpu", sensor_size=wide, t_start_us=start) as flow:
        assert flow.pipeline.speed_scale == resolve_camera(cfg, wide).scale
        got = [r.to_json() for r in flow.feed(ev["x"], ev["y"], ev["t"], ev["p"]) + flow.flush()]
    assert any(w["objects"] for w in want) and got[:len(want)] == want[:len(got)] and len(got) >= len(want) - 1
    with pytest.raises(ValueError, match="width, height"):
        api.FlowStream(env["bundle"], "cpu", sensor_size=(64,))


def test_feed_window_keeps_time_order_and_feed_goes_on_after_it(env):
    """feed_window refuses a window before the last one's end or at a negative t0 (it ran them
    through the tracker, and t0 < 0 broke the schema), and feed() then starts at its end (it
    processed window 0 a second time)."""
    b = env["bundle"]
    cfg = b.config
    w, h = cfg.sensor_size
    dt = cfg.dt_us
    z = np.zeros((cfg.n_bins, 2, h, w), np.uint8)
    with api.FlowStream(b, "cpu") as flow:
        flow.feed_window(2 * dt, z)
        for t0, msg in ((dt, "before the end"), (2 * dt, "before the end"), (-dt, ">= 0"), (0.5, "whole number")):
            with pytest.raises(ValueError, match=msg):
                flow.feed_window(t0, z)
        assert flow.feed_window(3 * dt, z).t0_us == 3 * dt
        flow.feed([1], [1], [4 * dt + 10], [1])
        with pytest.raises(ValueError, match="flush"):
            flow.feed_window(10 * dt, z)
    ev = read_events(env["rec"]).events
    ev = ev[ev["t"] >= dt]
    with api.FlowStream(b, "cpu", t_start_us=0) as flow:
        flow.feed_window(0, z)
        starts = [r.t0_us for r in flow.feed(ev["x"], ev["y"], ev["t"], ev["p"])]
    assert starts[:2] == [dt, 2 * dt]


def test_skip_empty_after_zero_never_skips_as_in_run(env):
    """skip_empty_after 0 (or None) processes every empty window, as `run --skip-empty-after 0`
    (it skipped every one at once); a negative count is refused."""
    dt = env["bundle"].config.dt_us
    for skip in (0, None):
        with api.FlowStream(env["bundle"], "cpu", t_start_us=0, skip_empty_after=skip, track=False) as flow:
            got = flow.feed([1, 2], [1, 2], [10, 20 * dt + 5], [1, 1]) + flow.flush(partial=True)
        assert [r.t0_us for r in got] == [k * dt for k in range(21)]
    with pytest.raises(ValueError, match="skip_empty_after"):
        api.FlowStream(env["bundle"], "cpu", skip_empty_after=-1)


def test_a_closed_stream_refuses_calls_and_an_open_one_keeps_its_pipeline(env):
    """Without ``with`` the pipeline opens at the first window and stays open (a Lava runtime
    started once a window before: 19 windows took 34 s on loihi-sim); after close() every call
    is refused (feed after close ran on, reopening the pipeline per window)."""
    b = env["bundle"]
    dt = b.config.dt_us
    flow = api.FlowStream(b, "cpu", t_start_us=0, track=False)
    assert not flow.pipeline._entered
    flow.feed([1, 2], [1, 2], [10, 3 * dt], [1, 1])
    assert flow.pipeline._entered and not flow.closed
    flow.close()
    assert flow.closed and not flow.pipeline._entered
    for call in (lambda: flow.feed([1], [1], [4 * dt], [1]), flow.flush, flow.__enter__, flow.reset,
                 lambda: flow.feed_window(5 * dt, np.zeros((b.config.n_bins, 2) + b.config.sensor_size[::-1]))):
        with pytest.raises(ValueError, match="closed"):
            call()
    assert not flow.pipeline._entered


def test_feed_window_refuses_a_window_off_the_grid(env):
    """A t0 off the grid of t_start_us moved the grid of every later feed (windows 750, 1250, ...
    after feed_window(250) on a grid from 0)."""
    b = env["bundle"]
    dt = b.config.dt_us
    z = np.zeros((b.config.n_bins, 2) + b.config.sensor_size[::-1], np.uint8)
    with api.FlowStream(b, "cpu", t_start_us=0, track=False) as flow:
        with pytest.raises(ValueError, match="off the window grid"):
            flow.feed_window(dt // 2, z)
        assert flow.feed_window(2 * dt, z).t0_us == 2 * dt


def test_feeding_from_two_threads_gives_each_window_once(env):
    """Calls are serialized: two threads feeding packets in time order (handed out under the
    caller's lock) got windows twice (370 results for 200 windows) without the stream's lock."""
    import threading

    ev = read_events(env["rec"]).events
    packets = np.array_split(ev, 60)
    with api.FlowStream(env["bundle"], "cpu", t_start_us=0, track=False) as flow:
        want = [r.t0_us for p in packets for r in flow.feed(p["x"], p["y"], p["t"], p["p"])]
    got, errors, nxt, order = [], [], [0], threading.Lock()

    def worker():
        while True:
            with order:
                i = nxt[0]
                nxt[0] += 1
            if i >= len(packets):
                return
            p = packets[i]
            try:
                got.extend(r.t0_us for r in flow.feed(p["x"], p["y"], p["t"], p["p"]))
            except ValueError as exc:          # a later packet can reach feed first: refused whole
                errors.append(exc)

    with api.FlowStream(env["bundle"], "cpu", t_start_us=0, track=False) as flow:
        threads = [threading.Thread(target=worker) for _ in range(2)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
    assert len(got) == len(set(got)) and set(got) <= set(want)
    assert errors or sorted(got) == want


def test_process_stream_names_a_bare_window(env):
    b = env["bundle"]
    z = np.zeros((b.config.n_bins, 2) + b.config.sensor_size[::-1], np.uint8)
    with pytest.raises(ValueError, match=r"\(t0_us, window\) pairs, got a ndarray of shape"):
        list(api.Pipeline(b, "cpu").process_stream([z]))
