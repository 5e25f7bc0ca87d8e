"""Gated assignment of sparse view pairs, one connected component at a time (compiled).

:func:`~reconstruction.matching.merge.solve_pair` gives the pairs that are not allowed a big finite cost M,
so the solver maximises the number of allowed pairs, then minimises their cost: the objective is
sum(cost - M) over the allowed pairs used, which splits over the connected components of the graph of
allowed pairs. In a crowd a view pair has hundreds of components of one or a few detections, so solving
each one alone (with the same M) is much cheaper than one dense (Na, Nb) problem. Each is solved over its allowed
entries alone (a crowd's view pair still has a component of ~75 x 75 with ~7 entries per row), from a row
reduction, by the shortest augmenting paths of scipy's solver (:func:`_solve_component`). Where the optimum is
unique (ties of float costs aside) the result is the dense solver's.

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
    _flip_path(cur, sink, path, col4row, row4col)
    return True


@njit(cache=True, error_model="numpy")
def _flip_path(cur, sink, path, col4row, row4col) -> None:
    """Augment along the shortest path from free row cur to the free column sink (path[j]: the row before column
    j): every row on it takes the column after it, col4row (nr,) and row4col (nc,) in place."""
    j = sink
    while True:
        i = path[j]
        row4col[j] = i
        col4row[i], j = j, col4row[i]
        if i == cur:
            break


@njit(cache=True, error_model="numpy")
def _solve_component(ks, li, lj, cost, big, row_at, col_at, keep) -> None:
    """Assign one component, its entries ks (ascending: rows ascending, each row's entries together): -> keep[ks]
    of the assignment. row_at, col_at: scratch (na,), (nb,) of -1, left as found.

    The dense problem (the entries not allowed at cost big) as a sparse one: each row has its allowed entries
    and a column of its own at cost big (matched to nothing), which has the dense problem's optimum (a row the
    dense solver gives a big entry is a row left unmatched, and there are enough columns for those). Solved by a
    row reduction, then :func:`lsap`'s shortest augmenting paths over the entries alone (:func:`_sparse_augment`).
    """
    E, R, C = len(ks), 0, 0
    cols = np.empty(E, dtype=np.int64)
    ptr = np.zeros(E + 1, dtype=np.int64)  # row r's entries: ks[ptr[r]:ptr[r + 1]]
    for t in range(E):
        k = ks[t]
        if row_at[li[k]] < 0:
            row_at[li[k]] = R
            R += 1
        if col_at[lj[k]] < 0:
            col_at[lj[k]] = C
            C += 1
        cols[t] = col_at[lj[k]]
        ptr[row_at[li[k]] + 1] = t + 1
    n = C + R  # the real columns, then each row's own
    u, v = np.empty(R), np.zeros(n)
    col4row, row4col = np.full(R, -1), np.full(n, -1)
    for r in range(R):  # row reduction: u_r = its cheapest entry, v = 0 (feasible; free columns keep v = 0)
        best, arg = big, C + r
        for t in range(ptr[r], ptr[r + 1]):
            if cost[ks[t]] < best:
                best, arg = cost[ks[t]], cols[t]
        u[r] = best
        if row4col[arg] == -1:  # the row's cheapest column, unless an earlier row has it: a tight pair
            col4row[r], row4col[arg] = arg, r
    work = (np.full(n, np.inf), np.empty(n, dtype=np.int64), np.zeros(n, dtype=np.bool_), np.empty(n, dtype=np.int64))
    work = (*work, np.empty(R, dtype=np.int64))
    for r in range(R):
        if col4row[r] == -1:
            _sparse_augment(r, ptr, cols, ks, cost, big, C, u, v, col4row, row4col, work)
    for r in range(R):
        for t in range(ptr[r], ptr[r + 1]):
            if cols[t] == col4row[r]:
                keep[ks[t]] = True
    for k in ks:
        row_at[li[k]], col_at[lj[k]] = -1, -1


@njit(cache=True, error_model="numpy")
def _sparse_augment(cur, ptr, cols, ks, cost, big, C, u, v, col4row, row4col, work) -> None:
    """:func:`_augment` for the sparse problem of :func:`_solve_component`: only the columns reached through the
    entries (row r's: cols[ptr[r]:ptr[r + 1]] at cost[ks[...]], and its own column C + r at big) are relaxed and
    scanned. work: spc (n,) of inf, path (n,), scanned (n,) of False (left as found), seen (n,) and rows (R,) scratch
    (the rows of the search tree, cur first)."""
    spc, path, scanned, seen, rows = work
    n_rows, n_seen, n_scanned = 0, 0, 0  # seen[:n_seen]: reached, not scanned; then scanned from the end
    min_val, i, sink = 0.0, cur, -1
    while sink == -1:
        rows[n_rows] = i
        n_rows += 1
        for t in range(ptr[i], ptr[i + 1] + 1):
            j, c = (cols[t], cost[ks[t]]) if t < ptr[i + 1] else (C + i, big)
            if scanned[j]:
                continue
            r = min_val + c - u[i] - v[j]
            if r < spc[j]:
                if spc[j] == np.inf:
                    seen[n_seen] = j
                    n_seen += 1
                path[j], spc[j] = i, r
        index, lowest = -1, np.inf
        for s in range(n_seen):  # the lowest reached column, a free one among equals (as lsap)
            j = seen[s]
            if spc[j] < lowest or (spc[j] == lowest and row4col[j] == -1):
                lowest, index = spc[j], s
        min_val, j = lowest, seen[index]  # the row's own column is always reached: index >= 0
        n_seen -= 1
        seen[index] = seen[n_seen]
        n_scanned += 1
        seen[len(seen) - n_scanned] = j
        scanned[j] = True
        if row4col[j] == -1:
            sink = j
        else:
            i = row4col[j]
    u[cur] += min_val  # the dual variables, then the augmentation (as _augment)
    for s in range(1, n_rows):
        u[rows[s]] += min_val - spc[col4row[rows[s]]]
    for s in range(len(seen) - n_scanned, len(seen)):
        v[seen[s]] -= min_val - spc[seen[s]]
    _flip_path(cur, sink, path, col4row, row4col)
    for s in range(n_seen):
        spc[seen[s]] = np.inf
    for s in range(len(seen) - n_scanned, len(seen)):
        spc[seen[s]], scanned[seen[s]] = np.inf, False


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
