"""Camera and ROS formats on real files written by the libraries themselves: Prophesee RAW (EVT 2.0,
EVT 3.0) and DAT written by faery, EVT3 cross-checked with the evt3 decoder, Metavision HDF5 in
the Metavision SDK's own layout (h5py), ROS1 / ROS2 bags written by rosbags. Exact events back,
`events info` and `events convert` on each, corrupt variants as one-line errors."""
import json
import shutil

import h5py
import numpy as np
import pytest

from toffe_deploy.cli import main
from toffe_deploy.errors import InputError
from toffe_deploy.events import make_events, open_events, read_events
from toffe_deploy.events import fmt_prophesee
from toffe_deploy.events.io import detect_format

SIZE = (64, 48)


def _bursts(rng, n_bursts=200, size=SIZE, gap_us=5_000_000):
    """Events as a camera sends them: runs of neighbouring pixels on one row at one time (EVT3
    packs them into vector words), both polarities, a long gap every 40 bursts (the span passes
    EVT3's 24-bit time wrap at 16.8 s)."""
    w, h = size
    cols, t = [], 7
    for k in range(n_bursts):
        t += gap_us if k % 40 == 39 else int(rng.integers(0, 40))
        x0, n = int(rng.integers(0, w)), int(rng.integers(1, 30))
        xs = np.arange(x0, min(x0 + n, w))
        xs = xs[rng.random(xs.size) < 0.7]
        y, p = int(rng.integers(0, h)), int(rng.integers(0, 2))
        cols.append(np.stack([np.full(xs.size, t), xs, np.full(xs.size, y), np.full(xs.size, p)], 1))
    a = np.concatenate(cols)
    return make_events(a[:, 1], a[:, 2], a[:, 0], a[:, 3])


@pytest.fixture(scope="module")
def events():
    ev = _bursts(np.random.default_rng(5))
    assert ev["t"][-1] > 1 << 24 and len(ev) > 1000
    return ev


def _faery_file(path, ev, size=SIZE, version=None, zero_t0=False):
    faery = pytest.importorskip("faery", reason="faery (test extra) writes the RAW and DAT files")
    arr = np.zeros(len(ev), faery.EVENTS_DTYPE)
    arr["t"], arr["x"], arr["y"], arr["on"] = ev["t"], ev["x"], ev["y"], ev["p"].astype(bool)
    kw = {"version": version} if version else {}
    faery.events_stream_from_array(arr, size).to_file(str(path), zero_t0=zero_t0, **kw)
    return path


@pytest.mark.parametrize("version", ["evt2", "evt3"])
def test_a_raw_file_whose_times_start_at_zero_keeps_its_first_events(events, tmp_path, version):
    """faery's default (zero_t0): EVT3 starts with a time high of 0 and no time low, and the
    events before the first time low are events at t = 0 + ..., not unknown times."""
    path = _faery_file(tmp_path / "z.raw", events, version=version, zero_t0=True)
    got = read_events(path).events
    want = events.copy()
    want["t"] -= events["t"][0]
    np.testing.assert_array_equal(got, want)


@pytest.mark.parametrize("version, t0", [("evt2", 0x25 << 6), ("evt3", (0x25 << 12) + 100)])
def test_a_raw_file_whose_first_data_byte_is_a_percent_sign_reads_back(events, tmp_path, version, t0):
    """faery writes no '% end': its first data word follows the header lines, and when that
    word's first byte is '%' (EVT 2.0: (t >> 6) & 0xFF = 0x25, 1 start time in 256; EVT 3.0: a
    first time high whose low byte is 0x25) it was read as a header line and the file refused
    as corrupt."""
    ev = events[:500].copy()
    ev["t"] += t0 - ev["t"][0]
    path = _faery_file(tmp_path / "pct.raw", ev, version=version)
    data = path.read_bytes()
    start = 0
    while data.startswith(b"% ", start):                    # faery's header lines
        start = data.index(b"\n", start) + 1
    assert data[start:start + 1] == b"%"                    # the case: its data starts with 0x25
    np.testing.assert_array_equal(read_events(path).events, ev)


@pytest.fixture(scope="module")
def prophesee_files(tmp_path_factory, events):
    root = tmp_path_factory.mktemp("prophesee")
    return {"evt2": _faery_file(root / "rec_evt2.raw", events, version="evt2"),
            "evt3": _faery_file(root / "rec_evt3.raw", events, version="evt3"),
            "dat": _faery_file(root / "rec_td.dat", events),
            "dat1": _faery_file(root / "rec_v1.dat", events, version="dat1")}


def _info(capsys, path, *extra):
    assert main(["events", "info", "--json", "--no-progress", str(path), *extra]) == 0
    return json.loads(capsys.readouterr().out)


def _cli_error(capsys, path, *extra):
    rc = main(["events", "info", "--no-progress", str(path), *extra])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and err[0].startswith("toffe-deploy: error: ") and str(path) in err[0], err
    return err[0]


def _convert_round_trip(tmp_path, path, ev, size=SIZE):
    out = tmp_path / "converted.h5"
    assert main(["events", "convert", str(path), str(out)]) == 0
    back = read_events(out)
    np.testing.assert_array_equal(back.events, ev)
    assert back.sensor_size == size


# ------------------------------------------------------------------ Prophesee RAW / DAT

@pytest.mark.parametrize("kind", ["evt2", "evt3", "dat", "dat1"])
def test_prophesee_files_written_by_faery_read_back_exactly(prophesee_files, events, kind, capsys, tmp_path):
    path = prophesee_files[kind]
    dat = kind.startswith("dat")
    assert detect_format(path) == ("dat" if dat else "raw")
    with open_events(path) as src:
        assert src.format_name == ("dat" if dat else f"raw-{kind}")
        assert src.sensor_size == SIZE                       # from the header, no argument
        assert src.num_events == len(events)
        assert (src.t_start_us, src.t_end_us) == (int(events["t"][0]), int(events["t"][-1]) + 1)
        windows = list(src.iter_windows(2_000_000))
        got = src.read(int(events["t"][100]), int(events["t"][900]))
    np.testing.assert_array_equal(np.concatenate([w for _, w in windows]), events)
    sel = events[(events["t"] >= events["t"][100]) & (events["t"] < events["t"][900])]
    np.testing.assert_array_equal(got, sel)
    info = _info(capsys, path)
    assert info["events"] == len(events) and (info["sensor_width"], info["sensor_height"]) == SIZE
    assert info["on_events"] == int(events["p"].sum())
    _convert_round_trip(tmp_path, path, events)


@pytest.mark.parametrize("kind", ["evt2", "evt3", "dat"])
def test_decoder_state_carries_across_chunk_borders_and_seeks(prophesee_files, events, kind, monkeypatch):
    monkeypatch.setattr(fmt_prophesee, "CHUNK_BYTES", 101)     # odd: every border splits a word
    np.testing.assert_array_equal(read_events(prophesee_files[kind]).events, events)
    t = events["t"]
    with open_events(prophesee_files[kind]) as src:
        assert len(src._points) > 10                # one restart point per packet, from the open pass
        calls = []
        packets = src._packets
        monkeypatch.setattr(src, "_packets", lambda resume=None: calls.append(resume) or packets(resume))
        for t0, t1 in [(t[0], t[5]), (t[1000] + 1, t[1300]), (t[-40], t[-1] + 1), (t[-1] + 1, t[-1] + 9)]:
            np.testing.assert_array_equal(src.read(int(t0), int(t1)), events[(t >= t0) & (t < t1)])
        assert calls[0] is not None and calls[1][-1] > 0      # the later reads restart mid-file
        windows = list(src.iter_windows(1_000_000, t_start=int(t[1500])))
    np.testing.assert_array_equal(np.concatenate([w for _, w in windows]), events[t >= t[1500]])


def test_evt3_agrees_with_the_evt3_decoder(prophesee_files):
    evt3 = pytest.importorskip("evt3", reason="evt3 (test extra): an independent EVT 3.0 decoder")
    ref = evt3.decode_file(str(prophesee_files["evt3"]))
    got = read_events(prophesee_files["evt3"])
    assert got.sensor_size == (ref.sensor_width, ref.sensor_height)
    for ours, theirs in (("x", ref.x), ("y", ref.y), ("p", ref.p)):
        np.testing.assert_array_equal(got.events[ours], np.asarray(theirs).astype(got.events[ours].dtype))
    # evt3 0.4 leaves EVT3's 24-bit time wrapped (the file spans 25 s > 16.8 s); we unwrap it
    np.testing.assert_array_equal(got.events["t"] % (1 << 24), np.asarray(ref.t).astype(np.int64))
    assert got.events["t"][-1] > 1 << 24 and np.all(np.diff(got.events["t"]) >= 0)


def test_raw_header_geometry_forms():
    f = fmt_prophesee.header_geometry
    assert f({"geometry": "1280x720"}) == (1280, 720)
    assert f({"format": "EVT3;height=720;width=1280"}) == (1280, 720)
    assert f({"width": "640", "height": "480"}) == (640, 480)
    assert f({"format": "EVT3"}) is None
    assert fmt_prophesee.raw_encoding({"format": "EVT3;height=720;width=1280"}) == "evt3"
    assert fmt_prophesee.raw_encoding({"evt": "2.0"}) == "evt2"


def _header_end(path):
    with open(path, "rb") as fh:
        return fmt_prophesee.read_header(path, fh)[1]


@pytest.mark.parametrize("kind", ["evt2", "evt3", "dat"])
def test_truncated_prophesee_file_is_one_line(prophesee_files, kind, tmp_path, capsys):
    path = tmp_path / prophesee_files[kind].name
    data = prophesee_files[kind].read_bytes()
    path.write_bytes(data[:-3])                    # ends inside a word / record
    assert "truncated" in _cli_error(capsys, path)


def test_corrupt_raw_word_and_missing_geometry_are_one_line(prophesee_files, tmp_path, capsys):
    src = prophesee_files["evt3"]
    data = bytearray(src.read_bytes())
    start = _header_end(src)
    data[start + 41] = 0x90                        # word 20: type 9 does not exist in EVT 3.0
    bad = tmp_path / "bad.raw"
    bad.write_bytes(bytes(data))
    assert f"word type 0x9 at byte {start + 40} " in _cli_error(capsys, bad)
    nogeo = tmp_path / "nogeo.raw"
    nogeo.write_bytes(b"% evt 3.0\n" + src.read_bytes()[start:])
    assert "--sensor-size" in _cli_error(capsys, nogeo)
    assert read_events(nogeo, sensor_size=SIZE).sensor_size == SIZE
    noenc = tmp_path / "noenc.raw"
    noenc.write_bytes(b"% geometry 64x48\n" + src.read_bytes()[start:])
    assert "no event encoding" in _cli_error(capsys, noenc)


def test_dat_polarity_order_and_sensor_checks(prophesee_files, events, tmp_path, capsys):
    src = prophesee_files["dat"]
    data = bytearray(src.read_bytes())
    start = _header_end(src) + 2
    data[start + 8 * 5 + 7] = 0x30                  # event 5: p = 3
    bad = tmp_path / "pol.dat"
    bad.write_bytes(bytes(data))
    assert "polarity p = 3 at event 5" in _cli_error(capsys, bad)
    data = bytearray(src.read_bytes())              # event 7 earlier than event 6: reported, not unwrapped
    data[start + 8 * 7: start + 8 * 7 + 4] = np.uint32(int(events["t"][6]) - 1).tobytes()
    bad.write_bytes(bytes(data))
    assert "timestamps decrease at event 7" in _cli_error(capsys, bad)
    assert "outside the 16x16 sensor" in _cli_error(capsys, src, "--sensor-size", "16", "16")



def test_dat_whose_last_events_go_back_is_an_order_error_in_run_too(prophesee_files, events, tmp_path, capsys,
                                                                    make_bundle):
    """Its span (first event to last + 1) is negative: `run` named the order, not "no events"."""
    src = prophesee_files["dat"]
    data = bytearray(src.read_bytes())
    start = _header_end(src) + 2
    n = len(events)
    for i in range(n - 3, n):                       # the last three events before the first
        data[start + 8 * i: start + 8 * i + 4] = np.uint32(int(events["t"][0]) - 10).tobytes()
    bad = tmp_path / "lastback.dat"
    bad.write_bytes(bytes(data))
    assert f"timestamps decrease at event {n - 3}" in _cli_error(capsys, bad)
    bundle = make_bundle(tmp_path)
    assert main(["run", str(bundle.root), "--events", str(bad), "--max-windows", "2", "--no-progress",
                 "--out", str(tmp_path / "o.jsonl")]) == 2
    err = capsys.readouterr().err
    assert f"timestamps decrease at event {n - 3}" in err and "no events" not in err


def test_raw_cut_inside_its_header_is_an_error_not_an_empty_recording(prophesee_files, tmp_path, capsys):
    src = prophesee_files["evt3"]
    cut = tmp_path / "cut.raw"
    cut.write_bytes(src.read_bytes()[: _header_end(src) // 2])
    assert cut.read_bytes().startswith(b"%") and not cut.read_bytes().endswith(b"\n")
    assert "ends inside its header" in _cli_error(capsys, cut)
    assert main(["events", "convert", str(cut), str(tmp_path / "out.npz")]) == 2
    assert not (tmp_path / "out.npz").exists()

# ------------------------------------------------------------------ Metavision HDF5

def _metavision_h5(path, ev, size=SIZE, **ds_kw):
    """A file in the Metavision SDK's HDF5 layout (hdf5_event_file_writer): compound /CD/events
    (x u2, y u2, p i2, t i8) in 16384-event chunks, /CD/indexes (id u8, ts i8) every 2 ms with
    its 'offset' attribute, empty /EXT_TRIGGER/{events,indexes}, string root attributes."""
    cd = np.dtype([("x", "<u2"), ("y", "<u2"), ("p", "<i2"), ("t", "<i8")])
    idx_dt = np.dtype([("id", "<u8"), ("ts", "<i8")])
    rec = np.empty(len(ev), cd)
    for n in "xypt":
        rec[n] = ev[n]
    t0 = int(ev["t"][0])
    edges = t0 + 2000 * np.arange((int(ev["t"][-1]) - t0) // 2000 + 2)
    ids = np.searchsorted(ev["t"], edges)
    idx = np.empty(ids.shape[0], idx_dt)
    idx["id"], idx["ts"] = ids, edges - t0
    with h5py.File(path, "w") as f:
        for k, v in {"version": "1.0", "geometry": f"{size[0]}x{size[1]}", "format": "EVT3",
                     "camera_integrator_name": "Prophesee", "generation": "4.2"}.items():
            f.attrs[k] = v
        f.create_dataset("CD/events", data=rec, chunks=(16384,), maxshape=(None,), **ds_kw)
        d = f.create_dataset("CD/indexes", data=idx, chunks=(16384,), maxshape=(None,))
        d.attrs["offset"] = str(-t0)
        f.create_dataset("EXT_TRIGGER/events", shape=(0,), maxshape=(None,), chunks=(16384,),
                         dtype=np.dtype([("p", "<i2"), ("t", "<i8"), ("id", "<i2")]))
        f.create_dataset("EXT_TRIGGER/indexes", shape=(0,), maxshape=(None,), chunks=(16384,), dtype=idx_dt)
    return path


@pytest.mark.parametrize("compression", [None, "gzip"])
def test_metavision_hdf5(events, tmp_path, capsys, compression):
    path = _metavision_h5(tmp_path / "rec.hdf5", events, compression=compression)
    assert detect_format(path) == "metavision"
    with open_events(path) as src:
        assert src.format_name == "metavision" and src.sensor_size == SIZE
        assert src.attrs["metadata"]["generation"] == "4.2"
        got = src.read(int(events["t"][300]), int(events["t"][700]))
    sel = events[(events["t"] >= events["t"][300]) & (events["t"] < events["t"][700])]
    np.testing.assert_array_equal(got, sel)
    np.testing.assert_array_equal(read_events(path).events, events)
    assert _info(capsys, path)["events"] == len(events)
    _convert_round_trip(tmp_path, path, events)


@pytest.mark.parametrize("where", ["first", "last"])
@pytest.mark.parametrize("kind", ["metavision", "npy"])
def test_time_going_back_at_either_end_is_refused_not_dropped(events, tmp_path, capsys, where, kind):
    """A file whose time goes back at its second event or at its last: the search for the
    file's range skipped those events, so `events info` counted 2 fewer and `events convert`
    wrote a copy without them, exit 0. Now the whole file is read and the decrease named."""
    ev = events[:400].copy()
    if where == "first":
        ev["t"][1] = ev["t"][0] - 1
    else:
        ev["t"][-1] = ev["t"][-2] - 100
    path = (_metavision_h5(tmp_path / "back.hdf5", ev) if kind == "metavision"
            else tmp_path / "back.npy")
    if kind == "npy":
        np.save(path, ev)
    at = 1 if where == "first" else len(ev) - 1
    assert f"timestamps decrease at event {at}" in _cli_error(capsys, path)
    with pytest.raises(InputError, match="timestamps decrease"):
        read_events(path)
    assert main(["events", "convert", str(path), str(tmp_path / "out.h5")]) == 2
    assert not (tmp_path / "out.h5").exists()


def test_metavision_ecf_without_the_plugin_names_the_filter(events, tmp_path, capsys):
    if h5py.h5z.filter_avail(0x8ECF):
        pytest.skip("the ECF plugin is installed here")
    path = _metavision_h5(tmp_path / "ecf.hdf5", events, compression=0x8ECF, allow_unknown_filter=True)
    err = _cli_error(capsys, path)
    assert "ECF (Prophesee) filter" in err and "hdf5_ecf" in err


# ------------------------------------------------------------------ ROS bags

def _ros_writer(path, ros1: bool, mcap: bool = False):
    if ros1:
        from rosbags.rosbag1 import Writer
        return Writer(path)
    from rosbags.rosbag2 import StoragePlugin, Writer
    return Writer(path, version=9, storage_plugin=StoragePlugin.MCAP if mcap else StoragePlugin.SQLITE3)


def _write_bag(path, msgtype, messages, ros1: bool, topic="/event_camera/events", mcap=False):
    """Write (stamp_ns, message) pairs with rosbags' own writer and serializer."""
    from toffe_deploy.events.fmt_rosbag import typestore

    ts = typestore("ROS1_NOETIC" if ros1 else "ROS2_HUMBLE")
    with _ros_writer(path, ros1, mcap) as w:
        conn = w.add_connection(topic, msgtype, typestore=ts)
        for stamp, make in messages:
            msg = make(ts)
            w.write(conn, stamp, ts.serialize_ros1(msg, msgtype) if ros1 else ts.serialize_cdr(msg, msgtype))
    return path


def _header(ts, t_us, seq):
    T, H = ts.types["builtin_interfaces/msg/Time"], ts.types["std_msgs/msg/Header"]
    stamp = T(sec=t_us // 1_000_000, nanosec=t_us % 1_000_000 * 1000)
    return H(seq=seq, stamp=stamp, frame_id="cam") if "seq" in H.__dataclass_fields__ \
        else H(stamp=stamp, frame_id="cam")


def _dvs_messages(ev, per_msg=700):
    def make(part, k):
        def f(ts):
            T, E = ts.types["builtin_interfaces/msg/Time"], ts.types["dvs_msgs/msg/Event"]
            evs = [E(x=int(e["x"]), y=int(e["y"]), ts=T(sec=int(e["t"]) // 1_000_000,
                                                         nanosec=int(e["t"]) % 1_000_000 * 1000),
                     polarity=bool(e["p"])) for e in part]
            return ts.types["dvs_msgs/msg/EventArray"](header=_header(ts, int(part["t"][0]), k),
                                                        height=SIZE[1], width=SIZE[0], events=evs)
        return f
    return [(int(ev["t"][k]) * 1000, make(ev[k:k + per_msg], k)) for k in range(0, len(ev), per_msg)]


def _packet_messages(chunks, encoding, time_bases, msgtype="event_camera_msgs/msg/EventPacket"):
    def make(data, k, tb):
        def f(ts):
            return ts.types[msgtype](
                header=_header(ts, tb // 1000, k), height=SIZE[1], width=SIZE[0], seq=k, time_base=tb,
                encoding=encoding, is_bigendian=False, events=np.frombuffer(data, np.uint8))
        return f
    return [(10 ** 9 + k, make(d, k, tb)) for k, (d, tb) in enumerate(zip(chunks, time_bases))]


@pytest.mark.parametrize("ros1, mcap", [(True, False), (False, False), (False, True)],
                         ids=["ros1", "ros2-sqlite3", "ros2-mcap"])
def test_dvs_msgs_bag(events, tmp_path, capsys, ros1, mcap):
    pytest.importorskip("rosbags")
    ev = events[:2000]
    path = _write_bag(tmp_path / ("dvs.bag" if ros1 else "dvs_bag"), "dvs_msgs/msg/EventArray",
                      _dvs_messages(ev), ros1, mcap=mcap)
    assert detect_format(path) == "rosbag"
    if not ros1:                                   # the bag's storage file names the bag too
        storage = next(path.glob("*.mcap" if mcap else "*.db3"))
        assert detect_format(storage) == "rosbag"
        np.testing.assert_array_equal(read_events(storage).events, ev)
    with open_events(path) as src:
        assert src.sensor_size == SIZE and src.attrs["msgtype"] == "dvs_msgs/msg/EventArray"
        np.testing.assert_array_equal(src.read_all().events, ev)
    info = _info(capsys, path)
    assert info["format"] == "rosbag" and info["events"] == len(ev)
    assert main(["events", "info", "--no-progress", str(path)]) == 0
    assert "topic:           /event_camera/events (dvs_msgs/msg/EventArray)" in capsys.readouterr().out
    _convert_round_trip(tmp_path, path, ev)
    if ros1:         # found by its content under any name: `rosbag record` killed leaves NAME.bag.active
        active = tmp_path / "rec.bag.active"
        active.write_bytes(path.read_bytes())
        assert detect_format(active) == "rosbag"
        np.testing.assert_array_equal(read_events(active).events, ev)


def test_dvs_msgs_deserialized_when_the_byte_layout_is_not_the_expected_one(events, tmp_path, monkeypatch):
    pytest.importorskip("rosbags")
    from toffe_deploy.events import fmt_rosbag

    ev = events[:1000]
    path = _write_bag(tmp_path / "dvs_bag", "dvs_msgs/msg/EventArray", _dvs_messages(ev), False)
    monkeypatch.setattr(fmt_rosbag, "_dvs_raw", lambda raw, is2: None)   # the object-per-event path
    np.testing.assert_array_equal(read_events(path).events, ev)


@pytest.mark.parametrize("ros1, msgtype", [(True, "event_camera_msgs/msg/EventPacket"),
                                           (False, "event_camera_msgs/msg/EventPacket"),
                                           (False, "event_array_msgs/msg/EventArray")],
                         ids=["ros1", "ros2", "ros2-event_array_msgs"])
def test_event_packet_mono_bag(events, tmp_path, ros1, msgtype):
    pytest.importorskip("rosbags")
    chunks, bases = [], []
    # one message per 900 events or 4 s, whichever first: dt is 32 bits of nanoseconds
    starts = [0]
    while starts[-1] < len(events):
        k = starts[-1]
        starts.append(min(k + 900, int(np.searchsorted(events["t"], events["t"][k] + 4_000_000))))
    for k0, k1 in zip(starts, starts[1:]):
        part = events[k0:k1]
        tb = int(part["t"][0]) * 1000                 # ns
        dt = part["t"].astype(np.uint64) * 1000 - np.uint64(tb)
        w = dt | part["x"].astype(np.uint64) << np.uint64(32) | part["y"].astype(np.uint64) << np.uint64(48) \
            | part["p"].astype(np.uint64) << np.uint64(63)
        chunks.append(w.astype("<u8").tobytes())
        bases.append(tb)
    path = _write_bag(tmp_path / ("mono.bag" if ros1 else "mono_bag"), msgtype,
                      _packet_messages(chunks, "mono", bases, msgtype), ros1)
    with open_events(path) as src:
        assert src.attrs["encoding"] == "mono" and src.sensor_size == SIZE
        np.testing.assert_array_equal(src.read_all().events, events)


@pytest.mark.parametrize("ros1", [True, False], ids=["ros1", "ros2"])
def test_event_packet_evt3_bag(prophesee_files, events, tmp_path, ros1):
    """The EVT 3.0 stream of a faery RAW file, cut into packets at arbitrary byte borders."""
    pytest.importorskip("rosbags")
    raw = prophesee_files["evt3"]
    data = raw.read_bytes()[_header_end(raw):]
    cuts = [0, 101, 2000, 2001, 7777, len(data)]
    chunks = [data[a:b] for a, b in zip(cuts, cuts[1:])]
    path = _write_bag(tmp_path / ("evt3.bag" if ros1 else "evt3_bag"), "event_camera_msgs/msg/EventPacket",
                      _packet_messages(chunks, "evt3", [0] * len(chunks)), ros1)
    np.testing.assert_array_equal(read_events(path).events, events)


def test_bag_errors_are_one_line(events, tmp_path, capsys):
    pytest.importorskip("rosbags")
    good = _write_bag(tmp_path / "dvs.bag", "dvs_msgs/msg/EventArray", _dvs_messages(events[:1500]), True)
    cut = tmp_path / "cut.bag"
    cut.write_bytes(good.read_bytes()[: good.stat().st_size // 2])
    assert "ROS bag" in _cli_error(capsys, cut)
    other = _write_bag(tmp_path / "other.bag", "std_msgs/msg/String",
                       [(1, lambda ts: ts.types["std_msgs/msg/String"](data="hi"))], True, topic="/chatter")
    assert "no event topic" in _cli_error(capsys, other) and "/chatter" in _cli_error(capsys, other)
    trig = _write_bag(tmp_path / "trig_bag", "event_camera_msgs/msg/EventPacket",
                      _packet_messages([b"\0" * 16], "trigger", [0]), False)
    assert "encoding 'trigger' is not supported" in _cli_error(capsys, trig)
    broken = tmp_path / "broken_bag"
    shutil.copytree(_write_bag(tmp_path / "ok_bag", "dvs_msgs/msg/EventArray", _dvs_messages(events[:800]), False),
                    broken)
    next(broken.glob("*.db3")).write_bytes(b"not sqlite" * 10)
    assert "ROS bag" in _cli_error(capsys, broken)
    empty = _write_bag(tmp_path / "empty.bag", "dvs_msgs/msg/EventArray", [], True)   # the topic, no message
    assert "has no messages" in _cli_error(capsys, empty)


def test_input_error_names_the_file(prophesee_files, tmp_path):
    path = tmp_path / "short.raw"
    path.write_bytes(prophesee_files["evt2"].read_bytes()[:-1])
    with pytest.raises(InputError) as ei:
        read_events(path)
    assert ei.value.path == str(path)


def test_metavision_layout_errors_are_one_line(events, tmp_path, capsys):
    bad_p = _metavision_h5(tmp_path / "pol.hdf5", events[:500])
    with h5py.File(bad_p, "r+") as f:
        rec = f["CD/events"][()]
        rec["p"][9] = 2
        f["CD/events"][...] = rec
    assert "polarity p = 2 at event 9" in _cli_error(capsys, bad_p)
    flat = tmp_path / "flat.hdf5"
    with h5py.File(flat, "w") as f:
        f.attrs["geometry"] = "64x48"
        f["CD/events"] = np.zeros((10, 4), np.int64)
    assert "compound dataset with fields x, y, p, t" in _cli_error(capsys, flat)
    nogeo = _metavision_h5(tmp_path / "nogeo.hdf5", events[:100])
    with h5py.File(nogeo, "r+") as f:
        del f.attrs["geometry"]
    assert "--sensor-size" in _cli_error(capsys, nogeo)
    cut = tmp_path / "cut.hdf5"
    cut.write_bytes(_metavision_h5(tmp_path / "whole.hdf5", events).read_bytes()[:3000])
    assert "HDF5" in _cli_error(capsys, cut)


def test_prophesee_files_without_their_extension_are_recognised_by_header(prophesee_files, tmp_path):
    for kind, want in (("evt3", "raw"), ("evt2", "raw"), ("dat", "dat")):
        path = tmp_path / f"recording_{kind}"
        shutil.copy(prophesee_files[kind], path)
        assert detect_format(path) == want
    text = tmp_path / "notes"
    text.write_bytes(b"% just a comment\nplain text\n")
    with pytest.raises(InputError, match="unknown event file format"):
        read_events(text)


def test_evt_time_high_wraps_only_past_half_its_range():
    """A time-high drop of more than half the counter's range is a wrap; a smaller one (a glitch,
    a camera clock reset, a jump back of 100 ms) stays a drop that the order check reports. Under
    the old 10-step rule a 24-step (100 ms) EVT3 drop read as 16.8 s later, silently."""
    def words(dtype, *w):
        return np.array(w, dtype).tobytes()

    TH, TL, Y, X = 0x8000, 0x6000, 0x0000, 0x2000
    dec = fmt_prophesee.Evt3Decoder()
    x, y, t, p = dec.feed(words("<u2", X | 1, TH | 100, TL | 7, Y | 3, X | 0x800 | 5,   # before the time base: dropped
                                TH | 95, X | 6,                                 # a 5-step drop: a glitch
                                TH | 76, X | 7,                                 # 100 ms back: a drop, not a wrap
                                TH | 4000, X | 8, TH | 50, X | 9))              # 4000 -> 50: a wrap (~200 ms on)
    assert x.tolist() == [5, 6, 7, 8, 9] and y.tolist() == [3] * 5 and p.tolist() == [1, 0, 0, 0, 0]
    assert t.tolist() == [100 << 12 | 7, 95 << 12 | 7, 76 << 12 | 7, 4000 << 12 | 7, (4096 + 50) << 12 | 7]
    with pytest.raises(ValueError, match="word type 0x9 at byte 2"):
        fmt_prophesee.Evt3Decoder().feed(words("<u2", TH, 0x9000))
    with pytest.raises(ValueError, match=r"ends inside an EVT 3\.0 word \(1 trailing byte: truncated\?\)"):
        dec = fmt_prophesee.Evt3Decoder()
        dec.feed(words("<u2", TH | 1) + b"\x01")
        dec.finish()

    def evt2(th, *cd):                       # a time high, then CD_ON events at x = cd, y = 2, t low 3
        return [0x80000000 | th] + [0x10000000 | 3 << 22 | c << 11 | 2 for c in cd]

    reset = (5_010_123 >> 6) & 0x0FFFFFFF    # a camera whose clock restarts at ~0 after 5.01 s
    x, _, t, _ = fmt_prophesee.Evt2Decoder().feed(words("<u4", *evt2(reset, 1), *evt2(2, 2),
                                                        *evt2((1 << 28) - 5, 3), *evt2(4, 4)))
    assert x.tolist() == [1, 2, 3, 4]
    assert t.tolist() == [reset << 6 | 3, 2 << 6 | 3, ((1 << 28) - 5) << 6 | 3, ((1 << 28) + 4) << 6 | 3]


def test_prophesee_files_are_known_by_their_header_not_their_extension(prophesee_files, events, tmp_path):
    """README: formats by content first. An EVT3 RAW named .dat and a DAT named .raw read as
    what they are (they were decoded as the other and refused)."""
    for kind, fake in (("evt3", "rec.dat"), ("dat", "rec.raw")):
        path = tmp_path / fake
        shutil.copy(prophesee_files[kind], path)
        assert detect_format(path) == ("raw" if kind == "evt3" else "dat")
        np.testing.assert_array_equal(read_events(path).events, events)


def test_a_bag_with_a_bad_event_late_in_it_fails_before_run_writes(events, tmp_path, capsys, make_bundle):
    """A sequential format's bad coordinates were found only by the read that reached them:
    `run` had replaced --out with the windows before (the array formats check the whole file when
    opened). The metadata pass, which reads the whole file at open, now checks every value."""
    pytest.importorskip("rosbags")
    ev = events[:900].copy()
    ev["x"][700] = SIZE[0] + 5                       # in the third message of 300
    path = _write_bag(tmp_path / "bad.bag", "dvs_msgs/msg/EventArray", _dvs_messages(ev, 300), True)
    with pytest.raises(InputError, match=f"x = {SIZE[0] + 5} outside the 64x48 sensor at event 700"):
        open_events(path)
    out = tmp_path / "o.jsonl"
    out.write_text("earlier results\n")
    assert main(["run", str(make_bundle(tmp_path).root), "--events", str(path), "--out", str(out), "--no-progress"]) == 2
    assert "outside the 64x48 sensor at event 700" in capsys.readouterr().err
    assert out.read_text() == "earlier results\n"


def test_bag_whose_times_go_back_mid_file_is_an_order_error_not_a_short_recording(events, tmp_path, capsys,
                                                                                   make_bundle):
    """A sequential format's metadata pass did not check order; its span ended at the last event
    (+ 1), and reading stopped at the first message starting past it, before the message going back
    in time: info, convert and run then dropped every event after it with exit 0. The pass now
    finds the decrease and open_events names it: `run` had replaced --out with the windows before
    it first."""
    pytest.importorskip("rosbags")
    ev = events[:900].copy()                         # 3 messages of 300; the camera's clock restarts
    ev["t"][600:] = 100 + np.arange(300)             # in the third, before the second's first event
    assert ev["t"][-1] < ev["t"][300]
    messages = [(10 ** 9 + k, make) for k, (_, make) in enumerate(_dvs_messages(ev, 300))]   # logged in order
    path = _write_bag(tmp_path / "back.bag", "dvs_msgs/msg/EventArray", messages, True)
    assert "timestamps decrease at event 600" in _cli_error(capsys, path)
    assert main(["events", "convert", str(path), str(tmp_path / "out.npz")]) == 2
    assert "timestamps decrease at event 600" in capsys.readouterr().err
    assert not (tmp_path / "out.npz").exists()
    with pytest.raises(InputError, match="timestamps decrease at event 600"):
        open_events(path)
    with open_events(path, sort=True) as src:       # sorted on request: every event, in time order
        assert src.num_events == len(ev) and np.all(np.diff(src.read_all().events["t"]) >= 0)
    out = tmp_path / "o.jsonl"
    out.write_text("earlier results\n")
    assert main(["run", str(make_bundle(tmp_path).root), "--events", str(path), "--out", str(out), "--no-progress"]) == 2
    assert "timestamps decrease at event 600" in capsys.readouterr().err
    assert out.read_text() == "earlier results\n"
