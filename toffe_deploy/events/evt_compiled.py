"""The EVT 2.0 / EVT 3.0 word loops, compiled (numba): one pass over a chunk of words, the
decoder state carried in a small int64 array from chunk to chunk.

Why compiled: EVT3 is a state machine (row, time, x base set by some words and used by the
next ones); its numpy form needed a binary search per state variable and event and ran at
1-3 M events/s, the loop runs at tens of M events/s. Compiled on first use, cached on disk
(``cache=True``) like toffe_deploy/compiled.py. Word layouts: fmt_prophesee's docstring.

State (int64 array of STATE_LEN): Y (row, -1 unknown), TL and TH (time low / unwrapped time high,
-1 unknown), TH_RAW (the last raw time high, -1 none), LOOPS (time-high wraps so far), BASE
(vector x base, -1 unknown), POL (vector polarity, -1 unknown), BAD (index of the first word of
an undefined type in the last chunk, -1 none: decoding stopped there).
"""
from __future__ import annotations

import numpy as np
from ..jit import njit

Y, TL, TH, TH_RAW, LOOPS, BASE, POL, BAD = range(8)
STATE_LEN = 8
#: A time-high word more than half its counter's range below the last one is a wrap of the
#: counter (EVT3: 2,048 of its 4,096 steps, 8.4 s; EVT2: 2**27 of 2**28, 2.4 h); a smaller drop
#: stays a drop (a glitch or a camera clock reset, which the time-order check reports as
#: decreasing timestamps). The reading closest in time wins: a drop of d steps is either d steps
#: back or (range - d) forward. Prophesee's reference decoders count a wrap only for a drop of
#: nearly the whole range, which a camera's time high every 4,096 us gives; a file or a ROS stream
#: with gaps between time-high words (faery's encoder, lost packets) can wrap with a smaller drop,
#: and does so here up to a gap of half the range. A drop of 10 steps (640 us in EVT2) had been
#: the rule: a clock reset or a 100 ms jump back then read as a wrap, 16.8 s or 4.8 h later.
EVT3_HALF_RANGE = 1 << 11
EVT2_HALF_RANGE = 1 << 27


def new_state() -> np.ndarray:
    """The state of a decoder that has seen no word (everything unknown, no wrap)."""
    s = np.full(STATE_LEN, -1, np.int64)
    s[LOOPS] = 0
    return s


@njit(cache=True, nogil=True)
def evt3_bound(w):
    """Most events the words can hold: 1 per EVT_ADDR_X, 12 per VECT_12, 8 per VECT_8."""
    n = 0
    for i in range(w.shape[0]):
        typ = w[i] >> 12
        if typ == 2:
            n += 1
        elif typ == 4:
            n += 12
        elif typ == 5:
            n += 8
    return n


@njit(cache=True, nogil=True)
def evt3_decode(w, state, x, y, t, p):
    """Decode EVT 3.0 words into x, y, t, p (preallocated, evt3_bound long); returns the count.
    Events before the row, the first time high or the vector base are known are dropped; the time
    low is 0 until a time-low word says otherwise (an encoder that starts at t = 0 writes none:
    faery's default zero_t0 file lost its first events)."""
    ys, tl, th, thraw, loops, base, pol = (state[Y], state[TL], state[TH], state[TH_RAW], state[LOOPS],
                                           state[BASE], state[POL])
    state[BAD] = -1
    n = 0
    for i in range(w.shape[0]):
        v = np.int64(w[i])
        typ = v >> 12
        pay = v & 0xFFF
        if typ == 0:                      # EVT_ADDR_Y
            ys = pay & 0x7FF
        elif typ == 2:                    # EVT_ADDR_X: one event
            if ys >= 0 and th >= 0 and tl >= 0:
                x[n] = pay & 0x7FF
                y[n] = ys
                t[n] = (th << 12) | tl
                p[n] = (pay >> 11) & 1
                n += 1
        elif typ == 3:                    # VECT_BASE_X
            base = pay & 0x7FF
            pol = (pay >> 11) & 1
        elif typ == 4 or typ == 5:        # VECT_12 / VECT_8
            width = 12 if typ == 4 else 8
            mask = pay if typ == 4 else pay & 0xFF
            if base >= 0:
                if ys >= 0 and th >= 0 and tl >= 0:
                    for k in range(width):
                        if (mask >> k) & 1:
                            x[n] = base + k
                            y[n] = ys
                            t[n] = (th << 12) | tl
                            p[n] = pol
                            n += 1
                base += width
        elif typ == 6:                    # EVT_TIME_LOW
            tl = pay
        elif typ == 8:                    # EVT_TIME_HIGH (12 bits of 24: unwrap)
            if thraw >= 0 and thraw - pay > EVT3_HALF_RANGE:
                loops += 1
            thraw = pay
            th = pay + 4096 * loops
            if tl < 0:
                tl = 0                    # a time high sets the time; a time low of 0 need not follow
        elif typ == 7 or typ == 10 or typ == 14 or typ == 15:
            pass                          # CONTINUED_4, EXT_TRIGGER, OTHERS, CONTINUED_12
        else:
            state[BAD] = i
            break
    state[Y], state[TL], state[TH], state[TH_RAW], state[LOOPS], state[BASE], state[POL] = (
        ys, tl, th, thraw, loops, base, pol)
    return n


@njit(cache=True, nogil=True)
def evt2_decode(w, state, x, y, t, p):
    """Decode EVT 2.0 words into x, y, t, p (preallocated, len(w) long); returns the count.
    Events before the first EVT_TIME_HIGH are dropped."""
    th, thraw, loops = state[TH], state[TH_RAW], state[LOOPS]
    state[BAD] = -1
    n = 0
    for i in range(w.shape[0]):
        v = np.int64(w[i])
        typ = v >> 28
        if typ <= 1:                      # CD_OFF / CD_ON
            if th >= 0:
                x[n] = (v >> 11) & 0x7FF
                y[n] = v & 0x7FF
                t[n] = (th << 6) | ((v >> 22) & 0x3F)
                p[n] = typ
                n += 1
        elif typ == 8:                    # EVT_TIME_HIGH (28 bits of 34: unwrap)
            raw = v & 0x0FFFFFFF
            if thraw >= 0 and thraw - raw > EVT2_HALF_RANGE:
                loops += 1
            thraw = raw
            th = raw + (loops << 28)
        elif typ == 10 or typ == 14 or typ == 15:
            pass                          # EXT_TRIGGER, OTHERS, CONTINUED
        else:
            state[BAD] = i
            break
    state[TH], state[TH_RAW], state[LOOPS] = th, thraw, loops
    return n
