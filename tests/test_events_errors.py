"""Every bad-input case: a real file on disk, an InputError naming it, and from the CLI one line
on stderr with exit code 2 (no traceback)."""
import re

import h5py
import numpy as np
import pytest

from toffe_deploy.cli import main
from toffe_deploy.errors import InputError
from toffe_deploy.events import make_events, open_events, read_events, write_events_h5

SIZE = (32, 24)


def _cli_error(capsys, path, *extra):
    rc = main(["events", "info", "--no-progress", str(path), *extra])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2
    assert len(err) == 1 and err[0].startswith("toffe-deploy: error: ") and str(path) in err[0]
    assert "Traceback" not in err[0]
    return err[0]


def _read_fails(path, match, **kw):
    with pytest.raises(InputError, match=match) as ei:
        read_events(path, **kw)
    assert ei.value.path == str(path)


def _npz(path, x, y, t, p, size=SIZE):
    np.savez(path, x=np.asarray(x), y=np.asarray(y), t=np.asarray(t), p=np.asarray(p), sensor_size=np.array(size))


def test_missing_file(tmp_path, capsys):
    _read_fails(tmp_path / "nope.h5", "no such file")
    assert "no such file" in _cli_error(capsys, tmp_path / "nope.h5")


def test_unknown_format(tmp_path, capsys):
    path = tmp_path / "events.csv"
    path.write_text("x,y,t,p\n1,2,3,1\n")
    _read_fails(path, "unknown event file format")
    _cli_error(capsys, path)


@pytest.mark.parametrize("version", ["2.0", "3.1"])
def test_old_aedat_says_which_aedat_it_is(tmp_path, capsys, version):
    path = tmp_path / "old.aedat"
    path.write_bytes(f"#!AER-DAT{version}\r\n#Format: RAW\r\n".encode() + bytes(64))
    _read_fails(path, re.escape(f"AEDAT {version} (jAER / cAER) is not read"))
    _cli_error(capsys, path)


def test_garbage_with_a_known_extension(tmp_path, capsys):
    path = tmp_path / "events.h5"
    path.write_bytes(b"this is not hdf5 at all" * 10)
    _read_fails(path, "does not look like a .h5 file")
    _cli_error(capsys, path)


def test_truncated_hdf5(tmp_path, capsys, random_events):
    path = tmp_path / "cut.h5"
    write_events_h5(path, random_events(20_000, SIZE, 100_000), SIZE)
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    _read_fails(path, "truncated or corrupt")
    _cli_error(capsys, path)


def test_corrupt_npz_and_npy(tmp_path, capsys, random_events):
    ev = random_events(500, SIZE)
    npz = tmp_path / "e.npz"
    np.savez_compressed(npz, x=ev["x"], y=ev["y"], t=ev["t"], p=ev["p"])
    data = npz.read_bytes()
    npz.write_bytes(data[: len(data) - 200])
    _read_fails(npz, "truncated or corrupt")
    _cli_error(capsys, npz)
    npy = tmp_path / "e.npy"
    np.save(npy, ev)
    data = npy.read_bytes()
    npy.write_bytes(data[: len(data) // 2])
    _read_fails(npy, "truncated or corrupt")


def test_truncated_aedat4(tmp_path, capsys, random_events):
    dv = pytest.importorskip("dv_processing", reason="dv-processing (test extra) writes the AEDAT4 file")
    path = tmp_path / "rec.aedat4"
    writer = dv.io.MonoCameraWriter(str(path), dv.io.MonoCameraWriter.EventOnlyConfig("test", SIZE))
    store = dv.EventStore()
    for e in random_events(200, SIZE):
        store.push_back(int(e["t"]), int(e["x"]), int(e["y"]), bool(e["p"]))
    writer.writeEvents(store)
    del writer
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])      # cuts a packet in two
    _read_fails(path, "AEDAT4")
    _cli_error(capsys, path)


def test_missing_fields(tmp_path, capsys, random_events):
    ev = random_events(100, SIZE)
    ours = tmp_path / "ours.h5"
    write_events_h5(ours, ev, SIZE)
    with h5py.File(ours, "a") as f:
        del f["events/p"]
    _read_fails(ours, "missing event fields /events/p")
    assert "/events/p" in _cli_error(capsys, ours)

    dsec = tmp_path / "dsec.h5"
    with h5py.File(dsec, "w") as f:
        for n in "xyt":
            f.create_dataset(f"events/{n}", data=ev[n])
        f.create_dataset("t_offset", data=np.int64(0))
    _read_fails(dsec, r"missing field /events/p")

    npz = tmp_path / "e.npz"
    np.savez(npz, x=ev["x"], y=ev["y"], t=ev["t"])
    _read_fails(npz, "lacks arrays p")

    npy = tmp_path / "e.npy"
    np.save(npy, ev[["x", "y", "t"]])
    _read_fails(npy, "lacks fields p")

    mvsec = tmp_path / "m.hdf5"
    with h5py.File(mvsec, "w") as f:
        f.create_dataset("davis/left/events", data=np.zeros((10, 3)))
    _read_fails(mvsec, "must be N x 4")

    other = tmp_path / "other.h5"
    with h5py.File(other, "w") as f:
        f.create_dataset("images", data=np.zeros((2, 4, 4)))
    _read_fails(other, "without an event layout we know")


def test_coordinates_outside_the_sensor(tmp_path, capsys):
    path = tmp_path / "wide.npz"
    _npz(path, [1, 40, 2], [1, 1, 1], [0, 1, 2], [1, 0, 1])
    _read_fails(path, r"x = 40 outside the 32x24 sensor at event 1")
    _cli_error(capsys, path)
    assert read_events(path, sensor_size=(64, 48)).sensor_size == (64, 48)   # the right size fixes it
    neg = tmp_path / "neg.npz"
    _npz(neg, [1, 2, 3], [1, -1, 1], [0, 1, 2], [1, 0, 1])
    _read_fails(neg, "y = -1 at event 1 is not a pixel coordinate")
    mv = tmp_path / "mv.hdf5"
    with h5py.File(mv, "w") as f:
        f.create_dataset("davis/left/events", data=np.array([[400.0, 10, 1.0, 1], [1, 1, 1.1, -1]]))
    _read_fails(mv, r"x = 400 outside the 346x260 sensor")


def test_negative_timestamps(tmp_path, capsys):
    path = tmp_path / "neg_t.npz"
    _npz(path, [1, 2, 3], [1, 1, 1], [-5, 0, 2], [1, 0, 1])
    _read_fails(path, r"negative timestamp t = -5 us at event 0")
    assert "negative timestamp" in _cli_error(capsys, path)


def test_decreasing_timestamps_error_unless_sorted(tmp_path, capsys):
    path = tmp_path / "unsorted.npz"
    _npz(path, [1, 2, 3, 4], [1, 1, 1, 1], [0, 50, 20, 60], [1, 0, 1, 0])
    _read_fails(path, r"timestamps decrease at event 2: t = 20 us after 50 us")
    msg = _cli_error(capsys, path)
    assert "--sort" in msg
    assert main(["events", "info", "--no-progress", "--sort", str(path)]) == 0
    assert read_events(path, sort=True).events["t"].tolist() == [0, 20, 50, 60]


def test_decreasing_timestamps_across_a_chunk_boundary(tmp_path):
    ev = make_events(np.zeros(6), np.zeros(6), [0, 10, 20, 15, 30, 40], np.ones(6))
    path = tmp_path / "u.h5"
    with h5py.File(path, "w") as f:        # hand-written: our writer refuses unsorted events
        f.attrs.update({"format": "toffe-events", "format_version": 1, "sensor_width": 4, "sensor_height": 4})
        for n in "xytp":
            f.create_dataset(f"events/{n}", data=ev[n])
    with open_events(path) as src:
        src.chunk_events = 3               # the decrease sits exactly between two chunks
        with pytest.raises(InputError, match="timestamps decrease at event 3"):
            list(src.iter_windows(10))


def test_seconds_instead_of_microseconds_is_reported(tmp_path):
    path = tmp_path / "sec.npz"
    _npz(path, [1, 2], [1, 1], [0.1, 0.2], [1, 0])
    _read_fails(path, "not a whole number of microseconds")


def test_bad_sensor_size_argument(tmp_path, random_events):
    path = tmp_path / "e.npz"
    ev = random_events(10, SIZE)
    _npz(path, ev["x"], ev["y"], ev["t"], ev["p"])
    _read_fails(path, "sensor size 0x24", sensor_size=(0, 24))


def test_writer_refuses_bad_events(tmp_path):
    ev = make_events([1, 2], [1, 1], [10, 5], [1, 0])
    with pytest.raises(ValueError, match="timestamps decrease"):
        write_events_h5(tmp_path / "x.h5", ev, SIZE)
    with pytest.raises(ValueError, match="reserved"):
        write_events_h5(tmp_path / "x.h5", ev[:1], SIZE, attrs={"sensor_width": 3})
    assert not (tmp_path / "x.h5").exists() and not list(tmp_path.iterdir())   # nothing half-written


def test_deeply_nested_json_attribute_is_one_line(tmp_path, capsys):
    """A root attribute holding JSON nested deeper than the parser's stack raised RecursionError."""
    path = tmp_path / "deep.h5"
    write_events_h5(path, make_events([1, 2], [1, 1], [0, 5], [1, 0]), SIZE, attrs={"note": 1})
    with h5py.File(path, "r+") as f:
        f.attrs["note"] = "[" * 3000 + "]" * 3000
    with open_events(path) as src, pytest.raises(InputError, match="root attribute note: JSON nested too deeply"):
        src.attrs
    assert "nested too deeply" in _cli_error(capsys, path)


def test_missing_sensor_size_attribute_is_named(tmp_path, capsys):
    """Named as the attribute, not as h5py's "Unable to synchronously open attribute (...)"."""
    path = tmp_path / "nosize.h5"
    write_events_h5(path, make_events([1, 2], [1, 1], [0, 5], [1, 0]), SIZE)
    with h5py.File(path, "r+") as f:
        del f.attrs["sensor_width"]
    _read_fails(path, r"missing root attribute sensor_width$")
    assert _cli_error(capsys, path).endswith("nosize.h5: missing root attribute sensor_width")
