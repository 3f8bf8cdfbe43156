"""The OFPD's motion planes (ofpd.motion "time_cov", ofpd_io module doc): which way time runs
inside each crop cell, the direction cue that does not depend on the contrast sign."""
import numpy as np
import pytest

from toffe_deploy import ofpd_io
from toffe_deploy.config import ToffeConfig
from toffe_deploy.model.train import OFPDSet, ofpd_batch

SENSOR = (160, 120)
CFG = ToffeConfig(sensor_size=SENSOR)          # current layout: motion planes on
B = CFG.n_bins


def moving_disc(step, bright=True, d=30, c=(80, 60)):
    """(B, 2, H, W) first spikes of a disc of diameter d moving by ``step`` px per bin: the
    leading edge fires ON for a bright object and OFF for a dark one, the trailing edge the
    other polarity."""
    h, w = SENSOR[1], SENSOR[0]
    yy, xx = np.mgrid[:h, :w]
    out = np.zeros((B, 2, h, w), bool)
    seen = np.zeros((2, h, w), bool)
    for b in range(B):
        cx, cy = c[0] + step[0] * b, c[1] + step[1] * b
        px, py = c[0] + step[0] * (b - 1), c[1] + step[1] * (b - 1)
        now = (xx - cx) ** 2 + (yy - cy) ** 2 <= (d / 2) ** 2
        before = (xx - px) ** 2 + (yy - py) ** 2 <= (d / 2) ** 2
        lead, trail = now & ~before, before & ~now
        p_lead = 1 if bright else 0
        for p, m in ((p_lead, lead), (1 - p_lead, trail)):
            new = m & ~seen[p]
            out[b, p] |= new
            seen[p] |= new
    return out


def motion_sum(frame):
    x = ofpd_io.prepare(frame[None], CFG)
    assert x.shape[1] == 2 * B + 4
    return x[0, 2 * B:2 * B + 2].sum(axis=(1, 2))


@pytest.mark.parametrize("bright", [True, False])
@pytest.mark.parametrize("step", [(1, 0), (-2, 0), (0, 1), (0, -3), (2, 2)])
def test_motion_planes_point_along_the_motion_for_either_contrast(step, bright):
    m = motion_sum(moving_disc(step, bright))
    angle = np.arctan2(m[1], m[0])
    want = np.arctan2(step[1], step[0])
    assert abs(np.angle(np.exp(1j * (angle - want)))) < np.deg2rad(10)


def test_legacy_configs_have_no_motion_planes():
    old = ToffeConfig(sensor_size=SENSOR, ofpd={"grouping": "blobs", "crop": "scaled", "speed_unit": "px_ms"})
    assert ofpd_io.ofpd_settings(old)["motion"] == "none"
    assert ofpd_io.input_shape(old)[0] == 2 * B + 2
    assert ofpd_io.prepare(moving_disc((1, 0))[None], old).shape[1] == 2 * B + 2


def test_motion_planes_do_not_depend_on_the_order_of_the_ones(rng):
    frame = moving_disc((2, 1))
    bb, cc, ys, xs = np.nonzero(frame)
    origins = ofpd_io.crop_origins(frame[None], CFG)
    ref = ofpd_io.prepare_xy([(xs, ys, 2 * bb + cc)], origins, CFG)
    p = rng.permutation(xs.size)
    shuffled = ofpd_io.prepare_xy([(xs[p], ys[p], (2 * bb + cc)[p])], origins, CFG)
    assert np.array_equal(ref, shuffled)
    assert np.abs(ref[0, 2 * B:2 * B + 2]).sum() > 0


class _AlwaysFlip:
    def random(self):
        return 0.0


@pytest.mark.parametrize("step", [(2, 0), (0, 1), (1, -2)])
def test_training_flips_keep_motion_planes_and_direction_target_consistent(step):
    frame = moving_disc(step, bright=False)
    x = ofpd_io.prepare(frame[None], CFG)
    g = x.shape[-1]
    org = ofpd_io.crop_origins(frame[None], CFG).astype(np.float64)
    pool = int(org[0, 2]) // g
    ds = OFPDSet(planes=np.rint(x[:, :2 * B] * pool * pool).astype(np.uint16), motion=x[:, 2 * B:2 * B + 2],
                 origin=org, x=np.array([80.0]), y=np.array([60.0]),
                 direction=np.array([np.arctan2(step[1], step[0])]), speed=np.array([0.0]), stage=np.array([1]))
    xb, _pose, direction, _v = ofpd_batch(ds, np.array([0]), _AlwaysFlip())
    m = xb[0, 2 * B:2 * B + 2].numpy().sum(axis=(1, 2))
    c, s = direction[0].numpy()
    assert abs(np.angle(np.exp(1j * (np.arctan2(m[1], m[0]) - np.arctan2(s, c))))) < np.deg2rad(10)
    # and the flipped planes are what prepare gives for the flipped-and-transposed frame
    flipped = np.ascontiguousarray(frame[..., ::-1, ::-1].swapaxes(-1, -2))
    sensor_t = ToffeConfig(sensor_size=SENSOR[::-1])
    assert abs(np.angle(np.exp(1j * (np.arctan2(*motion_sum_cfg(flipped, sensor_t)[::-1]) - np.arctan2(s, c))))) \
        < np.deg2rad(10)


def motion_sum_cfg(frame, cfg):
    return ofpd_io.prepare(frame[None], cfg)[0, 2 * B:2 * B + 2].sum(axis=(1, 2))


def _motion_reference(obj, xs, ys, ch, origins, n_obj, g, b):
    """The motion planes by their definition (ofpd_io.prepare_xy / compiled.fill_motion doc),
    one cell at a time with numpy: 12 n cov(t, u) / P^2 as 3 (n sum tt uu - sum tt sum uu) /
    (n P (B - 1) P^2), tt = 2 b - (B - 1), uu = 2 (x - x_cell) - (P - 1)."""
    out = np.zeros((n_obj, 2, g, g), np.float32)
    for o in range(n_obj):
        x0, y0, size = origins[o]
        pool = size // g
        sel = (obj == o) & (xs >= x0) & (xs < x0 + size) & (ys >= y0) & (ys < y0 + size) & (ch < 2 * b)
        x, y, t = xs[sel] - x0, ys[sel] - y0, 2 * (ch[sel] // 2) - (b - 1)
        for cy in range(g):
            for cx in range(g):
                m = (x // pool == cx) & (y // pool == cy)
                n = int(m.sum())
                if n < 2:
                    continue
                tt, uu, vv = t[m], 2 * (x[m] - cx * pool) - (pool - 1), 2 * (y[m] - cy * pool) - (pool - 1)
                den = float(n * pool * (b - 1) * pool * pool)
                out[o, 0, cy, cx] = np.float32(3 * (n * int((tt * uu).sum()) - int(tt.sum()) * int(uu.sum())) / den)
                out[o, 1, cy, cx] = np.float32(3 * (n * int((tt * vv).sum()) - int(tt.sum()) * int(vv.sum())) / den)
    return out


def test_compiled_motion_planes_equal_their_definition(rng):
    """compiled.fill_motion (sparse cells, one pass) bit for bit against the per-cell definition,
    with ones outside their crop and channels beyond 2B left out."""
    from toffe_deploy.compiled import fill_motion

    g, b = 8, 5
    origins = np.array([[3, 5, 16], [0, 0, 32], [40, 10, 64]], np.int64)
    n = 3000
    obj = rng.integers(0, 3, n).astype(np.int64)
    xs = (origins[obj, 0] + rng.integers(-4, 70, n)).astype(np.int64)
    ys = (origins[obj, 1] + rng.integers(-4, 70, n)).astype(np.int64)
    ch = rng.integers(0, 2 * b + 2, n).astype(np.int64)
    out = np.zeros((3, 2 * b + 4, g, g), np.float32)
    fill_motion(out, obj, xs, ys, ch, origins, b, 2 * b)
    ref = _motion_reference(obj, xs, ys, ch, origins, 3, g, b)
    assert np.count_nonzero(ref) > 50
    assert np.array_equal(out[:, 2 * b:2 * b + 2], ref)
    assert not out[:, :2 * b].any() and not out[:, 2 * b + 2:].any()
