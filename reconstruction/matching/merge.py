"""Pairwise matchers' pieces: each view pair a gated assignment, the edges merged cheapest first (Sec. 3.2, Solver)."""

from __future__ import annotations

from itertools import combinations
from typing import Callable

import numpy as np
from scipy.optimize import linear_sum_assignment

PairCost = Callable[[int, int], np.ndarray]  # (view a, view b) -> (N_a, N_b) edge costs


def solve_pair(cost: np.ndarray, gate: float = np.inf, margin: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Gated rectangular assignment (Eq. 5): cost (Na, Nb) -> rows (K,), cols (K,) of the pairs kept."""
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
    """Least extra cost of re-matching each accepted pair: cost (Na, Nb), rows, cols (K,) -> (K,) (or inf)."""
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
    """Edges of one solved view pair: rows (K,), cols (K,), cost (Na, Nb) -> (K, 5) (view_a, det_a, view_b, det_b, cost)."""
    rows = np.asarray(rows, dtype=np.int64)
    cols = np.asarray(cols, dtype=np.int64)
    k = len(rows)
    return np.column_stack(
        [np.full(k, view_a), rows, np.full(k, view_b), cols, np.asarray(cost, dtype=np.float64)[rows, cols]]
    ).astype(np.float64)


def as_edges(edges: np.ndarray) -> np.ndarray:
    """Validate an edge table: (E, 5) -> (E, 5) float64 (a copy)."""
    edges = np.array(edges, dtype=np.float64).reshape(-1, 5) if np.size(edges) else np.zeros((0, 5))
    if not np.all(np.isfinite(edges)):
        raise ValueError("edges must be finite (drop gated pairs before merging)")
    return edges


def merge_edges(edges: np.ndarray, num_detections: list[int], min_views: int = 2) -> np.ndarray:
    """Persons from edges (E, 5) (view_a, det_a, view_b, det_b, cost) -> (P, V) detection index or -1."""
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
    parent, views = list(range(len(view_of))), [1 << int(v) for v in view_of]  # plain ints: a loop per edge

    def find(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    for i, j in zip(ga[order].tolist(), gb[order].tolist()):
        a, b = find(i), find(j)
        if a != b and not views[a] & views[b]:
            parent[b] = a
            views[a] |= views[b]
    roots = np.array([find(g) for g in range(len(view_of))], dtype=np.int64)
    _, first, person = np.unique(roots, return_index=True, return_inverse=True)
    rows = np.full((len(first), V), -1, dtype=np.int64)
    rows[np.argsort(np.argsort(first))[person], view_of] = np.arange(len(view_of)) - offsets[view_of]
    return rows[(rows >= 0).sum(axis=1) >= min_views]


def match_pairs(
    pair_cost: PairCost, num_detections: list[int], gate: float, min_views: int, margin: float = 0.0
) -> np.ndarray:
    """Gated assignment of each view pair by pair_cost(a, b) (N_a, N_b), merged cheapest first -> (P, V)."""
    edges = [np.zeros((0, 5))]
    for a, b in combinations(range(len(num_detections)), 2):
        cost = pair_cost(a, b)
        rows, cols = solve_pair(cost, gate, margin)
        edges.append(pair_edges(a, b, rows, cols, cost))
    return merge_edges(np.concatenate(edges), num_detections, min_views)
