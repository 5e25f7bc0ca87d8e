"""Gated assignment of sparse view pairs, one connected component at a time (compiled).

:func:`~reconstruction.matching.merge.solve_pair` gives the pairs that are not allowed a big finite cost M,
so the solver maximises the number of allowed pairs, then minimises their cost: the objective is
sum(cost - M) over the allowed pairs used, which splits over the connected components of the graph of
allowed pairs. In a crowd a view pair has hundreds of components of one or a few detections, so solving
each one alone (with the same M) is much cheaper than one dense (Na, Nb) problem, and each is started from a row
reduction (:func:`lsap_reduced`). Where the optimum is unique (ties of float costs aside) the result is the dense
solver's.

:func:`linear_sum_assignment` is the dense solver for the tracker, the evaluation and the 2D association:
scipy's result for a finite matrix (its algorithm step for step, :func:`lsap`, so ties break alike) without
importing ``scipy.optimize`` (about 75 ms of every run's start on a 2-core machine of this class).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from reconstruction.matching.evidence_kernels import _find


@njit(cache=True, error_model="numpy")
def lsap(cost: np.ndarray) -> np.ndarray:
    """Minimum-cost assignment of a finite (nr, nc) matrix, nr <= nc: column of every row (nr,).

    The shortest augmenting path algorithm of scipy's ``linear_sum_assignment`` (Crouse 2016), step for step.
    """
    nr, nc = cost.shape
    u, v = np.zeros(nr), np.zeros(nc)
    col4row, row4col = np.full(nr, -1), np.full(nc, -1)
    work = _work(nr, nc)
    for cur in range(nr):
        if not _augment(cost, cur, u, v, col4row, row4col, work):  # infeasible (not with finite costs)
            break
    return col4row


@njit(cache=True, error_model="numpy")
def lsap_reduced(cost: np.ndarray) -> np.ndarray:
    """Minimum-cost assignment of a finite (nr, nc) matrix, nr <= nc: column of every row (nr,); an optimum of
    :func:`lsap`'s problem (the same one where the optimum is unique), reached faster on gated problems.

    A row reduction first (u_i = min_j c_ij, v = 0, each row given its cheapest column unless an earlier row has
    it: feasible duals with v_j = 0 on the free columns, the pairs tight), then :func:`lsap`'s shortest augmenting
    path for the rows left free: in a gated crowd most rows' cheapest columns differ, and few paths are searched.
    """
    nr, nc = cost.shape
    u, v = np.empty(nr), np.zeros(nc)
    col4row, row4col = np.full(nr, -1), np.full(nc, -1)
    for i in range(nr):  # row reduction: u_i = min_j c_ij, v = 0 (feasible; a free column keeps v_j = 0)
        best, arg = cost[i, 0], 0
        for j in range(1, nc):
            if cost[i, j] < best:
                best, arg = cost[i, j], j
        u[i] = best
        if row4col[arg] == -1:  # the row's cheapest column, unless an earlier row has it: a tight pair
            col4row[i], row4col[arg] = arg, i
    work = _work(nr, nc)
    for cur in range(nr):
        if col4row[cur] == -1 and not _augment(cost, cur, u, v, col4row, row4col, work):
            break
    return col4row


@njit(cache=True, error_model="numpy")
def _work(nr: int, nc: int) -> tuple:
    """Scratch of :func:`_augment`: spc (nc,), path (nc,), SR (nr,), SC (nc,), remaining (nc,)."""
    return (
        np.empty(nc),
        np.full(nc, -1),
        np.empty(nr, dtype=np.bool_),
        np.empty(nc, dtype=np.bool_),
        np.empty(nc, dtype=np.int64),
    )


@njit(cache=True, error_model="numpy")
def _augment(cost, cur, u, v, col4row, row4col, work) -> bool:
    """Assign free row cur along the shortest augmenting path (scipy's augmenting_path), the duals u (nr,), v (nc,)
    updated, col4row (nr,) and row4col (nc,) in place: -> False if no path (infeasible; not with finite costs)."""
    spc, path, SR, SC, remaining = work
    nr, nc = cost.shape
    min_val, num_remaining, i, sink = 0.0, nc, cur, -1
    for it in range(nc):
        remaining[it] = nc - it - 1  # reverse order, as scipy: a constant matrix gives the identity
        SC[it], spc[it] = False, np.inf
    for it in range(nr):
        SR[it] = False
    while sink == -1:
        index, lowest = -1, np.inf
        SR[i] = True
        for it in range(num_remaining):
            j = remaining[it]
            r = min_val + cost[i, j] - u[i] - v[j]
            if r < spc[j]:
                path[j], spc[j] = i, r
            if spc[j] < lowest or (spc[j] == lowest and row4col[j] == -1):
                lowest, index = spc[j], it
        min_val = lowest
        if min_val == np.inf:
            return False
        j = remaining[index]
        if row4col[j] == -1:
            sink = j
        else:
            i = row4col[j]
        SC[j] = True
        num_remaining -= 1
        remaining[index] = remaining[num_remaining]
    # update the dual variables, then augment
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
    return True


@njit(cache=True, error_model="numpy")
def _solve_component(ks, li, lj, cost, big, row_at, col_at, keep) -> None:
    """Assign one component, its entries ks (ascending, so rows ascending): -> keep[ks] of the assignment.
    row_at, col_at: scratch (na,), (nb,) of -1, left as found."""
    nr, nc = 0, 0
    cols = np.empty(len(ks), dtype=np.int64)
    for k in ks:
        if row_at[li[k]] < 0:
            row_at[li[k]] = nr
            nr += 1
        if col_at[lj[k]] < 0:
            col_at[lj[k]] = 0
            cols[nc] = lj[k]
            nc += 1
    for c in range(1, nc):  # insertion sort: the columns in their order in the view
        x, d = cols[c], c
        while d > 0 and cols[d - 1] > x:
            cols[d] = cols[d - 1]
            d -= 1
        cols[d] = x
    for c in range(nc):
        col_at[cols[c]] = c
    transpose = nr > nc  # the solver wants rows <= columns, as scipy transposes
    R, C = min(nr, nc), max(nr, nc)
    sub, at = np.empty((R, C)), np.empty((R, C), dtype=np.int64)
    for r in range(R):
        for c in range(C):
            sub[r, c], at[r, c] = big, -1
    for k in ks:
        r, c = row_at[li[k]], col_at[lj[k]]
        if transpose:
            r, c = c, r
        sub[r, c], at[r, c] = cost[k], k
    col = lsap_reduced(sub)
    for r in range(len(col)):
        if col[r] >= 0 and at[r, col[r]] >= 0:
            keep[at[r, col[r]]] = True
    for k in ks:
        row_at[li[k]], col_at[lj[k]] = -1, -1


@njit(cache=True, error_model="numpy")
def solve_sparse_pairs(starts: np.ndarray, sizes: np.ndarray, li: np.ndarray, lj: np.ndarray, cost: np.ndarray):
    """Gated assignment of view pairs given by their allowed entries -> accepted (E,) bool.

    Pair p has (sizes[p, 0], sizes[p, 1]) detections and the entries starts[p]:starts[p + 1] of li, lj
    (local row, column; sorted by row) and cost (finite); the entries not listed are not allowed. As
    :func:`~reconstruction.matching.merge.solve_pair` with the same big cost, component by component.
    """
    keep = np.zeros(len(cost), dtype=np.bool_)
    for p in range(len(starts) - 1):
        s, e = starts[p], starts[p + 1]
        na, nb = sizes[p, 0], sizes[p, 1]
        largest = 0.0
        for k in range(s, e):
            largest = max(largest, abs(cost[k]))
        big = (min(na, nb) + 1) * largest + 1.0
        parent = np.empty(na + nb, dtype=np.int64)
        for r in range(na + nb):
            parent[r] = r
        for k in range(s, e):
            a, b = _find(parent, li[k]), _find(parent, na + lj[k])
            if a != b:
                parent[max(a, b)] = min(a, b)
        # entries grouped by component (counting sort on the root, stable: rows stay ascending)
        start = np.zeros(na + nb + 1, dtype=np.int64)
        for k in range(s, e):
            start[_find(parent, li[k]) + 1] += 1
        for r in range(na + nb):
            start[r + 1] += start[r]
        fill, order = np.empty(na + nb, dtype=np.int64), np.empty(e - s, dtype=np.int64)
        for r in range(na + nb):
            fill[r] = start[r]
        for k in range(s, e):
            r = _find(parent, li[k])
            order[fill[r]] = k
            fill[r] += 1
        row_at, col_at = np.empty(na, dtype=np.int64), np.empty(nb, dtype=np.int64)
        for r in range(max(na, nb)):
            if r < na:
                row_at[r] = -1
            if r < nb:
                col_at[r] = -1
        for r in range(na + nb):
            m = start[r + 1] - start[r]
            if m == 1:  # one allowed pair alone: always taken (its cost - big < 0)
                keep[order[start[r]]] = True
            elif m > 1:
                _solve_component(order[start[r] : start[r + 1]], li, lj, cost, big, row_at, col_at, keep)
    return keep


def linear_sum_assignment(cost: np.ndarray, maximize: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Minimum (or maximum) cost assignment of a finite matrix (nr, nc) -> (rows, cols), each (min(nr, nc),)
    int64, rows ascending: scipy.optimize.linear_sum_assignment's result."""
    c = np.asarray(cost, dtype=np.float64)
    if c.ndim != 2:
        raise ValueError(f"expected a 2-D cost matrix, got shape {c.shape}")
    if not np.isfinite(c).all():
        raise ValueError("cost matrix has non-finite entries")
    if min(c.shape) == 0:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    c = -c if maximize else c
    transpose = c.shape[0] > c.shape[1]  # the solver wants rows <= columns, as scipy's
    col = lsap(np.ascontiguousarray(c.T if transpose else c))
    if transpose:
        order = np.argsort(col, kind="stable")
        return col[order], order.astype(np.int64)
    return np.arange(len(col), dtype=np.int64), col
