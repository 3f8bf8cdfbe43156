"""bin_window against a slow, obvious per-event loop, and binning of streamed windows."""
import numpy as np
import pytest

from toffe_deploy.events import bin_window, open_events, write_events_h5


def slow_bins(events, t0, dt, n_bins, sensor_size):
    """The definition, one event at a time: b = floor((t - t0) * B / dt), channel = polarity."""
    w, h = sensor_size
    out = np.zeros((n_bins, 2, h, w), np.int64)
    for e in events:
        t = int(e["t"])
        if t0 <= t < t0 + dt:
            b = (t - t0) * n_bins // dt
            out[b, 1 if e["p"] else 0, int(e["y"]), int(e["x"])] += 1
    return out


@pytest.mark.parametrize("n_bins,dt,t0", [(5, 1000, 0), (5, 777, 2_345), (1, 200, 100), (7, 5000, 4_000)])
def test_bin_window_matches_the_loop(random_events, n_bins, dt, t0):
    ev = random_events(3000, (32, 24), 12_000)       # a superset: events outside must be ignored
    fast = bin_window(ev, t0, dt, n_bins, (32, 24))
    assert fast.shape == (n_bins, 2, 24, 32) and fast.dtype == np.uint16
    np.testing.assert_array_equal(fast, slow_bins(ev, t0, dt, n_bins, (32, 24)))


def test_bin_edges_and_polarity_channels(random_events):
    from toffe_deploy.events import make_events

    ev = make_events([0, 1, 2, 3], [0, 0, 0, 0], [999, 1000, 1199, 1999], [1, 0, 1, 1])
    vol = bin_window(ev, 1000, 1000, 5, (4, 1))     # bins of 200 us: 1000->0, 1199->0, 1999->4
    assert vol[0, 0, 0, 1] == 1 and vol[0, 1, 0, 2] == 1 and vol[4, 1, 0, 3] == 1
    assert vol.sum() == 3                            # t = 999 is before the window


def test_streamed_windows_bin_like_the_whole_array(tmp_path, random_events):
    ev = random_events(4000, (32, 24), 10_000, t0=50)
    path = tmp_path / "e.h5"
    write_events_h5(path, ev, (32, 24))
    with open_events(path) as src:
        src.chunk_events = 100
        for t0, w in src.iter_windows(500):
            np.testing.assert_array_equal(bin_window(w, t0, 500, 5, src.sensor_size),
                                          bin_window(ev, t0, 500, 5, (32, 24)))


def test_empty_window_bins_to_zeros():
    from toffe_deploy.events import EVENT_DTYPE

    vol = bin_window(np.empty(0, EVENT_DTYPE), 0, 500, 5, (32, 24))
    assert vol.shape == (5, 2, 24, 32) and not vol.any()
