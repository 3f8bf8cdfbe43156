"""Two objects in a row along their motion, whose facing edges join into one blob
(ofpd.split_polarity > 0, compiled.two_sided): each half of the split holds one object's
leading edge of one polarity and its trailing edge of the other, so each half is a whole object
although it does not surround its centroid. One object's leading and trailing edges, and edges
whose pixels fired both polarities, stay one. Synthetic pixel sets on a 240 x 180 sensor, through
ofpd_io.group_objects_xy, and the same window through every form of the grouping (dense frames,
the cpu runtime's compiled batch and its Python form)."""
from __future__ import annotations

import numpy as np
import pytest

from toffe_deploy import ofpd_io
from toffe_deploy.compiled import new_scratch, two_sided
from toffe_deploy.config import ToffeConfig
from toffe_deploy.events.core import EVENT_DTYPE
from toffe_deploy.runtime import ofpd_input
from toffe_deploy.runtime.spikes import SpikeVolume

SENSOR = (240, 180)
SPLIT = {**ofpd_io.OFPD_DEFAULTS, "split_frac": 0.6, "split_waist": 0.65}
NO_POL = ToffeConfig(sensor_size=SENSOR, ofpd=SPLIT)
POL = ToffeConfig(sensor_size=SENSOR, ofpd={**SPLIT, "split_polarity": 0.25})
LEAD, TRAIL = 2, 1          # bit 2: channel 1 (ON), bit 1: channel 0 (OFF): a bright object moving up


def bars(cx, cy, side, thick=3):
    """(xs, ys, pol) of a square of ``side`` px at (cx, cy) moving up (-y): its top edge fired
    LEAD, its bottom edge TRAIL, ``thick`` px deep (how far it moved in the window)."""
    xs, ys, pol = [], [], []
    half = side // 2
    for y0, p in ((cy - half, LEAD), (cy + half - thick + 1, TRAIL)):
        yy, xx = np.mgrid[y0:y0 + thick, cx - half:cx + half + 1]
        xs.append(xx.ravel())
        ys.append(yy.ravel())
        pol.append(np.full(xx.size, p, np.int8))
    return np.concatenate(xs), np.concatenate(ys), np.concatenate(pol)


def join(*sets):
    return tuple(np.concatenate(a) for a in zip(*sets))


def shape(cx, cy, d, kind):
    ys, xs = np.ogrid[:SENSOR[1], :SENSOR[0]]
    if kind == "disc":
        return (xs - cx) ** 2 + (ys - cy) ** 2 <= (d / 2.0) ** 2
    if kind == "diamond":
        return np.abs(xs - cx) + np.abs(ys - cy) <= d / 2.0
    return np.maximum(np.abs(xs - cx), np.abs(ys - cy)) <= d / 2.0


def moving(cx, cy, d, kind, step=4.0):
    """(xs, ys, pol) of the events of an object of ``d`` px at (cx, cy) moving ``step`` px up
    (-y) in the window: where it arrived fired LEAD, where it left TRAIL."""
    now, before = shape(cx, cy - step / 2, d, kind), shape(cx, cy + step / 2, d, kind)
    ys, xs = np.nonzero(now ^ before)
    return xs, ys, np.where(now[ys, xs], LEAD, TRAIL).astype(np.int8)


def objects(xs, ys, pol, config):
    empty = (np.zeros(0, np.int64),) * 2 + (np.zeros(0, np.int8),)
    return ofpd_io.group_objects_xy([(xs, ys, pol), empty, empty, empty], SENSOR, config)[0]


@pytest.mark.parametrize("kinds", [("disc", "disc"), ("square", "diamond")])
def test_two_objects_in_a_row_whose_edges_join_are_two_with_polarity(kinds):
    """Two 40 px objects 4 px apart, the second ahead of the first at 60 degrees from their
    motion: the first's leading edge meets the second's trailing edge."""
    d, a = 40, np.radians(-90 + 60)
    u = (d + 4) * np.array([np.cos(a), np.sin(a)])
    c0 = np.array([110.0, 85.0]) - u / 2
    c1 = c0 + u
    xs, ys, pol = join(moving(*c0, d, kinds[0]), moving(*c1, d, kinds[1]))
    assert len(objects(xs, ys, pol, NO_POL)) == 1              # the halves do not surround their centroids
    objs = objects(xs, ys, pol, POL)
    assert len(objs) == 2
    np.testing.assert_allclose(sorted((o[1], o[2]) for o in objs), sorted([tuple(c0), tuple(c1)]), atol=5.0)


@pytest.mark.parametrize("kind, d", [("disc", 60), ("square", 50), ("diamond", 80)])
def test_one_moving_object_stays_one(kind, d):
    xs, ys, pol = moving(110, 90, d, kind, step=6.0)
    objs = objects(xs, ys, pol, POL)
    assert len(objs) == 1 and np.hypot(objs[0][1] - 110, objs[0][2] - 90) <= 2.0


def test_edges_that_fired_both_polarities_stay_one():
    d, a = 40, np.radians(-90 + 60)
    u = (d + 4) * np.array([np.cos(a), np.sin(a)])
    c0 = np.array([110.0, 85.0]) - u / 2
    xs, ys, pol = join(moving(*c0, d, "disc"), moving(*(c0 + u), d, "disc"))
    assert len(objects(xs, ys, np.full_like(pol, 3), POL)) == 1        # every pixel fired both
    rng = np.random.default_rng(0)
    mixed = rng.choice(np.array([1, 2], np.int8), size=pol.size)        # noise: both polarities everywhere
    assert len(objects(xs, ys, mixed, POL)) == 1
    with pytest.raises(ValueError, match="polarities"):
        objects(xs, ys, pol[:-1], POL)


def test_two_sided_needs_both_polarities_apart():
    xs, ys, pol = bars(50, 50, 31)
    assert two_sided(xs, ys, pol, 0.25)
    assert not two_sided(xs, ys, np.full_like(pol, LEAD), 0.25)
    lead = pol == LEAD
    few = pol.copy()
    few[np.flatnonzero(~lead)[5:]] = LEAD                      # 5 trailing pixels of 186: under a quarter
    assert not two_sided(xs, ys, few, 0.25)
    assert two_sided(xs, ys, few, 0.02)
    checker = (1 + (xs + ys) % 2).astype(np.int8)              # both polarities on each bar: centroids together
    assert not two_sided(xs, ys, checker, 0.25)


def window_events(sets):
    """A 500 us window whose events fire each (x, y, pol) set's pixels once, ON for LEAD."""
    xs, ys, pol = join(*sets)
    ev = np.zeros(xs.size, EVENT_DTYPE)
    ev["x"], ev["y"] = xs, ys
    ev["t"] = np.arange(xs.size) % 500
    ev["p"] = pol == LEAD
    return ev


def test_every_form_of_the_grouping_agrees_with_polarity():
    """The dense frames (training, eval, export), the cpu runtime's compiled batch, its Python
    form and merge_objects read the same polarities: the same objects, with the same ones."""
    d, a = 40, np.radians(-90 + 60)
    u = (d + 4) * np.array([np.cos(a), np.sin(a)])
    c0 = np.array([110.0, 85.0]) - u / 2
    ev = window_events([moving(*c0, d, "disc"), moving(*(c0 + u), d, "disc"), moving(205, 150, 30, "disc")])
    for cfg, n_obj in ((NO_POL, 2), (POL, 3)):
        vol = SpikeVolume.from_events(ev, 0, 500, cfg.n_bins, SENSOR)
        frames = [np.ones(len(vol), bool)] + [np.zeros(len(vol), bool)] * 3
        dense = np.stack([vol.subset(m).to_dense() for m in frames])
        ks_dense, merged = ofpd_io.merge_frames(dense, cfg)
        ks_c, _x, n_c, _ones = ofpd_input.batch(vol, frames, cfg, new_scratch(SENSOR[0] * SENSOR[1]))
        ks_py, _x, n_py, _ones = ofpd_input.batch(vol, frames, cfg)
        ks_m, merged_m = ofpd_input.merge_objects(vol, frames, cfg)
        assert ks_dense.size == n_obj
        for ks in (ks_c, ks_py, ks_m):
            np.testing.assert_array_equal(ks, ks_dense)
        n_dense = merged.reshape(n_obj, -1).sum(axis=1)
        np.testing.assert_array_equal(n_c, n_dense)
        np.testing.assert_array_equal(n_py, n_dense)
        np.testing.assert_array_equal([len(m) for m in merged_m], n_dense)


def test_split_polarity_settings():
    assert ofpd_io.ofpd_settings(ToffeConfig())["split_polarity"] == 0.0       # off unless a checkpoint sets it
    assert ofpd_io.blob_settings(ofpd_io.ofpd_settings(POL))[-2] == 0.25
    assert not ofpd_io.uses_polarity(ofpd_io.ofpd_settings(NO_POL))
    for bad in (-0.1, 0.6, "0.2", True):
        with pytest.raises(ValueError, match="split_polarity"):
            ofpd_io.ofpd_settings(ToffeConfig(ofpd={**SPLIT, "split_polarity": bad}))
    with pytest.raises(ValueError, match="split_frac"):
        ofpd_io.ofpd_settings(ToffeConfig(ofpd={**ofpd_io.OFPD_DEFAULTS, "split_polarity": 0.25}))
