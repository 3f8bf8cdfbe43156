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
