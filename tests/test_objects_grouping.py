"""Object grouping by event blobs (ofpd.grouping "blobs") and the OFPD crop scaled with the
object (crop "scaled", speed in px/ms): sizes 15..200 px, pairs at 3 and 4 radii, a fast
object's leftovers on slower stages, crop size and the pose / speed round trip through the
torch module and its ONNX export. Blobs are drawn in numpy the way a moving object's events
look: the symmetric difference of the object at two positions (its leading and trailing edges,
two crescents for a disc), or a filled disc."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from toffe_deploy import ofpd_io
from toffe_deploy.config import ToffeConfig
from toffe_deploy.model.ofpd import OFPD

SENSOR = (480, 360)
CFG = ToffeConfig(sensor_size=SENSOR)          # no ofpd settings: the current layout


def disc(cx, cy, d, shape=SENSOR[::-1]):
    ys, xs = np.ogrid[:shape[0], :shape[1]]
    return (xs - cx) ** 2 + (ys - cy) ** 2 <= (d / 2.0) ** 2


def moving_disc(cx, cy, d, step=(4, 0)):
    """Events of a disc of diameter d moving by ``step`` px: both edges, centred on (cx, cy)."""
    a = disc(cx - step[0] / 2, cy - step[1] / 2, d)
    b = disc(cx + step[0] / 2, cy + step[1] / 2, d)
    return a ^ b


def xy(mask):
    ys, xs = np.nonzero(mask)
    return xs, ys


def stages(*masks):
    """stage_pixels of 4 stages, masks[k-1] for stage k (None: empty)."""
    out = []
    for k in range(4):
        m = masks[k] if k < len(masks) and masks[k] is not None else np.zeros(SENSOR[::-1], bool)
        out.append(xy(m))
    return out


def test_current_layout_is_the_default_and_old_configs_keep_theirs():
    assert {k: ofpd_io.ofpd_settings(CFG)[k] for k in ofpd_io.CURRENT_LAYOUT} == ofpd_io.CURRENT_LAYOUT
    old = ToffeConfig(ofpd={"crop_px": 128, "pool": 4, "dedupe_px": 64})       # a checkpoint's config.json
    assert {k: ofpd_io.ofpd_settings(old)[k] for k in ofpd_io.LEGACY_LAYOUT} == ofpd_io.LEGACY_LAYOUT
    with pytest.raises(ValueError, match="grouping"):
        ofpd_io.ofpd_settings(ToffeConfig(ofpd={"grouping": "rings"}))


@pytest.mark.parametrize("d", [15, 40, 90, 200])
@pytest.mark.parametrize("kind", ["edges", "filled", "diagonal"])
def test_one_object_of_any_size(d, kind):
    cx, cy = 240.0, 180.0
    m = {"edges": lambda: moving_disc(cx, cy, d), "filled": lambda: disc(cx, cy, d),
         "diagonal": lambda: moving_disc(cx, cy, d, step=(6, 6))}[kind]()
    for stage in range(4):                                          # whichever stage fires on it
        objs, claims = ofpd_io.group_objects_xy(stages(*[m if k == stage else None for k in range(4)]), SENSOR, CFG)
        assert len(objs) == 1 and objs[0][0] == stage
        assert np.hypot(objs[0][1] - cx, objs[0][2] - cy) <= 2.0
        assert ofpd_io.object_masks_xy(*xy(m), objs, claims)[0].all()      # it claims the whole blob


@pytest.mark.parametrize("d", [20, 40, 90])
@pytest.mark.parametrize("radii", [3, 4])
@pytest.mark.parametrize("angle", [0.0, 45.0, 90.0])
def test_two_objects_three_and_four_radii_apart(d, radii, angle):
    """Centre distance 3r and 4r (edge gaps r and 2r) -> two objects at their centres. A gap of
    r is 0.5 of an object's extent, above merge_frac = 0.25; the gap between their events (r
    minus the 4 px each moves along the line joining them) must stay above the 4 px the closing
    bridges (link_px): r >= 9 px, objects from 18 px across."""
    r = d / 2.0
    dist = radii * r
    a = np.radians(angle)
    c0 = np.array([120.0, 90.0])                                   # both inside the 480 x 360 sensor
    c1 = c0 + dist * np.array([np.cos(a), np.sin(a)])
    m = moving_disc(*c0, d) | moving_disc(*c1, d)
    objs, claims = ofpd_io.group_objects_xy(stages(None, m), SENSOR, CFG)
    assert len(objs) == 2
    got = sorted((o[1], o[2]) for o in objs)
    want = sorted([tuple(c0), tuple(c1)])
    np.testing.assert_allclose(got, want, atol=2.0)
    # each object's frame holds all of its events and none of the other's
    xs, ys = xy(m)
    for g, inside in enumerate(ofpd_io.object_masks_xy(xs, ys, objs, claims)):
        near = np.hypot(xs - objs[g][1], ys - objs[g][2]) <= r + 4
        assert np.array_equal(inside, near)


def test_touching_objects_are_one_blob():
    """Centre distance 2r (edge gap 0): one connected blob, reported once (ofpd.split_frac 0, the
    default; with it > 0 two touching closed outlines are split: tests/test_objects_split.py)."""
    m = moving_disc(200, 170, 40) | moving_disc(240, 170, 40)
    objs, _ = ofpd_io.group_objects_xy(stages(m), SENSOR, CFG)
    assert len(objs) == 1


def test_fast_objects_leftovers_on_slower_stages_are_not_reported_again():
    d, cx, cy = 90, 200.0, 180.0
    edges = moving_disc(cx, cy, d, step=(8, 0))
    lead = edges & (np.arange(SENSOR[0]) > cx)[None, :]             # stage 4 takes the leading edge
    trail = edges & ~lead                                           # stage 2 gets the trailing edge
    arc = disc(cx - 2, cy, d + 6) & ~disc(cx - 2, cy, d) & (np.arange(SENSOR[1]) < cy - 30)[:, None]
    neighbour = moving_disc(cx + 1.5 * d, cy, d)                    # a slow object 3 radii away
    objs, _claims = ofpd_io.group_objects_xy(stages(arc | neighbour, trail, None, lead), SENSOR, CFG)
    assert [o[0] for o in objs] == [3, 0]                           # the fast one once, the neighbour once
    assert np.hypot(objs[1][1] - (cx + 1.5 * d), objs[1][2] - cy) <= 2.0
    # the fast object's frame is all of its events (every stage), none of the neighbour's
    frames = np.zeros((4, 5, 2) + SENSOR[::-1], bool)
    frames[3, 0, 0] = lead
    frames[1, 0, 0] = trail
    frames[0, 0, 0] = arc | neighbour
    ks, merged = ofpd_io.merge_frames(frames, CFG)
    assert ks.tolist() == [4, 1]
    px = ofpd_io.event_pixels(merged)
    assert np.array_equal(px[0], lead | trail | arc) and np.array_equal(px[1], neighbour)


def test_noise_pixels_are_no_object():
    rng = np.random.default_rng(0)
    m = np.zeros(SENSOR[::-1], bool)
    m[rng.integers(0, SENSOR[1], 400), rng.integers(0, SENSOR[0], 400)] = True      # isolated events
    objs, _ = ofpd_io.group_objects_xy(stages(m), SENSOR, CFG)
    assert objs == []


@pytest.mark.parametrize("d, size", [(15, 64), (36, 64), (50, 128), (90, 256), (200, 512), (400, 512)])
def test_crop_scales_with_the_object(d, size):
    m = moving_disc(240, 180, d) if d < 400 else np.ones(SENSOR[::-1], bool)
    xs, ys = xy(m)
    assert ofpd_io.crop_size_xy(xs, ys, CFG) == size
    x0, y0, s = ofpd_io.crop_origin_xy(xs, ys, SENSOR, CFG)
    assert s == size and abs(x0 + (s - 1) / 2 - xs.mean()) <= 0.5 and abs(y0 + (s - 1) / 2 - ys.mean()) <= 0.5
    # every event of the object is in the crop, pooled into the g x g cells
    frames = np.zeros((1, 5, 2) + SENSOR[::-1], bool)
    frames[0, 0, 1] = m
    x = ofpd_io.prepare(frames, CFG)
    c, g, _ = ofpd_io.input_shape(CFG)
    p = s // g
    assert x.shape == (1, c, g, g)
    inside = (xs >= x0) & (xs < x0 + s) & (ys >= y0) & (ys < y0 + s)
    assert x[0, :-2].sum() * p * p == pytest.approx(inside.sum())
    assert d >= 400 or inside.all()
    # the coordinate planes: cell centres, spacing P
    np.testing.assert_allclose(np.diff(x[0, -2, 0]) * ofpd_io.COORD_SCALE, p, atol=1e-3)
    assert ofpd_io.crop_size_xy(xs, ys, ToffeConfig(ofpd={"crop_px": 128})) == 128     # legacy: fixed


def test_pose_and_speed_round_trip_through_the_module_and_onnx(tmp_path):
    """Encode targets as head outputs (pose residual in cells of P px, ln cells/ms) -> the module
    and its ONNX export -> decode gives the targets back, for small and big crops."""
    import onnxruntime as ort

    c, g, _ = ofpd_io.input_shape(CFG)
    origins = np.array([[100, 50, 64], [-40, 10, 512], [300, 200, 256]], dtype=np.int64)
    x = ofpd_io.prepare_xy([(np.zeros(0, np.int64),) * 3] * 3, origins, CFG)
    pool = origins[:, 2] / g
    centre = origins[:, :2] + (origins[:, 2:] - 1) / 2.0
    pose_t = centre + np.array([[3.0, -2.0], [-100.0, 40.0], [10.5, 0.25]])
    ks = np.array([1, 4, 2])
    v_px = np.array([0.5, 12.0, 3.0])                              # px/ms inside bins 1, 4, 2
    dir_t = np.array([0.3, -2.0, 3.0])
    m = OFPD.from_config(CFG).eval()
    heads = [(m.pose_head, (pose_t - centre) / (g * pool[:, None] / 2)),
             (m.direction_head, np.stack([np.cos(dir_t), np.sin(dir_t)], axis=1)),
             (m.speed_head, (np.log(v_px) - np.log(pool))[:, None])]
    for i in range(3):                       # one row at a time: the heads' bias is the encoded target
        with torch.no_grad():
            for head, target in heads:
                head.weight.zero_()
                head.bias.copy_(torch.from_numpy(target[i].astype(np.float32)))
            out = [t.numpy() for t in m(torch.from_numpy(x[i:i + 1]))]
        torch.onnx.export(m, torch.from_numpy(x[i:i + 1]), tmp_path / "m.onnx", input_names=["events"],
                          output_names=["pose", "direction", "speed"], opset_version=17)
        onnx_out = ort.InferenceSession(str(tmp_path / "m.onnx"), providers=["CPUExecutionProvider"]).run(
            None, {"events": x[i:i + 1]})
        for got in (out, onnx_out):
            d = ofpd_io.decode(*got, ks[i:i + 1], CFG)
            np.testing.assert_allclose([d["x_px"][0], d["y_px"][0]], pose_t[i], atol=2e-3)
            np.testing.assert_allclose(d["direction_rad"][0], np.arctan2(np.sin(dir_t[i]), np.cos(dir_t[i])), atol=1e-5)
            np.testing.assert_allclose(d["speed_px_ms"][0], v_px[i], rtol=1e-5)
            np.testing.assert_allclose(d["speed_mps"][0], CFG.speed_scale.to_mps(v_px[i]), rtol=1e-5)
    # the training target is what the module outputs for the right head value
    np.testing.assert_allclose(ofpd_io.speed_target(v_px, CFG), np.log(v_px))


def test_link_components_equals_brute_force(rng):
    """compiled.link_components (sorted sweep, joins only what is needed) against the
    definition: pixels max(|dx|, |dy|) <= link apart are connected, transitively."""
    from toffe_deploy.compiled import link_components

    for t in range(60):
        h, w = 24, 32
        m = rng.random((h, w)) < rng.uniform(0.02, 0.4)
        ys, xs = np.nonzero(m)
        if xs.size == 0:
            continue
        link = int(rng.integers(1, 5))
        labels, n = link_components(xs.astype(np.int64), ys.astype(np.int64), link, w)
        adj = (np.abs(xs[:, None] - xs[None]) <= link) & (np.abs(ys[:, None] - ys[None]) <= link)
        ref = np.full(xs.size, -1)
        k = 0
        for i in range(xs.size):
            if ref[i] < 0:
                stack, ref[i] = [i], k
                while stack:
                    q = stack.pop()
                    for j in np.flatnonzero(adj[q] & (ref < 0)):
                        ref[j] = k
                        stack.append(j)
                k += 1
        assert n == k
        assert all(len(set(ref[labels == g])) == 1 for g in range(n))     # same partition
        assert labels[np.argmin(ys * w + xs)] == 0                          # numbered row-major


def test_min_gap_equals_brute_force_also_at_the_threshold(rng):
    """compiled.min_gap (vectorized brute force with bounding-box skips, any pixel order)
    against the definition: the smallest pairwise distance when it is <= t, else inf; t drawn
    also as exact distances sqrt(k), where float rounding decides."""
    from toffe_deploy.compiled import min_gap

    for _ in range(400):
        na, nb = rng.integers(1, 40, 2)
        s = int(rng.integers(3, 60))
        xa, ya = rng.integers(0, s, na), rng.integers(0, s, na)
        xb, yb = rng.integers(0, s, nb) + int(rng.integers(-30, 30)), rng.integers(0, s, nb)
        d = float(np.sqrt(((xa[:, None] - xb[None]) ** 2 + (ya[:, None] - yb[None]) ** 2).min()))
        for t in (float(rng.uniform(0, 40)), d, float(np.sqrt(max(round(d * d) - 1, 0)))):
            got = min_gap(xa, ya, xb, yb, t)
            assert got == (d if d <= t else np.inf), (d, t, got)
    assert min_gap(np.zeros(0, np.int64), np.zeros(0, np.int64), xb, yb, 5.0) == np.inf


# ---- ofpd.stages "union" (the current default) against "join" (each stage apart, checkpoints
# before it): the cascade hands one object's edges to several stages; together they are one
# object, and two objects stay two.

JOIN = ToffeConfig(sensor_size=SENSOR, ofpd={**ofpd_io.OFPD_DEFAULTS, "stages": "join"})


def grouped(mask, config):
    """The objects of one stage frame's pixels ``mask`` and the mask of each over those pixels
    (listed as xy(mask) gives them)."""
    objs, claims = ofpd_io.group_objects_xy(stages(mask), SENSOR, config)
    xs, ys = xy(mask)
    return objs, ofpd_io.object_masks_xy(xs, ys, objs, claims), (xs, ys)


def square_ring(cx, cy, side, width=3):
    """The outline of a square (what a square moving by ``width`` px along its diagonal gives)."""
    ys, xs = np.ogrid[:SENSOR[1], :SENSOR[0]]
    d = np.maximum(np.abs(xs - cx), np.abs(ys - cy))
    return (d <= side / 2) & (d > side / 2 - width)


def test_settings_current_union_legacy_join():
    assert ofpd_io.ofpd_settings(CFG)["stages"] == "union"
    assert ofpd_io.ofpd_settings(ToffeConfig(ofpd={"grouping": "blobs"}))["stages"] == "join"   # an older config.json
    with pytest.raises(ValueError, match="stages"):
        ofpd_io.ofpd_settings(ToffeConfig(ofpd={"stages": "all"}))


def test_pieces_a_faster_stage_reported_apart_are_one_object():
    """The appearance split's commonest false positive: a 140 px square whose four corners
    reached stage 2 (each >= min_events) and whose outline went to stage 1. "join" reports
    each corner (the outline joins the first); "union" one object at the centre, of stage 2,
    claiming every pixel."""
    cx, cy, side = 240, 180, 140
    ring = square_ring(cx, cy, side)
    ys, xs = np.ogrid[:SENSOR[1], :SENSOR[0]]
    corners = ring & (np.abs(xs - cx) > side / 2 - 6) & (np.abs(ys - cy) > side / 2 - 6)
    pix = stages(ring & ~corners, corners)
    assert len(ofpd_io.group_objects_xy(pix, SENSOR, JOIN)[0]) == 4
    objs, claims = ofpd_io.group_objects_xy(pix, SENSOR, CFG)
    assert len(objs) == 1 and objs[0][0] == 1
    assert np.hypot(objs[0][1] - cx, objs[0][2] - cy) <= 1.0
    assert ofpd_io.object_masks_xy(*xy(ring), objs, claims)[0].all()


@pytest.mark.parametrize("radii", [3.5, 4.0, 5.0])
def test_two_objects_whose_edges_the_cascade_split_stay_two(radii):
    """The pairs split's merge: disc A's sides on stage 4 and the rest of its edges on stage
    2, disc B's left edge on stage 2 and its right edge on stage 3 (each stage sees open
    pieces; stage 2 holds pieces of both). "union": two objects at their centres, each
    claiming exactly its own events, A of stage 4 and B of stage 3."""
    d, r = 36, 18.0
    a = np.array([150.0, 180.0])
    b = a + [radii * r, 0.0]
    ea, eb = moving_disc(*a, d), moving_disc(*b, d)
    cols = np.arange(SENSOR[0])[None, :]
    sides = ea & (np.abs(cols - a[0]) > 0.6 * r)
    pix = stages(None, (ea & ~sides) | (eb & (cols < b[0])), eb & (cols >= b[0]), sides)
    objs, claims = ofpd_io.group_objects_xy(pix, SENSOR, CFG)
    assert [o[0] for o in objs] == [3, 2]
    np.testing.assert_allclose([o[1:] for o in objs], [a, b], atol=2.0)
    xs, ys = xy(ea | eb)
    masks = ofpd_io.object_masks_xy(xs, ys, objs, claims)
    assert np.array_equal(masks[0], ea[ys, xs]) and np.array_equal(masks[1], eb[ys, xs])


def test_sparse_arcs_of_a_large_slow_object_are_one_object():
    """A 160 px disc moving 0.5 px: its two edges come out as short pieces (< min_events each,
    gaps > link_px), two open arcs 150 px apart. The second merge on the groups joins them:
    one object at the centre (as "join" joined them), not two reported on the arcs."""
    cx, cy, d = 240.0, 180.0, 160
    ring = disc(cx + 1, cy, d) ^ disc(cx - 1, cy, d)
    ys, xs = np.nonzero(ring)
    theta = np.arctan2(ys - cy, xs - cx)
    keep = np.floor(theta / 0.1).astype(int) % 2 == 0                 # pieces of ~8 px, gaps of ~8 px
    m = np.zeros_like(ring)
    m[ys[keep], xs[keep]] = True
    objs, claims = ofpd_io.group_objects_xy(stages(m), SENSOR, CFG)
    assert len(objs) == 1 and np.hypot(objs[0][1] - cx, objs[0][2] - cy) <= 3.0
    assert ofpd_io.object_masks_xy(*xy(m), objs, claims)[0].mean() > 0.95     # all but isolated specks
    assert len(ofpd_io.group_objects_xy(stages(m), SENSOR, JOIN)[0]) == 1    # (at the first arc's centroid)


def star_edges(cx, cy, r_out, r_in, step, rot):
    """The events of a 5-pointed star (points at r_out, notches at r_in) moving ``step`` px up."""
    import cv2

    def star(y):
        a = np.arange(10) * np.pi / 5 + rot
        r = np.where(np.arange(10) % 2 == 0, r_out, r_in)
        pts = np.stack([cx + r * np.sin(a), y - r * np.cos(a)], 1).round().astype(np.int32)
        m = np.zeros(SENSOR[::-1], np.uint8)
        cv2.fillPoly(m, [pts], 1)
        return m.astype(bool)

    return star(cy) ^ star(cy - step)


def test_a_closed_object_stays_closed_when_a_noise_seed_joins_it():
    """pairs_b4_001's merge: a spiky object surrounds its centroid, a 4-pixel noise seed 8 px
    away joins it (within merge_frac) and moves the union's centroid so that ``surrounds`` no
    longer holds; the group then counted as open edges and took in a neighbour's edge 12 px
    away (ratio 0.25 < edge_merge_frac). Closed once, closed for good: two objects."""
    from toffe_deploy.compiled import surrounds

    star = star_edges(200, 180, 24, 6, 3, 0.6)
    seed = np.zeros_like(star)
    seed[209:211, 194:196] = True
    edge = np.zeros_like(star)
    edge[142:144, 185:215] = True                                   # 12 px above the star's top point
    assert surrounds(*xy(star)) and not surrounds(*xy(star | seed))
    objs, masks, (xs, ys) = grouped(star | seed | edge, CFG)
    assert len(objs) == 2
    np.testing.assert_allclose(sorted(o[1:] for o in objs), [(199.5, 142.5), (200.0, 178.0)], atol=0.6)
    top = int(np.argmin([o[2] for o in objs]))
    assert np.array_equal(masks[top], edge[ys, xs])                  # the edge alone; the seed is the star's
    assert np.array_equal(masks[1 - top], (star | seed)[ys, xs])


def test_stage_is_the_fastest_holding_min_events():
    """A few pixels (below min_events) of the object on stage 4 do not make it a stage-4
    object; stage 3's 30 do; the rest of its edges are on stage 1."""
    cx, cy = 200.0, 150.0
    e = moving_disc(cx, cy, 40)
    ys, xs = np.nonzero(e)
    order = np.argsort(xs, kind="stable")
    s4, s3 = np.zeros_like(e), np.zeros_like(e)
    s4[ys[order[-5:]], xs[order[-5:]]] = True
    s3[ys[order[-35:-5]], xs[order[-35:-5]]] = True
    objs, claims = ofpd_io.group_objects_xy(stages(e & ~s4 & ~s3, None, s3, s4), SENSOR, CFG)
    assert [o[0] for o in objs] == [2]
    assert ofpd_io.object_masks_xy(xs, ys, objs, claims)[0].all()


def test_row_major_and_link_components_on_shuffled_pixels_with_repeats(rng):
    """compiled.row_major (two counting sorts) gives the stable (y, x) order of any input order,
    repeated pixels included, and link_components' labels do not depend on the input order."""
    from toffe_deploy.compiled import link_components, row_major

    for t in range(40):
        n = int(rng.integers(1, 200))
        xs = rng.integers(3, 3 + int(rng.integers(1, 60)), n).astype(np.int64)
        ys = rng.integers(5, 5 + int(rng.integers(1, 40)), n).astype(np.int64)
        order, row_start, y0 = row_major(xs, ys)
        assert np.array_equal(order, np.lexsort((xs, ys)))                 # stable: repeats in input order
        assert y0 == ys.min() and np.array_equal(np.diff(row_start), np.bincount(ys - y0))
        u = np.unique(ys * 64 + xs)
        ux, uy = u % 64, u // 64
        perm = rng.permutation(u.size)
        link = int(rng.integers(1, 4))
        labels, k = link_components(ux, uy, link, 64)
        labels_p, k_p = link_components(ux[perm], uy[perm], link, 64)
        assert k == k_p and np.array_equal(labels_p, labels[perm])


def test_union_objects_claims_are_the_stage_order_claims_sorted_stably(rng):
    """compiled.union_objects' claims (keys sorted, owner) are the claimed stage pixels taken
    fastest stage first and sorted stably by key, whether the stages' pixels are disjoint (the
    row-major walk) or repeat across stages (the sort)."""
    from toffe_deploy.compiled import union_objects

    n_checked = 0
    for t in range(60):
        xs, ys, starts, seen = [], [], [0], np.zeros(0, np.int64)
        for i in range(int(rng.integers(1, 5))):
            cx, cy = rng.integers(0, 60, 2)
            k = int(rng.integers(0, 120))
            key = np.unique(np.clip(cy + rng.integers(-8, 9, k), 0, 47) * 64 + np.clip(cx + rng.integers(-8, 9, k), 0, 63))
            if t % 2:                                            # disjoint stages, as the cascade gives them
                key = np.setdiff1d(key, seen)
                seen = np.union1d(seen, key)
            key = rng.permutation(key)
            xs.append(key % 64)
            ys.append(key // 64)
            starts.append(starts[-1] + key.size)
        xs, ys = np.concatenate(xs).astype(np.int64), np.concatenate(ys).astype(np.int64)
        starts = np.array(starts, np.int64)
        _stage, _cx, _cy, owner, keys, own = union_objects(xs, ys, starts, 64, 2, 0.2, 1.5, 6, 2)
        order = np.concatenate([np.arange(starts[i], starts[i + 1]) for i in range(len(starts) - 2, -1, -1)])
        order = order[owner[order] >= 0]
        ref_keys = ys[order] * 64 + xs[order]
        srt = np.argsort(ref_keys, kind="stable")
        assert np.array_equal(keys, ref_keys[srt]) and np.array_equal(own, owner[order][srt])
        n_checked += keys.size
    assert n_checked > 500


APART = ToffeConfig(sensor_size=SENSOR, ofpd={**ofpd_io.OFPD_DEFAULTS, "closed_apart": True})


def test_two_whole_outlines_stay_two_objects_with_closed_apart():
    """`crossing` seed 20's merge: a 17 px ring 7 px from the corner of a 57 px square's outline
    (both surround their centroids, both >= min_events pixels; 7 px < merge_frac 0.2 * 57):
    joined into one object between them by default, two objects at their centres with
    ofpd.closed_apart. A piece of one outline (an open edge) near it still joins it."""
    from toffe_deploy.compiled import surrounds

    sq = square_ring(200, 200, 57)
    ring = disc(243, 163, 17) ^ disc(243, 163, 12)                  # corner (228, 172): gap ~7 px
    edge = np.zeros_like(sq)
    edge[202:204, 233:243] = True                                   # an open piece 5 px right of the square
    assert surrounds(*xy(sq)) and surrounds(*xy(ring)) and not surrounds(*xy(edge))
    assert len(ofpd_io.group_objects_xy(stages(sq | ring), SENSOR, CFG)[0]) == 1
    objs, masks, (xs, ys) = grouped(sq | ring | edge, APART)
    assert len(objs) == 2
    np.testing.assert_allclose(sorted(o[1:] for o in objs), [(200.5, 200.1), (243.0, 163.0)], atol=1.5)
    big = int(np.argmin([o[1] for o in objs]))
    assert np.array_equal(masks[big], (sq | edge)[ys, xs]) and np.array_equal(masks[1 - big], ring[ys, xs])
    with pytest.raises(ValueError, match="closed_apart"):
        ofpd_io.ofpd_settings(ToffeConfig(ofpd={**ofpd_io.OFPD_DEFAULTS, "closed_apart": 1}))
    with pytest.raises(ValueError, match="closed_apart"):
        ofpd_io.ofpd_settings(ToffeConfig(ofpd={**ofpd_io.OFPD_DEFAULTS, "stages": "join", "closed_apart": True}))
