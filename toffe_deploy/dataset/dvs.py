"""Log-intensity DVS emulator, sampled (the paper's simulated DAVIS: 20,000 samples/s).

Each pixel keeps the log intensity L0 it saw at the start and an integer level m (its number of
net ON minus OFF events so far); its reference is L0 + m C, with C the pixel's own contrast
threshold (mismatch: C ~ N(C_mean, C_sigma) per pixel, clipped at C_min). At every sample with
log intensity L the pixel fires as many events as threshold crossings since its reference:

    x = (L - L0) / C,   m' = clamp(m, floor(x), ceil(x)),   events = m' - m  (ON if > 0)

i.e. |L - ref| >= C fires floor(|L - ref| / C) events and moves the reference by that many C
(the usual DVS model, ESIM/v2e style), all time-stamped at the sample. Written as a clamp, one
sample costs one numpy call over the pixels being rendered, and a chunk of samples is rendered
at once.

Refractory period (``refractory_us`` > 0, a real pixel's reset and bandwidth limit): a pixel
fires at most one event per sample, only if its last event is at least ``refractory_us`` old,
and firing resets its reference to the current log intensity (m = x, no longer an integer):

    n = trunc(x - m),   fire = n != 0 and t - t_last >= refractory_us,   m' = x if fire

so crossings beyond the first at one sample, or inside the refractory period, are lost, as on a
sensor whose pixel is held in reset. With ``refractory_us`` = 0 the ideal model above is used.

Background activity (optional): each pixel fires independent Poisson noise events at
``noise_rate_hz`` with random polarity, also on the sample grid. Hot pixels (optional): a
fraction ``hot_pixel_fraction`` of the pixels (drawn per sequence) fire Poisson events at
``hot_pixel_rate_hz`` (1 kHz by default: a leaky pixel, one polarity each, drawn). Noise and hot
pixel events are added after the emulator, so the refractory period does not thin them.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from ..jit import njit

from ..events.core import EVENT_DTYPE


@dataclass(frozen=True)
class DVSParams:
    """Contrast threshold C (log units) with per-pixel mismatch, refractory period, background
    noise and hot pixels (module doc)."""

    threshold: float = 0.25
    threshold_sigma: float = 0.03
    threshold_min: float = 0.05
    noise_rate_hz: float = 0.0
    log_eps: float = 1e-3
    refractory_us: float = 0.0
    hot_pixel_fraction: float = 0.0
    hot_pixel_rate_hz: float = 1000.0

    def log(self, intensity: np.ndarray) -> np.ndarray:
        """The sensor's log intensity, log(I + eps) (eps keeps black pixels finite)."""
        return np.log(intensity + self.log_eps)


class DVSEmulator:
    """Per-pixel DVS state over a (height, width) sensor; feed it rectangles or lists of pixels
    with their samples."""

    def __init__(self, initial_log: np.ndarray, params: DVSParams, rng: np.random.Generator):
        h, w = initial_log.shape
        self.params = params
        self.width = w
        self.l0 = np.asarray(initial_log, dtype=np.float64).copy()
        thr = rng.normal(params.threshold, params.threshold_sigma, size=(h, w))
        self.inv_c = 1.0 / np.maximum(thr, params.threshold_min)
        self.m = np.zeros((h, w), dtype=np.float64)  # integers, kept float to clamp in place
        refractory = params.refractory_us > 0
        self.t_last = np.full((h, w), -np.inf) if refractory else None
        #: flat indices of pixels holding a crossing the refractory period kept from firing: they
        #: may fire later with no change of input, so a caller feeding only changing pixels must
        #: feed these too (None without a refractory period).
        self.pending = np.zeros(0, dtype=np.int64) if refractory else None
        self._fed = np.zeros(h * w, dtype=bool) if refractory else None   # scratch, all False

    def process(self, y0: int, x0: int, log_i: np.ndarray, t_us: np.ndarray) -> np.ndarray:
        """Events of the rectangle at (y0, x0) for samples log_i (K, h, w) taken at t_us (K,).

        The rectangle must hold every pixel whose intensity changed since the previous call
        that covered it; pixels outside it keep their state. Returns EVENT_DTYPE sorted by t.
        """
        k, h, w = log_i.shape
        ys, xs = np.mgrid[y0:y0 + h, x0:x0 + w]
        return self.process_pixels((ys * self.width + xs).reshape(-1), log_i.reshape(k, h * w), t_us)

    def process_pixels(self, idx: np.ndarray, log_i: np.ndarray, t_us: np.ndarray) -> np.ndarray:
        """Events of the pixels at flat indices idx (N,) (y * width + x) for samples log_i (K, N)
        taken at t_us (K,). Every pixel whose intensity changed since its last call (and every
        pending one) must be fed; the others keep their state. EVENT_DTYPE sorted by t."""
        k = log_i.shape[0]
        m_flat = self.m.reshape(-1)
        x = (log_i - self.l0.reshape(-1)[idx]) * self.inv_c.reshape(-1)[idx]
        if self.t_last is not None:
            d = self._refractory(idx, x, np.asarray(t_us, dtype=np.float64))
        else:
            lo, hi = np.floor(x), np.ceil(x)
            levels = np.empty((k + 1, idx.shape[0]), dtype=np.float64)
            levels[0] = m_flat[idx]
            for i in range(k):  # the reference depends on the past: one clamp per sample
                np.clip(levels[i], lo[i], hi[i], out=levels[i + 1])
            m_flat[idx] = levels[k]
            d = np.diff(levels, axis=0)
        ks, js = np.nonzero(d)
        dv = d[ks, js]
        n = np.abs(dv).astype(np.int64)
        pix = idx[js]
        out = np.empty(int(n.sum()), dtype=EVENT_DTYPE)
        out["t"] = np.repeat(np.asarray(t_us, dtype=np.int64)[ks], n)
        out["x"] = np.repeat(pix % self.width, n)
        out["y"] = np.repeat(pix // self.width, n)
        out["p"] = np.repeat(dv > 0, n)
        return out

    def _refractory(self, idx: np.ndarray, x: np.ndarray, t_us: np.ndarray) -> np.ndarray:
        """(K, N) int8 events (+1 ON, -1 OFF, 0) of the refractory model (module doc)."""
        m_flat, last_flat = self.m.reshape(-1), self.t_last.reshape(-1)
        m, last = m_flat[idx], last_flat[idx]
        d = np.zeros(x.shape, dtype=np.int8)
        still = np.zeros(idx.shape[0], dtype=bool)
        _refractory_kernel(np.ascontiguousarray(x), m, last, t_us, float(self.params.refractory_us), d, still)
        m_flat[idx], last_flat[idx] = m, last
        fed = self._fed
        fed[idx] = True
        old = self.pending[~fed[self.pending]]
        fed[idx] = False
        self.pending = np.concatenate([old, idx[still]])
        return d


@njit(cache=True, nogil=True)
def _refractory_kernel(x, m, last, t_us, refr, d, still):
    """The refractory model (module doc) per pixel j over samples i, in place on m, last (N,),
    d (K, N); still[j] = the pixel holds a crossing at the end (pending). Compiled: one pass
    per pixel instead of six numpy calls per sample."""
    k, n = x.shape
    for j in range(n):
        mj, lj = m[j], last[j]
        for i in range(k):
            c = np.trunc(x[i, j] - mj)
            if c != 0 and t_us[i] - lj >= refr:
                d[i, j] = 1 if c > 0 else -1
                mj = x[i, j]
                lj = t_us[i]
        m[j], last[j] = mj, lj
        still[j] = np.trunc(x[k - 1, j] - mj) != 0


def noise_events(rate_hz: float, n_samples: int, sample_us: int, sensor_size: tuple[int, int],
                 rng: np.random.Generator) -> np.ndarray:
    """Background activity: Poisson(rate * pixels * duration) events, uniform over pixels and
    samples 1..n_samples-1, random polarity; sorted by t."""
    w, h = sensor_size
    if rate_hz <= 0 or n_samples < 2:
        return np.empty(0, dtype=EVENT_DTYPE)
    n = int(rng.poisson(rate_hz * w * h * (n_samples - 1) * sample_us * 1e-6))
    out = np.empty(n, dtype=EVENT_DTYPE)
    out["t"] = np.sort(rng.integers(1, n_samples, n)) * sample_us
    out["x"] = rng.integers(0, w, n)
    out["y"] = rng.integers(0, h, n)
    out["p"] = rng.integers(0, 2, n)
    return out


def hot_pixel_events(fraction: float, rate_hz: float, n_samples: int, sample_us: int,
                     sensor_size: tuple[int, int], rng: np.random.Generator) -> np.ndarray:
    """Hot pixels: round(fraction * W * H) distinct pixels, one polarity each, each firing
    Poisson(rate * duration) events uniform over samples 1..n_samples-1; sorted by t."""
    w, h = sensor_size
    n_hot = int(round(fraction * w * h))
    if n_hot <= 0 or rate_hz <= 0 or n_samples < 2:
        return np.empty(0, dtype=EVENT_DTYPE)
    pix = rng.choice(w * h, size=n_hot, replace=False)
    pol = rng.integers(0, 2, n_hot)
    counts = rng.poisson(rate_hz * (n_samples - 1) * sample_us * 1e-6, n_hot)
    which = np.repeat(np.arange(n_hot), counts)
    out = np.empty(which.shape[0], dtype=EVENT_DTYPE)
    out["t"] = rng.integers(1, n_samples, which.shape[0]) * sample_us
    out["x"] = pix[which] % w
    out["y"] = pix[which] // w
    out["p"] = pol[which]
    return out[np.argsort(out["t"], kind="stable")]
