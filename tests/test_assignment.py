"""The compiled matching (toffe_deploy/assignment.py) against brute force on small matrices: the
most allowed pairs, then the least total distance; and the Hungarian method's optimum."""
import itertools

import numpy as np
import pytest

from toffe_deploy.assignment import match_pairs, min_cost_pairs


def _best(d, ok):
    """(pairs, total) of every partial one-to-one assignment over allowed pairs: most, then least."""
    n, m = d.shape
    best = (0, 0.0)
    for k in range(1, min(n, m) + 1):
        for rows in itertools.combinations(range(n), k):
            for cols in itertools.permutations(range(m), k):
                if all(ok[r, c] for r, c in zip(rows, cols)):
                    tot = sum(d[r, c] for r, c in zip(rows, cols))
                    if k > best[0] or (k == best[0] and tot < best[1]):
                        best = (k, tot)
    return best


def test_match_pairs_takes_the_most_allowed_pairs_then_the_least_distance(rng):
    for _ in range(300):
        n, m = rng.integers(0, 5, 2)
        d = np.round(rng.random((n, m)) * 20, 1)             # ties too
        ok = d <= rng.uniform(3, 20)
        rows, cols = match_pairs(d, ok)
        assert len(set(rows.tolist())) == len(rows) and len(set(cols.tolist())) == len(cols)
        assert all(ok[r, c] for r, c in zip(rows, cols)) and list(rows) == sorted(rows)
        k, tot = _best(d, ok)
        assert len(rows) == k and d[rows, cols].sum() == pytest.approx(tot)


def test_min_cost_pairs_is_optimal_on_wide_and_tall_matrices(rng):
    for shape in [(3, 5), (5, 3), (4, 4), (1, 3), (3, 1)]:
        c = rng.random(shape)
        rows, cols = min_cost_pairs(c)
        assert len(rows) == min(shape) and list(rows) == sorted(rows)
        k = min(shape)
        best = min(sum(c[r, q] for r, q in zip(rs, cs)) for rs in itertools.combinations(range(shape[0]), k)
                   for cs in itertools.permutations(range(shape[1]), k))
        assert c[rows, cols].sum() == pytest.approx(best)
