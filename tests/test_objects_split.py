"""Splitting a blob that holds two touching objects (ofpd.split_frac > 0, compiled.split_two):
two touching outlines give two objects at their own centres, while one large ring, one filled
disc, a fast object's smear and one object whose leading and trailing edges lie apart stay one.
Synthetic pixel sets on a 240 x 180 sensor, through ofpd_io.group_objects_xy (the kernel the
cpu runtime calls too: compiled.union_objects)."""
from __future__ import annotations

import numpy as np
import pytest

from toffe_deploy import ofpd_io
from toffe_deploy.compiled import split_two
from toffe_deploy.config import ToffeConfig

SENSOR = (240, 180)
SPLIT = ToffeConfig(sensor_size=SENSOR, ofpd={**ofpd_io.OFPD_DEFAULTS, "split_frac": 0.6, "split_waist": 0.65})
PLAIN = ToffeConfig(sensor_size=SENSOR)


def disc(cx, cy, d):
    ys, xs = np.ogrid[:SENSOR[1], :SENSOR[0]]
    return (xs - cx) ** 2 + (ys - cy) ** 2 <= (d / 2.0) ** 2


def ring(cx, cy, d, width=3):
    """An object's closed outline (a diamond or square whose every edge fired, a textured disc)."""
    return disc(cx, cy, d) & ~disc(cx, cy, d - 2 * width)


def objects(mask, config=SPLIT, stage=1):
    ys, xs = np.nonzero(mask)
    pix = [(xs, ys) if k == stage else (np.zeros(0, np.int64), np.zeros(0, np.int64)) for k in range(4)]
    return ofpd_io.group_objects_xy(pix, SENSOR, config)


@pytest.mark.parametrize("d0, d1, angle", [(40, 40, 0.0), (40, 40, 45.0), (40, 40, 30.0), (80, 80, 90.0),
                                           (60, 30, 0.0), (60, 30, 45.0)])
def test_two_touching_outlines_are_two_objects_at_their_centres(d0, d1, angle):
    a = np.radians(angle)
    c0 = np.array([70.0, 60.0])
    c1 = c0 + (d0 + d1) / 2.0 * np.array([np.cos(a), np.sin(a)])       # centre distance = sum of radii
    r0, r1 = ring(*c0, d0), ring(*c1, d1)
    assert len(objects(r0 | r1, PLAIN)[0]) == 1                           # split off: one blob between them
    objs, claims = objects(r0 | r1)
    assert len(objs) == 2 and all(o[0] == 1 for o in objs)
    got = sorted((o[1], o[2]) for o in objs)
    np.testing.assert_allclose(got, sorted([tuple(c0), tuple(c1)]), atol=2.0)
    ys, xs = np.nonzero(r0 | r1)
    masks = ofpd_io.object_masks_xy(xs, ys, objs, claims)
    mine = [int(np.argmin([np.hypot(o[1] - c[0], o[2] - c[1]) for o in objs])) for c in (c0, c1)]
    for c, own, d in zip((c0, c1), mine, (d0, d1)):                      # each claims its own outline
        near = np.hypot(xs - c[0], ys - c[1]) <= d / 2.0 + 0.5
        assert (masks[own] & ~near).sum() <= 0.05 * near.sum()


@pytest.mark.parametrize("angle", [0.0, 90.0])
def test_two_touching_moving_discs_edges_are_two_objects(angle):
    """The events of two 40 px discs moving 4 px to the right (each its leading and trailing
    crescent), side by side or one above the other, touching: two objects near their centres."""
    a = np.radians(angle)
    c0 = np.array([70.0, 60.0])
    c1 = c0 + 40.0 * np.array([np.cos(a), np.sin(a)])
    m = [disc(*(c + [dx, 0.0]), 40) for c in (c0, c1) for dx in (-2.0, 2.0)]
    edges = (m[0] ^ m[1]) | (m[2] ^ m[3])
    assert len(objects(edges, PLAIN)[0]) == 1
    objs, _ = objects(edges)
    assert len(objs) == 2
    np.testing.assert_allclose(sorted((o[1], o[2]) for o in objs), sorted([tuple(c0), tuple(c1)]), atol=3.0)


def test_one_object_stays_one():
    cx, cy = 120.0, 90.0
    ys, xs = np.ogrid[:SENSOR[1], :SENSOR[0]]
    cases = {
        "ring 160": ring(cx, cy, 160),
        "filled 60": disc(cx, cy, 60),
        "smear": np.any([disc(cx + dx, cy, 30) for dx in range(-15, 16)], axis=0),   # 30 px disc moving 30 px
        "fast edges": disc(cx - 8, cy, 30) ^ disc(cx + 8, cy, 30),        # its edges when moving 16 px
        "leading and trailing edges": (np.abs(ys - cy) <= 30) & (np.abs(np.abs(xs - cx) - 30) <= 1.5),
        "square outline 140": (np.maximum(np.abs(xs - cx), np.abs(ys - cy)) <= 70)
        & (np.maximum(np.abs(xs - cx), np.abs(ys - cy)) > 67),
    }
    for name, m in cases.items():
        objs, _ = objects(m)
        assert len(objs) == 1, name
        assert np.hypot(objs[0][1] - cx, objs[0][2] - cy) <= 2.0, name


def test_split_two_cut_runs_through_the_contact():
    """The cut lies where the two outlines touch: each side is one whole ring."""
    r0, r1 = ring(60, 90, 60), ring(105, 90, 30)
    ys, xs = np.nonzero(r0 | r1)
    side = split_two(xs.astype(np.int64), ys.astype(np.int64), 12, 0.6, 0.65)
    assert side.any()
    second = r1[ys, xs] if side[np.argmax(xs)] else r0[ys, xs]
    assert (side == second).mean() >= 0.98


def test_split_settings():
    assert ofpd_io.ofpd_settings(PLAIN)["split_frac"] == 0.0                 # off unless a checkpoint sets it
    assert ofpd_io.blob_settings(ofpd_io.ofpd_settings(SPLIT))[-4:] == (0.6, 0.65, 0.0, False)
    with pytest.raises(ValueError, match="split_frac"):
        ofpd_io.ofpd_settings(ToffeConfig(ofpd={**ofpd_io.OFPD_DEFAULTS, "stages": "join", "split_frac": 0.6}))
