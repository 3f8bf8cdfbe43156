"""The cpu target's event-driven cascade against the dense fixed-point reference, bit for bit."""
import cv2
import numpy as np
import pytest

from toffe_deploy.cascade import close_binary, run_cascade
from toffe_deploy.events.binning import bin_window
from toffe_deploy.fixed_point import quantize_ofs, run_ofs_fixed
from toffe_deploy.runtime.cpu import CpuCascade
from toffe_deploy.runtime.morph import CompactClosing
from toffe_deploy.compiled import dedupe, lif_window, new_scratch
from toffe_deploy.runtime.ofs_sparse import run_ofs_sparse
from toffe_deploy.runtime.spikes import SpikeVolume


def _stage_params(rng, n=3, k=3, c=2):
    out = []
    for i in range(n):
        w = rng.uniform(-0.05, 0.2, (1, c, k, k))
        w[0, :, k // 2, k // 2] = 0.2
        out.append(quantize_ofs(w, threshold=(0.3 + 0.2 * i) * k * k / 9, leak=float(rng.uniform(0.2, 0.9))))
    return out


def _blobby(rng, shape=(5, 2, 24, 32), n_blobs=3, p=0.5):
    """Sparse volume with a few dense blobs, some touching the sensor edge."""
    x = np.zeros(shape, bool)
    b, c, h, w = shape
    for _ in range(n_blobs):
        y0, x0 = rng.integers(-2, h - 3), rng.integers(-2, w - 3)
        sy, sx = rng.integers(3, 9, 2)
        ys, xs = slice(max(y0, 0), max(y0 + sy, 0)), slice(max(x0, 0), max(x0 + sx, 0))
        view = x[:, :, ys, xs]
        view |= rng.random(view.shape) < p
    x |= rng.random(shape) < 0.01
    return x


def test_dedupe_gives_unique_values_and_inverse(rng):
    v = rng.integers(0, 50, 300)
    scratch = new_scratch(50)
    for _ in range(2):                           # the scratch is left clean for the next call
        uniq, inv = dedupe(v, scratch)
        assert uniq.tolist() == list(dict.fromkeys(v.tolist()))     # order of first appearance
        assert np.array_equal(uniq[inv], v)
        assert np.all(scratch == -1)
        v = rng.integers(0, 50, 300)


def test_spike_volume_from_events_matches_bin_window(random_events):
    ev = random_events(n=3000, sensor_size=(32, 24), duration_us=2000)
    vol = SpikeVolume.from_events(ev, 400, 500, 5, (32, 24))
    assert np.array_equal(vol.to_dense(), bin_window(ev, 400, 500, 5, (32, 24)) > 0)
    assert np.all(np.diff(vol.idx) > 0)


@pytest.mark.parametrize("seed", range(6))
def test_sparse_ofs_is_bit_exact_with_dense_reference(seed):
    rng = np.random.default_rng(seed)
    k = [1, 3, 5][seed % 3]
    x = _blobby(rng)
    for p in _stage_params(rng, n=2, k=k):
        ref = run_ofs_fixed(x, p)
        assert ref.any()                       # the comparison means something
        assert np.array_equal(run_ofs_sparse(x, p), ref)


@pytest.mark.parametrize("seed", range(8))
def test_compact_closing_equals_full_frame_closing(seed):
    rng = np.random.default_rng(100 + seed)
    h, w = 40, 56
    img = _blobby(rng, (1, 1, h, w), n_blobs=4, p=0.3)[0, 0]
    kernel = [5, 3, 4, 7][seed % 4]
    ref = close_binary(img, kernel)
    cc = CompactClosing(np.flatnonzero(img), h, w, kernel)
    assert np.array_equal(cc.dense(), ref)
    assert np.array_equal(cc.at(np.arange(h * w)), ref.ravel())


def test_compact_closing_of_nothing_is_empty():
    cc = CompactClosing(np.zeros(0, np.int64), 10, 12, 5)
    assert not cc.dense().any() and not cc.at(np.arange(120)).any()


@pytest.mark.parametrize("seed", range(4))
def test_cpu_cascade_equals_run_cascade(seed):
    rng = np.random.default_rng(200 + seed)
    params = _stage_params(rng, n=4)
    windows = [_blobby(rng, n_blobs=4).astype(np.uint16) * 3 for _ in range(2)] + [np.zeros((5, 2, 24, 32), np.uint16)]
    with CpuCascade(params, 5, 5, (32, 24)) as cas:
        got = list(cas.cascade_stream(windows))
    assert len(got) == 3
    for x, g in zip(windows, got):
        ref = run_cascade(x, lambda k, inp: run_ofs_fixed(inp, params[k - 1]), 4, 5)
        for field in ("inputs", "spikes", "closed", "frames"):
            for a, b in zip(getattr(ref, field), getattr(g, field)):
                assert a.shape == b.shape and np.array_equal(a, b), field



@pytest.mark.parametrize("pool", [2, 3])
def test_pooled_frames_equal_the_cascade_of_the_pooled_window(rng, pool):
    """CpuCascade.pooled_frames (pool, cascade and Up_p in one compiled call) gives the frames
    of cascade_sparse on volume.pool(p), brought back to the sensor ones, and the volume's planes
    and pixels."""
    params = _stage_params(rng, n=4)
    for x in (_blobby(rng, shape=(5, 2, 47, 64), n_blobs=6), np.zeros((5, 2, 47, 64), bool)):
        vol = SpikeVolume.from_dense(x)
        grid, inverse = vol.pool(pool)
        cas = CpuCascade(params, 5, 5, (grid.shape[3], grid.shape[2]))
        want = cas.cascade_sparse(grid).frames[:, inverse] if len(vol) else np.zeros((4, 0), bool)
        fresh = SpikeVolume(vol.idx, vol.shape)
        got = cas.pooled_frames(fresh, pool)
        assert got.shape == want.shape and np.array_equal(got, want)
        assert np.array_equal(fresh.bc, vol.bc) and np.array_equal(fresh.pix, vol.pix)
        if len(vol):
            assert want.any() and not want.all()

def test_cpu_cascade_rejects_wrong_window_shape(rng):
    cas = CpuCascade(_stage_params(rng, n=2), 5, 5, (32, 24))
    with pytest.raises(ValueError, match="window must be"):
        next(cas.cascade_stream([np.zeros((5, 2, 24, 30), np.uint8)]))


@pytest.mark.parametrize("reset", ["subtract", "zero"])
@pytest.mark.parametrize("dv", [0, 1, 1094, 2048, 4095])
def test_lif_window_equals_lif_step_including_saturation(rng, dv, reset):
    from toffe_deploy.fixed_point import LoihiOFSParams, lif_step

    p = LoihiOFSParams(weight=np.ones((1, 1, 1, 1), np.int32), vth_mant=int(rng.integers(1, 3000)), dv=dv,
                       weight_scale=1.0, reset=reset)
    a = rng.integers(-3000, 3000, (7, 4000))
    a[:, :50] = 200_000                   # drives v into the +24-bit clip
    a[:, 50:100] = -200_000               # and the - clip
    v, o = np.zeros(4000, np.int64), np.zeros(4000, bool)
    ref = []
    for t in range(7):
        v, o = lif_step(v, o, a[t], p)
        ref.append(o)
    assert np.array_equal(lif_window(a.astype(np.int64), p.dv, p.vth_mant, reset == "zero"), np.stack(ref))


def test_warm_up_compiles_every_kernel_the_cascade_uses(rng):
    """After warm_up, a cascade (spikes, closings, masks) and the OFPD pixel sets compile
    nothing new: the first window of a stream does not pay for compilation."""
    from toffe_deploy import compiled

    compiled.warm_up()
    before = {k.__name__: len(k.signatures) for k in compiled.KERNELS}
    assert all(before.values())
    x = _blobby(rng)
    cas = CpuCascade(_stage_params(rng), 5, 5, (32, 24))
    res = cas.cascade_sparse(SpikeVolume.from_dense(x))
    assert any(c.empty is False for c in res.closings)       # the closing kernels ran
    res.closings[0].at(np.arange(10))
    SpikeVolume.from_dense(x).pixel_index(new_scratch(32 * 24))
    assert {k.__name__: len(k.signatures) for k in compiled.KERNELS} == before


def test_active_set_is_the_dilated_input_and_leaves_scratch_clean(rng):
    from toffe_deploy.compiled import active_set

    w, h = 13, 9
    scratch = new_scratch(w * h)
    for k in (1, 3, 5):
        pix = rng.choice(w * h, 12, replace=False).astype(np.int64)
        active, taps = active_set(pix, w, h, k, scratch)
        img = np.zeros((h, w), np.uint8)
        img.reshape(-1)[pix] = 1
        want = np.flatnonzero(cv2.dilate(img, np.ones((k, k), np.uint8), borderType=cv2.BORDER_CONSTANT, borderValue=0))
        assert sorted(active.tolist()) == want.tolist()
        assert np.all(scratch == -1)
        r = k // 2
        for q, p in enumerate(pix):                           # tap (i, j) of pixel p drives p + (r - i, r - j)
            y, x = divmod(int(p), w)
            for t, s in enumerate(taps[q]):
                ty, tx = y + r - t // k, x + r - t % k
                inside = 0 <= ty < h and 0 <= tx < w
                assert (s >= 0) == inside and (not inside or active[s] == ty * w + tx)


def test_close_square_equals_opencv_closing_on_random_images(rng):
    """compiled.close_square (the cascade's closing) against cv2.morphologyEx, odd and even
    kernels, images smaller than the kernel, empty and full ones."""
    from toffe_deploy.compiled import close_square

    for _ in range(300):
        k = int(rng.integers(1, 8))
        h, w = (int(v) for v in rng.integers(1, 24, 2))
        img = (rng.random((h, w)) < rng.choice([0.0, 0.1, 0.4, 0.8, 1.0])).astype(np.uint8)
        ref = cv2.morphologyEx(img, cv2.MORPH_CLOSE, np.ones((k, k), np.uint8))
        assert np.array_equal(close_square(img, k), ref), (k, h, w)


def test_sorted_unique_equals_np_unique(rng):
    from toffe_deploy.compiled import sorted_unique

    for n, top in ((0, 10), (1, 5), (500, 40), (3000, 5 * 2 * 480 * 640), (2000, 1 << 40)):
        v = rng.integers(0, top, n).astype(np.int64)
        got = sorted_unique(v)
        assert got.dtype == np.int64 and np.array_equal(got, np.unique(v))



def test_event_ones_equals_np_unique_of_the_bin_index(rng):
    """events.binning.event_ones (compiled.binned_ones, the cpu path's binning in one call)
    against np.unique of event_bin_index: events in and out of the window, repeats, none."""
    from toffe_deploy.events.binning import event_bin_index, event_ones
    from toffe_deploy.events.core import EVENT_DTYPE

    for n, w, h, b in ((0, 8, 6, 5), (1, 8, 6, 1), (400, 32, 24, 5), (3000, 64, 48, 3)):
        ev = np.zeros(n, EVENT_DTYPE)
        ev["x"], ev["y"] = rng.integers(0, w, n), rng.integers(0, h, n)
        ev["t"], ev["p"] = np.sort(rng.integers(-50, 560, n)), rng.integers(0, 2, n)
        got = event_ones(ev, 0, 500, b, (w, h))
        assert got.dtype == np.int64 and np.array_equal(got, np.unique(event_bin_index(ev, 0, 500, b, (w, h))))

def test_closed_bits_equals_opencv_closing_on_random_images(rng):
    """compiled.closed_bits (the cascade's closing, read at pixels) against cv2.morphologyEx:
    odd and even kernels (up to the 32 it takes), rows of one to four 64-bit words, empty edges
    and full images."""
    from toffe_deploy.compiled import closed_bits

    for i in range(300):
        k = int(rng.integers(1, 8)) if i % 10 else int(rng.choice([9, 16, 31, 32]))
        h, w = int(rng.integers(1, 30)), int(rng.integers(1, 200))
        img = (rng.random((h, w)) < rng.choice([0.02, 0.1, 0.4, 0.8, 1.0])).astype(np.uint8)
        img[0, 0] = 1
        fr, fc = np.nonzero(img)
        ref = cv2.morphologyEx(img, cv2.MORPH_CLOSE, np.ones((k, k), np.uint8))
        ys, xs = np.divmod(np.arange(h * w), w)
        got = closed_bits(fr.astype(np.int64), fc.astype(np.int64), ys, xs, h, w, k)
        assert np.array_equal(got, ref.ravel() > 0), (k, h, w)


def test_cascade_int32_scatter_equals_int64(rng):
    """cascade_window's int32 scatter buffer (small weights) gives the int64 buffer's results."""
    from toffe_deploy import compiled

    params = _stage_params(rng, n=4, k=5)
    cas = CpuCascade(params, 5, 5, (32, 24))
    win_vol = SpikeVolume.from_dense(_blobby(rng, n_blobs=5))
    from toffe_deploy.runtime.ofs_sparse import SparseOFSWindow

    win = SparseOFSWindow(win_vol, 5)
    args = (win.b, win.c, win.pix_inverse, win.input_pixels, win.tap_target, win.active)
    rest = (cas._dv, cas._vth, cas._reset_zero, 5, 24, 32, 5)
    small = compiled.cascade_window(*args, cas._weights, *rest)
    wide = compiled._cascade(*args, cas._weights.astype(np.int64), *rest)
    assert small[2][0].sum() < small[2][-1].sum()           # a faster stage masked some ones
    for a, b in zip(small, wide):
        assert np.array_equal(a, b)


def test_div_small_is_floor_division(rng):
    """compiled._div_small (the kernels' v // d without an integer division) against //, at
    the quotient's edges (multiples of d and one below) and up to 2**49."""
    from numba import njit

    from toffe_deploy.compiled import _div_small

    @njit
    def div_all(v, d):
        out = np.empty(v.shape[0], np.int64)
        inv = 1.0 / d
        for i in range(v.shape[0]):
            out[i] = _div_small(v[i], d, inv)
        return out

    for d in (1, 2, 3, 5, 7, 320, 640, 641, 4095, 76_800, 307_200, 999_983, 2**31 - 1):
        q = rng.integers(0, 2**49 // d, 2000)
        v = np.concatenate([q * d, q * d - 1, q * d + d - 1, rng.integers(0, 2**49, 2000), np.arange(min(3 * d + 5, 10_000))])
        v = v[(v >= 0) & (v < 2**49)].astype(np.int64)
        assert np.array_equal(div_all(v, d), v // d), d
