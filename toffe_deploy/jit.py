"""numba's ``njit`` for every compiled kernel of the package, with compile ids that cannot collide.

Why: numba names each compiled function's machine-code symbol after its qualified name, its
argument types and a per-process counter (``FunctionIdentity._unique_ids``: 1, 2, 3, ...). Two
processes that compile different functions, and cache them (``cache=True``), can hand out the
same counter value to two different bodies of one helper, e.g. the quicksort numba generates for
``np.sort`` inside one kernel and for ``np.argsort`` inside another. A later process that loads
both caches gets two symbols of one name, and the JIT linker keeps one body for both: the other
kernel then runs the wrong code, silently (numba issue #10486, open in numba 0.61). We met it as
the DOTIE baseline's kernels giving unsorted, wrong spikes whenever a pipeline had been loaded
from the cache first in the same process (tests/test_bench_dotie_fast.py after tests/test_api.py).

The fix, as PyTensor's: the counter is replaced by random 64-bit ids before anything compiles,
so ids of kernels compiled in different processes differ (a collision is a 2^-64 chance per pair).
Every module of the package takes ``njit`` from here, never from numba directly, so that the
replacement is in place whichever module a process imports first. Caches written before it
(ids 1, 2, 3, ...) are invalidated by numba itself when their source file changes (a new install).
"""
from __future__ import annotations

import secrets

from numba import njit as _numba_njit
from numba.core import bytecode


def njit(*args, **options):
    """numba's njit with ``error_model="numpy"`` unless a kernel asks otherwise: a division by
    zero gives inf, nan or 0 instead of raising ZeroDivisionError from compiled code, so float
    ``/`` loses its zero test and integer ``//`` and ``%`` their exception path. Every kernel
    divides by sizes, counts and constants its callers check first, so the results are the same
    bits; measured on the shipped sample, one pinned core, four A/B pairs of processes with
    separate caches: 780 -> 772 us a window (1 %), the same object flow (docs/speed-log.md,
    2026-11-30). numba's cache key holds no compile options: a cache written before this change
    is used until a kernel's source file changes (a new install), with the same results."""
    options.setdefault("error_model", "numpy")
    return _numba_njit(*args, **options)


class _RandomIds:
    """An endless iterator of random 64-bit ids, in place of numba's counter."""

    def __iter__(self):
        return self

    def __next__(self) -> int:
        return secrets.randbits(64)


if not isinstance(bytecode.FunctionIdentity._unique_ids, _RandomIds):   # once, also on re-import
    bytecode.FunctionIdentity._unique_ids = _RandomIds()

__all__ = ["njit"]
