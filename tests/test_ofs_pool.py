"""The OFS grid (ToffeConfig.ofs_pool): stages on the sensor OR-pooled over p x p blocks, their
masks back on every sensor pixel; every backend gives the same object flow as the dense reference
(the cpu pipeline's case: tests/test_run_pipeline.py, test_cpu_pipeline_equals_dense_reference)."""
import json

import numpy as np
import pytest

from toffe_deploy.cascade import pool_any, run_cascade, unpool
from toffe_deploy.cli import main
from toffe_deploy.energy.cost_model import loihi2_footprint
from toffe_deploy.fixed_point import run_ofs_fixed
from toffe_deploy.runtime.spikes import SpikeVolume

SENSOR = (63, 47)          # odd: the last row and column of blocks are partial


@pytest.fixture(scope="module")
def env(tmp_path_factory, make_bundle, make_recording):
    root = tmp_path_factory.mktemp("pool")
    return {"root": root, "bundle": make_bundle(root / "sub", sensor=SENSOR, ofs_pool=2),
            "zero": make_bundle(root / "zero", sensor=SENSOR, ofs_pool=2, reset="zero"),
            "rec": make_recording(root / "rec.h5", sensor=SENSOR)}


def test_pool_and_unpool_on_partial_blocks(rng):
    x = rng.random((5, 2, 7, 9)) < 0.1
    p = pool_any(x, 2)
    assert p.shape == (5, 2, 4, 5)
    for y in range(4):
        for xx in range(5):
            assert p[..., y, xx].tolist() == x[..., 2 * y:2 * y + 2, 2 * xx:2 * xx + 2].any(axis=(-2, -1)).tolist()
    up = unpool(p, 2, (7, 9))
    assert up.shape == x.shape and np.all(up[x])          # every one lies in a firing cell
    assert pool_any(x, 1) is not x and np.array_equal(pool_any(x, 1), x)


def test_spike_volume_pool_matches_dense_and_maps_back(rng):
    x = rng.random((5, 2, 7, 9)) < 0.1
    vol = SpikeVolume.from_dense(x)
    grid, inv = vol.pool(2)
    assert np.array_equal(grid.to_dense(), pool_any(x, 2))
    # a mask over the grid's ones comes back as the ones of the masked cells
    keep = rng.random(len(grid)) < 0.5
    back = vol.subset(keep[inv]).to_dense()
    assert np.array_equal(back, x & unpool(grid.subset(keep).to_dense(), 2, (7, 9)))
    assert vol.pool(1) == (vol, None)


def test_pooled_cascade_stages_see_the_masked_pooled_window(env):
    """Pool(x_k) = inp_k: the masks, constant on each block, commute with the pooling."""
    b = env["bundle"]
    from toffe_deploy.events.binning import bin_window
    from toffe_deploy.events.io import open_events

    cfg = b.config
    with open_events(env["rec"]) as src:
        xs = [bin_window(ev, t0, cfg.dt_us, cfg.n_bins, cfg.sensor_size) for t0, ev in src.iter_windows(cfg.dt_us)]
    fired = 0
    for x in xs:
        res = run_cascade(x, lambda k, inp: run_ofs_fixed(inp, b.ofs[k - 1]), cfg.n_speed_bins, cfg.mask_kernel, 2)
        rest = x > 0
        for k in range(cfg.n_speed_bins, 0, -1):
            assert res.inputs[k - 1].shape[-2:] == (24, 32) and res.frames[k - 1].shape == x.shape
            assert np.array_equal(pool_any(rest, 2), res.inputs[k - 1])
            assert np.array_equal(res.frames[k - 1], rest & unpool(res.closed[k - 1], 2, x.shape[-2:]))
            rest = rest & ~res.frames[k - 1]
            fired += int(res.spikes[k - 1].sum())
    assert fired > 0


def test_pooled_reset_zero_bundle_runs_stock_lava_like_cpu(env, capsys, tmp_path):
    pytest.importorskip("lava")
    out = {}
    for target in ("cpu", "loihi-sim"):
        rc = main(["run", str(env["zero"].root), "--target", target, "--events", str(env["rec"]), "--max-windows", "5",
                   "--out", str(tmp_path / f"{target}.jsonl"), "--no-progress"])
        assert rc == 0, capsys.readouterr().err
        lines = [json.loads(s) for s in (tmp_path / f"{target}.jsonl").read_text().splitlines()]
        out[target] = [r for r in lines if r.get("type") != "header"]       # the header names the target
    assert out["cpu"] == out["loihi-sim"]
    assert sum(len(r.get("objects", [])) for r in out["cpu"]) > 0


def test_pool_2_puts_four_640x480_stages_on_one_chip():
    full, pooled = loihi2_footprint(640, 480, 4, 5), loihi2_footprint(640, 480, 4, 5, pool=2)
    assert full["chips"] == 2 and not full["fits_one_chip"]
    assert pooled["ofs_grid"] == [320, 240] and pooled["neurons"] == 4 * 76800
    assert pooled["cores"] == 40 and pooled["chips"] == 1 and pooled["fits_one_chip"]


def test_spike_volume_pool_equals_numpy_unique_for_any_block_size(rng):
    """SpikeVolume.pool (compiled.pool_index: a merge of each pooled row's sorted runs) gives
    np.unique of the pooled ids with its inverse, and both volumes' planes and pixels."""
    for p in (2, 3, 4):
        for _ in range(20):
            shape = (int(rng.integers(1, 6)), 2, int(rng.integers(1, 30)), int(rng.integers(1, 30)))
            vol = SpikeVolume.from_dense(rng.random(shape) < rng.uniform(0, 0.5))
            grid, inv = vol.pool(p)
            b, c, h, w = shape
            hp, wp = -(-h // p), -(-w // p)
            bc, pix = np.divmod(vol.idx, h * w)
            want, want_inv = np.unique((bc * hp + pix // w // p) * wp + pix % w // p, return_inverse=True)
            assert np.array_equal(grid.idx, want) and np.array_equal(inv, want_inv.reshape(-1))
            assert grid.shape == (b, c, hp, wp)
            assert np.array_equal(grid.bc, grid.idx // (hp * wp)) and np.array_equal(grid.pix, grid.idx % (hp * wp))
            assert np.array_equal(vol.bc, bc) and np.array_equal(vol.pix, pix)
