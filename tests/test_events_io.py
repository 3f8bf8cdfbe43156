"""Event readers and the writer: round trips, every format we read, streaming windows."""
import h5py
import numpy as np
import pytest

from toffe_deploy.cli import main
from toffe_deploy.events import EVENT_DTYPE, make_events, open_events, read_events, write_events_h5, write_events_npz
from toffe_deploy.events.fmt_toffe import ToffeH5Source, ms_index
from toffe_deploy.events.io import detect_format

SIZE = (32, 24)


def _gt(n_obj=2, period=50, duration=20_000):
    t = np.repeat(np.arange(0, duration, period), n_obj)
    k = t.shape[0]
    oid = np.tile(np.arange(n_obj), k // n_obj)
    return {"t": t, "object_id": oid, "x": np.linspace(0, 31, k), "y": np.linspace(0, 23, k),
            "direction": np.full(k, 0.5), "speed": np.full(k, 20.0), "speed_bin": np.full(k, 2),
            "visible": np.ones(k, bool)}


def test_h5_round_trip_with_ground_truth_and_attrs(tmp_path, random_events):
    ev = random_events(3000, SIZE, 20_000, t0=100)
    gt = _gt()
    attrs = {"objects": [{"id": 0, "shape": "star"}, {"id": 1, "shape": "circle"}],
             "generator": {"fov_deg": 60.0}, "seed": 7}
    path = tmp_path / "seq.h5"
    write_events_h5(path, ev, SIZE, ground_truth=gt, attrs=attrs)
    assert detect_format(path) == "toffe-events"
    with open_events(path) as src:
        assert src.sensor_size == SIZE and src.num_events == 3000
        assert src.t_start_us == 0                       # ground truth starts before the first event
        assert src.t_end_us == max(int(ev["t"][-1]) + 1, int(gt["t"].max()) + 1)
        assert src.attrs == attrs
        got = src.ground_truth
        assert set(got) == set(gt) | {"speed_px_ms"}   # derived: the file predates the column
        assert got["t"].dtype == np.int64 and got["object_id"].dtype == np.int32
        assert got["x"].dtype == np.float32 and got["speed_bin"].dtype == np.int8
        assert got["visible"].dtype == np.bool_
        np.testing.assert_allclose(got["x"], gt["x"].astype(np.float32))
        np.testing.assert_array_equal(got["t"], gt["t"])
    back = read_events(path)
    assert back.events.dtype == EVENT_DTYPE and back.sensor_size == SIZE
    np.testing.assert_array_equal(back.events, ev)


def test_h5_layout_is_chunked_compressed_and_indexed(tmp_path, random_events):
    ev = random_events(5000, SIZE, 50_000, t0=1234)
    path = tmp_path / "e.h5"
    write_events_h5(path, ev, SIZE, t_range=(0, 60_000))
    with h5py.File(path, "r") as f:
        assert f.attrs["format"] == "toffe-events" and f.attrs["format_version"] == 1
        assert (f.attrs["sensor_width"], f.attrs["sensor_height"]) == SIZE
        for name in "xytp":
            assert f["events"][name].chunks is not None and f["events"][name].compression == "gzip"
        idx = f["events/ms_to_idx"][()]
        t0 = f["events/ms_to_idx"].attrs["index_t0_us"]
    t = ev["t"]
    for m in range(idx.shape[0]):
        assert idx[m] == np.searchsorted(t, t0 + 1000 * m)   # first event at or after each ms
    with open_events(path) as src:
        assert (src.t_start_us, src.t_end_us) == (0, 60_000)


def test_npz_round_trip(tmp_path, random_events):
    ev = random_events(500, SIZE)
    path = tmp_path / "e.npz"
    write_events_npz(path, ev, SIZE)
    back = read_events(path)
    np.testing.assert_array_equal(back.events, ev)
    assert back.sensor_size == SIZE


def test_npz_writer_is_numpys_layout_and_closes_its_zip_when_interrupted(tmp_path):
    """fileio.savez_compressed writes what np.savez_compressed writes (np.load reads the same
    arrays) and closes its zip on an exception mid-write: numpy's left it open, and after a
    Ctrl-C in `events convert OUT.npz` its __del__ wrote into the closed buffer (a traceback
    under "interrupted")."""
    import gc
    import io
    import sys

    from toffe_deploy.fileio import savez_compressed

    arrays = {"x": np.arange(7, dtype=np.uint16), "t": np.arange(7, dtype=np.int64) * 3, "b": np.eye(2, dtype=bool)}
    savez_compressed(tmp_path / "ours.npz", **arrays)
    np.savez_compressed(tmp_path / "numpy.npz", **arrays)
    with np.load(tmp_path / "ours.npz") as ours, np.load(tmp_path / "numpy.npz") as ref:
        assert ours.files == ref.files
        assert all(np.array_equal(ours[k], ref[k]) and ours[k].dtype == ref[k].dtype for k in ref.files)

    class Interrupting:
        def __array__(self, dtype=None, copy=None):
            raise KeyboardInterrupt

    unraisable, hook = [], sys.unraisablehook
    sys.unraisablehook = unraisable.append
    try:
        buf = io.BytesIO()
        with pytest.raises(KeyboardInterrupt) as info:     # its traceback holds the writer's frames,
            savez_compressed(buf, x=arrays["x"], y=Interrupting())
        buf.close()                                        # as the CLI's did while it unwound
        del info
        gc.collect()
    finally:
        sys.unraisablehook = hook
    assert unraisable == []


def test_convert_round_trip_h5_to_npz_to_h5(tmp_path, random_events):
    from toffe_deploy.cli import main

    ev = random_events(800, SIZE)
    write_events_h5(tmp_path / "a.h5", ev, SIZE, ground_truth=_gt(), attrs={"seed": 3})
    assert main(["events", "convert", str(tmp_path / "a.h5"), str(tmp_path / "b.npz")]) == 0
    assert main(["events", "convert", str(tmp_path / "b.npz"), str(tmp_path / "c.h5")]) == 0
    assert main(["events", "convert", str(tmp_path / "a.h5"), str(tmp_path / "d.h5")]) == 0
    np.testing.assert_array_equal(read_events(tmp_path / "c.h5").events, ev)
    with open_events(tmp_path / "d.h5") as src:            # ground truth and attrs carried over
        assert src.attrs["seed"] == 3 and src.ground_truth["object_id"].shape == _gt()["object_id"].shape
    assert main(["events", "convert", str(tmp_path / "a.h5"), str(tmp_path / "b.npz")]) == 2   # exists


@pytest.mark.parametrize("layout", ["structured", "n_by_4"])
def test_npy_reader_memory_maps(tmp_path, random_events, layout):
    ev = random_events(400, SIZE)
    arr = ev if layout == "structured" else np.stack([ev[n] for n in "xytp"], 1).astype(np.int64)
    path = tmp_path / "e.npy"
    np.save(path, arr)
    with open_events(path, sensor_size=SIZE) as src:
        assert src.format_name == "npy"
        np.testing.assert_array_equal(src.read_all().events, ev)
    inferred = open_events(path)                       # no size anywhere: max + 1, and said so
    assert inferred.sensor_size == (int(ev["x"].max()) + 1, int(ev["y"].max()) + 1)
    assert inferred.attrs["sensor_size_inferred"] is True


def test_dsec_reader_uses_offset_and_default_size(tmp_path, random_events):
    ev = random_events(2000, SIZE, 30_000, t0=5_000)
    off = 1_600_000_000_000_000
    path = tmp_path / "events.h5"
    with h5py.File(path, "w") as f:
        for n in "xyp":
            f.create_dataset(f"events/{n}", data=ev[n])
        f.create_dataset("events/t", data=ev["t"].astype(np.uint32))
        f.create_dataset("t_offset", data=np.int64(off))
        f.create_dataset("ms_to_idx", data=ms_index(ev["t"], 0).astype(np.uint64))
    with open_events(path) as src:
        assert src.format_name == "dsec" and src.sensor_size == (640, 480)
        assert src.attrs["sensor_size_default"] == "DSEC"        # the file records none: said so (events info, run)
        assert src.t_start_us == off + ev["t"][0]
        got = src.read(off + 10_000, off + 20_000)
    sel = ev[(ev["t"] >= 10_000) & (ev["t"] < 20_000)]
    np.testing.assert_array_equal(got["t"] - off, sel["t"])
    np.testing.assert_array_equal(got[["x", "y", "p"]], sel[["x", "y", "p"]])
    with open_events(path, sensor_size=(346, 260)) as src:
        assert "sensor_size_default" not in src.attrs
    from toffe_deploy.events.info import format_info, summarize
    assert "(DSEC's default: the file records none; pass --sensor-size WxH)" in format_info(
        summarize(path, progress=False))


def test_dsec_reader_reads_blosc_compressed_files_as_dsec_ships_them(tmp_path, random_events):
    """DSEC's events.h5 are Blosc-compressed: hdf5plugin (a dependency) writes such a file here
    and the reader opens it with no HDF5_PLUGIN_PATH set by hand."""
    import hdf5plugin                                 # a dependency: no skip when it is missing
    ev = random_events(3000, SIZE, 40_000)
    path = tmp_path / "events.h5"
    blosc = hdf5plugin.Blosc(cname="zstd", clevel=5, shuffle=hdf5plugin.Blosc.SHUFFLE)
    with h5py.File(path, "w") as f:
        for n in "xyp":
            f.create_dataset(f"events/{n}", data=ev[n], chunks=(1024,), **blosc)
        f.create_dataset("events/t", data=ev["t"].astype(np.uint32), chunks=(1024,), **blosc)
        f.create_dataset("t_offset", data=np.int64(0))
        f.create_dataset("ms_to_idx", data=ms_index(ev["t"], 0).astype(np.uint64))
        assert f["events/t"].id.get_create_plist().get_filter(0)[0] == 32001      # Blosc
    assert main(["events", "info", "--no-progress", str(path)]) == 0
    with open_events(path) as src:
        assert src.format_name == "dsec"
        np.testing.assert_array_equal(src.read_all().events, ev)


def test_mvsec_reader_maps_seconds_and_polarity(tmp_path, random_events):
    ev = random_events(1000, SIZE)
    t_s = 1_504_000_000.0 + ev["t"] / 1e6
    path = tmp_path / "outdoor_day1_data.hdf5"
    with h5py.File(path, "w") as f:
        f.create_dataset("davis/left/events",
                         data=np.stack([ev["x"], ev["y"], t_s, ev["p"] * 2.0 - 1.0], 1))
    back = read_events(path)
    assert back.sensor_size == (346, 260)
    np.testing.assert_array_equal(back.events["p"], ev["p"])          # -1 -> 0, +1 -> 1
    np.testing.assert_array_equal(back.events["t"] - 1_504_000_000_000_000, ev["t"])
    assert read_events(path, sensor_size=SIZE).sensor_size == SIZE


def test_aedat4_reader_on_a_file_written_by_dv_processing(tmp_path, random_events):
    dv = pytest.importorskip("dv_processing", reason="dv-processing (test extra) writes the AEDAT4 file")
    ev = random_events(300, SIZE, 20_000, t0=1_000)
    path = tmp_path / "rec.aedat4"
    writer = dv.io.MonoCameraWriter(str(path), dv.io.MonoCameraWriter.EventOnlyConfig("test", SIZE))
    store = dv.EventStore()
    for e in ev:                         # a few hundred events: the writer's API is per event
        store.push_back(int(e["t"]), int(e["x"]), int(e["y"]), bool(e["p"]))
    writer.writeEvents(store)
    del writer                           # closes and finalizes the file
    with open_events(path) as src:
        assert src.format_name == "aedat4" and src.sensor_size == SIZE
        assert src.num_events == 300
        windows = list(src.iter_windows(1_000))
    np.testing.assert_array_equal(np.concatenate([w for _, w in windows]), ev)
    np.testing.assert_array_equal(read_events(path).events, ev)


def test_iter_windows_streams_in_bounded_chunks_and_yields_empty_windows(tmp_path, random_events):
    a = random_events(700, SIZE, 10_000, t0=0)
    b = random_events(700, SIZE, 10_000, t0=30_000)     # 20 ms gap: empty windows in between
    ev = np.concatenate([a, b])
    path = tmp_path / "gap.h5"
    write_events_h5(path, ev, SIZE)

    class Recording(ToffeH5Source):      # the real reader, noting how much it reads at once
        sizes = []

        def _read_index(self, i0, i1):
            self.sizes.append(i1 - i0)
            return super()._read_index(i0, i1)

    with h5py.File(path, "r") as f:
        src = Recording(path, f)
        src.chunk_events = 64
        windows = list(src.iter_windows(700))
        assert max(Recording.sizes) <= 64
        assert sum(Recording.sizes) == ev.shape[0]       # every event read once
    t0s = [t0 for t0, _ in windows]
    assert t0s == list(range(int(ev["t"][0]), int(ev["t"][-1]) + 1, 700))
    for t0, w in windows:
        np.testing.assert_array_equal(w, ev[(ev["t"] >= t0) & (ev["t"] < t0 + 700)])
    empties = [w for t0, w in windows if 11_000 < t0 < 29_000]
    assert empties and all(w.shape == (0,) and w.dtype == EVENT_DTYPE for w in empties)


def test_read_seeks_any_range(tmp_path, random_events):
    ev = random_events(3000, SIZE, 100_000, t0=0)
    path = tmp_path / "e.h5"
    write_events_h5(path, ev, SIZE)
    rng = np.random.default_rng(5)
    with open_events(path) as src:
        for _ in range(20):
            t0 = int(rng.integers(-2000, 110_000))
            t1 = t0 + int(rng.integers(0, 5000))
            np.testing.assert_array_equal(src.read(t0, t1), ev[(ev["t"] >= t0) & (ev["t"] < t1)])


def test_sort_true_sorts_stably(tmp_path):
    ev = make_events([1, 2, 3, 4], [0, 0, 0, 0], [30, 10, 20, 10], [1, 0, 1, 1])
    path = tmp_path / "unsorted.npz"
    np.savez(path, x=ev["x"], y=ev["y"], t=ev["t"], p=ev["p"], sensor_size=np.array(SIZE))
    back = read_events(path, sort=True)
    assert back.events["t"].tolist() == [10, 10, 20, 30]
    assert back.events["x"].tolist() == [2, 4, 3, 1]          # ties keep file order


def test_empty_file_is_valid(tmp_path):
    path = tmp_path / "empty.h5"
    write_events_h5(path, np.empty(0, EVENT_DTYPE), SIZE, t_range=(0, 2000))
    with open_events(path) as src:
        assert src.num_events == 0
        windows = list(src.iter_windows(500))
    assert [t0 for t0, _ in windows] == [0, 500, 1000, 1500]
    assert all(w.shape == (0,) for _, w in windows)


def test_count_before_is_searchsorted_on_the_times_for_any_buffer_and_time():
    """events.core.count_before (the windows' cut: a growing prefix, not a copy of the whole
    unaligned time column) = np.searchsorted(events["t"], t, "left") on small, large, empty and
    duplicate-time buffers, times before, inside, on and after them."""
    import numpy as np

    from toffe_deploy.events.core import count_before, make_events

    rng = np.random.default_rng(3)
    for n in (0, 1, 5, 4095, 4096, 4097, 20000, 70000):
        t = np.sort(rng.integers(0, 1000, n)) * 7
        ev = make_events(np.zeros(n), np.zeros(n), t, np.zeros(n))
        for q in (-1, 0, 3, 7, 3500, 6993, 6999, 7000, 10**9, *(t[rng.integers(0, n, 5)] if n else ())):
            assert count_before(ev, int(q)) == int(np.searchsorted(t, q, side="left")), (n, q)


def test_copy_events_is_an_independent_writable_copy_of_a_window():
    """events.core.copy_events (the windows' copy as bytes: numpy copies an unaligned structured
    array field by field, 10x slower) equals the slice, owns its memory and writes nowhere else;
    a strided view is copied too."""
    import numpy as np

    from toffe_deploy.events.core import EVENT_DTYPE, copy_events, make_events

    rng = np.random.default_rng(4)
    n = 3000
    buf = make_events(rng.integers(0, 640, n), rng.integers(0, 480, n), np.sort(rng.integers(0, 10**6, n)),
                      rng.integers(0, 2, n))
    for part in (buf[100:2300], buf[:0], buf[::3]):
        out = copy_events(part)
        assert out.dtype == EVENT_DTYPE and np.array_equal(out, part)
        if out.size:
            assert not np.shares_memory(out, buf) and out.flags.writeable
            out["x"][0] = 999
            assert part["x"][0] != 999
