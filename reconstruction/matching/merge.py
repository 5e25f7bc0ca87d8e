"""Pieces shared by the pairwise matchers: a gated two-view assignment and the multi-view merger.

A matcher scores the detections of every view pair (l < m), solves each pair with
:func:`solve_pair`, collects the accepted edges with :func:`pair_edges` and turns them into persons
with :func:`merge_edges`, which resolves cross-view conflicts giving priority to cheaper edges
(paper Sec. 3.2, "Solver").
"""

from __future__ import annotations

from itertools import combinations
from typing import Callable

import numpy as np
from scipy.optimize import linear_sum_assignment

PairCost = Callable[[int, int], np.ndarray]  # (view a, view b) -> (N_a, N_b) edge costs

EDGE_COLUMNS = ("view_a", "det_a", "view_b", "det_b", "cost")


def solve_pair(cost: np.ndarray, gate: float = np.inf, margin: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Gated rectangular assignment: cost (Na, Nb) -> rows (K,), cols (K,) of the accepted pairs.

    Pairs with a non-finite cost or a cost above ``gate`` are never accepted. They get a large finite
    cost M > min(Na, Nb) * (largest allowed cost), so ``linear_sum_assignment`` (a Jonker-Volgenant
    shortest augmenting path solver) first maximises the number of allowed pairs and then minimises
    their total cost, as the equality constraints of the paper's Eq. 5 ask; the gated pairs it still
    has to use are dropped afterwards. With ``margin`` > 0, an accepted pair is kept only if it is
    distinct: every alternative of :func:`swap_regret` costs at least ``margin`` more.
    """
    cost = np.asarray(cost, dtype=np.float64)
    if cost.ndim != 2:
        raise ValueError(f"cost must be 2-D (Na, Nb), got shape {cost.shape}")
    empty = np.zeros(0, dtype=np.int64)
    allowed = np.isfinite(cost) & (cost <= gate)
    if not allowed.any():
        return empty, empty.copy()
    largest = float(np.max(np.abs(cost[allowed])))
    big = (min(cost.shape) + 1) * largest + 1.0
    rows, cols = linear_sum_assignment(np.where(allowed, cost, big))
    keep = allowed[rows, cols]
    rows, cols = rows[keep].astype(np.int64), cols[keep].astype(np.int64)
    if margin > 0:
        distinct = swap_regret(cost, rows, cols) >= margin
        rows, cols = rows[distinct], cols[distinct]
    return rows, cols


def swap_regret(cost: np.ndarray, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """Least extra cost of re-matching each accepted pair: cost (Na, Nb), rows (K,), cols (K,) -> (K,).

    For the accepted pair (i, j) the alternatives are: swapping partners with another accepted pair
    (i', j'), i.e. (i, j') + (i', j) instead of (i, j) + (i', j'); or i taking a column j'' that no
    accepted pair uses (j then unmatched), or j a free row i''. Gated pairs count as alternatives
    with their cost (a competitor just above the gate is still a competitor); non-finite ones never
    do. +inf where no alternative exists.
    """
    cost = np.where(np.isfinite(cost), np.asarray(cost, dtype=np.float64), np.inf)
    rows, cols = np.asarray(rows, dtype=np.int64), np.asarray(cols, dtype=np.int64)
    if len(rows) == 0:
        return np.zeros(0)
    sub = cost[np.ix_(rows, cols)]  # (K, K): sub[k, l] = cost(rows[k], cols[l])
    own = np.diag(sub).copy()
    swap = sub + sub.T - own[:, None] - own[None, :]
    np.fill_diagonal(swap, np.inf)
    regret = swap.min(axis=1)
    free_cols = np.setdiff1d(np.arange(cost.shape[1]), cols)
    free_rows = np.setdiff1d(np.arange(cost.shape[0]), rows)
    if len(free_cols):
        regret = np.minimum(regret, cost[np.ix_(rows, free_cols)].min(axis=1) - own)
    if len(free_rows):
        regret = np.minimum(regret, cost[np.ix_(free_rows, cols)].min(axis=0) - own)
    return regret


def pair_edges(view_a: int, view_b: int, rows: np.ndarray, cols: np.ndarray, cost: np.ndarray) -> np.ndarray:
    """Edges of one solved view pair: rows (K,), cols (K,), cost (Na, Nb) -> (K, 5) see EDGE_COLUMNS."""
    rows = np.asarray(rows, dtype=np.int64)
    cols = np.asarray(cols, dtype=np.int64)
    k = len(rows)
    return np.column_stack(
        [np.full(k, view_a), rows, np.full(k, view_b), cols, np.asarray(cost, dtype=np.float64)[rows, cols]]
    ).astype(np.float64)


class _Components:
    """Union-find over global detection indices that tracks the set of views of each component."""

    def __init__(self, view_of: np.ndarray, num_views: int) -> None:
        # Plain lists and integer bit masks of views: this loop runs once per edge, and numpy
        # scalar operations would dominate the matching time in crowds.
        self.parent = list(range(len(view_of)))
        self.views = [1 << int(v) for v in view_of]

    def find(self, i: int) -> int:
        """Root of i, with path halving."""
        parent = self.parent
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    def union_if_compatible(self, i: int, j: int) -> bool:
        """Merge the components of i and j unless they share a view; whether they are now one."""
        a, b = self.find(i), self.find(j)
        if a == b:
            return True
        if self.views[a] & self.views[b]:
            return False
        self.parent[b] = a
        self.views[a] |= self.views[b]
        return True


def as_edges(edges: np.ndarray) -> np.ndarray:
    """Validate an edge table: (E, 5) -> (E, 5) float64 (a copy)."""
    edges = np.array(edges, dtype=np.float64).reshape(-1, 5) if np.size(edges) else np.zeros((0, 5))
    if not np.all(np.isfinite(edges)):
        raise ValueError("edges must be finite (drop gated pairs before merging)")
    return edges


def merge_edges(edges: np.ndarray, num_detections: list[int], min_views: int = 2) -> np.ndarray:
    """Persons from pairwise edges: (E, 5) rows (view_a, det_a, view_b, det_b, cost) -> (P, V).

    Edges are taken by increasing cost (ties by view and detection indices, so the result does not
    depend on the edge order) and each one merges its two detections' persons unless that would put
    two detections of one view into a person. Persons seen in >= ``min_views`` views are returned,
    ordered by their smallest (view, detection); -1 marks a view without a detection.
    """
    edges = as_edges(edges)
    counts = np.asarray(num_detections, dtype=np.int64)
    V = len(counts)
    offsets = np.concatenate([[0], np.cumsum(counts)])
    view_of = np.repeat(np.arange(V), counts)
    va, da, vb, db = (edges[:, k].astype(np.int64) for k in range(4))
    bad = (va < 0) | (va >= V) | (vb < 0) | (vb >= V) | (va == vb)
    if np.any(bad):
        raise ValueError(f"edge {int(np.argmax(bad))} names a view outside 0..{V - 1} or one view twice")
    if np.any((da < 0) | (da >= counts[va]) | (db < 0) | (db >= counts[vb])):
        raise ValueError("an edge names a detection index outside its view")
    ga, gb = offsets[va] + da, offsets[vb] + db
    order = np.lexsort((gb, ga, edges[:, 4]))
    comps = _Components(view_of, V)
    for i, j in zip(ga[order].tolist(), gb[order].tolist()):
        comps.union_if_compatible(i, j)
    return _components_to_assignment(comps, view_of, offsets, min_views)


def _components_to_assignment(
    comps: _Components, view_of: np.ndarray, offsets: np.ndarray, min_views: int
) -> np.ndarray:
    """(P, V) rows of the components with >= min_views views, by smallest global index."""
    V = len(offsets) - 1
    rows: dict[int, np.ndarray] = {}
    for g, v in enumerate(view_of.tolist()):  # increasing g = increasing (view, det): first seen = smallest
        root = comps.find(g)
        row = rows.get(root)
        if row is None:  # not setdefault: that would build a row for every detection
            row = rows[root] = np.full(V, -1, dtype=np.int64)
        if row[v] >= 0:
            raise AssertionError("merger produced two detections of one view in a person")
        row[v] = g - offsets[v]
    kept = [row for row in rows.values() if np.sum(row >= 0) >= min_views]
    return np.stack(kept) if kept else np.zeros((0, V), dtype=np.int64)


def match_pairs(
    pair_cost: PairCost, num_detections: list[int], gate: float, min_views: int, margin: float = 0.0
) -> np.ndarray:
    """Gated assignment of every view pair (a < b), then the cheapest-first merge: -> (P, V).

    ``pair_cost(a, b)`` returns the (N_a, N_b) cost of the view pair, +inf where not allowed;
    ``margin`` > 0 keeps only the distinct pairs (:func:`solve_pair`).
    """
    edges = [np.zeros((0, 5))]
    for a, b in combinations(range(len(num_detections)), 2):
        cost = pair_cost(a, b)
        rows, cols = solve_pair(cost, gate, margin)
        edges.append(pair_edges(a, b, rows, cols, cost))
    return merge_edges(np.concatenate(edges), num_detections, min_views)
