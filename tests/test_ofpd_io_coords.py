"""ofpd_io's coordinate core (the one definition of object selection and OFPD input, used by the
cpu runtime) against the dense definitions it replaced: box-filter density seed, dense report /
merge / prepare. The dense references below are the previous dense implementation, kept here
verbatim as the specification the trained checkpoint was fitted on."""
import cv2
import numpy as np
import pytest

from toffe_deploy import ofpd_io
from toffe_deploy.config import ToffeConfig


def dense_seed(mask, r):
    """Argmax of the (2r+1)^2 box count over the whole sensor, first in row-major order."""
    d = cv2.boxFilter(mask.astype(np.float32), -1, (2 * r + 1, 2 * r + 1), normalize=False,
                      borderType=cv2.BORDER_CONSTANT)
    sy, sx = np.unravel_index(int(np.argmax(d)), d.shape)
    return int(sx), int(sy)


def dense_centroid(xs, ys, half, w, h):
    """Mean of the pixels, then mean of those within ``half`` of it; sensor centre when empty."""
    if xs.size == 0:
        return (w - 1) / 2.0, (h - 1) / 2.0
    cx, cy = float(xs.mean()), float(ys.mean())
    near = (np.abs(xs - cx) < half) & (np.abs(ys - cy) < half)
    if near.any():
        cx, cy = float(xs[near].mean()), float(ys[near].mean())
    return cx, cy


def dense_box(cx, cy, r, h, w):
    ys, xs = np.ogrid[:h, :w]
    return (np.abs(xs - cx) < r) & (np.abs(ys - cy) < r)


def dense_mode_centroid(mask, r, half):
    h, w = mask.shape
    sx, sy = dense_seed(mask, r)
    ys, xs = np.nonzero(mask)
    cx, cy = float(sx), float(sy)
    for _ in range(2):
        near = (np.abs(xs - cx) < r) & (np.abs(ys - cy) < r)
        if not near.any():
            return dense_centroid(xs, ys, half, w, h)
        cx, cy = float(xs[near].mean()), float(ys[near].mean())
    return cx, cy


def dense_report_objects(pixels, cfg):
    s = ofpd_io.ofpd_settings(cfg)
    r = int(s["dedupe_px"])
    n, h, w = pixels.shape
    claimed = np.zeros((h, w), dtype=bool)
    out = []
    for i in range(n - 1, -1, -1):
        rem = pixels[i] & ~claimed
        while rem.sum() >= s["min_events"]:
            cx, cy = dense_mode_centroid(rem, r, s["crop_px"] // 2)
            box = dense_box(cx, cy, r, h, w)
            if (rem & box).sum() < s["min_events"]:
                break
            out.append((i, cx, cy))
            claimed |= box
            rem &= ~box
    return out


def dense_merge(frames, cfg):
    frames = frames > 0
    objs = dense_report_objects(ofpd_io.event_pixels(frames), cfg)
    r = ofpd_io.ofpd_settings(cfg)["dedupe_px"]
    h, w = frames.shape[-2:]
    every = frames.any(axis=0)
    merged = np.zeros((len(objs),) + frames.shape[1:], dtype=bool)
    for j, (_i, cx, cy) in enumerate(objs):
        merged[j] = every & dense_box(cx, cy, r, h, w)
    return np.array([i + 1 for i, _, _ in objs], dtype=np.int64), merged


def dense_prepare(frames, cfg):
    n, b, _c, h, w = frames.shape
    s = ofpd_io.ofpd_settings(cfg)
    size, pool = s["crop_px"], s["pool"]
    g = size // pool
    out = np.zeros((n, 2 * b + 2, g, g), dtype=np.float32)
    centres = (np.arange(g) + 0.5) * pool - 0.5
    px = ofpd_io.event_pixels(frames)
    for i in range(n):
        ys, xs = np.nonzero(px[i])
        cx, cy = dense_centroid(xs, ys, size // 2, w, h)
        x0, y0 = int(np.floor(cx - (size - 1) / 2 + 0.5)), int(np.floor(cy - (size - 1) / 2 + 0.5))
        sx0, sy0, sx1, sy1 = max(x0, 0), max(y0, 0), min(x0 + size, w), min(y0 + size, h)
        crop = np.zeros((b * 2, size, size), dtype=np.float32)
        if sx1 > sx0 and sy1 > sy0:
            crop[:, sy0 - y0:sy1 - y0, sx0 - x0:sx1 - x0] = \
                frames[i, :, :, sy0:sy1, sx0:sx1].reshape(b * 2, sy1 - sy0, sx1 - sx0) > 0
        out[i, :2 * b] = crop.reshape(2 * b, g, pool, g, pool).mean(axis=(2, 4))
        out[i, 2 * b] = ((x0 + centres) / ofpd_io.COORD_SCALE)[None, :]
        out[i, 2 * b + 1] = ((y0 + centres) / ofpd_io.COORD_SCALE)[:, None]
    return out


def random_frames(rng, n, h, w, kind):
    """N stage frames with several objects each: dense blobs (many equal box counts: ties),
    isolated pixels (seeds between events), noise, identical twin blobs at opposite corners
    (an exact tie between two objects) and blobs cut by the sensor border."""
    f = np.zeros((n, 5, 2, h, w), bool)
    for i in range(n):
        for _ in range(int(rng.integers(1, 5))):
            cy, cx, sz = rng.integers(-4, h + 4), rng.integers(-4, w + 4), int(rng.integers(1, 9))
            ys, xs = slice(max(cy - sz, 0), max(cy + sz, 0)), slice(max(cx - sz, 0), max(cx + sz, 0))
            if kind == "pixels":
                f[i, rng.integers(0, 5), rng.integers(0, 2), rng.integers(0, h, 15), rng.integers(0, w, 15)] = True
            else:
                f[i, :, :, ys, xs] = rng.random(f[i, :, :, ys, xs].shape) < (0.5 if kind == "solid" else 0.3)
                f[i, 0, 0, ys, xs] |= kind == "solid"
        if kind == "noise":
            f[i] |= rng.random(f[i].shape) < 0.003
        if kind == "twins":
            f[i, :, 1, 0:5, 0:4] = True
            f[i, :, 1, h - 5:h, w - 4:w] = True
    return f


OFPD = [{"crop_px": 32, "pool": 2, "min_events": 10, "dedupe_px": 12},
        {"crop_px": 16, "pool": 4, "min_events": 4, "dedupe_px": 20},
        {"crop_px": 24, "pool": 3, "min_events": 1, "dedupe_px": 6},
        {"crop_px": 20, "pool": 5, "min_events": 2, "dedupe_px": 3}]


@pytest.mark.parametrize("kind", ["solid", "pixels", "noise", "twins"])
@pytest.mark.parametrize("ofpd", OFPD)
def test_coordinate_core_equals_dense_definition(rng, kind, ofpd):
    n_obj = 0
    for sensor in [(64, 48), (37, 29)]:
        cfg = ToffeConfig(sensor_size=sensor, ofpd=ofpd)
        w, h = sensor
        for _ in range(4):
            f = random_frames(rng, int(rng.integers(1, 5)), h, w, kind)
            px = ofpd_io.event_pixels(f)
            ref = dense_report_objects(px, cfg)
            # the core itself, fed unique pixels in a shuffled order (the runtime's O(n) sets)
            xy = []
            for p in px:
                ys, xs = np.nonzero(p)
                o = rng.permutation(xs.size)
                xy.append((xs[o], ys[o]))
            assert ofpd_io.report_objects_xy(xy, sensor, cfg) == ref
            assert ofpd_io.report_objects(px, cfg) == ref
            assert ofpd_io.has_object(f, cfg).tolist() == [i in {o[0] for o in ref} for i in range(len(f))]
            ks_ref, merged_ref = dense_merge(f, cfg)
            ks, merged = ofpd_io.merge_frames(f, cfg)
            assert ks.dtype == ks_ref.dtype and ks.tolist() == ks_ref.tolist()
            assert merged.shape == merged_ref.shape and np.array_equal(merged, merged_ref)
            for frames in (f, merged_ref):
                assert ofpd_io.prepare(frames, cfg).tobytes() == dense_prepare(frames, cfg).tobytes()
            n_obj += len(ref)
    assert n_obj > 8


def test_density_seed_equals_box_filter_argmax(rng):
    """Ties (first in row-major order, possibly on a pixel without an event), objects at the
    border, gaps just above and below 2r, r = 0, empty input."""
    assert ofpd_io.density_seed(np.zeros(0, int), np.zeros(0, int), 3, 10, 8) == (0, 0)
    for t in range(600):
        w, h, r = int(rng.integers(4, 80)), int(rng.integers(4, 60)), int(rng.integers(0, 16))
        m = np.zeros((h, w), bool)
        for _ in range(int(rng.integers(1, 6))):
            cx, cy, sz = rng.integers(-3, w + 3), rng.integers(-3, h + 3), int(rng.integers(1, 10))
            m[max(cy - sz, 0):max(cy + sz, 0), max(cx - sz, 0):max(cx + sz, 0)] = True
        if t % 3 == 0:
            m |= rng.random(m.shape) < 0.01
        if t % 5 == 0 and w > 2 * r + 3:          # two single pixels exactly 2r and 2r+1 apart
            m[:] = False
            m[h // 2, 0], m[h // 2, min(2 * r + t % 2, w - 1)] = True, True
        if not m.any():
            continue
        ys, xs = np.nonzero(m)
        o = rng.permutation(xs.size)
        assert ofpd_io.density_seed(xs[o], ys[o], r, w, h) == dense_seed(m, r), (t, w, h, r)


def test_mode_centroid_lands_on_one_of_two_equal_objects():
    m = np.zeros((40, 60), bool)
    m[2:6, 3:7] = True
    m[30:34, 50:54] = True                    # same count: the first in row-major order wins
    assert ofpd_io.mode_centroid(m, 5, 8) == (4.5, 3.5) == dense_mode_centroid(m, 5, 8)
    assert ofpd_io.report_objects(m[None], ToffeConfig(sensor_size=(60, 40), ofpd={"dedupe_px": 5, "min_events": 4})) \
        == [(0, 4.5, 3.5), (0, 51.5, 31.5)]
