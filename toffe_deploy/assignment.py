"""One-to-one matching of rows to columns, compiled (numba): what the evaluation's gated matching
(metrics.match_gated) and the tracker's association (tracking, windows where a gate holds two
candidates) both run.

    min_cost_pairs(cost)     exact minimum-cost assignment of an (n, m) matrix: min(n, m) pairs,
                             each row and column at most once (Hungarian method with potentials,
                             O(n^2 m); scipy's linear_sum_assignment without scipy, which the lean
                             runtime does not ship)
    match_pairs(d, ok)       among the allowed pairs ``ok`` of a distance matrix ``d``: the most
                             pairs, then the least total distance. The bipartite graph of allowed
                             pairs is split into connected components first: a component of one
                             pair is that pair, one of a single row or column its nearest allowed
                             pair, any other the Hungarian method on its rows and columns with a
                             disallowed pair costing more than all its allowed ones together.

Both return (rows, cols) int64 arrays sorted by row. Why compiled: the tracker meets a window with
two candidates in one gate in about 1 of 40 windows of the shipped sample, and the Python form of
these steps cost ~190 us there on the cache the pipeline's other kernels leave (~5 us a window
on average, 200 us at p99); compiled, the whole ambiguous window stays one call.
"""
from __future__ import annotations

import numpy as np
from .jit import njit

from .compiled import _root


@njit(cache=True, nogil=True)
def min_cost_pairs(cost):
    """(rows, cols) of the minimum-cost assignment of ``cost`` (n, m) float64 (module doc); finite
    costs (metrics.min_cost_assignment makes them so: a NaN or inf entry there costs more than
    all the finite ones together)."""
    flip = cost.shape[0] > cost.shape[1]
    a = cost.T if flip else cost                 # n <= m
    n, m = a.shape
    u = np.zeros(n + 1)
    v = np.zeros(m + 1)
    owner = np.zeros(m + 1, np.int64)            # owner[j] = 1-based row assigned to column j
    way = np.zeros(m + 1, np.int64)
    minv = np.empty(m + 1)
    used = np.empty(m + 1, np.bool_)
    for i in range(1, n + 1):
        owner[0] = i
        j0 = 0
        minv[:] = np.inf
        used[:] = False
        while True:
            used[j0] = True
            i0 = owner[j0]
            for j in range(1, m + 1):
                if not used[j]:
                    red = a[i0 - 1, j - 1] - u[i0] - v[j]
                    if red < minv[j]:
                        minv[j] = red
                        way[j] = j0
            j1 = 0
            delta = np.inf
            for j in range(1, m + 1):                # the first free column of least minv (one is
                if not used[j] and (j1 == 0 or minv[j] < delta):   # free: n <= m; so the loop ends)
                    j1 = j
                    delta = minv[j]
            for j in range(m + 1):
                if used[j]:
                    u[owner[j]] += delta
                    v[j] -= delta
                elif j > 0:
                    minv[j] -= delta
            j0 = j1
            if owner[j0] == 0:
                break
        while j0:
            j1 = way[j0]
            owner[j0] = owner[j1]
            j0 = j1
    k = 0
    for j in range(1, m + 1):
        k += owner[j] > 0
    rows = np.empty(k, np.int64)
    cols = np.empty(k, np.int64)
    k = 0
    for j in range(1, m + 1):
        if owner[j] > 0:
            rows[k], cols[k] = owner[j] - 1, j - 1
            k += 1
    if flip:
        rows, cols = cols, rows
    order = np.argsort(rows, kind="mergesort")
    return rows[order], cols[order]


@njit(cache=True, nogil=True)
def match_pairs(d, ok):
    """(rows, cols) of the most allowed pairs of ``d`` (n, m) float64 under ``ok`` (n, m) bool,
    then the least total distance (module doc)."""
    n, m = d.shape
    parent = np.arange(n + m)
    n_edges = 0
    for i in range(n):
        for j in range(m):
            if ok[i, j]:
                parent[_root(parent, i)] = _root(parent, n + j)
                n_edges += 1
    comp = np.empty(n_edges, np.int64)           # each allowed pair's component (its row's root)
    ei = np.empty(n_edges, np.int64)
    ej = np.empty(n_edges, np.int64)
    e = 0
    for i in range(n):
        for j in range(m):
            if ok[i, j]:
                comp[e], ei[e], ej[e] = _root(parent, i), i, j
                e += 1
    rows = np.empty(min(n, m), np.int64)
    cols = np.empty(min(n, m), np.int64)
    k = 0
    done = np.zeros(n + m, np.bool_)
    row_in = np.full(n, -1, np.int64)
    col_in = np.full(m, -1, np.int64)
    for e0 in range(n_edges):
        c = comp[e0]
        if done[c]:
            continue
        done[c] = True
        nr = nc = 0
        best = -1
        for e in range(e0, n_edges):             # the component's rows and columns, in order
            if comp[e] != c:
                continue
            if row_in[ei[e]] < 0:
                row_in[ei[e]] = nr
                nr += 1
            if col_in[ej[e]] < 0:
                col_in[ej[e]] = nc
                nc += 1
            if best < 0 or d[ei[e], ej[e]] < d[ei[best], ej[best]]:
                best = e
        if nr == 1 or nc == 1:                   # one pair, or one row or column: its nearest pair
            rows[k], cols[k] = ei[best], ej[best]
            k += 1
        else:
            ri = np.empty(nr, np.int64)
            ci = np.empty(nc, np.int64)
            for i in range(n):
                if row_in[i] >= 0:
                    ri[row_in[i]] = i
            for j in range(m):
                if col_in[j] >= 0:
                    ci[col_in[j]] = j
            ri.sort()
            ci.sort()
            big = 0.0                            # above any sum of the component's allowed distances
            for e in range(e0, n_edges):
                if comp[e] == c:
                    big += d[ei[e], ej[e]]
            big += 1.0
            sub = np.empty((nr, nc))
            for a in range(nr):
                for b in range(nc):
                    sub[a, b] = d[ri[a], ci[b]] if ok[ri[a], ci[b]] else big
            sr, sc = min_cost_pairs(sub)
            for q in range(sr.shape[0]):
                if ok[ri[sr[q]], ci[sc[q]]]:
                    rows[k], cols[k] = ri[sr[q]], ci[sc[q]]
                    k += 1
        for e in range(e0, n_edges):
            if comp[e] == c:
                row_in[ei[e]] = -1
                col_in[ej[e]] = -1
    order = np.argsort(rows[:k], kind="mergesort")
    return rows[:k][order], cols[:k][order]
