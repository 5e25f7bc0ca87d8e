"""Gated assignment of sparse view pairs, one connected component at a time (compiled).

:func:`~reconstruction.matching.merge.solve_pair` gives the pairs that are not allowed a big finite cost M,
so the solver maximises the number of allowed pairs, then minimises their cost: the objective is
sum(cost - M) over the allowed pairs used, which splits over the connected components of the graph of
allowed pairs. In a crowd a view pair has hundreds of components of one or a few detections, so solving
each one alone (with the same M) is much cheaper than one dense (Na, Nb) problem. Where the optimum is
unique (ties of float costs aside) the result is the dense solver's.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def _augment(cost, u, v, path, row4col, spc, i, SR, SC, remaining) -> tuple[int, float]:
    """One shortest augmenting path from row i: (sink column or -1, its reduced length)."""
    nc = cost.shape[1]
    min_val = 0.0
    num_remaining = nc
    for it in range(nc):
        remaining[it] = nc - it - 1  # reverse order, as scipy: a constant matrix gives the identity
    SR[:] = False
    SC[:] = False
    spc[:] = np.inf
    sink = -1
    while sink == -1:
        index = -1
        lowest = np.inf
        SR[i] = True
        for it in range(num_remaining):
            j = remaining[it]
            r = min_val + cost[i, j] - u[i] - v[j]
            if r < spc[j]:
                path[j] = i
                spc[j] = r
            if spc[j] < lowest or (spc[j] == lowest and row4col[j] == -1):
                lowest = spc[j]
                index = it
        min_val = lowest
        if min_val == np.inf:
            return -1, min_val
        j = remaining[index]
        if row4col[j] == -1:
            sink = j
        else:
            i = row4col[j]
        SC[j] = True
        num_remaining -= 1
        remaining[index] = remaining[num_remaining]
    return sink, min_val


@njit(cache=True)
def lsap(cost: np.ndarray) -> np.ndarray:
    """Minimum-cost assignment of a finite (nr, nc) matrix, nr <= nc: column of every row (nr,).

    The shortest augmenting path algorithm of scipy's ``linear_sum_assignment`` (Crouse 2016), step for step.
    """
    nr, nc = cost.shape
    u, v = np.zeros(nr), np.zeros(nc)
    spc = np.empty(nc)
    path = np.full(nc, -1)
    col4row, row4col = np.full(nr, -1), np.full(nc, -1)
    SR, SC = np.zeros(nr, dtype=np.bool_), np.zeros(nc, dtype=np.bool_)
    remaining = np.empty(nc, dtype=np.int64)
    for cur in range(nr):
        sink, min_val = _augment(cost, u, v, path, row4col, spc, cur, SR, SC, remaining)
        if sink < 0:
            return np.full(nr, -1)
        u[cur] += min_val
        for i in range(nr):
            if SR[i] and i != cur:
                u[i] += min_val - spc[col4row[i]]
        for j in range(nc):
            if SC[j]:
                v[j] -= min_val - spc[j]
        j = sink
        while True:
            i = path[j]
            row4col[j] = i
            col4row[i], j = j, col4row[i]
            if i == cur:
                break
    return col4row


@njit(cache=True)
def _root(parent: np.ndarray, i: int) -> int:
    """Root of i, with path halving."""
    while parent[i] != i:
        parent[i] = parent[parent[i]]
        i = parent[i]
    return i


@njit(cache=True)
def _solve_component(rows, cols, ei, ej, ec, big, keep, idx) -> None:
    """Assign one component: its rows, cols (sorted local indices), its entries (ei, ej, ec, index idx)."""
    transpose = len(rows) > len(cols)
    nr, nc = (len(cols), len(rows)) if transpose else (len(rows), len(cols))
    sub = np.full((nr, nc), big)
    at = np.full((nr, nc), -1)
    for k in range(len(ei)):
        r, c = np.searchsorted(rows, ei[k]), np.searchsorted(cols, ej[k])
        if transpose:
            r, c = c, r
        sub[r, c] = ec[k]
        at[r, c] = idx[k]
    col = lsap(sub)
    for r in range(nr):
        if col[r] >= 0 and at[r, col[r]] >= 0:
            keep[at[r, col[r]]] = True


@njit(cache=True)
def solve_sparse_pairs(starts: np.ndarray, sizes: np.ndarray, li: np.ndarray, lj: np.ndarray, cost: np.ndarray):
    """Gated assignment of view pairs given by their allowed entries -> accepted (E,) bool.

    Pair p has (sizes[p, 0], sizes[p, 1]) detections and the entries starts[p]:starts[p + 1] of li, lj
    (local row, column) and cost (finite); the entries not listed are not allowed. As
    :func:`~reconstruction.matching.merge.solve_pair` with the same big cost, component by component.
    """
    keep = np.zeros(len(cost), dtype=np.bool_)
    for p in range(len(starts) - 1):
        s, e = starts[p], starts[p + 1]
        if e == s:
            continue
        na, nb = sizes[p, 0], sizes[p, 1]
        largest = 0.0
        for k in range(s, e):
            largest = max(largest, abs(cost[k]))
        big = (min(na, nb) + 1) * largest + 1.0
        parent = np.arange(na + nb)
        for k in range(s, e):
            a, b = _root(parent, li[k]), _root(parent, na + lj[k])
            if a != b:
                parent[max(a, b)] = min(a, b)
        comp = np.empty(e - s, dtype=np.int64)
        for k in range(s, e):
            comp[k - s] = _root(parent, li[k])
        order = np.argsort(comp, kind="mergesort")
        g = 0
        while g < len(order):
            h = g
            while h < len(order) and comp[order[h]] == comp[order[g]]:
                h += 1
            idx = s + order[g:h]
            if h - g == 1:  # one allowed pair alone: always taken (cost - big < 0)
                keep[idx[0]] = True
            else:
                _solve_component(np.unique(li[idx]), np.unique(lj[idx]), li[idx], lj[idx], cost[idx], big, keep, idx)
            g = h
    return keep
