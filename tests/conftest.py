"""Shared pytest fixtures: tiny factories, no mocks of real parts."""
from __future__ import annotations

import numpy as np
import pytest

from toffe_deploy.events import make_events


@pytest.fixture
def rng():
    return np.random.default_rng(1234)


@pytest.fixture
def random_events(rng):
    """Factory: n time-sorted random events on a (width, height) sensor over duration_us."""

    def make(n=1000, sensor_size=(32, 24), duration_us=10_000, t0=0):
        w, h = sensor_size
        t = np.sort(rng.integers(t0, t0 + duration_us, n))
        return make_events(rng.integers(0, w, n), rng.integers(0, h, n), t, rng.integers(0, 2, n))

    return make


def _make_bundle(root, sensor=(64, 48), ofpd=None, reset="subtract", ofs_pool=1, **config):
    """init_checkpoint -> quantize -> ONNX -> write_bundle: a real bundle without the exporter
    (``config``: further ToffeConfig fields, e.g. the front end's)."""
    import torch

    from toffe_deploy import ofpd_io
    from toffe_deploy.checkpoint import init_checkpoint, load_checkpoint
    from toffe_deploy.config import ToffeConfig
    from toffe_deploy.deploy.bundle import write_bundle
    from toffe_deploy.fixed_point import quantize_ofs
    from toffe_deploy.model.ofpd import OFPD

    cfg = ToffeConfig(sensor_size=sensor, ofpd=ofpd or {"crop_px": 32, "pool": 2, "min_events": 4}, reset=reset,
                      ofs_pool=ofs_pool, **config)
    ck = load_checkpoint(init_checkpoint(root / "ckpt", cfg, seed=1))
    # Low thresholds (0.25 .. 0.55, DOTIE's are 1.0 ..) so the sparse events of a tiny sensor make spikes.
    ofs = [quantize_ofs(p["weight"], 0.25 + 0.1 * k, 0.7, reset) for k, p in enumerate(ck.ofs)]
    model = OFPD.from_config(ck.config)
    model.load_state_dict({k: torch.from_numpy(v) for k, v in ck.ofpd_state.items()})
    model.eval()
    onnx_path = root / "ofpd.onnx"
    torch.onnx.export(model, torch.zeros((1,) + ofpd_io.input_shape(ck.config)), str(onnx_path),
                      input_names=["events"], output_names=["pose", "direction", "speed"],
                      dynamic_axes={"events": {0: "N"}}, opset_version=17)
    return write_bundle(root / "bundle", ck.config, ofs, onnx_path)


def _make_recording(path, sensor=(64, 48), duration=0.012, index=0, seed=0):
    """A multi-object recording from the data-set generator (our HDF5, with ground truth)."""
    import dataclasses

    from toffe_deploy.camera import PinholeCamera
    from toffe_deploy.dataset.splits import split_specs
    from toffe_deploy.dataset.synth import generate_sequence
    from toffe_deploy.events.io import write_events_h5

    spec = split_specs("multi", seed=seed, duration_s=duration)[index]
    spec = dataclasses.replace(spec, camera=PinholeCamera(width=sensor[0], height=sensor[1]))
    ev, gt, size = generate_sequence(spec, seed=seed)
    write_events_h5(path, ev, size, ground_truth=gt, t_range=(0, int(duration * 1e6)))
    return path


@pytest.fixture(scope="session")
def make_bundle():
    """Factory: make_bundle(root, sensor=(64, 48), ofpd=None, reset="subtract", ofs_pool=1) -> a real tiny deploy
    Bundle at root/bundle (untrained DOTIE-initialised OFS with low thresholds, random OFPD in ONNX)."""
    return _make_bundle


@pytest.fixture(scope="session")
def make_recording():
    """Factory: make_recording(path, sensor=(64, 48), duration=0.012, index=0, seed=0) -> path of a
    generated multi-object recording with ground truth."""
    return _make_recording


@pytest.fixture(scope="session")
def lines_per_target():
    """Factory: lines_per_target(bundle, windows, targets=("cpu", "loihi-sim")) -> {target: the
    JSON line of each window (sorted keys), tracker off}: the real Lava runtime for loihi-sim."""
    import json

    def run(bundle, windows, targets=("cpu", "loihi-sim")):
        from toffe_deploy.runtime.pipeline import Pipeline

        out = {}
        for target in targets:
            with Pipeline(bundle, target, track=False) as pipe:
                out[target] = [json.dumps(r.to_json(), sort_keys=True) for r in pipe.process_stream(windows)]
        return out

    return run
