"""The per-window loops of the hot path, compiled (numba): the window's binning (bin_index,
sorted_unique), the input front end (front_end_keep), the cpu cascade's indexing, OFS stage,
closing (compaction and close_square; closed_bits on 64-bit rows in the cascade) and mask split, and ofpd_io's box tests, box
means, density-seed grouping, the event-blob grouping of a window's stages (blob_objects:
components, their merging and the objects' claims in one pass), each object's crop and ones
(object_crops) and the OFPD input (fill_input, fill_motion).

Why compiled: a 500 us window holds a few thousand events, so the numpy form of these steps
(~25 calls per stage on arrays of ~2,000 values, plus the window's de-duplication and scatter
maps) spent most of its time in per-call overhead, not arithmetic. Each kernel here is one pass
over the window's ones, its active pixels or an object's pixels. The OFS runs on exact
integers (its scatter in int32 or int64, its LIF in float64, all values below 2**53): the
same integers as ``toffe_deploy.fixed_point.lif_step`` (tested bit exact, saturation included,
in tests/test_run_sparse.py); the means are exact integer sums divided once, as numpy's.

Kernels are compiled on first use and cached on disk (numba ``cache=True``), so only the first
run on a machine pays the compile (a few seconds); ``warm_up()`` does it eagerly.

Scratch: ``slot_of`` arrays are (H * W,) int32 filled with -1 (``new_scratch``); every kernel
that marks entries clears them again before it returns, so one scratch array serves every window.
"""
from __future__ import annotations

import numpy as np
from .jit import njit

from .fixed_point import DECAY_BITS, DECAY_UNITY, STATE_MAX, STATE_SHIFT


def new_scratch(n_pixels: int) -> np.ndarray:
    """A (n_pixels,) scratch array in the state the kernels expect (all -1); int32 (slots are
    below H * W), half the cache footprint of int64 for the random lookups."""
    return np.full(int(n_pixels), -1, dtype=np.int32)


@njit(cache=True, nogil=True)
def _slot(slot_of, key, keys, n):
    """The slot of ``key``: its existing one, or slot n (then keys[n] = key, and the caller
    counts n + 1 slots). A plain call that LLVM inlines: numba's IR-level inline="always" made
    the loops below three times slower (measured)."""
    s = slot_of[key]
    if s < 0:
        s = n
        slot_of[key] = n
        keys[n] = key
    return s


@njit(cache=True, nogil=True)
def _div_small(v, d, inv_d):
    """v // d for 0 <= v < 2**50 and d >= 1 (inv_d = 1.0 / d, rounded), from one float product
    and no correction: an integer division per element costs more than the rest of a pass over a
    window's ones (it is neither pipelined nor vectorized), a multiply does not. Exact: with
    v = q d + r, (v + 0.5) / d = q + (r + 0.5) / d lies at least 0.5 / d from an integer, and the
    two roundings (of 1 / d and of the product) move it by at most (v + 0.5) / d * 2**-52, less
    than 0.5 / d while v + 0.5 < 2**51 (tests/test_run_sparse.py checks it against //)."""
    return int((v + 0.5) * inv_d)


@njit(cache=True, nogil=True)
def dedupe(values, slot_of):
    """(unique values in order of first appearance, inverse) of non-negative ints below
    len(slot_of), in O(n) without sorting: values = unique[inverse]."""
    n = values.shape[0]
    uniq = np.empty(n, np.int64)
    inverse = np.empty(n, np.int64)
    u = 0
    for i in range(n):
        inverse[i] = s = _slot(slot_of, values[i], uniq, u)
        if s == u:
            u += 1
    for q in range(u):
        slot_of[uniq[q]] = -1
    return uniq[:u], inverse


@njit(cache=True, nogil=True)
def active_set(in_pix, width, height, kernel, slot_of):
    """The pixels an input at ``in_pix`` can drive through a kernel x kernel cross-correlation.

    Returns (active (M,) linear ids in order of first reach, tap_target (U, K*K)): input pixel q
    feeds active slot tap_target[q, i*K + j] through weight tap (i, j), or -1 where that target
    lies off the sensor (zero padding: no neuron there).
    """
    r = kernel // 2
    u = in_pix.shape[0]
    kk = kernel * kernel
    tap_target = np.empty((u, kk), np.int64)
    active = np.empty(u * kk, np.int64)
    m = 0
    inv_w = 1.0 / width
    off = np.empty(kk, np.int64)              # linear offset of each tap's target
    for i in range(kernel):
        for j in range(kernel):
            off[i * kernel + j] = (r - i) * width + (r - j)
    lo = kernel - 1 - r                        # targets span y - lo .. y + r (and x)
    for q in range(u):
        y = _div_small(in_pix[q], width, inv_w)
        x = in_pix[q] - y * width
        if y >= lo and y + r < height and x >= lo and x + r < width:    # every target on the sensor
            for k in range(kk):
                tap_target[q, k] = s = _slot(slot_of, in_pix[q] + off[k], active, m)
                if s == m:
                    m += 1
            continue
        for i in range(kernel):
            ty = y + r - i                      # out[ty, tx] += w[i, j] * in[ty + i - r, tx + j - r]
            for j in range(kernel):
                tx = x + r - j
                if ty < 0 or ty >= height or tx < 0 or tx >= width:
                    tap_target[q, i * kernel + j] = -1
                    continue
                tap_target[q, i * kernel + j] = s = _slot(slot_of, ty * width + tx, active, m)
                if s == m:
                    m += 1
    for s in range(m):
        slot_of[active[s]] = -1
    return active[:m].copy(), tap_target


@njit(cache=True, nogil=True)
def ofs_window(bc, pix, n_channels, width, height, kernel, slot_of):
    """runtime.ofs_sparse.SparseOFSWindow's indexing of a window's ones in one call: (b, c) of
    each one from its plane bc = b * C + c, (unique pixels in order of first appearance,
    inverse) = dedupe(pix), then active_set of those pixels: (b, c, in_pix, pix_inverse,
    active, tap_target)."""
    n = bc.shape[0]
    b = np.empty(n, np.int64)
    c = np.empty(n, np.int64)
    if n_channels == 2:
        for i in range(n):
            b[i] = bc[i] >> 1
            c[i] = bc[i] & 1
    else:
        inv_c = 1.0 / n_channels
        for i in range(n):
            b[i] = _div_small(bc[i], n_channels, inv_c)
            c[i] = bc[i] - b[i] * n_channels
    in_pix, inverse = dedupe(pix, slot_of)
    active, tap_target = active_set(in_pix, width, height, kernel, slot_of)
    return b, c, in_pix, inverse, active, tap_target


@njit(cache=True, nogil=True)
def lif_window(a_in, dv, vth_mant, reset_zero=False):
    """Spikes (B, M) of fixed_point.lif_step iterated over a window of a_in (B, M) int64 from
    v = 0, o = 0 (the neuron of ofs_stage); ``reset_zero``: the stock "zero" reset, else "subtract"."""
    spikes = np.empty(a_in.shape, np.bool_)
    lif_into(a_in, spikes, dv, vth_mant, reset_zero)
    return spikes


@njit(cache=True, nogil=True)
def lif_into(a_in, spikes, dv, vth_mant, reset_zero):
    """lif_window written into ``spikes`` (B, M) bool, from the first M columns of a_in (B, >= M),
    int64 or narrower (cascade_window's int32 buffer, with its dummy last column).

    In float64, exactly: every value is an integer below 2**53 (|v| < 2**23, v * (4096 - dv)
    < 2**35), the scaling by 1 / 4096 is exact, so trunc0(v * keep / 4096) is np.trunc of the
    product, and the sums, the clip and the compare are exact too. No o array: o[t-1] is
    v[t-1] > vth, so "zero" keeps (o ? 0 : v) as the state and "subtract" reads o from v.
    Branch free and time-step outer: the M neurons of a step are independent iterations the
    compiler vectorizes (float64 multiplies and truncations vectorize where int64 ones did not)."""
    n_bins, m = spikes.shape
    v = np.zeros(m, np.float64)
    vth = float(np.int64(vth_mant) << STATE_SHIFT)
    keep = float(DECAY_UNITY - dv) / DECAY_UNITY
    scale = float(1 << STATE_SHIFT)
    hi = float(STATE_MAX)
    if reset_zero:
        for t in range(n_bins):
            for s in range(m):
                x = np.trunc(v[s] * keep) + a_in[t, s] * scale
                x = min(max(x, -hi), hi)
                f = x > vth
                v[s] = 0.0 if f else x
                spikes[t, s] = f
    else:
        for t in range(n_bins):
            for s in range(m):
                x = np.trunc(v[s] * keep) + a_in[t, s] * scale - (vth if v[s] > vth else 0.0)
                x = min(max(x, -hi), hi)
                v[s] = x
                spikes[t, s] = x > vth


@njit(cache=True, nogil=True)
def ofs_stage(alive, b, c, pix_inverse, tap_target, weight, n_bins, n_active, dv, vth_mant, reset_zero=False):
    """One OFS stage on a window's active set: (spikes (B, M) bool, fired (M,) bool = any over t).

    a_in[t, slot] = sum of weight[c, tap] over the alive ones (b = t, channel c) that reach the
    slot through the tap; then per slot, from v = 0, o = 0 (fixed_point.lif_step):
        v = clip24(trunc0(v * (4096 - dv) / 4096) + (a_in << 6) - (vth_mant << 6) * o);  o = v > vth
    (with ``reset_zero``: v = clip24(trunc0((o ? 0 : v) * (4096 - dv) / 4096) + (a_in << 6)))
    """
    kk = tap_target.shape[1]
    a_in = np.zeros((n_bins, n_active), np.int64)
    for i in range(alive.shape[0]):
        if alive[i]:
            q = pix_inverse[i]
            t = b[i]
            ch = c[i]
            for k in range(kk):
                s = tap_target[q, k]
                if s >= 0:
                    a_in[t, s] += weight[ch, k]
    spikes = lif_window(a_in, dv, vth_mant, reset_zero)
    fired = np.zeros(n_active, np.bool_)
    for t in range(n_bins):
        for s in range(n_active):
            if spikes[t, s]:
                fired[s] = True
    return spikes, fired


@njit(cache=True, nogil=True)
def split_closed(alive, pix_inverse, closed_at_pixel):
    """(in_closed, rest) over a window's ones: in_closed = alive & closed at the one's pixel
    (the stage's frame, inp_k & closed_k), rest = alive & ~closed (the next stage's input)."""
    n = alive.shape[0]
    in_closed = np.empty(n, np.bool_)
    rest = np.empty(n, np.bool_)
    for i in range(n):                         # no branch per one: alive and closed are data
        a = alive[i]
        c = closed_at_pixel[pix_inverse[i]]
        in_closed[i] = a & c
        rest[i] = a & (not c)
    return in_closed, rest


@njit(cache=True, nogil=True)
def cascade_window(b, c, pix_inverse, input_pixels, tap_target, active, weights, dv, vth_mant, reset_zero,
                   n_bins, height, width, mask_kernel):
    """The whole cascade of a window in one call (runtime/cpu.py's loop, its per-stage calls
    compiled together): for k = N..1 (index k - 1), from alive = every one,
        inputs[k-1] = alive;  spikes[k-1], fired = ofs_stage(alive, stage k)
        closed = the closing of the fired active pixels (compact_closed), read at the window's
                 input pixels (compact_lookup)
        frames[k-1], alive = split_closed(alive, closed)      (nothing fired: frame empty)
    weights (N, C, K*K), dv, vth_mant, reset_zero (N,) per stage. Returns (spikes (N, B, M),
    fired (N, M), inputs (N, n), frames (N, n)) bool. ofs_stage's scatter is inlined on one
    buffer, the LIF is lif_into and the closing is closed_bits (closed_at for a mask kernel
    over 32): the same values; tests/test_run_sparse.py checks the cascade against the dense
    reference.

    The scatter adds into int32 when no sum can leave its range: a slot gets at most one
    weight per (channel, tap) and bin (the ones are unique), so |a_in| <= C * K*K * max |weight|
    < 2**31, always for Loihi's 8-bit weights; only the never-read dummy column may wrap. The
    same integers in half the cache footprint (~20% less scatter time, measured)."""
    n_ch, kk = weights.shape[1], weights.shape[2]
    if n_ch * kk * np.abs(weights).max() < 2 ** 31:
        return _cascade(b, c, pix_inverse, input_pixels, tap_target, active, weights.astype(np.int32), dv,
                        vth_mant, reset_zero, n_bins, height, width, mask_kernel)
    return _cascade(b, c, pix_inverse, input_pixels, tap_target, active, weights, dv, vth_mant, reset_zero,
                    n_bins, height, width, mask_kernel)



@njit(cache=True, nogil=True)
def pooled_cascade(idx, n_pixels, width, p, hp, wp, n_channels, kernel, slot_of, weights, dv, vth_mant, reset_zero,
                   n_bins, mask_kernel):
    """The cpu pipeline's cascade of one window given as its sensor ones ``idx`` (sorted unique
    linear ids into (B, C, H, W)), pooled p x p (p > 1) to the (hp, wp) OFS grid: pool_index,
    ofs_window and cascade_window back to back, the stage frames brought back to the sensor ones
    (frames[:, inverse], Up_p), in one call instead of three. Returns (bc, pix (n,) of the sensor
    ones, as pool_index gives them; frames (N, n) bool over the sensor ones)."""
    _u, inverse, u_bc, u_pix, bc, pix = pool_index(idx, n_pixels, width, p, hp, wp)
    b, c, in_pix, pix_inverse, active, tap_target = ofs_window(u_bc, u_pix, n_channels, wp, hp, kernel, slot_of)
    _spikes, _fired, _inputs, frames = cascade_window(b, c, pix_inverse, in_pix, tap_target, active, weights, dv,
                                                      vth_mant, reset_zero, n_bins, hp, wp, mask_kernel)
    n_frames = frames.shape[0]
    n = inverse.shape[0]
    up = np.empty((n_frames, n), np.bool_)
    for k in range(n_frames):
        for i in range(n):
            up[k, i] = frames[k, inverse[i]]
    return bc, pix, up

@njit(cache=True, nogil=True)
def _cascade(b, c, pix_inverse, input_pixels, tap_target, active, weights, dv, vth_mant, reset_zero,
             n_bins, height, width, mask_kernel):
    """cascade_window with its scatter buffer in the dtype of ``weights`` (int32 or int64)."""
    n = b.shape[0]
    m = active.shape[0]
    n_st = weights.shape[0]
    kk = tap_target.shape[1]
    spikes = np.empty((n_st, n_bins, m), np.bool_)
    fired = np.zeros((n_st, m), np.bool_)
    inputs = np.empty((n_st, n), np.bool_)
    frames = np.zeros((n_st, n), np.bool_)
    alive = np.ones(n, np.bool_)
    # ofs_stage's scatter without its branch: flat, one leading dummy, then bin t's slots s at
    # 1 + t * mm + s (mm = m + 1, a dummy last column m per bin); tap_target read as unsigned,
    # so an off-sensor tap's -1 wraps 1 + t * mm - 1 to bin t - 1's dummy (the leading one for
    # t = 0): no test for a negative index per add, no converted copy of tap_target
    mm = m + 1
    a_flat = np.empty(1 + n_bins * mm, weights.dtype)
    a_in = a_flat[1:].reshape(n_bins, mm)
    target = np.ascontiguousarray(tap_target).view(np.uint64)
    # rows and columns of the active and input pixels, once per window (closed_at)
    inv_w = 1.0 / width
    act_r = np.empty(m, np.int64)
    act_c = np.empty(m, np.int64)
    for s in range(m):
        act_r[s] = _div_small(active[s], width, inv_w)
        act_c[s] = active[s] - act_r[s] * width
    u = input_pixels.shape[0]
    in_r = np.empty(u, np.int64)
    in_c = np.empty(u, np.int64)
    for q in range(u):
        in_r[q] = _div_small(input_pixels[q], width, inv_w)
        in_c[q] = input_pixels[q] - in_r[q] * width
    for k in range(n_st - 1, -1, -1):
        inputs[k] = alive
        a_flat[:] = 0
        w_k = weights[k]
        for i in range(n):
            if alive[i]:
                q = pix_inverse[i]
                row = np.uint64(1 + b[i] * mm)
                ch = c[i]
                for j in range(kk):
                    a_flat[row + target[q, j]] += w_k[ch, j]
        sp = spikes[k]
        lif_into(a_in, sp, dv[k], vth_mant[k], reset_zero[k])
        f_k = fired[k]
        for t in range(n_bins):
            for s in range(m):
                f_k[s] |= sp[t, s]
        n_fired = 0
        for s in range(m):
            n_fired += f_k[s]
        if n_fired == 0:
            continue
        f_r = np.empty(m, np.int64)               # the fired pixels, compacted without a branch per neuron
        f_c = np.empty(m, np.int64)
        j = 0
        for s in range(m):
            f_r[j] = act_r[s]
            f_c[j] = act_c[s]
            j += f_k[s]
        f_r = f_r[:n_fired]
        f_c = f_c[:n_fired]
        if 1 <= mask_kernel <= 32:
            at = closed_bits(f_r, f_c, in_r, in_c, height, width, mask_kernel)
        else:
            at = closed_at(f_r, f_c, in_r, in_c, height, width, mask_kernel)
        frame, alive = split_closed(alive, pix_inverse, at)
        frames[k] = frame
    return spikes, fired, inputs, frames


@njit(cache=True, nogil=True)
def _kept(pos, n, radius):
    """((n,) bool: within ``radius`` of any of ``pos``, (n,) int64: index among the kept, count)."""
    diff = np.zeros(n + 1, np.int64)
    for p in pos:
        diff[max(p - radius, 0)] += 1
        diff[min(p + radius + 1, n)] -= 1
    keep = np.zeros(n, np.bool_)
    index = np.empty(n, np.int64)
    run = 0
    kept = 0
    for i in range(n):
        run += diff[i]
        keep[i] = run > 0
        kept += keep[i]
        index[i] = kept - 1
    return keep, index, kept


@njit(cache=True, nogil=True)
def compact_image(pix, height, width, radius):
    """The pixels ``pix`` (linear ids, non-empty) on the sensor compacted to the rows and columns
    within ``radius`` of one of them (morph.CompactClosing): (keep_r, keep_c, map_r, map_c,
    image (kept rows, kept columns) uint8 with 1 at each pixel)."""
    rows = np.empty(pix.shape[0], np.int64)
    inv_w = 1.0 / width
    for i in range(pix.shape[0]):
        rows[i] = _div_small(pix[i], width, inv_w)
    cols = pix - rows * width
    keep_r, map_r, n_r = _kept(rows, height, radius)
    keep_c, map_c, n_c = _kept(cols, width, radius)
    image = np.zeros((n_r, n_c), np.uint8)
    for i in range(pix.shape[0]):
        image[map_r[rows[i]], map_c[cols[i]]] = 1
    return keep_r, keep_c, map_r, map_c, image


@njit(cache=True, nogil=True)
def _shift_pass(src, kernel, step, dilate):
    """out[i] = OR (dilate) or AND (erode) of src[i + d * step], d = -a..kernel-1-a (a = kernel // 2),
    over a flat padded image; contributions from outside the array are left out. One loop per d
    over views indexed from 0 (no wraparound test, no branch): LLVM vectorizes them."""
    n = src.shape[0]
    a = kernel // 2
    out = np.empty(n, np.uint8)
    out[:] = 0 if dilate else 1
    for d in range(-a, kernel - a):
        off = d * step
        lo = max(0, -off)
        hi = min(n, n - off)
        if hi <= lo:
            continue
        dst = out[lo:hi]
        val = src[lo + off:hi + off]
        if dilate:
            for i in range(hi - lo):
                dst[i] |= val[i]
        else:
            for i in range(hi - lo):
                dst[i] &= val[i]
    return out


@njit(cache=True, nogil=True)
def close_square(image, kernel):
    """cv2.morphologyEx(image, MORPH_CLOSE, ones((kernel, kernel))) of a 0/1 uint8 image:
    the erosion of the dilation with OpenCV's anchor (kernel // 2) and border (off-image
    positions left out), tested equal in tests/test_run_sparse.py. Separable, on the image
    padded by a = kernel // 2 on every side (0 for the dilation, 1 for the erosion) and
    flattened, so a pass is ``kernel`` vectorized loops (_shift_pass): rows use offsets d,
    columns d * padded width; a pixel's reads stay in its own padded row or column."""
    n_r, n_c = image.shape
    a = kernel // 2
    pw = n_c + 2 * a
    ph = n_r + 2 * a
    src = np.zeros(ph * pw, np.uint8)
    for y in range(n_r):
        for x in range(n_c):
            src[(y + a) * pw + x + a] = image[y, x]
    ero = _close_padded(src, n_r, n_c, kernel).reshape(ph, pw)
    return ero[a:a + n_r, a:a + n_c].copy()


@njit(cache=True, nogil=True)
def _close_padded(src, n_r, n_c, kernel):
    """close_square of the (n_r, n_c) image held in ``src``: flat, padded by a = kernel // 2 on
    every side with 0 (row width n_c + 2a). Returns the closing in the same padded layout."""
    a = kernel // 2
    pw = n_c + 2 * a
    ph = n_r + 2 * a
    dil = _shift_pass(_shift_pass(src, kernel, 1, True), kernel, pw, True)
    grid = dil.reshape(ph, pw)
    grid[:a, :] = 1                                  # the erosion's neutral border
    grid[a + n_r:, :] = 1
    grid[:, :a] = 1
    grid[:, a + n_c:] = 1
    return _shift_pass(_shift_pass(dil, kernel, 1, False), kernel, pw, False)


@njit(cache=True, nogil=True)
def closed_at(f_rows, f_cols, rows, cols, height, width, kernel):
    """compact_lookup(pixels, ..., compact_closed(fired pixels, height, width, max(kernel, 1),
    kernel)) from the rows and columns of both sets: (n,) bool, whether each pixel (rows, cols)
    lies in the closing of the fired pixels (f_rows, f_cols, non-empty). The compacted image is
    written straight into the closing's padded layout (_close_padded) and read there: no
    image copies, no division."""
    radius = max(kernel, 1)
    keep_r, map_r, n_r = _kept(f_rows, height, radius)
    keep_c, map_c, n_c = _kept(f_cols, width, radius)
    a = kernel // 2
    pw = n_c + 2 * a
    src = np.zeros((n_r + 2 * a) * pw, np.uint8)
    for i in range(f_rows.shape[0]):
        src[(map_r[f_rows[i]] + a) * pw + map_c[f_cols[i]] + a] = 1
    closed = _close_padded(src, n_r, n_c, kernel)
    out = np.zeros(rows.shape[0], np.bool_)
    for i in range(rows.shape[0]):
        y = rows[i]
        x = cols[i]
        if keep_r[y] and keep_c[x]:
            out[i] = closed[(map_r[y] + a) * pw + map_c[x] + a] != 0
    return out


@njit(cache=True, nogil=True)
def closed_bits(f_rows, f_cols, rows, cols, height, width, kernel):
    """closed_at (the same (n,) bool) on bit rows: the fired pixels set bits of (H, ceil(W / 64))
    uint64 words, the dilation is a few word shifts and ORs per row that holds a fired pixel
    and per row near one, and the erosion is read only at the n pixels asked, as K masked words,
    not over an image. cv2's closing with anchor a = kernel // 2 and border "off-image positions
    left out": D(y, x) = OR F(y + i, x + j), closed(y, x) = AND D(y + i, x + j) over i, j in
    -a..kernel-1-a and on the sensor. For 1 <= kernel <= 32 (a kernel's span then lies in at most
    two words); tests/test_run_sparse.py checks it equal to closed_at.

    Each row's words carry a zero guard word on both sides (the fired rows' first one doubles as
    their "listed" flag), so a word's shifted neighbours need no branch; a fired row's horizontal
    dilation is ORed into its K rows as it is made, with no second image (~15 % less time than
    two passes with a branch per word, measured)."""
    a = kernel // 2
    lo_d = -a
    hi_d = kernel - 1 - a
    nw = (width + 63) >> 6
    one = np.uint64(1)
    bits = np.zeros((height, nw + 2), np.uint64)       # words 1..nw, a zero guard word each side
    f_list = np.empty(f_rows.shape[0], np.int64)       # the fired rows, each once
    n_f = 0
    for i in range(f_rows.shape[0]):
        y = f_rows[i]
        x = f_cols[i]
        row = bits[y]
        if row[0] == 0:
            row[0] = one                                # the left guard marks a listed row
            f_list[n_f] = y
            n_f += 1
        row[1 + (x >> 6)] |= one << np.uint64(x & 63)
    dil = np.zeros((height, nw + 1), np.uint64)         # a guard word after the last (the reads below)
    h_row = np.empty(nw, np.uint64)
    for t in range(n_f):
        y = f_list[t]
        src = bits[y]
        src[0] = 0
        for w in range(nw):                             # OR over j of F(y, x + j): bit x of the word
            lo = src[w]                                 # shifted by j, its neighbours' bits shifted in
            mid = src[w + 1]
            hi = src[w + 2]
            acc = mid
            for d in range(1, hi_d + 1):
                acc |= (mid >> np.uint64(d)) | (hi << np.uint64(64 - d))
            for d in range(1, a + 1):
                acc |= (mid << np.uint64(d)) | (lo >> np.uint64(64 - d))
            h_row[w] = acc
        for r in range(max(y - hi_d, 0), min(y - lo_d, height - 1) + 1):    # row y feeds rows y - i
            for w in range(nw):
                dil[r, w] |= h_row[w]
    out = np.empty(rows.shape[0], np.bool_)
    for q in range(rows.shape[0]):
        y = rows[q]
        x0 = max(cols[q] + lo_d, 0)
        x1 = min(cols[q] + hi_d, width - 1)
        mask = (one << np.uint64(x1 - x0 + 1)) - one    # x1 - x0 + 1 <= 32 bits
        w0 = x0 >> 6
        off = np.uint64(x0 & 63)
        back = np.uint64(63) - off                      # (v << back) << 1: v << (64 - off), 0 for off 0
        ok = True
        for r in range(max(y + lo_d, 0), min(y + hi_d, height - 1) + 1):    # off-image rows left out
            v = (dil[r, w0] >> off) | ((dil[r, w0 + 1] << back) << one)
            if (v & mask) != mask:
                ok = False
                break
        out[q] = ok
    return out


@njit(cache=True, nogil=True)
def compact_closed(pix, height, width, radius, kernel):
    """compact_image, with the image replaced by its closing (close_square)."""
    keep_r, keep_c, map_r, map_c, image = compact_image(pix, height, width, radius)
    return keep_r, keep_c, map_r, map_c, close_square(image, kernel)


@njit(cache=True, nogil=True)
def compact_lookup(pix, width, keep_r, keep_c, map_r, map_c, image):
    """image at the compacted position of each pixel of ``pix``, False outside the kept rows
    and columns: (n,) bool."""
    out = np.zeros(pix.shape[0], np.bool_)
    inv_w = 1.0 / width
    for i in range(pix.shape[0]):
        y = _div_small(pix[i], width, inv_w)
        x = pix[i] - y * width
        if keep_r[y] and keep_c[x]:
            out[i] = image[map_r[y], map_c[x]] != 0
    return out


@njit(cache=True, nogil=True)
def _inside(x, y, cx, cy, r):
    """The box of an object at (cx, cy): |x - cx| < r and |y - cy| < r."""
    return max(abs(x - cx), abs(y - cy)) < r


@njit(cache=True, nogil=True)
def in_boxes(xs, ys, centres, r):
    """(G, n) bool: pixel i inside the box of object g at centres[g] = (cx, cy)."""
    out = np.empty((centres.shape[0], xs.shape[0]), np.bool_)
    for g in range(centres.shape[0]):
        cx = centres[g, 0]
        cy = centres[g, 1]
        for i in range(xs.shape[0]):
            out[g, i] = _inside(xs[i], ys[i], cx, cy, r)
    return out


@njit(cache=True, nogil=True)
def box_mean(xs, ys, cx, cy, r):
    """(count, mean x, mean y) of the pixels in the box of an object at (cx, cy) (``_inside``);
    the means are the exact integer sums divided by the count (nan when the box is empty)."""
    sx = np.int64(0)
    sy = np.int64(0)
    n = 0
    for i in range(xs.shape[0]):
        if _inside(xs[i], ys[i], cx, cy, r):
            sx += xs[i]
            sy += ys[i]
            n += 1
    if n == 0:
        return 0, np.nan, np.nan
    return n, sx / n, sy / n


@njit(cache=True, nogil=True)
def two_pass_centroid(xs, ys, half, width, height):
    """ofpd_io.centroid_of_pixels: the mean of the pixels, then the mean of those in the box of
    half-side ``half`` around it (box_mean, exact integer sums); the sensor centre when empty."""
    if xs.shape[0] == 0:
        return (width - 1) / 2.0, (height - 1) / 2.0
    _n, cx, cy = box_mean(xs, ys, 0.0, 0.0, np.inf)
    n, nx, ny = box_mean(xs, ys, cx, cy, float(half))
    if n:
        return nx, ny
    return cx, cy


@njit(cache=True, nogil=True)
def crop_origin(xs, ys, size, width, height):
    """ofpd_io.crop_origin_xy for a crop of side ``size``: (x0, y0) with the crop centre
    x0 + (size - 1) / 2 nearest to the two-pass centroid (half-side size // 2)."""
    cx, cy = two_pass_centroid(xs, ys, size // 2, width, height)
    return int(np.floor(cx - (size - 1) / 2 + 0.5)), int(np.floor(cy - (size - 1) / 2 + 0.5))


@njit(cache=True, nogil=True)
def density_groups(xs, ys, r, width):
    """ofpd_io.density_seed's splitting of (non-empty) pixels into groups separated by gaps > 2r
    along x, then y, then x...: (best count n and smallest key y * W + x over the groups that fit
    in one box, order (n,) a permutation of the pixels, hard (k, 2) [start, end) ranges of
    ``order``: the groups with no gap left on either axis, which need a box filter)."""
    n = xs.shape[0]
    r2 = 2 * r
    order = np.arange(n)
    hard = np.empty((n, 2), np.int64)
    n_hard = 0
    x_lo, x_hi, y_lo, y_hi = xs.min(), xs.max(), ys.min(), ys.max()
    if x_hi - x_lo <= r2 and y_hi - y_lo <= r2:                  # one box holds them all
        return n, max(y_hi - r, 0) * width + max(x_hi - r, 0), order, hard[:0]
    best_n = 0
    best_key = 0
    # work stack of (start, end, axis, other axis tried): live segments are disjoint, so <= n + 1
    stack = np.empty((n + 2, 4), np.int64)
    stack[0, 0], stack[0, 1], stack[0, 2], stack[0, 3] = 0, n, 0 if x_hi - x_lo > r2 else 1, 0
    top = 1
    while top > 0:
        top -= 1
        s, e, axis, tried = stack[top, 0], stack[top, 1], stack[top, 2], stack[top, 3]
        seg = order[s:e].copy()
        a = xs[seg] if axis == 0 else ys[seg]
        by = np.argsort(a)
        sa = a[by]
        order[s:e] = seg[by]
        cut = False
        for j in range(1, e - s):
            if sa[j] - sa[j - 1] > r2:
                cut = True
                break
        if not cut:                              # no gap on this axis: the other, else box filter
            if tried:
                hard[n_hard, 0], hard[n_hard, 1] = s, e
                n_hard += 1
            else:
                stack[top, 0], stack[top, 1], stack[top, 2], stack[top, 3] = s, e, 1 - axis, 1
                top += 1
            continue
        g0 = 0
        for j in range(1, e - s + 1):
            if j < e - s and sa[j] - sa[j - 1] <= r2:
                continue
            xmin = xmax = xs[order[s + g0]]
            ymin = ymax = ys[order[s + g0]]
            for q in range(s + g0 + 1, s + j):
                xmin = min(xmin, xs[order[q]])
                xmax = max(xmax, xs[order[q]])
                ymin = min(ymin, ys[order[q]])
                ymax = max(ymax, ys[order[q]])
            if xmax - xmin <= r2 and ymax - ymin <= r2:
                m = j - g0
                key = max(ymax - r, 0) * width + max(xmax - r, 0)
                if m > best_n or (m == best_n and key < best_key):
                    best_n, best_key = m, key
            else:                                # no gap left on this axis: try the other
                stack[top, 0], stack[top, 1], stack[top, 2], stack[top, 3] = s + g0, s + j, 1 - axis, 1
                top += 1
            g0 = j
    return best_n, best_key, order, hard[:n_hard]


@njit(cache=True, nogil=True)
def _root(parent, i):
    """Union-find root of i, halving the path on the way."""
    while parent[i] != i:
        parent[i] = parent[parent[i]]
        i = parent[i]
    return i


@njit(cache=True, nogil=True)
def _union(parent, a, b):
    """Joins the sets of a and b under the smaller root (so labels do not depend on the order)."""
    ra = _root(parent, a)
    rb = _root(parent, b)
    if ra < rb:
        parent[rb] = ra
    elif rb < ra:
        parent[ra] = rb


@njit(cache=True, nogil=True)
def row_major(xs, ys):
    """(order (n,), row_start (R + 1,), y0): the pixels (non-empty) in row-major order, by two
    stable counting sorts, on x over x0..x0 + X - 1, then on the rows y0..y0 + R - 1: O(n + X + R),
    no comparisons (the pixels of a window come as runs of sorted planes, which cost an insertion
    sort many moves); row r's pixels are order[row_start[r]:row_start[r + 1]], by x, equal
    pixels in input order."""
    n = xs.shape[0]
    y0 = ys.min()
    n_rows = ys.max() - y0 + 1
    x0 = xs.min()
    n_cols = xs.max() - x0 + 1
    col_start = np.zeros(n_cols + 1, np.int64)
    for i in range(n):
        col_start[xs[i] - x0 + 1] += 1
    for c in range(n_cols):
        col_start[c + 1] += col_start[c]
    by_x = np.empty(n, np.int64)
    for i in range(n):
        c = xs[i] - x0
        by_x[col_start[c]] = i
        col_start[c] += 1
    row_start = np.zeros(n_rows + 1, np.int64)
    for i in range(n):
        row_start[ys[i] - y0 + 1] += 1
    for r in range(n_rows):
        row_start[r + 1] += row_start[r]
    fill = row_start[:n_rows].copy()
    order = np.empty(n, np.int64)
    for a in range(n):
        i = by_x[a]
        r = ys[i] - y0
        order[fill[r]] = i
        fill[r] += 1
    return order, row_start, y0


@njit(cache=True, nogil=True)
def link_components(xs, ys, link, width):
    """Connected components of unique pixels (xs, ys) (link_components_ordered's labels, C)."""
    labels, c, _order = link_components_ordered(xs, ys, link, width)
    return labels, c


@njit(cache=True, nogil=True)
def link_components_ordered(xs, ys, link, width):
    """Connected components of unique pixels (xs, ys) where two pixels are linked when
    max(|dx|, |dy|) <= link: (labels (n,) 0..C-1 numbered by each component's first pixel in
    row-major order, C, the pixels in row-major order (row_major's order)).

    On runs, not pixels: the pixels of a row (row_major) split into runs where consecutive
    pixels are <= link apart (each run is connected). Two runs [a0, a1], [b0, b1] of rows
    <= link apart are linked exactly when [a0 - link, a1 + link] meets [b0, b1]: a pixel of
    the other run then lies in it (an end, or one of the > link positions it covers, which no
    gap of a run spans), and that pixel is <= link from the run's nearest pixel. Each row's
    runs are swept against the next link rows' with one pointer per row: O(n + runs * link)."""
    n = xs.shape[0]
    labels = np.empty(n, np.int64)
    if n == 0:
        return labels, 0, np.empty(0, np.int64)
    order, row_start, y0 = row_major(xs, ys)
    n_rows = row_start.shape[0] - 1
    run_x0 = np.empty(n, np.int64)
    run_x1 = np.empty(n, np.int64)
    run_of = np.empty(n, np.int64)             # run of each pixel of ``order``
    row_run = np.zeros(n_rows + 1, np.int64)   # row r's runs: row_run[r]:row_run[r + 1]
    m = 0
    for r in range(n_rows):
        row_run[r] = m
        for a in range(row_start[r], row_start[r + 1]):
            x = xs[order[a]]
            if a == row_start[r] or x - run_x1[m - 1] > link:
                run_x0[m] = x
                m += 1
            run_x1[m - 1] = x
            run_of[a] = m - 1
    row_run[n_rows] = m
    parent = np.arange(m)
    for r in range(n_rows):
        for dy in range(1, link + 1):
            if r + dy >= n_rows:
                break
            j = row_run[r + dy]
            j_end = row_run[r + dy + 1]
            for q in range(row_run[r], row_run[r + 1]):
                lo = run_x0[q] - link
                hi = run_x1[q] + link
                while j < j_end and run_x1[j] < lo:
                    j += 1
                k = j
                while k < j_end and run_x0[k] <= hi:
                    _union(parent, q, k)
                    k += 1
    label_of_root = np.full(m, -1, np.int64)
    run_label = np.empty(m, np.int64)
    c = 0
    for q in range(m):                         # runs in row-major order: components numbered so
        root = _root(parent, q)
        if label_of_root[root] < 0:
            label_of_root[root] = c
            c += 1
        run_label[q] = label_of_root[root]
    for a in range(n):                         # each pixel its run's label: no root search per pixel
        labels[order[a]] = run_label[run_of[a]]
    return labels, c, order


@njit(cache=True, nogil=True)
def _empty_boxes(n):
    """(n, 4) int64 boxes x_min, y_min, x_max, y_max, empty (min above max) for min/max updates."""
    box = np.empty((n, 4), np.int64)
    for c in range(n):
        box[c, 0] = box[c, 1] = 1 << 40
        box[c, 2] = box[c, 3] = -(1 << 40)
    return box


@njit(cache=True, nogil=True)
def component_stats(labels, n_comp, xs, ys):
    """Per component: (count (C,), sum x (C,), sum y (C,), bbox (C, 4) = x_min, y_min, x_max,
    y_max), exact integers."""
    count = np.zeros(n_comp, np.int64)
    sx = np.zeros(n_comp, np.int64)
    sy = np.zeros(n_comp, np.int64)
    bbox = _empty_boxes(n_comp)
    for i in range(labels.shape[0]):
        c = labels[i]
        count[c] += 1
        sx[c] += xs[i]
        sy[c] += ys[i]
        bbox[c, 0] = min(bbox[c, 0], xs[i])
        bbox[c, 1] = min(bbox[c, 1], ys[i])
        bbox[c, 2] = max(bbox[c, 2], xs[i])
        bbox[c, 3] = max(bbox[c, 3], ys[i])
    return count, sx, sy, bbox


@njit(cache=True, nogil=True)
def box_gap(a, b):
    """Chebyshev gap between two inclusive boxes (x_min, y_min, x_max, y_max); <= 0 if they touch."""
    return max(a[0] - b[2], b[0] - a[2], a[1] - b[3], b[1] - a[3])


@njit(cache=True, nogil=True)
def min_gap(xa, ya, xb, yb, t):
    """Smallest Euclidean distance between a pixel of set a and one of set b when it is <= t,
    else inf (any order of either set). Brute force over the pairs, as exact integer squares:
    for each pixel of a that can still come closer (the gap from it to b's bounding box is
    below the smallest square so far and within t), the smallest square to b's pixels is one
    branch-free loop that LLVM vectorizes, several times faster on the few hundred pixels of
    a frame's components than a scan that narrows by x but branches per pair. The result is
    sqrt of the smallest square (correctly rounded: the smallest of the pairs' float distances)."""
    nb = xb.shape[0]
    if nb == 0:
        return np.inf
    bx0 = bx1 = xb[0]
    by0 = by1 = yb[0]
    for j in range(nb):
        bx0 = min(bx0, xb[j])
        bx1 = max(bx1, xb[j])
        by0 = min(by0, yb[j])
        by1 = max(by1, yb[j])
    t2_hi = t * t * (1.0 + 1e-12) + 1.0      # no pair with a larger square is within t
    best2 = np.int64(1) << 62
    for i in range(xa.shape[0]):
        x = xa[i]
        y = ya[i]
        gx = max(bx0 - x, x - bx1, 0)
        gy = max(by0 - y, y - by1, 0)
        g2 = gx * gx + gy * gy
        if g2 >= best2 or g2 > t2_hi:
            continue
        m = best2
        for j in range(nb):
            dx = x - xb[j]
            dy = y - yb[j]
            m = min(m, dx * dx + dy * dy)
        best2 = m
    if best2 > t2_hi:
        return np.inf
    d = np.sqrt(best2)
    return d if d <= t else np.inf


@njit(cache=True, nogil=True)
def _sector(dx, dy):
    """floor((atan2(dy, dx) + pi) * 4 / pi) % 8, the 45 degree sector of (dx, dy): from the
    signs and |dx| vs |dy| where the angle is clearly inside a sector, from the formula itself
    within 1e-9 (relative) of a sector boundary (an axis or a diagonal), so bit for bit the same."""
    ax = abs(dx)
    ay = abs(dy)
    eps = 1e-9 * max(ax, ay)
    if ax <= eps or ay <= eps or abs(ax - ay) <= eps:
        return int(np.floor((np.arctan2(dy, dx) + np.pi) * (4.0 / np.pi))) % 8
    steep = ay > ax
    if dy < 0:
        if dx < 0:
            return 1 if steep else 0
        return 2 if steep else 3
    if dx > 0:
        return 5 if steep else 4
    return 6 if steep else 7


@njit(cache=True, nogil=True)
def _surrounds_ranges(xs, ys, lo, hi, k):
    """surrounds of the pixels xs, ys[lo[i]:hi[i]] for i < k (one set in several ranges)."""
    n = 0
    sx = 0
    sy = 0
    x0 = y0 = 1 << 40
    x1 = y1 = -(1 << 40)
    for i in range(k):
        for p in range(lo[i], hi[i]):
            n += 1
            sx += xs[p]
            sy += ys[p]
            x0 = min(x0, xs[p])
            x1 = max(x1, xs[p])
            y0 = min(y0, ys[p])
            y1 = max(y1, ys[p])
    if n == 0:
        return False
    cx = sx / n
    cy = sy / n
    r = 0.25 * (max(x1 - x0, y1 - y0) + 1)
    occupied = 0
    for i in range(k):
        for p in range(lo[i], hi[i]):
            dx = xs[p] - cx
            dy = ys[p] - cy
            if dx * dx + dy * dy <= r * r:
                continue
            occupied |= 1 << _sector(dx, dy)
            if occupied == 255:
                return True
    return False


@njit(cache=True, nogil=True)
def surrounds(xs, ys):
    """Whether pixels surround their centroid: one or more in each of 8 sectors of 45 degrees
    around it, counting only the pixels farther from it than a quarter of the set's extent
    (max(width, height) of its bounding box), so that a thick edge does not pass. A whole
    object's outline or blob does; one edge of it (a line, an L, a crescent) does not."""
    return _surrounds_ranges(xs, ys, np.zeros(1, np.int64), np.full(1, xs.shape[0], np.int64), 1)


@njit(cache=True, nogil=True)
def merge_blobs(labels, count, bbox, xs, ys, frac_closed, frac_open, min_count, known_closed=None, apart_px=0):
    """Groups a frame's components into objects, closest pairs first.

    Components with >= min_count pixels (seeds) are joined in order of their gap (smallest
    pixel distance) over the larger extent (max(width, height) of the bounding box), while
    that ratio is <= frac_open when neither group surrounds its centroid yet (``surrounds``:
    the leading and trailing edges of one object, as far apart as the object is wide) and
    <= frac_closed otherwise: once an object's edges have closed around it, only pieces close
    to it join, not a neighbour's edges. A group stays closed once it is (the pieces that join
    it can move its centroid and widen its extent so that ``surrounds`` no longer holds for the
    union: a star-shaped object plus a 4-pixel noise seed, which then took a dense neighbour 25
    px away in as an open edge; pairs split, whole streams: misses 817 -> 767, appearance
    unchanged). A smaller component (a speck) joins the first seed it
    comes within frac_closed * the seed's extent of; specks never group on their own. Returns
    (group (C,) 0..G-1 numbered by smallest member, -1 for specks in no group; per group count,
    bbox and whether it is closed: it surrounds its centroid, or did before a join). known_closed (C,) int8, optional: a seed's
    ``surrounds`` when the caller knows it (0 / 1), -1 where not (union_objects' second pass).
    apart_px > 0 (ofpd.closed_apart: min_events): two closed groups that each hold >= apart_px
    pixels are two objects, never joined: two whole outlines, each an object on its own (a small
    object beside a big one's corner came within frac_closed of the big one's extent and was
    taken in: `crossing` seed 20, a 17 px circle 7 px from a 57 px square)."""
    n = count.shape[0]
    start = np.zeros(n + 1, np.int64)
    for c in range(n):
        start[c + 1] = start[c] + count[c]
    size = count.copy()                                   # pixels per group (at its root)
    px = np.empty(labels.shape[0], np.int64)              # the pixels by component (any order within)
    py = np.empty(labels.shape[0], np.int64)
    fill = start[:n].copy()
    for i in range(labels.shape[0]):
        c = labels[i]
        px[fill[c]] = xs[i]
        py[fill[c]] = ys[i]
        fill[c] += 1
    parent = np.arange(n)
    ext = np.empty(n)
    for c in range(n):
        ext[c] = max(bbox[c, 2] - bbox[c, 0], bbox[c, 3] - bbox[c, 1]) + 1
    seeds = np.flatnonzero(count >= min_count)
    closed = np.zeros(n, np.bool_)
    gbox = bbox.copy()
    for a in seeds:
        if known_closed is not None and known_closed[a] >= 0:
            closed[a] = known_closed[a] > 0
        else:
            closed[a] = surrounds(px[start[a]:start[a + 1]], py[start[a]:start[a + 1]])
    # candidate seed pairs and their gap ratio, smallest first
    m = seeds.shape[0]
    pa = np.empty(m * m, np.int64)
    pb = np.empty(m * m, np.int64)
    ratio = np.empty(m * m)
    k = 0
    for i in range(m):
        a = seeds[i]
        for j in range(i + 1, m):
            b = seeds[j]
            big = max(ext[a], ext[b])
            t = frac_open * big
            if box_gap(bbox[a], bbox[b]) > t:
                continue
            d = min_gap(px[start[a]:start[a + 1]], py[start[a]:start[a + 1]],
                        px[start[b]:start[b + 1]], py[start[b]:start[b + 1]], t)
            if d <= t:
                pa[k], pb[k], ratio[k] = a, b, d / big
                k += 1
    by = np.argsort(ratio[:k], kind="mergesort")
    lo = np.empty(n, np.int64)
    hi = np.empty(n, np.int64)
    for q in by:
        ra = _root(parent, pa[q])
        rb = _root(parent, pb[q])
        if ra == rb:
            continue
        was_closed = closed[ra] or closed[rb]
        limit = frac_closed if was_closed else frac_open
        if ratio[q] > limit:
            continue
        if apart_px > 0 and closed[ra] and closed[rb] and size[ra] >= apart_px and size[rb] >= apart_px:
            continue                         # two whole outlines: two objects
        _union(parent, ra, rb)
        r = _root(parent, ra)
        size[r] = size[ra] + size[rb]
        for c in range(4):
            gbox[r, c] = min(gbox[ra, c], gbox[rb, c]) if c < 2 else max(gbox[ra, c], gbox[rb, c])
        k = 0
        for c in range(n):                   # the group's components, in order
            if _root(parent, c) == r:
                lo[k] = start[c]
                hi[k] = start[c + 1]
                k += 1
        closed[r] = was_closed or _surrounds_ranges(px, py, lo, hi, k)
    for b in range(n):                       # specks join a seed they come close to
        if count[b] >= min_count:
            continue
        for a in seeds:
            t = frac_closed * ext[a]
            if box_gap(bbox[a], bbox[b]) <= t and min_gap(px[start[b]:start[b + 1]], py[start[b]:start[b + 1]],
                                                         px[start[a]:start[a + 1]], py[start[a]:start[a + 1]], t) <= t:
                was = closed[_root(parent, a)]
                _union(parent, a, b)
                closed[_root(parent, a)] = was       # the root may now be the speck
                break
    seeded = np.zeros(n, np.bool_)
    for a in seeds:
        seeded[_root(parent, a)] = True
    group = np.full(n, -1, np.int64)
    label_of_root = np.full(n, -1, np.int64)
    g = 0
    for c in range(n):
        r = _root(parent, c)
        if not seeded[r]:
            continue
        if label_of_root[r] < 0:
            label_of_root[r] = g
            g += 1
        group[c] = label_of_root[r]
    gc = np.zeros(g, np.int64)
    gclosed = np.zeros(g, np.bool_)
    gb = _empty_boxes(g)
    for c in range(n):
        q = group[c]
        if q < 0:
            continue
        gc[q] += count[c]
        if count[c] >= min_count:
            gclosed[q] |= closed[_root(parent, c)]
        gb[q, 0] = min(gb[q, 0], bbox[c, 0])
        gb[q, 1] = min(gb[q, 1], bbox[c, 1])
        gb[q, 2] = max(gb[q, 2], bbox[c, 2])
        gb[q, 3] = max(gb[q, 3], bbox[c, 3])
    return group, gc, gb, gclosed


@njit(cache=True, nogil=True)
def _near_members(gx, gy, box, obox, head, nxt, xs, ys, t, buf_x, buf_y):
    """Whether a pixel of the group (gx, gy) with bounding box ``box`` lies within Euclidean
    distance t of a member of an object with bounding box ``obox`` (linked list head / nxt over
    xs, ys): only the group's pixels inside the object's box grown by t (kept in buf_x, buf_y)
    and the members inside the group's box grown by t can be: the exact test on fewer pairs)."""
    k = 0
    for i in range(gx.shape[0]):
        if obox[0] - t <= gx[i] <= obox[2] + t and obox[1] - t <= gy[i] <= obox[3] + t:
            buf_x[k] = gx[i]
            buf_y[k] = gy[i]
            k += 1
    if k == 0:
        return False
    x0, y0, x1, y1 = box[0] - t, box[1] - t, box[2] + t, box[3] + t
    t2 = t * t
    bx = buf_x[:k]
    by = buf_y[:k]
    p = head
    while p >= 0:
        mx = xs[p]
        my = ys[p]
        if x0 <= mx <= x1 and y0 <= my <= y1:
            m = np.int64(1) << 62                # the member's smallest square: a vectorized loop
            for i in range(k):
                dx = bx[i] - mx
                dy = by[i] - my
                m = min(m, dx * dx + dy * dy)
            if m <= t2:
                return True
        p = nxt[p]
    return False


@njit(cache=True, nogil=True)
def blob_objects(xs, ys, starts, width, link, frac_closed, frac_open, need, min_count):
    """ofpd_io.blob_objects_xy's loop over the stages in one pass: the pixels of stage i are
    xs, ys[starts[i]:starts[i + 1]] (unique per stage). From the fastest stage down, each
    frame's groups (link_components, component_stats, merge_blobs) join the first object
    whose box comes within t = (frac_closed if either surrounds its centroid else frac_open) *
    the larger extent and that has a pixel within t of one of theirs; the others with >= need
    pixels are new objects at their centroid (exact integer sums over the count).

    Returns (stage (G,), cx (G,), cy (G,), owner (n,) the object claiming each pixel or -1,
    claim keys (M,) sorted linear ids y * width + x of the claimed pixels and their owners
    (M,), keys of equal value in fastest-stage-first order)."""
    n = xs.shape[0]
    n_stages = starts.shape[0] - 1
    owner = np.full(n, -1, np.int64)
    nxt = np.full(n, -1, np.int64)
    o_stage = np.empty(n, np.int64)                            # at most one object per pixel
    o_cx = np.empty(n)
    o_cy = np.empty(n)
    o_box = np.empty((n, 4), np.int64)
    o_closed = np.empty(n, np.bool_)
    o_head = np.empty(n, np.int64)
    n_obj = 0
    claim_key = np.empty(n, np.int64)
    buf_x = np.empty(n, np.int64)
    buf_y = np.empty(n, np.int64)
    claim_own = np.empty(n, np.int64)
    m = 0
    for i in range(n_stages - 1, -1, -1):                     # fastest stage first
        s0 = starts[i]
        s1 = starts[i + 1]
        if s1 == s0:
            continue
        sx = xs[s0:s1]
        sy = ys[s0:s1]
        labels, n_comp = link_components(sx, sy, link, width)
        count, _sx, _sy, bbox = component_stats(labels, n_comp, sx, sy)
        comp_group, gcount, gbox, gclosed = merge_blobs(labels, count, bbox, sx, sy, frac_closed, frac_open, min_count)
        n_groups = gcount.shape[0]
        if n_groups == 0:
            continue
        # the stage's pixels by group (stable: pixel order within a group)
        gstart = np.zeros(n_groups + 1, np.int64)
        for p in range(s1 - s0):
            q = comp_group[labels[p]]
            if q >= 0:
                gstart[q + 1] += 1
        for q in range(n_groups):
            gstart[q + 1] += gstart[q]
        fill = gstart[:n_groups].copy()
        members = np.empty(gstart[n_groups], np.int64)
        for p in range(s1 - s0):
            q = comp_group[labels[p]]
            if q >= 0:
                members[fill[q]] = s0 + p
                fill[q] += 1
        host_of = np.full(n_groups, -1, np.int64)
        for q in range(n_groups):
            sel = members[gstart[q]:gstart[q + 1]]
            gx = xs[sel]
            gy = ys[sel]
            box = gbox[q]
            e = float(max(box[2] - box[0], box[3] - box[1]) + 1)
            host = -1
            for j in range(n_obj):
                b = o_box[j]
                t = (frac_closed if gclosed[q] or o_closed[j] else frac_open) * max(e, float(max(b[2] - b[0], b[3] - b[1]) + 1))
                if box_gap(box, b) > t:
                    continue
                if _near_members(gx, gy, box, b, o_head[j], nxt, xs, ys, t, buf_x, buf_y):
                    host = j
                    break
            if host >= 0:
                for c in range(2):
                    o_box[host, c] = min(o_box[host, c], box[c])
                    o_box[host, c + 2] = max(o_box[host, c + 2], box[c + 2])
            elif gcount[q] >= need:
                host = n_obj
                n_obj += 1
                o_stage[host] = i
                o_cx[host] = gx.sum() / sel.shape[0]
                o_cy[host] = gy.sum() / sel.shape[0]
                o_box[host] = box
                o_closed[host] = gclosed[q]
                o_head[host] = -1
            host_of[q] = host
            if host >= 0:
                for p in sel:
                    owner[p] = host
                    nxt[p] = o_head[host]
                    o_head[host] = p
        for p in range(s1 - s0):                               # the stage's claims, in pixel order
            q = comp_group[labels[p]]
            if q >= 0 and host_of[q] >= 0:
                claim_key[m] = sy[p] * width + sx[p]
                claim_own[m] = host_of[q]
                m += 1
    srt = _stable_order(claim_key[:m])
    return o_stage[:n_obj].copy(), o_cx[:n_obj].copy(), o_cy[:n_obj].copy(), owner, claim_key[srt], claim_own[srt]


SPLIT_ELONGATION = 1.8     # split_two: the blob's principal variances differ by at least this factor
SPLIT_MIDDLE = 0.15        # split_two: the cut leaves at least this share of the pixels on each side
SPLIT_SIDES_APART = 0.3    # two_sided: the two polarities' centroids lie >= this * the set's extent apart
SPLIT_SIDES_ALIKE = 0.6    # split_two: a half whole by two_sided alone has >= this * the other's extent, and v.v.


@njit(cache=True, nogil=True)
def _elongated(n, sx, sy, sxx, syy, sxy):
    """Whether a pixel set (count and integer sums of x, y, x^2, y^2, xy) has principal
    variances l1 >= SPLIT_ELONGATION * l2: two touching outlines of radii R and r side by side
    give (w1 R^2 + w2 r^2) / 2 + w1 w2 (R + r)^2 over (w1 R^2 + w2 r^2) / 2 (w the perimeter
    shares), 3 for R = r and 1.86 for R = 3r; one ring gives 1."""
    cxx = sxx / n - (sx / n) ** 2
    cyy = syy / n - (sy / n) ** 2
    cxy = sxy / n - (sx / n) * (sy / n)
    half = 0.5 * (cxx + cyy)
    root = np.sqrt(0.25 * (cxx - cyy) ** 2 + cxy * cxy)
    return half + root >= SPLIT_ELONGATION * (half - root)


@njit(cache=True, nogil=True)
def split_two(gx, gy, need, frac, waist, gpol=None, polarity=0.0):
    """Whether the pixels (gx, gy) of one group are two objects, and if so which side each is
    on (else an all-False array). The cut is the line across the principal axis (1 px steps,
    leaving >= SPLIT_MIDDLE of the pixels and >= need on each side) where the pixels within
    2 px of it span the least across the axis: where two touching outlines meet (a point),
    a gap if they do not touch. The halves are two objects when that span is <= waist * the
    narrower half's width across the axis (a fast object's smear, a filled disc, a ring are as
    wide at any cut in their middle), each half surrounds its own centroid (``surrounds``: a
    whole outline, not a leading or trailing edge of one object, not half of a ring) and their
    centroids are >= frac * the larger half's extent apart. With ``gpol`` (each pixel's
    polarities, bit 1 one channel, bit 2 the other) and ``polarity`` > 0, a half that does not
    surround its centroid is a whole object too when it holds both a leading and a trailing
    edge (``two_sided``: two objects in a row along their motion, whose facing edges join) and
    the halves' extents are alike (>= SPLIT_SIDES_ALIKE of each other): a star's spike cut off
    its body is two-sided too, but half the body's extent (measured on `test`: 13 against 26 px,
    where the pairs of `pairs` that it splits have halves of 17-23 px against 18-19). Blobs
    that are not elongated (_elongated) are one object without trying: the test that keeps
    this cheap (most groups stop there, after one pass over their pixels)."""
    n = gx.shape[0]
    none = np.zeros(n, np.bool_)
    if n < 2 * need:
        return none
    sx = sy = sxx = syy = sxy = 0
    for i in range(n):
        sx += gx[i]
        sy += gy[i]
        sxx += gx[i] * gx[i]
        syy += gy[i] * gy[i]
        sxy += gx[i] * gy[i]
    if not _elongated(n, sx, sy, sxx, syy, sxy):
        return none
    mx = sx / n
    my = sy / n
    th = 0.5 * np.arctan2(2.0 * (sxy / n - mx * my), (sxx / n - mx * mx) - (syy / n - my * my))
    ux = np.cos(th)
    uy = np.sin(th)
    t = np.empty(n)
    v = np.empty(n)
    for i in range(n):
        t[i] = (gx[i] - mx) * ux + (gy[i] - my) * uy
        v[i] = (gy[i] - my) * ux - (gx[i] - mx) * uy
    t0 = t.min()
    nb = int(t.max() - t0) + 1
    b = np.empty(n, np.int64)
    cnt = np.zeros(nb, np.int64)
    lo = np.full(nb, np.inf)
    hi = np.full(nb, -np.inf)
    for i in range(n):
        k = int(t[i] - t0)
        b[i] = k
        cnt[k] += 1
        lo[k] = min(lo[k], v[i])
        hi[k] = max(hi[k], v[i])
    lo_min = max(need, int(np.ceil(SPLIT_MIDDLE * n)))
    best = -1
    best_span = np.inf
    best_below = 0
    below = 0
    for j in range(1, nb):                      # side b: bins >= j
        below += cnt[j - 1]
        if below < lo_min or n - below < lo_min:
            continue
        a = np.inf
        z = -np.inf
        for k in range(max(0, j - 2), min(nb, j + 2)):
            a = min(a, lo[k])
            z = max(z, hi[k])
        span = z - a + 1.0 if z >= a else 0.0
        if span < best_span or (span == best_span and abs(2 * below - n) < abs(2 * best_below - n)):
            best_span = span               # the narrowest; of equals the most even
            best = j
            best_below = below
    if best < 0:
        return none
    side = np.empty(n, np.bool_)
    va = np.array([np.inf, -np.inf])
    vb = np.array([np.inf, -np.inf])
    for k in range(nb):
        w = vb if k >= best else va
        w[0] = min(w[0], lo[k])
        w[1] = max(w[1], hi[k])
    if best_span > waist * min(va[1] - va[0] + 1.0, vb[1] - vb[0] + 1.0):
        return none
    # a set that surrounds its centroid has a pixel beyond extent / 4 in each 45 degree sector,
    # so it spans more than 2 cos(45) / 4 = 0.354 of its extent along any direction, and its
    # extent is >= its span across the axis / sqrt(2): a half whose bins along the axis span
    # <= 0.25 of that (an edge of one object, the commonest case) cannot, nor can both
    first = 0
    while cnt[first] == 0:
        first += 1
    last = nb - 1
    while cnt[last] == 0:
        last -= 1
    if best - first <= 0.25 * (va[1] - va[0]) or last - best + 1 <= 0.25 * (vb[1] - vb[0]):
        return none
    nb_side = 0
    for i in range(n):
        side[i] = b[i] >= best
        nb_side += side[i]
    ax = np.empty(n - nb_side, np.int64)
    ay = np.empty(n - nb_side, np.int64)
    bx = np.empty(nb_side, np.int64)
    by = np.empty(nb_side, np.int64)
    pa = np.zeros(n - nb_side if gpol is not None else 0, np.int8)
    pb = np.zeros(nb_side if gpol is not None else 0, np.int8)
    ia = ib = 0
    for i in range(n):
        if side[i]:
            bx[ib] = gx[i]
            by[ib] = gy[i]
            if gpol is not None:
                pb[ib] = gpol[i]
            ib += 1
        else:
            ax[ia] = gx[i]
            ay[ia] = gy[i]
            if gpol is not None:
                pa[ia] = gpol[i]
            ia += 1
    dist = np.sqrt((bx.sum() / ib - ax.sum() / ia) ** 2 + (by.sum() / ib - ay.sum() / ia) ** 2)
    ea = max(ax.max() - ax.min(), ay.max() - ay.min()) + 1
    eb = max(bx.max() - bx.min(), by.max() - by.min()) + 1
    if dist < frac * max(ea, eb):
        return none
    if gpol is None or polarity <= 0.0:
        if not surrounds(ax, ay) or not surrounds(bx, by):
            return none
        return side
    alike = min(ea, eb) >= SPLIT_SIDES_ALIKE * max(ea, eb)
    if not (surrounds(ax, ay) or (alike and two_sided(ax, ay, pa, polarity))):
        return none
    if not (surrounds(bx, by) or (alike and two_sided(bx, by, pb, polarity))):
        return none
    return side


@njit(cache=True, nogil=True)
def two_sided(xs, ys, pol, frac):
    """Whether pixels hold a moving object's leading and trailing edges: >= frac of them fired
    one polarity only and >= frac the other only (pol: bit 1 and bit 2 as split_two's gpol), and
    the centroids of the two lie >= SPLIT_SIDES_APART * the set's extent (max(width, height))
    apart. An edge moving over the sensor fires the sign of its contrast, which is opposite on
    an object's leading and trailing sides, so one object moving fast enough to outrun the
    edges' noise gives two single-polarity bands about its length apart along its motion; one
    edge of it (what a cut through one object leaves on each side) has one polarity; mixed
    polarities on the same pixels (noise, flicker) have both centroids in one place."""
    n = xs.shape[0]
    if n == 0:
        return False
    c1 = c2 = 0
    x1 = y1 = x2 = y2 = 0
    for i in range(n):
        p = pol[i]
        if p == 1:
            c1 += 1
            x1 += xs[i]
            y1 += ys[i]
        elif p == 2:
            c2 += 1
            x2 += xs[i]
            y2 += ys[i]
    if c1 < frac * n or c2 < frac * n or c1 == 0 or c2 == 0:
        return False
    extent = max(xs.max() - xs.min(), ys.max() - ys.min()) + 1
    dx = x1 / c1 - x2 / c2
    dy = y1 / c1 - y2 / c2
    return np.sqrt(dx * dx + dy * dy) >= SPLIT_SIDES_APART * extent


@njit(cache=True, nogil=True)
def split_groups(xs, ys, pg, n_groups, need, frac, waist, pol=None, polarity=0.0):
    """Splits every group of pixels (pg (n,) group per pixel, -1 for none; groups 0..n_groups-1)
    that split_two finds to be two objects, in place: the second side becomes group n_groups,
    n_groups + 1, ... and each part is tried again (three objects in one blob: two splits).
    Only groups with >= 2 * need pixels that are elongated are looked at (their moments from one
    pass over the pixels; the others cost nothing more). pol, polarity: split_two's gpol (per
    pixel) and polarity. Returns the number of groups."""
    n = xs.shape[0]
    mom = np.zeros((n_groups, 6), np.int64)         # count and sums of x, y, x^2, y^2, xy per group
    for p in range(n):
        q = pg[p]
        if q >= 0:
            x = xs[p]
            y = ys[p]
            mom[q, 0] += 1
            mom[q, 1] += x
            mom[q, 2] += y
            mom[q, 3] += x * x
            mom[q, 4] += y * y
            mom[q, 5] += x * y
    todo = np.zeros(n_groups, np.bool_)
    any_todo = False
    for q in range(n_groups):
        todo[q] = mom[q, 0] >= 2 * need and _elongated(mom[q, 0], mom[q, 1], mom[q, 2], mom[q, 3], mom[q, 4],
                                                       mom[q, 5])
        any_todo |= todo[q]
    if not any_todo:
        return n_groups
    start = np.zeros(n_groups + 1, np.int64)        # the pixels by group (counting sort), pixel order within
    for q in range(n_groups):
        start[q + 1] = start[q] + mom[q, 0]
    order = np.empty(start[n_groups], np.int64)
    fill = start[:n_groups].copy()
    for p in range(n):
        q = pg[p]
        if q >= 0:
            order[fill[q]] = p
            fill[q] += 1
    stack = np.empty((n // max(need, 1) + n_groups + 1, 3), np.int64)    # (first, end, group) still to try
    top = 0
    for q in range(n_groups - 1, -1, -1):
        if todo[q]:
            stack[top, 0] = start[q]
            stack[top, 1] = start[q + 1]
            stack[top, 2] = q
            top += 1
    g = n_groups
    while top > 0:
        top -= 1
        lo = stack[top, 0]
        hi = stack[top, 1]
        q = stack[top, 2]
        idx = order[lo:hi].copy()
        if pol is None:
            side = split_two(xs[idx], ys[idx], need, frac, waist)
        else:
            side = split_two(xs[idx], ys[idx], need, frac, waist, pol[idx], polarity)
        na = 0
        for i in range(hi - lo):
            na += not side[i]
        if na == hi - lo:
            continue
        a = lo
        b = lo + na
        for i in range(hi - lo):                  # stable partition: side a first, then side b
            if side[i]:
                order[b] = idx[i]
                pg[idx[i]] = g
                b += 1
            else:
                order[a] = idx[i]
                a += 1
        stack[top, 0] = lo + na                   # both parts are tried again, the first one first
        stack[top, 1] = hi
        stack[top, 2] = g
        stack[top + 1, 0] = lo
        stack[top + 1, 1] = lo + na
        stack[top + 1, 2] = q
        top += 2
        g += 1
    return g


@njit(cache=True, nogil=True)
def union_objects(xs, ys, starts, width, link, frac_closed, frac_open, need, min_count, split_frac=0.0,
                  split_waist=0.65, split_polarity=0.0, closed_apart=False, recent=None, recent_rule=None, pol=None):
    """ofpd_io.blob_objects_xy with ofpd.stages "union": the window's stage pixels (stage i's
    are xs, ys[starts[i]:starts[i + 1]], disjoint: the cascade gives each pixel to one stage)
    form blobs together (link_components, component_stats, merge_blobs, as one frame's), and
    merge_blobs runs once more on the groups it gave (their extents, not their components':
    the two open arcs of a large sparse object, each made of short pieces, join as one object
    the way "join" joined them). Each group with >= need pixels is an object of the fastest
    stage holding >= need of its pixels (else of the stage holding most, the faster on ties),
    at the centroid of all its pixels (exact integer sums over the count). An object's edges
    that the cascade handed to several stages are one outline here, which surrounds its
    centroid, so a neighbour's edges join it only within frac_closed. Objects are numbered
    fastest stage first, then by group. With split_frac > 0, a group that split_groups finds to
    hold two objects (two touching outlines, split_two with split_frac and split_waist) is two
    groups; with split_polarity > 0 and ``pol`` (per pixel: bit 1 and bit 2 for the two
    polarities of its ones, frame_pixels' spol) a half that holds a leading and a trailing
    edge is a whole object too (split_two, two_sided). With closed_apart, two groups that each
    surround their centroid and hold >= need pixels are never joined (merge_blobs' apart_px).
    With ``recent`` (the (H * W,) uint8 event-pixel counts of the latest windows,
    ofpd.recent_events) a group short of need is an object too when recent_reaches holds for it
    (recent_rule = [r, m, c, E]; its stage is then the one holding most of its pixels).
    Returns what blob_objects returns."""
    n = xs.shape[0]
    n_stages = starts.shape[0] - 1
    owner = np.full(n, -1, np.int64)
    if n == 0:
        return np.zeros(0, np.int64), np.zeros(0), np.zeros(0), owner, np.zeros(0, np.int64), np.zeros(0, np.int64)
    stage_of = np.empty(n, np.int64)
    for i in range(n_stages):
        stage_of[starts[i]:starts[i + 1]] = i
    labels, n_comp, order = link_components_ordered(xs, ys, link, width)
    count, _sx, _sy, bbox = component_stats(labels, n_comp, xs, ys)
    apart_px = need if closed_apart else 0
    first, count1, box1, closed1 = merge_blobs(labels, count, bbox, xs, ys, frac_closed, frac_open, min_count,
                                               None, apart_px)
    # a group without specks is its seeds, whose ``surrounds`` the first pass computed last
    # (closed1); an open one with specks gets it computed again over all its pixels (a closed
    # one stays closed, as in merge_blobs)
    known = np.empty(count1.shape[0], np.int8)
    for q in range(count1.shape[0]):
        known[q] = 1 if closed1[q] else 0
    for c in range(n_comp):
        if first[c] >= 0 and count[c] < min_count and known[first[c]] == 0:
            known[first[c]] = -1
    inside = np.flatnonzero(first[labels] >= 0)                # the same rule once more, on the groups
    second, gcount, _gbox, _gclosed = merge_blobs(first[labels[inside]], count1, box1, xs[inside], ys[inside],
                                                  frac_closed, frac_open, min_count, known, apart_px)
    comp_group = np.full(n_comp, -1, np.int64)
    for c in range(n_comp):
        if first[c] >= 0:
            comp_group[c] = second[first[c]]
    n_groups = gcount.shape[0]
    pg = np.empty(n, np.int64)                                 # the group of each pixel
    for p in range(n):
        pg[p] = comp_group[labels[p]]
    if split_frac > 0.0:
        if pol is None or split_polarity <= 0.0:
            n_groups = split_groups(xs, ys, pg, n_groups, need, split_frac, split_waist)
        else:
            n_groups = split_groups(xs, ys, pg, n_groups, need, split_frac, split_waist, pol, split_polarity)
    per_stage = np.zeros((n_groups, n_stages), np.int64)
    gsx = np.zeros(n_groups, np.int64)
    gsy = np.zeros(n_groups, np.int64)
    size = np.zeros(n_groups, np.int64)                         # gcount, also of the split groups
    for p in range(n):
        q = pg[p]
        if q >= 0:
            per_stage[q, stage_of[p]] += 1
            gsx[q] += xs[p]
            gsy[q] += ys[p]
            size[q] += 1
    short = size < need                                         # groups that are no object
    if recent is not None:
        short = recent_short(xs, ys, pg, n_groups, short, width, frac_open, recent, recent_rule)
    gstage = np.full(n_groups, -1, np.int64)
    for q in range(n_groups):
        if short[q]:
            continue
        best = n_stages - 1
        for i in range(n_stages - 1, -1, -1):
            if per_stage[q, i] >= need:
                best = i
                break
            if per_stage[q, i] > per_stage[q, best]:
                best = i
        gstage[q] = best
    obj_of = np.full(n_groups, -1, np.int64)
    o_stage = np.empty(n_groups, np.int64)
    o_cx = np.empty(n_groups)
    o_cy = np.empty(n_groups)
    g = 0
    for i in range(n_stages - 1, -1, -1):                      # fastest stage first
        for q in range(n_groups):
            if gstage[q] == i:
                obj_of[q] = g
                o_stage[g] = i
                o_cx[g] = gsx[q] / size[q]
                o_cy[g] = gsy[q] / size[q]
                g += 1
    claim_key = np.empty(n, np.int64)
    claim_own = np.empty(n, np.int64)
    # the claims sorted by key: the claimed pixels in row-major order, when no pixel repeats
    # (the stages' pixels are disjoint); a repeat takes the stable sort of the stage-order claims
    m = 0
    repeats = False
    for a in range(n):
        p = order[a]
        q = pg[p]
        if q >= 0 and obj_of[q] >= 0:
            owner[p] = obj_of[q]
            key = ys[p] * width + xs[p]
            if m > 0 and key == claim_key[m - 1]:
                repeats = True
                break
            claim_key[m] = key
            claim_own[m] = obj_of[q]
            m += 1
    if not repeats:
        return o_stage[:g].copy(), o_cx[:g].copy(), o_cy[:g].copy(), owner, claim_key[:m].copy(), claim_own[:m].copy()
    m = 0
    for i in range(n_stages - 1, -1, -1):                      # claims stage by stage, fastest first
        for p in range(starts[i], starts[i + 1]):
            q = pg[p]
            if q >= 0 and obj_of[q] >= 0:
                owner[p] = obj_of[q]
                claim_key[m] = ys[p] * width + xs[p]
                claim_own[m] = obj_of[q]
                m += 1
    srt = _stable_order(claim_key[:m])
    return o_stage[:g].copy(), o_cx[:g].copy(), o_cy[:g].copy(), owner, claim_key[srt], claim_own[srt]


@njit(cache=True, nogil=True)
def recent_reaches(recent, width, x0, y0, x1, y1, radius, m, noise_factor, total):
    """ofpd.recent_events' rule for a group with bounding box (x0, y0, x1, y1) inclusive: with
    e_j(q) = 1 when pixel q had an event in the j-th latest window (j = 0: this one; the K of
    input_support, ``recent`` = sum_j e_j as events.support.SupportHistory holds it after the
    window's front end, ``total`` = E its sum) and the box grown by ``radius`` px (clipped to
    the sensor) holding A pixels,
        sum over q in the box of recent[q]  >=  m + floor(noise_factor * A * E / (H * W))
    (the second term: noise_factor times what the sensor's event-pixel density alone puts there)."""
    height = recent.shape[0] // width
    xa, xb = max(0, x0 - radius), min(width - 1, x1 + radius)
    ya, yb = max(0, y0 - radius), min(height - 1, y1 + radius)
    s = 0
    for y in range(ya, yb + 1):
        row = y * width
        for x in range(xa, xb + 1):
            s += np.int64(recent[row + x])
    area = np.int64(xb - xa + 1) * np.int64(yb - ya + 1)
    return s >= m + (noise_factor * area * total) // recent.shape[0]


@njit(cache=True, nogil=True)
def recent_short(xs, ys, pg, n_groups, short, width, frac_open, recent, recent_rule):
    """``short`` (groups with fewer than need pixels) less those that recent_reaches lets through
    (recent_rule = [radius, m, noise_factor, E]) and that lie apart from every object: a group
    whose box comes within frac_open (edge_merge_frac) * an object's extent of that object's
    box is its leftover edge, not an object of its own (measured: pieces of large or fast
    objects, whose trail fills the latest windows). Why: a slow object fires a few pixels of its
    edge per window, at the same place window after window."""
    big = np.iinfo(np.int64).max
    x0 = np.full(n_groups, big)
    y0 = np.full(n_groups, big)
    x1 = np.full(n_groups, -1)
    y1 = np.full(n_groups, -1)
    for p in range(xs.shape[0]):
        q = pg[p]
        if q >= 0:
            x0[q] = min(x0[q], xs[p])
            y0[q] = min(y0[q], ys[p])
            x1[q] = max(x1[q], xs[p])
            y1[q] = max(y1[q], ys[p])
    out = short.copy()
    for q in range(n_groups):
        if not short[q] or x1[q] < 0:
            continue
        apart = True
        for o in range(n_groups):
            if short[o] or x1[o] < 0:
                continue
            gap = max(x0[o] - x1[q], x0[q] - x1[o], y0[o] - y1[q], y0[q] - y1[o])
            if gap <= frac_open * (max(x1[o] - x0[o], y1[o] - y0[o]) + 1):
                apart = False
                break
        if apart:
            out[q] = not recent_reaches(recent, width, x0[q], y0[q], x1[q], y1[q], recent_rule[0], recent_rule[1],
                                        recent_rule[2], recent_rule[3])
    return out


@njit(cache=True, nogil=True)
def _stable_order(keys):
    """Stable argsort of non-negative int keys: LSD radix sort on 11-bit digits (2 passes for
    a 640 x 480 sensor's pixel ids), O(n + 2048) per pass."""
    n = keys.shape[0]
    order = np.arange(n)
    if n == 0:
        return order
    top = keys.max()
    tmp = np.empty(n, np.int64)
    cnt = np.empty(2049, np.int64)
    shift = 0
    while (top >> shift) > 0:
        cnt[:] = 0
        for i in range(n):
            cnt[((keys[i] >> shift) & 2047) + 1] += 1
        for d in range(2048):
            cnt[d + 1] += cnt[d]
        for i in range(n):
            q = order[i]
            d = (keys[q] >> shift) & 2047
            tmp[cnt[d]] = q
            cnt[d] += 1
        order, tmp = tmp, order
        shift += 11
    return order


@njit(cache=True, nogil=True)
def claimed_by(keys, owner, query, n_objects, slot_of):
    """(G, n) bool: the pixel query[i] (linear id) is claimed by object g, i.e. the first entry
    of the sorted ``keys`` equal to it has owner g (ofpd_io.Claims of grouping "blobs"). With a
    scratch ``slot_of`` (all -1, left so) longer than every key, by marking the keys on it,
    else by binary search."""
    out = np.zeros((n_objects, query.shape[0]), np.bool_)
    if keys.shape[0] == 0:
        return out
    if keys[-1] < slot_of.shape[0]:
        for j in range(keys.shape[0] - 1, -1, -1):         # the first of equal keys last: it stays
            slot_of[keys[j]] = owner[j]
        for i in range(query.shape[0]):
            q = query[i]
            if q < slot_of.shape[0] and slot_of[q] >= 0:
                out[slot_of[q], i] = True
        for j in range(keys.shape[0]):
            slot_of[keys[j]] = -1
        return out
    at = np.searchsorted(keys, query)
    for i in range(query.shape[0]):
        j = at[i]
        if j < keys.shape[0] and keys[j] == query[i]:
            out[owner[j], i] = True
    return out


@njit(cache=True, nogil=True)
def crop_pool(extent, g, pool_min, pool_max):
    """Cell side P of crop "scaled" for an object of the given extent (px): the smallest power of
    two P >= 1.5 * extent / g (2^ceil(log2(1.5 * extent / g)), 1 for extent 0, in integers:
    2 P g >= 3 extent), clipped to [pool_min, pool_max]."""
    p = 1
    while 2 * p * g < 3 * extent:
        p *= 2
    return min(max(p, pool_min), pool_max)


@njit(cache=True, nogil=True)
def frame_pixels(frames, pix_inverse, upix, width, plane, n_channels, polarity=False):
    """The unique pixels of a window's stage frames and the ones in any frame: frames (N, n)
    bool over the window's ones, pix_inverse (n,) the window pixel of each one, upix (U,) the
    window pixels (linear y * W + x), plane (n,) each one's b * C + c. Returns (xs, ys (M,) the
    pixels of frame 0, then frame 1, ..., each frame's in order of first appearance, starts
    (N + 1,) where each frame's begin, then for the ones in any frame, in order: their window
    pixel ev_u, x, y and OFPD channel 2 b + c (E,), then spol (M,) int8: with ``polarity``, the
    polarities of each listed pixel's ones in any frame (bit 1: channel 0, bit 2: channel 1;
    ofpd_io.pixel_polarity of the dense frames), else empty)."""
    n_frames, n = frames.shape
    n_u = upix.shape[0]
    ux = np.empty(n_u, np.int64)
    uy = np.empty(n_u, np.int64)
    inv_w = 1.0 / width
    for u in range(n_u):                       # y = p // W by a float estimate corrected by one
        p = upix[u]
        y = int(p * inv_w)
        if y * width > p:
            y -= 1
        elif (y + 1) * width <= p:
            y += 1
        uy[u] = y
        ux[u] = p - y * width
    stamp = np.full(n_u, -1, np.int64)
    xs = np.empty(n_frames * n, np.int64)
    ys = np.empty(n_frames * n, np.int64)
    su = np.empty(n_frames * n if polarity else 0, np.int64)     # each listed pixel's window pixel
    starts = np.zeros(n_frames + 1, np.int64)
    in_any = np.zeros(n, np.bool_)
    sel = np.empty(n, np.int64)
    m = 0
    for k in range(n_frames):
        cnt = 0
        for i in range(n):                     # the frame's ones, compacted without a branch per one
            f = frames[k, i]
            sel[cnt] = i
            cnt += f
            in_any[i] |= f
        for j in range(cnt):
            u = pix_inverse[sel[j]]
            if stamp[u] != k:
                stamp[u] = k
                xs[m] = ux[u]
                ys[m] = uy[u]
                if polarity:
                    su[m] = u
                m += 1
        starts[k + 1] = m
    n_ev = 0
    for i in range(n):
        n_ev += in_any[i]
    ev_u = np.empty(n_ev, np.int64)
    fx = np.empty(n_ev, np.int64)
    fy = np.empty(n_ev, np.int64)
    ch = np.empty(n_ev, np.int64)
    e = 0
    for i in range(n):
        if in_any[i]:
            u = pix_inverse[i]
            ev_u[e] = u
            fx[e] = ux[u]
            fy[e] = uy[u]
            pl = plane[i]
            ch[e] = pl if n_channels == 2 else (pl // n_channels) * 2 + pl % n_channels
            e += 1
    if not polarity:
        return xs[:m], ys[:m], starts, ev_u, fx, fy, ch, np.zeros(0, np.int8)
    pol_u = np.zeros(n_u, np.int8)
    for j in range(n_ev):
        pol_u[ev_u[j]] |= np.int8(1 << (ch[j] & 1))
    spol = np.empty(m, np.int8)
    for j in range(m):
        spol[j] = pol_u[su[j]]
    return xs[:m], ys[:m], starts, ev_u, fx, fy, ch, spol


@njit(cache=True, nogil=True)
def object_crops(masks, xs, ys, ch, pix_inverse, n_pixels, fixed_size, g, pool_min, pool_max, width, height):
    """Each object's crop and ones from the claims (G, n) bool over a window's ones (pixel (xs,
    ys), channel ch, window pixel pix_inverse): ofpd_io.crop_origin_xy of its unique pixels
    (side fixed_size, or g * crop_pool of their extent when fixed_size is 0; crop_origin on a
    (width, height) sensor) and the claimed ones. Returns
    (origins (G, 3) = x0, y0, S, n_ones (G,), and the claimed ones as flat arrays object, x, y,
    channel, object by object)."""
    n_obj, n = masks.shape
    origins = np.empty((n_obj, 3), np.int64)
    n_ones = np.zeros(n_obj, np.int64)
    for j in range(n_obj):
        for i in range(n):
            n_ones[j] += masks[j, i]
    total = n_ones.sum()
    obj = np.empty(total, np.int64)
    ox = np.empty(total, np.int64)
    oy = np.empty(total, np.int64)
    och = np.empty(total, np.int64)
    seen = np.full(n_pixels, -1, np.int64)
    ux = np.empty(n, np.int64)
    uy = np.empty(n, np.int64)
    m = 0
    for j in range(n_obj):
        nu = 0
        for i in range(n):
            if masks[j, i]:
                obj[m] = j
                ox[m] = xs[i]
                oy[m] = ys[i]
                och[m] = ch[i]
                m += 1
                u = pix_inverse[i]
                if seen[u] != j:
                    seen[u] = j
                    ux[nu] = xs[i]
                    uy[nu] = ys[i]
                    nu += 1
        px = ux[:nu]
        py = uy[:nu]
        size = fixed_size
        if size == 0:
            extent = 0 if nu == 0 else max(px.max() - px.min(), py.max() - py.min()) + 1
            size = g * crop_pool(extent, g, pool_min, pool_max)
        origins[j, 0], origins[j, 1] = crop_origin(px, py, size, width, height)
        origins[j, 2] = size
    return origins, n_ones, obj, ox, oy, och


@njit(cache=True, nogil=True)
def object_input(masks, xs, ys, ch, pix_inverse, n_pixels, fixed_size, g, pool_min, pool_max, width, height,
                 n_channels, n_bins, coord_scale):
    """object_crops, then ofpd_io.prepare_flat's OFPD input (N, n_channels, g, g) float32 of the
    claimed ones (fill_input; fill_motion when n_channels - 2 > 2 n_bins) in one call: the
    runtime's batch after the grouping. Returns (input, n_ones (G,), and the claimed ones as flat
    arrays object, x, y, channel: plane_fit.object_planes_flow's input, for the objects whose
    OFPD speed asks for it)."""
    origins, n_ones, obj, ox, oy, och = object_crops(masks, xs, ys, ch, pix_inverse, n_pixels, fixed_size, g,
                                                     pool_min, pool_max, width, height)
    out = np.zeros((masks.shape[0], n_channels, g, g), np.float32)
    fill_input(out, obj, ox, oy, och, origins, n_channels - 2, coord_scale)
    if n_channels - 2 > 2 * n_bins:
        fill_motion(out, obj, ox, oy, och, origins, n_bins, 2 * n_bins)
    return out, n_ones, obj, ox, oy, och


@njit(cache=True, nogil=True)
def window_objects(frames, pix_inverse, upix, width, plane, n_channels, union, link, frac_closed, frac_open, need,
                   min_count, split_frac, split_waist, split_polarity, closed_apart, slot_of, fixed_size, g, pool_min,
                   pool_max, height, n_input, n_bins, coord_scale, recent=None, recent_rule=None):
    """The runtime's batch for grouping "blobs" in one call: frame_pixels, then union_objects
    (``union``) or blob_objects, claimed_by (scratch ``slot_of``) and object_input, the same
    kernels on the same arrays back to back, so that a window crosses from Python into compiled
    code once for all of them and gets back seven arrays instead of sixteen. Returns (stage
    (G,) 0-based, OFPD input (G, n_input, g, g) float32, n_ones (G,), then object_input's
    claimed ones: object, x, y, channel); ``recent``, ``recent_rule``: union_objects'."""
    with_pol = union and split_frac > 0.0 and split_polarity > 0.0
    sx, sy, starts, ev_u, fx, fy, ch, spol = frame_pixels(frames, pix_inverse, upix, width, plane, n_channels,
                                                          with_pol)
    if union:                                  # spol is empty and split_polarity 0 when polarities are not read
        stage, _cx, _cy, _own, keys, owner = union_objects(sx, sy, starts, width, link, frac_closed, frac_open, need,
                                                           min_count, split_frac, split_waist,
                                                           split_polarity if with_pol else 0.0, closed_apart, recent,
                                                           recent_rule, spol)
    else:
        stage, _cx, _cy, _own, keys, owner = blob_objects(sx, sy, starts, width, link, frac_closed, frac_open, need,
                                                          min_count)
    masks = claimed_by(keys, owner, fy * width + fx, stage.shape[0], slot_of)
    x, n_ones, obj, ox, oy, och = object_input(masks, fx, fy, ch, ev_u, upix.shape[0], fixed_size, g, pool_min,
                                               pool_max, width, height, n_input, n_bins, coord_scale)
    return stage, x, n_ones, obj, ox, oy, och

@njit(cache=True, nogil=True)
def in_rects(xs, ys, rects):
    """(G, n) bool: pixel i inside rectangle g, rects[g] = (x_min, y_min, x_max, y_max) inclusive."""
    out = np.empty((rects.shape[0], xs.shape[0]), np.bool_)
    for g in range(rects.shape[0]):
        for i in range(xs.shape[0]):
            out[g, i] = rects[g, 0] <= xs[i] <= rects[g, 2] and rects[g, 1] <= ys[i] <= rects[g, 3]
    return out


@njit(cache=True, nogil=True)
def cell_centres(origins, g, coord_scale):
    """ofpd_io.coordinate_planes: (x (N, g), y (N, g)) = (x0 + (i + 0.5) * (S / g) - 0.5) /
    coord_scale (and y0) for crops at origins (N, 3) float64 = (x0, y0, S)."""
    n = origins.shape[0]
    px = np.empty((n, g))
    py = np.empty((n, g))
    for o in range(n):
        pool = origins[o, 2] / g
        for i in range(g):
            c = (i + 0.5) * pool - 0.5
            px[o, i] = (origins[o, 0] + c) / coord_scale
            py[o, i] = (origins[o, 1] + c) / coord_scale
    return px, py


@njit(cache=True, nogil=True)
def _cell_table(origins, g):
    """(pool (N,), cell_of (N, max S)) for crops at origins (N, 3) = (x0, y0, S): P = S // g and
    cell_of[o, v] = v // P for 0 <= v < S, so that the passes over the ones divide nothing."""
    n_obj = origins.shape[0]
    side = 0
    for o in range(n_obj):
        side = max(side, origins[o, 2])
    pool_of = np.empty(n_obj, np.int64)
    cell_of = np.empty((n_obj, side), np.int64)
    for o in range(n_obj):
        pool_of[o] = pool = origins[o, 2] // g
        c = 0
        k = 0
        for v in range(origins[o, 2]):
            cell_of[o, v] = c
            k += 1
            if k == pool:
                k = 0
                c += 1
    return pool_of, cell_of


@njit(cache=True, nogil=True)
def fill_input(out, obj, xs, ys, ch, origins, n_channels, coord_scale):
    """The OFPD input of ofpd_io.prepare_xy into ``out`` (N, n_channels + 2, g, g) float32 of
    zeros: out[obj, ch, y // P, x // P] = the number of ones (object obj, pixel (x, y), channel
    ch < n_channels) in that cell of its object's S x S crop, origins[obj] = (x0, y0, S), P = S / g
    (crop coordinates x, y; ones outside are dropped), divided by P * P in float32 (exact
    integer counts < 2**24, one division each: numpy's result); then the coordinate planes
    out[obj, n_channels, :, i], out[obj, n_channels + 1, i, :] = cell_centres (float64, stored
    as float32)."""
    n_obj = out.shape[0]
    g = out.shape[-1]
    flat = out.reshape(-1)
    plane = g * g
    cell = np.empty(xs.shape[0], np.int64)
    pool_of, cell_of = _cell_table(origins, g)
    for i in range(xs.shape[0]):               # counts, negative until divided
        o = obj[i]
        size = origins[o, 2]
        x = xs[i] - origins[o, 0]
        y = ys[i] - origins[o, 1]
        cell[i] = -1
        if 0 <= x < size and 0 <= y < size and 0 <= ch[i] < n_channels:
            cell[i] = at = ((o * (n_channels + 2) + ch[i]) * g + cell_of[o, y]) * g + cell_of[o, x]
            flat[at] -= 1
    for i in range(xs.shape[0]):               # each counted cell divided once
        at = cell[i]
        if at >= 0 and flat[at] < 0:
            pool = pool_of[obj[i]]
            flat[at] = -flat[at] / np.float32(pool * pool)
    px, py = cell_centres(origins.astype(np.float64), g, coord_scale)
    for o in range(n_obj):
        base = (o * (n_channels + 2) + n_channels) * plane
        for j in range(g):
            for i in range(g):
                flat[base + j * g + i] = np.float32(px[o, i])
                flat[base + plane + j * g + i] = np.float32(py[o, j])
    return out


@njit(cache=True, nogil=True)
def fill_motion(out, obj, xs, ys, ch, origins, n_bins, at):
    """The motion planes of ofpd_io.prepare_xy (ofpd.motion "time_cov") into out[:, at] (x) and
    out[:, at + 1] (y): per cell of each object's crop, 12 n cov(t, u) / P^2 over the n ones in
    it (channel ch = 2 b + p < 2 n_bins), t = b / (B - 1) - 1/2, u = the x offset inside the
    cell in cells, (x - x_cell + 1/2) / P - 1/2 (and v likewise for y). The 12 (= 1 / the
    variance of a uniform on [-1/2, 1/2]) puts a cell whose ones are perfectly time ordered
    along x at about its event density, the scale of the event planes.

    Computed in integers, tt = 2b - (B - 1) and uu = 2 (x - x_cell) - (P - 1):
    12 n cov = 3 (n * sum(tt uu) - sum(tt) sum(uu)) / (n P (B - 1)), divided by P^2 in the same
    float64 division (exact integer numerator and denominator: the same result in any order of
    the ones), stored as float32."""
    n_obj, g = out.shape[0], out.shape[-1]
    # per touched cell c = o * g * g + cy * g + cx (slot_of[c], in order of first touch): n,
    # sum tt, sum uu, sum vv, sum tt uu, sum tt vv; indexed element by element (a row view per
    # one cost more than the sums) and finished only for the cells some one touched
    slot_of = np.full(n_obj * g * g, -1, np.int32)
    acc = np.zeros((xs.shape[0], 6), np.int64)
    touched = np.empty((xs.shape[0], 3), np.int64)     # object, cy, cx of each touched cell
    n_touched = 0
    pool_of, cell_of = _cell_table(origins, g)
    for i in range(xs.shape[0]):
        o = obj[i]
        size = origins[o, 2]
        pool = pool_of[o]
        x = xs[i] - origins[o, 0]
        y = ys[i] - origins[o, 1]
        if 0 <= x < size and 0 <= y < size and 0 <= ch[i] < 2 * n_bins:
            cx = cell_of[o, x]
            cy = cell_of[o, y]
            tt = 2 * (ch[i] >> 1) - (n_bins - 1)
            uu = 2 * (x - cx * pool) - (pool - 1)
            vv = 2 * (y - cy * pool) - (pool - 1)
            cell = (o * g + cy) * g + cx
            c = slot_of[cell]
            if c < 0:
                c = slot_of[cell] = n_touched
                touched[n_touched, 0] = o
                touched[n_touched, 1] = cy
                touched[n_touched, 2] = cx
                n_touched += 1
            acc[c, 0] += 1
            acc[c, 1] += tt
            acc[c, 2] += uu
            acc[c, 3] += vv
            acc[c, 4] += tt * uu
            acc[c, 5] += tt * vv
    for c in range(n_touched):
        o = touched[c, 0]
        cy = touched[c, 1]
        cx = touched[c, 2]
        pool = pool_of[o]
        n = acc[c, 0]
        if n > 1 and n_bins > 1:
            den = float(n * pool * (n_bins - 1) * pool * pool)
            out[o, at, cy, cx] = np.float32(3 * (n * acc[c, 4] - acc[c, 1] * acc[c, 2]) / den)
            out[o, at + 1, cy, cx] = np.float32(3 * (n * acc[c, 5] - acc[c, 1] * acc[c, 3]) / den)
    return out


@njit(cache=True, nogil=True)
def front_end_keep(idx, n_channels, n_pixels, width, first, min_size, slot_of):
    """Keep mask of the input front end (events/frontend.py) over a sorted, unique linear index
    of ones into a (B, C, H, W) volume, in one pass: with ``first``, only the first one (the
    smallest b) of each (c, pixel); with min_size > 1, only the ones whose pixel lies in an
    8-connected cluster of >= min_size of the window's event pixels (the pixel set is the
    same with or without ``first``, so the two filters commute).

    Each one's pixel gets a slot (``slot_of``, an all -1 (n_pixels,) scratch left so); a new
    pixel joins the clusters of its already seen 8 neighbours (union-find over slots); a bit
    per channel and slot marks the (c, pixel)s seen. No division per one: the index is sorted,
    so its plane b * C + c only steps up, and y, x come from a float estimate of p / W
    corrected by one. O(ones), no sorting."""
    keep, slot, parent, pix, u = front_end_pass(idx, n_channels, n_pixels, width, first, min_size > 1, slot_of)
    if min_size > 1:
        size = cluster_sizes(parent, u)
        for i in range(idx.shape[0]):
            if keep[i]:
                keep[i] = size[_root(parent, slot[i])] >= min_size
    for q in range(u):
        slot_of[pix[q]] = -1
    return keep


@njit(cache=True, nogil=True)
def front_end_pass(idx, n_channels, n_pixels, width, first, link, slot_of):
    """front_end_keep's pass over the ones: (keep (n,) of ``first`` alone, slot (n,) of each
    one's pixel, parent (n,) union-find over slots (8-neighbour clusters when ``link``),
    pix (n,) the pixel of each slot (pix[:u]: the window's event pixels, first seen first), u).
    Leaves slot_of[p] = the slot of each event pixel p: the caller resets pix[:u] to -1."""
    n = idx.shape[0]
    keep = np.empty(n, np.bool_)
    pix = np.empty(n, np.int64)
    slot = np.empty(n, np.int64)
    parent = np.empty(n, np.int64)
    if n == 0:
        return keep, slot, parent, pix, 0
    bits = np.zeros(n, np.int64)
    plane = idx[0] // n_pixels
    base = plane * n_pixels
    c = plane % n_channels
    inv_w = 1.0 / width
    nbr = np.array([-width - 1, -width, -width + 1, -1, 1, width - 1, width, width + 1])
    u = 0
    for i in range(n):
        v = idx[i]
        while v >= base + n_pixels:
            base += n_pixels
            c += 1
            if c == n_channels:
                c = 0
        p = v - base
        s = slot_of[p]
        if s < 0:
            s = u
            slot_of[p] = u
            pix[u] = p
            parent[u] = u
            if link:
                y = int(p * inv_w)
                if y * width > p:
                    y -= 1
                elif (y + 1) * width <= p:
                    y += 1
                x = p - y * width
                if y >= 1 and p + width < n_pixels and x >= 1 and x + 1 < width:   # all 8 on the sensor
                    for k in range(8):
                        q = slot_of[p + nbr[k]]
                        if q >= 0:
                            _union(parent, u, q)
                else:
                    for dy in range(-1, 2):
                        yy = y + dy
                        if yy < 0 or yy * width >= n_pixels:
                            continue
                        for dx in range(-1, 2):
                            xx = x + dx
                            if (dy == 0 and dx == 0) or xx < 0 or xx >= width:
                                continue
                            q = slot_of[yy * width + xx]
                            if q >= 0:
                                _union(parent, u, q)
            u += 1
        slot[i] = s
        if first:
            bit = np.int64(1) << c
            keep[i] = (bits[s] & bit) == 0
            bits[s] |= bit
        else:
            keep[i] = True
    return keep, slot, parent, pix, u


@njit(cache=True, nogil=True)
def cluster_sizes(parent, u):
    """(u,) the number of slots in each union-find root's set (0 at non-roots)."""
    size = np.zeros(u, np.int64)
    for q in range(u):
        size[_root(parent, q)] += 1
    return size


@njit(cache=True, nogil=True)
def bin_index(t, x, y, p, t0, dt_us, n_bins, height, width):
    """events.binning.event_bin_index in one pass: the linear index ((b * 2 + (p > 0)) * H + y) * W + x
    of each event with t0 <= t < t0 + dt_us, b = (t - t0) * B // dt_us, in event order."""
    n = t.shape[0]
    out = np.empty(n, np.int64)
    m = 0
    t1 = t0 + dt_us
    inv_dt = 1.0 / dt_us
    for i in range(n):
        ti = np.int64(t[i])
        if ti < t0 or ti >= t1:
            continue
        b = _div_small((ti - t0) * n_bins, dt_us, inv_dt)
        pol = np.int64(1) if p[i] > 0 else np.int64(0)
        out[m] = ((b * 2 + pol) * height + np.int64(y[i])) * width + np.int64(x[i])
        m += 1
    return out[:m]


@njit(cache=True, nogil=True)
def sorted_unique(values):
    """np.unique of non-negative ints: an LSD radix sort of the values themselves (11-bit
    digits, two passes for a 640x480x5x2 volume's linear ids; every digit's histogram from one
    pass over them), then one pass dropping repeats. Sorting the values, not an order of them
    (_stable_order: equal ints need no stable order here), spares a gather per pass."""
    n = values.shape[0]
    if n == 0:
        return values.copy()
    top = values.max()
    n_pass = 0
    while n_pass < 6 and (top >> (11 * n_pass)) > 0:       # 6 digits hold any int64
        n_pass += 1
    cnt = np.zeros((max(n_pass, 1), 2049), np.int64)
    if n_pass == 2:                                # the usual volume: both digits unrolled
        c0 = cnt[0]
        c1 = cnt[1]
        for i in range(n):
            v = values[i]
            c0[(v & 2047) + 1] += 1
            c1[((v >> 11) & 2047) + 1] += 1
    else:
        for i in range(n):
            v = values[i]
            for d in range(n_pass):
                cnt[d, ((v >> (11 * d)) & 2047) + 1] += 1
    for d in range(n_pass):
        for k in range(2048):
            cnt[d, k + 1] += cnt[d, k]
    src = values.copy()
    dst = np.empty(n, values.dtype)
    for d in range(n_pass):
        shift = 11 * d
        c = cnt[d]
        for i in range(n):
            v = src[i]
            k = (v >> shift) & 2047
            dst[c[k]] = v
            c[k] += 1
        src, dst = dst, src
    m = 1
    for i in range(1, n):
        v = src[i]
        if v != src[m - 1]:
            src[m] = v
            m += 1
    return src[:m].copy()


@njit(cache=True, nogil=True)
def binned_ones(t, x, y, p, t0, dt_us, n_bins, height, width):
    """sorted_unique(bin_index(...)): a window's sorted unique linear ids in one call from Python
    (SpikeVolume.from_events), the index array handed over while still in cache."""
    return sorted_unique(bin_index(t, x, y, p, t0, dt_us, n_bins, height, width))


@njit(cache=True, nogil=True)
def pool_index(idx, n_pixels, width, p, hp, wp):
    """spikes.SpikeVolume.pool on a sorted unique linear index into a (B, C, H, W) volume, in
    O(n) without sorting: (u, inverse, u_bc, u_pix, bc, pix) with u = np.unique of the pooled
    ids (bc * hp + y // p) * wp + x // p and u[inverse] the pooled id of each one; u_bc, u_pix
    the plane and pooled pixel of each u, bc, pix those of each one (idx = bc * n_pixels + pix).

    Sorted idx lists the ones plane by plane and row by row, so the ones of one pooled row
    (plane, y // p) are contiguous: up to p runs (one per sensor row), each sorted by x. A
    p-way merge of the runs by x // p gives that row's pooled ids in order."""
    n = idx.shape[0]
    u = np.empty(n, np.int64)
    inverse = np.empty(n, np.int64)
    bc = np.empty(n, np.int64)
    pix = np.empty(n, np.int64)
    rowkey = np.empty(n, np.int64)
    ys = np.empty(n, np.int64)
    xp = np.empty(n, np.int64)
    if n == 0:
        return u, inverse, bc.copy(), pix.copy(), bc, pix
    plane = idx[0] // n_pixels
    base = plane * n_pixels
    inv_w = 1.0 / width
    inv_p = 1.0 / p
    for i in range(n):
        v = idx[i]
        while v >= base + n_pixels:
            base += n_pixels
            plane += 1
        q = v - base
        bc[i] = plane
        pix[i] = q
        y = _div_small(q, width, inv_w)
        ys[i] = y
        xp[i] = _div_small(q - y * width, p, inv_p)
        rowkey[i] = plane * hp + _div_small(y, p, inv_p)
    ptr = np.empty(p, np.int64)
    end = np.empty(p, np.int64)
    m = 0
    i = 0
    gp = hp * wp
    while i < n:
        rk = rowkey[i]
        e = i
        while e < n and rowkey[e] == rk:
            e += 1
        nr = 0
        j = i
        while j < e:                         # the runs of the pooled row: one per sensor row
            ptr[nr] = j
            k = j + 1
            while k < e and ys[k] == ys[j]:
                k += 1
            end[nr] = k
            nr += 1
            j = k
        last = -1
        while True:
            best = -1
            bx = 0
            for r in range(nr):
                if ptr[r] < end[r] and (best < 0 or xp[ptr[r]] < bx):
                    bx = xp[ptr[r]]
                    best = r
            if best < 0:
                break
            if bx != last:
                u[m] = rk * wp + bx
                m += 1
                last = bx
            inverse[ptr[best]] = m - 1
            ptr[best] += 1
        i = e
    u = u[:m].copy()
    u_bc = np.empty(m, np.int64)
    u_pix = np.empty(m, np.int64)
    inv_g = 1.0 / gp
    for j in range(m):
        u_bc[j] = _div_small(u[j], gp, inv_g)
        u_pix[j] = u[j] - u_bc[j] * gp
    return u, inverse, u_bc, u_pix, bc, pix


@njit(cache=True, nogil=True)
def unique_inverse(values):
    """np.unique(values, return_inverse=True) of non-negative ints in O(n) passes: the stable
    radix order (_stable_order), then one pass numbering the distinct values."""
    n = values.shape[0]
    inverse = np.empty(n, np.int64)
    if n == 0:
        return values.copy(), inverse
    order = _stable_order(values)
    u = np.empty(n, values.dtype)
    m = 0
    for i in range(n):
        v = values[order[i]]
        if m == 0 or v != u[m - 1]:
            u[m] = v
            m += 1
        inverse[order[i]] = m - 1
    return u[:m].copy(), inverse


# the kernels called from Python (the others are compiled into their callers)
KERNELS = (dedupe, active_set, ofs_window, ofs_stage, split_closed, compact_image, compact_lookup, compact_closed,
           cascade_window, pooled_cascade, window_objects,
           in_boxes, box_mean, density_groups, link_components, component_stats, merge_blobs, min_gap, surrounds,
           blob_objects, claimed_by, crop_pool, crop_origin, two_pass_centroid, frame_pixels, object_crops, object_input,
           in_rects,
           cell_centres, fill_input, fill_motion, front_end_keep, bin_index, sorted_unique, binned_ones, unique_inverse, pool_index)


#: warm_up's groups: the kernels one path of the cpu runtime calls from Python (Pipeline.warm_groups)
WARM_GROUPS = ("binning", "front_end", "pooled", "objects", "objects_recent", "other")


def warm_up(only=None) -> None:
    """Compile (first run on a machine, a few seconds) or load from the on-disk cache every
    kernel for the argument types the cpu runtime passes, so that the first window of a stream
    is not the one that pays for it. ``only``: the WARM_GROUPS one path needs (the Pipeline's
    fast path: binning, front end, pooled cascade and one window_objects form; Pipeline.warm_groups),
    None: all of them (~1.6 s from the cache, of which ~0.9 s is kernels that path never calls:
    the other groupings, the unpooled cascade, window_objects' other form). tests/test_run_sparse.py
    checks that a cascade after warm_up compiles nothing new, tests/test_run_pipeline.py that a
    Pipeline's windows after its own warm-up load no kernel."""
    groups = set(WARM_GROUPS if only is None else only)
    unknown = groups - set(WARM_GROUPS)
    if unknown:
        raise ValueError(f"unknown warm-up groups {sorted(unknown)}; choose from {', '.join(WARM_GROUPS)}")
    i64 = np.zeros(1, np.int64)
    scratch = new_scratch(4)
    if "binning" in groups:
        from .events.core import EVENT_DTYPE

        for ev in (np.zeros(1, EVENT_DTYPE), np.zeros(2, EVENT_DTYPE)):   # fields of 2+ events are strided ('A')
            sorted_unique(bin_index(ev["t"], ev["x"], ev["y"], ev["p"], 0, 1, 1, 1, 1))
            binned_ones(ev["t"], ev["x"], ev["y"], ev["p"], 0, 1, 1, 1, 1)
    if "front_end" in groups:
        front_end_keep(i64, 2, 1, 1, True, 2, scratch)
        dedupe(i64, scratch)
    if "pooled" in groups:
        pooled_cascade(i64, 4, 2, 2, 1, 1, 2, 1, scratch, np.ones((1, 1, 1), np.int64), i64, i64,
                       np.zeros(1, np.bool_), 1, 1)
    if "objects" in groups:                    # without ofpd.recent_events: ofpd_io.recent_args' (None, None)
        window_objects(np.ones((1, 1), np.bool_), i64, i64, 2, i64, 2, True, 1, 0.2, 1.5, 1, 1, 0.0, 0.65, 0.0,
                       False, scratch, 0, 1, 1, 1, 2, 5, 1, 1000.0, None, None)
    if "objects_recent" in groups:
        window_objects(np.ones((1, 1), np.bool_), i64, i64, 2, i64, 2, True, 1, 0.2, 1.5, 1, 1, 0.0, 0.65, 0.0,
                       False, scratch, 0, 1, 1, 1, 2, 5, 1, 1000.0, np.zeros(4, np.uint8), np.zeros(4, np.int64))
    if "other" in groups:
        _warm_other(i64, scratch)


def _warm_other(i64, scratch) -> None:
    """warm_up's group "other": the unpooled and Lava-side cascade kernels, every grouping's
    kernels as Python calls them (eval, the older groupings) and the OFPD input's."""
    uniq, inverse = dedupe(i64, scratch)
    active, tap_target = active_set(uniq, 2, 2, 1, scratch)
    ofs_window(i64, i64, 2, 2, 2, 1, scratch)
    weight = np.ones((1, 1), np.int64)
    alive = np.ones(1, np.bool_)
    spikes, fired = ofs_stage(alive, i64, i64, inverse, tap_target, weight, 1, active.shape[0], 0, 1, False)
    keep_r, keep_c, map_r, map_c, image = compact_image(active, 2, 2, 1)
    keep_r, keep_c, map_r, map_c, image = compact_closed(active, 2, 2, 1, 1)
    closed = compact_lookup(uniq, 2, keep_r, keep_c, map_r, map_c, image.view(np.bool_))
    split_closed(alive, inverse, closed)
    cascade_window(i64, i64, inverse, uniq, tap_target, active, np.ones((1, 1, 1), np.int64), i64, i64,
                   np.zeros(1, np.bool_), 1, 2, 2, 1)
    box_mean(i64, i64, 0.0, 0.0, 1.0)
    in_boxes(i64, i64, np.zeros((1, 2)), 1.0)
    density_groups(i64, i64, 1, 2)
    labels, n_comp = link_components(i64, i64, 1, 2)
    count, sx, sy, bbox = component_stats(labels, n_comp, i64, i64)
    merge_blobs(labels, count, bbox, i64, i64, 0.2, 1.5, 1)
    blob_objects(i64, i64, np.array([0, 1], np.int64), 2, 1, 0.2, 1.5, 1, 1)
    union_objects(i64, i64, np.array([0, 1], np.int64), 2, 1, 0.2, 1.5, 1, 1, 0.0, 0.65, 0.0, False, None, None,
                  None)
    union_objects(i64, i64, np.array([0, 1], np.int64), 2, 1, 0.2, 1.5, 1, 1, 0.0, 0.65, 0.0, False,
                  np.zeros(2, np.uint8), np.zeros(4, np.int64), None)   # as group_objects_flat passes them: explicit Nones
    i8 = np.zeros(1, np.int8)                  # ofpd.split_polarity: the pixels' polarities
    union_objects(i64, i64, np.array([0, 1], np.int64), 2, 1, 0.2, 1.5, 1, 1, 0.6, 0.65, 0.25, False, None, None, i8)
    union_objects(i64, i64, np.array([0, 1], np.int64), 2, 1, 0.2, 1.5, 1, 1, 0.6, 0.65, 0.25, False,
                  np.zeros(2, np.uint8), np.zeros(4, np.int64), i8)
    split_groups(i64, i64, i64.copy(), 1, 1, 0.6, 0.65)
    min_gap(i64, i64, i64, i64, 1.0)
    surrounds(i64, i64)
    in_rects(i64, i64, np.zeros((1, 4), np.int64))
    claimed_by(i64, i64, i64, 1, scratch)
    crop_pool(1, 1, 1, 1)
    frame_pixels(np.ones((1, 1), np.bool_), i64, i64, 1, i64, 2)
    object_crops(np.ones((1, 1), np.bool_), i64, i64, i64, i64, 1, 0, 1, 1, 1, 2, 2)
    object_input(np.ones((1, 1), np.bool_), i64, i64, i64, i64, 1, 0, 1, 1, 1, 2, 2, 5, 1, 1000.0)
    crop_origin(i64, i64, 1, 2, 2)
    two_pass_centroid(i64, i64, 1.0, 2, 2)
    fill_input(np.zeros((1, 3, 1, 1), np.float32), i64, i64, i64, i64, np.ones((1, 3), np.int64), 1, 1000.0)
    fill_motion(np.zeros((1, 4, 1, 1), np.float32), i64, i64, i64, i64, np.ones((1, 3), np.int64), 1, 0)
    cell_centres(np.ones((1, 3)), 1, 1000.0)
    unique_inverse(i64)
    pool_index(i64, 1, 1, 1, 1, 1)
