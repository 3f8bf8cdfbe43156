"""Sparse OFS equals the dense conv + LIF, and a tiny OFS learns to separate fast from slow."""
from __future__ import annotations

import numpy as np
import torch

from toffe_deploy.config import ToffeConfig
from toffe_deploy.model.data import WindowSet
from toffe_deploy.model.ofs import OFS
from toffe_deploy.model.ofs_sparse import pack_window, sparse_ofs_margin
from toffe_deploy.model.lif import lif_sequence
from toffe_deploy.model.train import calibrate_threshold, separation_scores, train_ofs_stage, pack_training_windows


def test_sparse_rows_equal_dense_conv_and_lif(rng):
    torch.manual_seed(0)
    m = OFS(2, 3)
    with torch.no_grad():
        m.conv.weight.normal_(0.3, 0.2)
    vol = np.zeros((5, 2, 20, 26), bool)
    vol[:, :, 4:12, 6:15] = rng.random((5, 2, 8, 9)) < 0.4
    vol[:, :, 15, 20] = True
    bits, event = pack_window(vol, 3)
    feats = ((torch.from_numpy(bits)[..., None] >> torch.arange(18, dtype=torch.int32)) & 1).float()
    with torch.no_grad():
        cur_dense = m.conv(torch.from_numpy(vol.astype(np.float32)))[:, 0]            # (B, H, W)
        near = torch.from_numpy(np.abs(cur_dense.numpy()).sum(0) > 0)
        margin = sparse_ofs_margin(feats, m.conv.weight, m.threshold, m.leak)
        spikes_dense = lif_sequence(cur_dense, m.threshold, m.leak)
    cur_sparse = (feats @ m.conv.weight.reshape(-1)).detach()
    # every pixel with nonzero dense current is a packed row, and the currents agree
    ys, xs = np.nonzero(near.numpy())
    packed_px = set(zip(*np.nonzero(np.pad(vol.any(axis=(0, 1)), 1)[1:-1, 1:-1] | near.numpy())))
    assert set(zip(ys, xs)) <= packed_px
    dense_at_rows = cur_dense.reshape(5, -1)[:, _row_pixels(vol)]
    torch.testing.assert_close(cur_sparse, dense_at_rows)
    fired_dense = spikes_dense.reshape(5, -1)[:, _row_pixels(vol)].amax(0) > 0
    assert torch.equal(margin > 0, fired_dense) and fired_dense.any()
    assert event.sum() == vol.any(axis=(0, 1)).sum()


def _row_pixels(vol):
    import cv2

    ev = vol.any(axis=(0, 1)).astype(np.uint8)
    near = cv2.dilate(ev, np.ones((3, 3), np.uint8)).astype(bool)
    ys, xs = np.nonzero(near)
    return torch.from_numpy(ys * vol.shape[-1] + xs)


def _square_window(rng, speed_px_per_bin, size=8, n_bins=5, res=32):
    """Events of a bright square moving right: ON at newly covered, OFF at uncovered pixels,
    sampled at 4 sub-steps per bin; edges also flicker (p = 0.25) as a DVS pixel near threshold does."""
    vol = np.zeros((n_bins, 2, res, res), bool)
    x0 = rng.uniform(4, 10)
    y0 = int(rng.integers(4, res - size - 4))
    prev = None
    for t in range(n_bins):
        for sub in range(4):
            x = x0 + speed_px_per_bin * (t + sub / 4)
            occ = np.zeros(res, bool)
            occ[int(np.floor(x)):int(np.floor(x)) + size] = True
            if prev is not None:
                vol[t, 1, y0:y0 + size, occ & ~prev] = True
                vol[t, 0, y0:y0 + size, prev & ~occ] = True
            prev = occ
        lead, trail = int(np.floor(x)) + size, int(np.floor(x))
        for col, ch in ((min(lead, res - 1), 1), (trail, 0)):
            vol[t, ch, y0:y0 + size, col] |= rng.random(size) < 0.25
    return vol


def test_tiny_ofs_learns_to_separate_fast_from_slow():
    rng = np.random.default_rng(0)
    cfg = ToffeConfig(sensor_size=(32, 32), speed_bins=((1, 10), (10, 100)), representative_speeds=(5, 50),
                      ofpd={"min_events": 4})
    speeds = [0.1] * 24 + [3.0] * 24
    vols = np.stack([_square_window(rng, s) for s in speeds])
    bins = np.array([1] * 24 + [2] * 24)
    ws = WindowSet.from_dense(vols, bins)
    packed, pbins = pack_training_windows(ws, 3, seed=0, progress=False)
    # DOTIE weights with a low threshold: fires on both speeds, nothing separated yet
    init = dict(weight=np.full((1, 2, 3, 3), 0.15, np.float32), threshold=0.2, leak=0.3)
    from toffe_deploy.model.reference import quantize_stages

    before = separation_scores(quantize_stages([init, init]), ws, cfg)[1]
    r = train_ofs_stage(2, packed, pbins, epochs=25, seed=0, device=torch.device("cpu"), batch=16, lr=0.05,
                        init=init, progress=False)
    trained = dict(weight=r["weight"], threshold=r["threshold"], leak=r["leak"])
    learned = separation_scores(quantize_stages([trained, trained]), ws, cfg)[1]
    p, _curve = calibrate_threshold(2, trained, ws, cfg)
    after = separation_scores(quantize_stages([p, p]), ws, cfg)[1]
    assert r["loss_curve"][-1] < r["loss_curve"][0]
    bal = lambda s: 0.5 * (s["tp"] / (s["tp"] + s["fn"]) + s["tn"] / (s["tn"] + s["fp"]))
    assert bal(before) <= 0.6                       # the start fires on (nearly) everything
    assert bal(learned) >= 0.9 and bal(after) >= bal(learned)
