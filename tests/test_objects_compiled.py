"""The compiled object grouping and OFPD batch (compiled.blob_objects, runtime.ofpd_input.batch)
against the straightforward implementation they replaced, kept here as the reference: the same
objects (stage, centre bit for bit), the same claims and the same OFPD inputs, on real windows of
the shipped sample and on the grouping tests' synthetic blobs."""
from __future__ import annotations

import numpy as np
import pytest

from toffe_deploy import ofpd_io
from toffe_deploy.config import ToffeConfig
from toffe_deploy.runtime import ofpd_input
from toffe_deploy.runtime.spikes import SpikeVolume

SENSOR = (480, 360)
CFG = ToffeConfig(sensor_size=SENSOR)          # the current layout: blobs over the union of the stages, scaled crop
JOIN = ToffeConfig(sensor_size=SENSOR, ofpd={**ofpd_io.OFPD_DEFAULTS, "stages": "join"})


def sets_within(xa, ya, xb, yb, t):
    """Whether some pixel of set a lies within Euclidean distance t of some pixel of set b (all pairs)."""
    return bool(((xa[:, None] - xb[None]) ** 2 + (ya[:, None] - yb[None]) ** 2 <= t * t).any())


def blob_objects_reference(stage_pixels, sensor_size, config):
    """ofpd_io.blob_objects_xy as first written: a Python loop over each stage's groups."""
    s = ofpd_io.ofpd_settings(config)
    frac, frac_open, need = float(s["merge_frac"]), float(s["edge_merge_frac"]), int(s["min_events"])
    w = int(sensor_size[0])
    objs, px, boxes, closed, keys, owner = [], [], [], [], [], []
    for i in range(len(stage_pixels) - 1, -1, -1):
        xs, ys = (np.ascontiguousarray(a, dtype=np.int64) for a in stage_pixels[i])
        group, count, gbox, gclosed = ofpd_io.blobs_xy(xs, ys, w, config)
        n_groups = count.shape[0]
        if not n_groups:
            continue
        order = np.argsort(group, kind="stable")
        bounds = np.searchsorted(group[order], np.arange(n_groups + 1))
        host_of = np.full(n_groups, -1, np.int64)
        for q in range(n_groups):
            box = gbox[q].tolist()
            e = float(max(box[2] - box[0], box[3] - box[1]) + 1)
            sel = order[bounds[q]:bounds[q + 1]]
            for j in range(len(objs)):
                b = boxes[j]
                t = (frac if gclosed[q] or closed[j] else frac_open) * max(e, float(max(b[2] - b[0], b[3] - b[1]) + 1))
                if max(box[0] - b[2], b[0] - box[2], box[1] - b[3], b[1] - box[3]) > t:
                    continue
                if any(sets_within(xs[sel], ys[sel], ox, oy, t) for ox, oy in px[j]):
                    host_of[q] = j
                    break
            if host_of[q] >= 0:
                j = host_of[q]
                b = boxes[j]
                boxes[j] = [min(b[0], box[0]), min(b[1], box[1]), max(b[2], box[2]), max(b[3], box[3])]
            elif count[q] >= need:
                host_of[q] = len(objs)
                objs.append((i, float(xs[sel].sum() / sel.size), float(ys[sel].sum() / sel.size)))
                px.append([])
                boxes.append(box)
                closed.append(bool(gclosed[q]))
            if host_of[q] >= 0:
                px[host_of[q]].append((xs[sel], ys[sel]))
        pix_host = np.where(group >= 0, host_of[np.maximum(group, 0)], -1)
        mine = pix_host >= 0
        keys.append(ys[mine] * w + xs[mine])
        owner.append(pix_host[mine])
    if not objs:
        return [], np.zeros(0, np.int64), np.zeros(0, np.int64)
    k, o = np.concatenate(keys), np.concatenate(owner)
    srt = np.argsort(k, kind="stable")
    return objs, k[srt], o[srt]


def union_objects_reference(stage_pixels, sensor_size, config):
    """ofpd_io.blob_objects_xy with stages "union" in numpy: blobs_xy on all stages' pixels,
    merge_blobs once more on its groups (a closed group stays closed, an open one is tested
    again over all its pixels, specks included), then each group's stage, centre and claims."""
    from toffe_deploy.compiled import merge_blobs

    s = ofpd_io.ofpd_settings(config)
    need, w = int(s["min_events"]), int(sensor_size[0])
    xs = np.concatenate([np.asarray(p[0], np.int64) for p in stage_pixels])
    ys = np.concatenate([np.asarray(p[1], np.int64) for p in stage_pixels])
    stage = np.concatenate([np.full(len(p[0]), i) for i, p in enumerate(stage_pixels)])
    if xs.size == 0:
        return [], np.zeros(0, np.int64), np.zeros(0, np.int64)
    group, count, gbox, closed = ofpd_io.blobs_xy(xs, ys, w, config)
    inside = group >= 0
    known = np.where(closed, 1, -1).astype(np.int8)       # closed stays closed; open: over all its pixels
    second = merge_blobs(group[inside], count, gbox, xs[inside], ys[inside], float(s["merge_frac"]),
                         float(s["edge_merge_frac"]), max(1, -(-need // 4)), known)[0]
    final = np.full(xs.size, -1)
    final[inside] = second[group[inside]]
    found = []
    for q in range(final.max() + 1):
        sel = final == q
        if sel.sum() < need:
            continue
        per = np.bincount(stage[sel], minlength=len(stage_pixels))
        full = np.flatnonzero(per >= need)
        k = int(full.max()) if full.size else int(len(per) - 1 - np.argmax(per[::-1]))
        found.append((-k, q, (k, float(xs[sel].sum() / sel.sum()), float(ys[sel].sum() / sel.sum()))))
    found.sort()
    obj_of = {q: j for j, (_k, q, _o) in enumerate(found)}
    mine = np.array([obj_of.get(int(q), -1) for q in final])
    keys, owner = ys * w + xs, mine
    srt = np.argsort(keys, kind="stable")
    keep = owner[srt] >= 0
    return [o for _k, _q, o in found], keys[srt][keep], owner[srt][keep]


def batch_reference(volume, frames, config):
    """runtime.ofpd_input.batch as first written: per-object masks, crop origins and ones in Python."""
    _b, nc, h, w = volume.shape
    upix, pinv = volume.pixel_index()
    uy, ux = np.divmod(upix, w)

    def pixels_of(ones):
        mark = np.zeros(upix.shape[0], dtype=bool)
        mark[pinv[ones]] = True
        return np.flatnonzero(mark)

    objs, claims = ofpd_io.group_objects_xy([(ux[u], uy[u]) for u in (pixels_of(m) for m in frames)], (w, h), config)
    if not objs:
        return np.zeros(0, np.int64), None, np.zeros(0, np.int64)
    every = np.flatnonzero(np.logical_or.reduce(list(frames)))
    fx, fy = ux[pinv[every]], uy[pinv[every]]
    masks = claims.masks(fx, fy, len(objs))
    ev_pix = pixels_of(every)
    pix_masks = claims.masks(ux[ev_pix], uy[ev_pix], len(objs))
    ch = volume.b[every] * 2 + volume.c[every]
    ones, origins = [], []
    for m, pm in zip(masks, pix_masks):
        mu = ev_pix[pm]
        origins.append(ofpd_io.crop_origin_xy(ux[mu], uy[mu], (w, h), config))
        ones.append((fx[m], fy[m], ch[m]))
    x = ofpd_io.prepare_xy(ones, np.asarray(origins, dtype=np.int64).reshape(-1, 3), config)
    return np.array([i + 1 for i, _, _ in objs]), x, np.array([o[0].shape[0] for o in ones])


def assert_same_grouping(stage_pixels, sensor_size, config):
    objs, claims = ofpd_io.group_objects_xy(stage_pixels, sensor_size, config)
    union = ofpd_io.ofpd_settings(config)["stages"] == "union"
    ref, keys, owner = (union_objects_reference if union else blob_objects_reference)(stage_pixels, sensor_size, config)
    assert objs == ref                                     # stage and centre, bit for bit
    np.testing.assert_array_equal(claims.keys, keys)
    np.testing.assert_array_equal(claims.owner, owner)
    return objs


def disc(cx, cy, d):
    ys, xs = np.ogrid[:SENSOR[1], :SENSOR[0]]
    return (xs - cx) ** 2 + (ys - cy) ** 2 <= (d / 2.0) ** 2


def ring(cx, cy, d, step):
    return disc(cx - step[0] / 2, cy - step[1] / 2, d) ^ disc(cx + step[0] / 2, cy + step[1] / 2, d)


def xy(mask):
    ys, xs = np.nonzero(mask)
    return xs, ys


def synthetic_cases():
    """The shapes of tests/test_objects_grouping.py, a few at once and spread over the stages."""
    rng = np.random.default_rng(3)
    empty = (np.zeros(0, np.int64), np.zeros(0, np.int64))
    for d in (15, 40, 90, 200):
        for m in (ring(240, 180, d, (4, 0)), disc(240, 180, d), ring(240, 180, d, (3, 3))):
            for k in range(4):
                yield [xy(m) if j == k else empty for j in range(4)]
    for d in (20, 40, 90):
        for radii in (2, 3, 4):
            for angle in (0.0, 45.0, 90.0):
                dx, dy = radii * d / 2 * np.cos(np.radians(angle)), radii * d / 2 * np.sin(np.radians(angle))
                m = ring(200 - dx / 2, 180 - dy / 2, d, (3, 0)) | ring(200 + dx / 2, 180 + dy / 2, d, (3, 0))
                yield [empty, xy(m), empty, empty]
    arc = ring(150, 150, 60, (8, 0))                       # a fast object's edges spread over stages
    lead, trail = arc & (np.arange(SENSOR[0]) >= 150)[None, :], arc & (np.arange(SENSOR[0]) < 150)[None, :]
    yield [xy(arc | ring(300, 150, 40, (3, 0))), xy(trail), empty, xy(lead)]
    for _ in range(6):                                     # noise, specks and blobs in every stage
        out = []
        for _k in range(4):
            m = rng.random(SENSOR[::-1]) < 0.002
            for _b in range(rng.integers(0, 3)):
                m |= ring(*rng.integers(40, 440, 2), rng.integers(10, 80), tuple(rng.integers(-4, 5, 2)))
            xs, ys = xy(m)
            p = rng.permutation(xs.size)
            out.append((xs[p], ys[p]))
        yield out


@pytest.mark.parametrize("config", [CFG, JOIN], ids=["union", "join"])
def test_compiled_grouping_equals_reference_on_synthetic_blobs(config):
    n = 0
    for case in synthetic_cases():
        n += len(assert_same_grouping(case, SENSOR, config))
    assert n > 60


@pytest.fixture(scope="module")
def sample_windows(tmp_path_factory, make_bundle):
    """(bundle, [(volume, stage frames)]) of windows of the shipped 640x480 sample through the cpu cascade."""
    from toffe_deploy.commands.run import SAMPLE
    from toffe_deploy.events.io import open_events
    from toffe_deploy.runtime.cpu import CpuCascade

    bundle = make_bundle(tmp_path_factory.mktemp("b"), sensor=(640, 480), ofpd=dict(ofpd_io.CURRENT_LAYOUT))
    cfg = bundle.config
    out = []
    with open_events(SAMPLE) as src, CpuCascade(bundle.ofs, cfg.n_bins, cfg.mask_kernel, cfg.sensor_size) as cascade:
        for _, (t0, ev) in zip(range(40), src.iter_windows(cfg.dt_us, t_start=10_000)):
            vol = SpikeVolume.from_events(ev, t0, cfg.dt_us, cfg.n_bins, cfg.sensor_size).front_end(cfg.input_norm, cfg.input_min_cluster)
            out.append((vol, cascade.cascade_sparse(vol).frames))
    return bundle, out


def test_compiled_grouping_and_batch_equal_reference_on_the_sample(sample_windows):
    from toffe_deploy.compiled import new_scratch

    bundle, windows = sample_windows
    cfg = bundle.config
    scratch = new_scratch(640 * 480)
    n_obj = 0
    for vol, frames in windows:
        stage_pixels = []
        for m in frames:
            u = np.unique(vol.pix[m])
            stage_pixels.append((u % 640, u // 640))
        assert_same_grouping(stage_pixels, (640, 480), cfg)
        ks, x, n_ev, _ones = ofpd_input.batch(vol, frames, cfg, scratch)
        rk, rx, rn = batch_reference(vol, frames, cfg)
        np.testing.assert_array_equal(ks, rk)
        np.testing.assert_array_equal(n_ev, rn)
        if rx is not None:
            assert x.dtype == rx.dtype and x.tobytes() == rx.tobytes()      # OFPD inputs bit for bit
        n_obj += ks.size
        assert (scratch == -1).all()                        # the scratch is left as found
    assert n_obj >= 20


def surrounds_reference(xs, ys):
    """compiled.surrounds as first written: every sector from np.arctan2."""
    cx, cy = xs.sum() / xs.size, ys.sum() / ys.size
    r = 0.25 * (max(xs.max() - xs.min(), ys.max() - ys.min()) + 1)
    dx, dy = xs - cx, ys - cy
    far = dx * dx + dy * dy > r * r
    sectors = np.floor((np.arctan2(dy[far], dx[far]) + np.pi) * (4.0 / np.pi)).astype(np.int64) % 8
    return np.unique(sectors).size == 8


def test_surrounds_sectors_equal_arctan2_also_on_axes_and_diagonals(rng):
    """compiled.surrounds takes sectors from signs and |dx| vs |dy| away from the boundaries:
    the same answer as atan2 on sets whose centroid is a pixel (points exactly on the axes and
    diagonals) and on random ones, which pass and fail."""
    from toffe_deploy.compiled import surrounds

    answers = set()
    for i in range(400):
        if i % 2:                                          # symmetric: integer centroid
            k = int(rng.integers(1, 9))
            ox, oy = rng.integers(-6, 7, k), rng.integers(-6, 7, k)
            sym = [(ox, oy), (-ox, -oy)] + ([(oy, ox), (-oy, -ox)] if i % 4 == 1 else [])
            xs = np.concatenate([a for a, _ in sym]) + 50
            ys = np.concatenate([b for _, b in sym]) + 50
        else:
            n = int(rng.integers(3, 40))
            xs, ys = rng.integers(0, 30, n), rng.integers(0, 30, n)
        xs, ys = xs.astype(np.int64), ys.astype(np.int64)
        want = surrounds_reference(xs, ys)
        assert surrounds(xs, ys) == want
        answers.add(want)
    assert answers == {True, False}
