"""OFS in Loihi 2 fixed point: the quantizer and the numpy reference of the arithmetic.

This is the arithmetic our Lava OFS neuron (lava_procs, tag ``fixed_pt``) runs, and the fast
host path of the ``cpu`` target. Per time step t of a window (state reset at window start):

    a_in[t] = sum_{c,i,j} w[c,i,j] * s_in[t, c, y+i-K//2, x+j-K//2]        (integer conv, zero pad)
    u[t]    = a_in[t] << 6                                                    (du = 4095: memoryless)
    reset "subtract":  v[t] = clip24( trunc0(v[t-1] * (4096 - dv) / 4096) + u[t] - (vth_mant << 6) * o[t-1] )
    reset "zero":      v[t] = clip24( trunc0((o[t-1] ? 0 : v[t-1]) * (4096 - dv) / 4096) + u[t] )
    o[t]    = v[t] > (vth_mant << 6)

"subtract" is the paper's eq. (1)-(2) (reset by subtraction of vth * o[t-1], undecayed, at step
t); "zero" is Loihi 2's stock CUBA LIF (Lava's PyLifModelBitAcc / LIFReset: v = 0 after a
spike), what NeuroCores, netx and NIR run. Float quantities: W = w / s, vth = vth_mant / s,
lambda = 1 - dv / 4096, the state scaled by 64 * s. trunc0 truncates toward zero (as Lava's
bit-accurate LIF); clip24 saturates to +-(2^23 - 1). Inputs are binary spikes (count > 0) per
polarity.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from .config import RESETS

WEIGHT_BITS = 8
WEIGHT_MAX = 2 ** (WEIGHT_BITS - 1) - 1      # 127: symmetric int8 range
DECAY_BITS = 12
DECAY_UNITY = 2 ** DECAY_BITS                 # 4096
VTH_MANT_MAX = 2 ** 17 - 1                    # 17-bit threshold mantissa
STATE_MAX = 2 ** 23 - 1                       # 24-bit signed state
STATE_SHIFT = 6                               # Lava scales a_in and vth by 2**6


@dataclass(frozen=True)
class LoihiOFSParams:
    """One OFS stage as Loihi 2 integers.

    weight: int32 array (1, C_in, K, K), values in [-127, 127], torch's cross-correlation layout.
    vth_mant: threshold mantissa (spike where v > vth_mant << 6).
    dv: voltage decay, v <- trunc0(v * (4096 - dv) / 4096); lambda = 1 - dv / 4096.
    du: current decay; 4095 makes the synaptic current memoryless (u = a_in << 6).
    weight_scale: s, float weight = weight / s, float threshold = vth_mant / s.
    reset: "subtract" (paper eq. 1) or "zero" (stock Loihi 2 LIF); see the module docstring.
    """

    weight: np.ndarray
    vth_mant: int
    dv: int
    weight_scale: float
    du: int = DECAY_UNITY - 1
    notes: tuple[str, ...] = field(default=())
    reset: str = "subtract"

    def __post_init__(self) -> None:
        if self.reset not in RESETS:
            raise ValueError(f"reset must be one of {', '.join(RESETS)}, got {self.reset!r}")

    @property
    def kernel_size(self) -> int:
        return int(self.weight.shape[-1])

    def float_equivalent(self) -> tuple[np.ndarray, float, float]:
        """(W, vth, lambda) in float units that this integer stage represents exactly."""
        s = self.weight_scale
        return self.weight.astype(np.float64) / s, self.vth_mant / s, 1.0 - self.dv / DECAY_UNITY


def quantize_ofs(weight: np.ndarray, threshold: float, leak: float, reset: str = "subtract") -> LoihiOFSParams:
    """Quantize a float OFS stage (weight (1, C, K, K), threshold, leak) to Loihi 2 fixed point.

    The weight scale s maps the largest |w| to 127, using the full 8-bit range; the threshold
    is expressed in the same scale. A threshold whose mantissa would exceed 17 bits lowers s.
    Values Loihi cannot hold are clamped, and each clamp is named in ``notes``.
    Raises ValueError for non-finite or non-positive inputs that cannot be represented at all.
    """
    w = np.asarray(weight, dtype=np.float64)
    notes: list[str] = []
    if not np.all(np.isfinite(w)):
        raise ValueError("weight has NaN or infinite values")
    if not (np.isfinite(threshold) and np.isfinite(leak)):
        raise ValueError(f"threshold {threshold} or leak {leak} is not finite")
    if threshold <= 0:
        raise ValueError(f"threshold {threshold} must be > 0 (Loihi thresholds are unsigned)")
    wmax = float(np.max(np.abs(w)))
    if wmax == 0.0:
        raise ValueError("all weights are zero")
    s = WEIGHT_MAX / wmax
    if threshold * s > VTH_MANT_MAX:
        s = VTH_MANT_MAX / threshold
        notes.append(f"threshold/weight ratio too large for 17 bits: weight scale lowered to {s:.4g}")
    w_int = np.clip(np.rint(w * s), -WEIGHT_MAX, WEIGHT_MAX).astype(np.int32)
    vth_mant = int(np.clip(np.rint(threshold * s), 1, VTH_MANT_MAX))
    lam = float(leak)
    if lam < 0.0 or lam > 1.0:
        notes.append(f"leak {lam:.4g} outside [0, 1] clamped to {min(max(lam, 0.0), 1.0):g}")
        lam = min(max(lam, 0.0), 1.0)
    dv = int(np.clip(np.rint((1.0 - lam) * DECAY_UNITY), 0, DECAY_UNITY))
    if dv == DECAY_UNITY:
        # 12-bit field holds 0..4095; dv = 4096 (no memory) is the same as 4095 up to 1/4096.
        dv = DECAY_UNITY - 1
        notes.append("leak 0 represented as dv = 4095 (lambda = 1/4096)")
    return LoihiOFSParams(weight=w_int, vth_mant=vth_mant, dv=dv, weight_scale=float(s), notes=tuple(notes),
                          reset=reset)


def trunc_decay(v: np.ndarray, decay: int) -> np.ndarray:
    """trunc0(v * (4096 - decay) / 4096) in int64, truncating toward zero as Loihi does."""
    x = v.astype(np.int64) * (DECAY_UNITY - decay)
    return np.sign(x) * (np.abs(x) >> DECAY_BITS)


def synaptic_input(spikes_in: np.ndarray, weight: np.ndarray) -> np.ndarray:
    """a_in for one time step: integer cross-correlation of (C, H, W) binary input, zero padded.

    cv2.filter2D in float32 is exact here: every partial sum is an integer below 2**24.
    """
    c_in, h, w = spikes_in.shape
    acc = np.zeros((h, w), dtype=np.float32)
    for c in range(c_in):
        if not spikes_in[c].any():
            continue
        acc += cv2.filter2D(spikes_in[c].astype(np.float32), cv2.CV_32F, weight[0, c].astype(np.float32),
                            borderType=cv2.BORDER_CONSTANT)
    return acc.astype(np.int64)


def lif_step(v: np.ndarray, o_prev: np.ndarray, a_in: np.ndarray, p: LoihiOFSParams) -> tuple[np.ndarray, np.ndarray]:
    """One fixed-point OFS neuron step (see module docstring; p.reset picks the rule). Returns (v, o)."""
    vth = p.vth_mant << STATE_SHIFT
    if p.reset == "zero":
        v = trunc_decay(np.where(o_prev, 0, v), p.dv) + (a_in.astype(np.int64) << STATE_SHIFT)
    else:
        v = trunc_decay(v, p.dv) + (a_in.astype(np.int64) << STATE_SHIFT) - vth * o_prev.astype(np.int64)
    np.clip(v, -STATE_MAX, STATE_MAX, out=v)
    return v, v > vth


def run_ofs_fixed(spikes_in: np.ndarray, p: LoihiOFSParams) -> np.ndarray:
    """Run one OFS stage over a window. spikes_in: (B, C, H, W), nonzero = spike.

    Returns the output spikes (B, H, W) bool. The state starts at zero for every window.
    """
    b, _c, h, w = spikes_in.shape
    v = np.zeros((h, w), dtype=np.int64)
    o = np.zeros((h, w), dtype=bool)
    out = np.zeros((b, h, w), dtype=bool)
    for t in range(b):
        v, o = lif_step(v, o, synaptic_input(spikes_in[t] > 0, p.weight), p)
        out[t] = o
    return out
