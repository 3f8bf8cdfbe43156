"""OFS on the pixels that can fire: a sparse, exact form of conv + LIF for fast training.

A pixel whose K x K neighbourhood holds no event in the whole window gets zero current at every
step, so from zero state it never fires and adds nothing to the OFS loss. Training therefore
only needs the set P of pixels within K // 2 of an event pixel. For each p in P and step t the
binary neighbourhood is packed into one integer (bit c*K*K + i*K + j = input[t, c, y+i-K//2,
x+j-K//2], torch's cross-correlation order), so

    current[t, p] = sum_bits bit * W.flatten()      ==  conv2d(input, W)[t, y_p, x_p]

and eq. (1)-(2) run on |P| neurons instead of R^2. A 160 x 160 training crop has ~1-3 k such
pixels: the conv that dominated dense training (a 2 -> 1 channel conv is memory bound) becomes
a (rows x 18) matrix product. tests/test_model_ofs_sparse.py checks equality with OFS.forward.
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
import torch

from .lif import lif_sequence, lif_step


@dataclass
class SparseWindows:
    """Packed neighbourhoods of many windows: rows[offsets[i]:offsets[i+1]] belong to window i.

    bits (B, M) int32, event (M,) bool (the pixel itself had an event), n_event (N,) per window.
    """

    bits: np.ndarray
    event: np.ndarray
    offsets: np.ndarray
    kernel: int
    channels: int

    def __len__(self) -> int:
        return int(self.offsets.shape[0] - 1)

    def batch(self, idx: np.ndarray, device) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """(features (B, M, C*K*K) float, event (M,) float, window id (M,) long) of windows idx."""
        rows = [np.arange(self.offsets[i], self.offsets[i + 1]) for i in idx]
        owner = np.concatenate([np.full(r.size, j, dtype=np.int64) for j, r in enumerate(rows)]) if rows else np.zeros(0, np.int64)
        rows = np.concatenate(rows) if rows else np.zeros(0, np.int64)
        nb = self.channels * self.kernel * self.kernel
        b = torch.from_numpy(self.bits[:, rows]).to(device)
        feats = ((b[..., None] >> torch.arange(nb, device=device, dtype=b.dtype)) & 1).to(torch.float32)
        return feats, torch.from_numpy(self.event[rows]).to(device=device, dtype=torch.float32), torch.from_numpy(owner).to(device)


def pack_window(vol: np.ndarray, kernel: int) -> tuple[np.ndarray, np.ndarray]:
    """(B, C, H, W) binary -> (bits (B, |P|) int32, or int64 past 31 bits, event (|P|,) bool)
    for the pixel set P (2 channels x 5 x 5 = 50 bits needs int64)."""
    b, c, h, w = vol.shape
    nbits = c * kernel * kernel
    if nbits > 63:
        raise ValueError(f"a {c} x {kernel} x {kernel} neighbourhood ({nbits} bits) is too large to pack into int64")
    dtype = np.int32 if nbits <= 31 else np.int64
    r = kernel // 2
    vol = vol > 0
    ev = vol.any(axis=(0, 1))
    near = cv2.dilate(ev.astype(np.uint8), np.ones((kernel, kernel), np.uint8)).astype(bool)
    ys, xs = np.nonzero(near)
    padded = np.pad(vol, ((0, 0), (0, 0), (r, r), (r, r)))
    bits = np.zeros((b, ys.size), dtype=dtype)
    for ci in range(c):
        for i in range(kernel):
            for j in range(kernel):
                bit = ci * kernel * kernel + i * kernel + j
                bits |= padded[:, ci, ys + i, xs + j].astype(dtype) << bit
    return bits, ev[ys, xs]


def pack_windows(vols, kernel: int) -> SparseWindows:
    """Pack an iterable of (B, C, H, W) windows."""
    bits, event, lens, c = [], [], [], 2
    for v in vols:
        bt, e = pack_window(v, kernel)
        bits.append(bt)
        event.append(e)
        lens.append(e.size)
        c = v.shape[1]
    dtype = np.result_type(*[bt.dtype for bt in bits]) if bits else np.int32
    return SparseWindows(np.concatenate([bt.astype(dtype, copy=False) for bt in bits], axis=1), np.concatenate(event), np.concatenate([[0], np.cumsum(lens)]).astype(np.int64),
                         kernel, c)


def sparse_ofs_spikes(feats: torch.Tensor, weight: torch.Tensor, vth: torch.Tensor, leak: torch.Tensor,
                      reset: str = "subtract") -> torch.Tensor:
    """Spikes (B, M) of eq. (1)-(2) with current = feats @ W.flatten()."""
    return lif_sequence(feats @ weight.reshape(-1), vth, leak, reset)


def sparse_ofs_margin(feats: torch.Tensor, weight: torch.Tensor, vth: torch.Tensor, leak: torch.Tensor,
                      reset: str = "subtract") -> torch.Tensor:
    """d (M,) = max_t u[t] / vth - 1 of eq. (1)-(2) (d > 0 iff the neuron fired in the window).

    A margin rather than spikes: it has a gradient for silent neurons too, so training cannot
    get stuck with a stage that never fires (the surrogate gradient vanishes far below vth).
    """
    cur = feats @ weight.reshape(-1)
    u = torch.zeros_like(cur[0])
    o = torch.zeros_like(cur[0])
    best = None
    for t in range(cur.shape[0]):
        u, o = lif_step(u, o, cur[t], vth, leak, reset)
        z = u / vth - 1.0
        best = z if best is None else torch.maximum(best, z)
    return best
