"""Evaluation broken down by a numeric per-sequence attribute (``eval --by NAME[=EDGES]``).

A sequence file's attrs (events/fmt_toffe: JSON per attr; the generator's spec under
``generator.spec``) say how it was made: object size, pair spacing, noise rate, contrast...
``attr_value`` finds NAME in them: a dotted path (``generator.spec.dvs.noise_hz``) exactly; else
the first key, breadth first, equal to NAME, then starting with NAME (``size`` finds
``size_px``), then ending with ``_NAME``. A list of numbers (one per object) counts as its mean.

Buckets: with EDGES e1 < e2 < ... a value v falls in [e_i, e_i+1) (plus ``< e1`` and ``>= en``);
without, one bucket per distinct value (at most ``MAX_DISTINCT``, else the quartiles become the
edges). Sequences without the attribute go to bucket ``n/a``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

MAX_DISTINCT = 12
NA = "n/a"


@dataclass(frozen=True)
class Breakdown:
    """One ``--by``: attribute NAME, optional bucket edges (ascending)."""

    name: str
    edges: tuple[float, ...] | None = None

    @classmethod
    def parse(cls, text: str) -> "Breakdown":
        """``NAME`` or ``NAME=E1,E2,...``; ValueError with the reason otherwise."""
        name, _, rest = text.partition("=")
        name = name.strip()
        if not name:
            raise ValueError(f"expected NAME or NAME=EDGE,EDGE,..., got {text!r}")
        if not rest.strip():
            return cls(name)
        try:
            edges = tuple(float(v) for v in rest.split(",") if v.strip())
        except ValueError:
            raise ValueError(f"bucket edges must be numbers, got {rest!r}") from None
        if not edges or any(not math.isfinite(e) for e in edges) or any(b <= a for a, b in zip(edges, edges[1:])):
            raise ValueError(f"bucket edges must be finite and ascending, got {rest!r}")
        return cls(name, edges)


def _numeric(v: Any) -> float | None:
    if isinstance(v, bool):
        return None
    if isinstance(v, (int, float)):
        return float(v) if math.isfinite(v) else None
    if isinstance(v, list) and v and all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in v):
        return float(np.mean(v))
    return None


def _walk(attrs: dict):
    """(path, key, value) of every entry, breadth first; lists of dicts are entered too."""
    queue = [("", attrs)]
    while queue:
        prefix, node = queue.pop(0)
        items = node.items() if isinstance(node, dict) else enumerate(node)
        for k, v in items:
            path = f"{prefix}{k}"
            yield path, str(k), v
            if isinstance(v, dict) or (isinstance(v, list) and any(isinstance(x, dict) for x in v)):
                queue.append((path + ".", v))


def attr_value(attrs: dict, name: str) -> tuple[str, float] | None:
    """(path found, value) of attribute NAME in a sequence's attrs (module doc), or None."""
    entries = list(_walk(attrs))
    tests = [lambda path, key: path == name, lambda path, key: key == name,
             lambda path, key: key.startswith(name), lambda path, key: key.endswith("_" + name)]
    for test in tests:
        hits = [(path, _numeric(v)) for path, key, v in entries if test(path, key)]
        hits = [(path, v) for path, v in hits if v is not None]
        if hits:
            # the same key on every object (objects.0.size_px, objects.1.size_px, ...): their mean
            key = hits[0][0].split(".")[-1]
            same = [(p, v) for p, v in hits if p.split(".")[-1] == key]
            path = same[0][0] if len(same) == 1 else f"mean of {key}"
            return path, float(np.mean([v for _p, v in same]))
    return None


def numeric_keys(attrs: dict) -> list[str]:
    """The names --by can break down by in a sequence's attrs: every key with a numeric value
    (attr_value's), sorted, each once."""
    return sorted({key for _path, key, v in _walk(attrs) if not key.isdigit() and _numeric(v) is not None})


def bucket_labels(values: list[float | None], edges: tuple[float, ...] | None) -> list[str]:
    """Bucket label of each value (None -> ``n/a``), module doc."""
    known = np.asarray([v for v in values if v is not None], dtype=np.float64)
    if edges is None and known.size:
        distinct = np.unique(known)
        if distinct.size > MAX_DISTINCT:
            edges = tuple(np.unique(np.quantile(known, [0.25, 0.5, 0.75])).tolist())
    out = []
    for v in values:
        if v is None:
            out.append(NA)
        elif edges is None:
            out.append(f"{v:g}")
        else:
            i = int(np.searchsorted(edges, v, side="right"))
            out.append(f"< {edges[0]:g}" if i == 0 else f">= {edges[-1]:g}" if i == len(edges)
                       else f"{edges[i - 1]:g}-{edges[i]:g}")
    return out


def bucket_order(labels: list[str], values: list[float | None]) -> list[str]:
    """Distinct labels by ascending value, ``n/a`` last."""
    lowest: dict[str, float] = {}
    for lab, v in zip(labels, values):
        lowest[lab] = min(lowest.get(lab, math.inf), math.inf if v is None else v)
    return sorted(lowest, key=lambda lab: (lab == NA, lowest[lab]))
