"""The swap regret of a sparse assignment's accepted pairs in numpy: the reference for data.assignment.swap_regrets
(the sparse counterpart of :func:`reconstruction.matching.merge.swap_regret`)."""

from __future__ import annotations

import numpy as np


def sparse_swap_regret(q: np.ndarray, a: np.ndarray, b: np.ndarray, cost: np.ndarray, kept: np.ndarray) -> np.ndarray:
    """Least extra cost of re-matching each accepted pair within its view pair: candidates' view pair q, detections
    a, b and cost (E,) each, kept (K,) indices of the accepted candidates -> (K,), inf without an alternative.

    Alternatives: a candidate to a free detection, or swapping partners with another accepted pair of the view pair
    (both cross candidates must exist); a pair that is not a candidate never counts."""
    regret = np.full(len(kept), np.inf)
    if not len(kept):
        return regret
    width = int(max(a.max(), b.max())) + 1
    other = np.ones(len(cost), dtype=bool)
    other[kept] = False
    others = np.flatnonzero(other)
    slot_a = holders(q[kept] * width + a[kept], q[others] * width + a[others], int(q.max() + 1) * width)
    slot_b = holders(q[kept] * width + b[kept], q[others] * width + b[others], int(q.max() + 1) * width)
    own = cost[kept]
    free_b = (slot_a >= 0) & (slot_b < 0)  # a accepted with another partner, b free
    np.minimum.at(regret, slot_a[free_b], cost[others[free_b]] - own[slot_a[free_b]])
    free_a = (slot_b >= 0) & (slot_a < 0)
    np.minimum.at(regret, slot_b[free_a], cost[others[free_a]] - own[slot_b[free_a]])
    cross = np.flatnonzero((slot_a >= 0) & (slot_b >= 0))  # (a of k, b of l): the swap also needs (a of l, b of k)
    k, l = slot_a[cross], slot_b[cross]
    pair_key = (q.astype(np.int64) * width + a) * width + b
    back = find(pair_key, (q[kept][k].astype(np.int64) * width + a[kept][l]) * width + b[kept][k])
    ok = back >= 0
    swap = cost[others[cross][ok]] + cost[back[ok]] - own[k[ok]] - own[l[ok]]
    np.minimum.at(regret, k[ok], swap)
    np.minimum.at(regret, l[ok], swap)
    return regret


def holders(held: np.ndarray, queries: np.ndarray, size: int) -> np.ndarray:
    """For each query key (M,) in [0, size), the index of the held key (K,) (distinct) equal to it, or -1."""
    table = np.full(size, -1, dtype=np.int64)
    table[held] = np.arange(len(held))
    return table[queries]


def find(keys: np.ndarray, queries: np.ndarray) -> np.ndarray:
    """Index in keys (N,) (distinct) of each query (M,), -1 where absent."""
    if not len(keys):
        return np.full(len(queries), -1)
    order = np.argsort(keys, kind="stable")  # linear time where the keys come sorted (the matcher's candidates do)
    ordered, by_key = keys[order], np.argsort(queries)  # sorted queries search several times faster
    at = np.empty(len(queries), dtype=np.int64)
    at[by_key] = np.minimum(np.searchsorted(ordered, queries[by_key]), len(keys) - 1)
    return np.where(ordered[at] == queries, order[at], -1)
