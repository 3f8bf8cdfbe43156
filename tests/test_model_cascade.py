"""Cascade masking against OpenCV, and the bounding-box shortcut of the reference stages."""
from __future__ import annotations

import cv2
import numpy as np
import torch

from toffe_deploy.cascade import run_cascade
from toffe_deploy.fixed_point import quantize_ofs, run_ofs_fixed
from toffe_deploy.model.ofs import OFS
from toffe_deploy.model.reference import fixed_stage_fn, float_stage_fn


def test_closing_and_inversion_mask_match_opencv(rng):
    x = rng.random((3, 2, 20, 24)) < 0.3
    spikes = {2: rng.random((3, 20, 24)) < 0.05, 1: rng.random((3, 20, 24)) < 0.05}
    res = run_cascade(x, lambda k, inp: spikes[k] & inp.any(axis=1), 2, mask_kernel=5)
    se = np.ones((5, 5), np.uint8)
    out2 = (spikes[2] & x.any(axis=1)).any(axis=0).astype(np.uint8)
    closed2 = cv2.erode(cv2.dilate(out2, se), se).astype(bool)      # closing = dilate, then erode
    np.testing.assert_array_equal(res.closed[1], closed2)
    np.testing.assert_array_equal(res.frames[1], x & closed2)
    np.testing.assert_array_equal(res.inputs[0], x & ~closed2)      # eq. 4: inverted mask
    assert not (res.frames[0] & res.frames[1]).any()                # each event in one bin at most


def _blob_window(rng, h=30, w=40):
    x = np.zeros((5, 2, h, w), bool)
    x[:, :, 8:14, 25:33] = rng.random((5, 2, 6, 8)) < 0.6
    x[:, :, 20:24, 3:9] = rng.random((5, 2, 4, 6)) < 0.2
    return x


def test_fixed_stage_on_bbox_equals_full_sensor_run(rng):
    p = quantize_ofs(np.full((1, 2, 3, 3), 0.3), 0.9, 0.4)
    x = _blob_window(rng)
    np.testing.assert_array_equal(fixed_stage_fn([p])(1, x), run_ofs_fixed(x, p))


def test_float_stage_on_bbox_equals_full_sensor_run(rng):
    m = OFS(2, 3)
    x = _blob_window(rng)
    with torch.no_grad():
        full = m(torch.from_numpy(x.astype(np.float32))[:, None])[:, 0, 0].numpy() > 0
    np.testing.assert_array_equal(float_stage_fn([m])(1, x), full)
    assert full.any()
