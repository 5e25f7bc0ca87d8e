"""Assignment solvers of the matchers, the tracker and the evaluation: label grouping, gated sparse assignment."""

from __future__ import annotations

import numpy as np
from numba import njit


def assignment_from_labels(labels: list[np.ndarray], min_views: int = 2) -> np.ndarray:
    """Group by person label: V arrays (N_v,) int (-1 = none) -> (P, V) detection or -1; a label twice: ValueError."""
    V = len(labels)
    people: dict[int, np.ndarray] = {}
    for v, lab in enumerate(labels):
        for det, person in enumerate(np.asarray(lab, dtype=np.int64).tolist()):
            if person < 0:
                continue
            row = people.get(person)
            if row is None:  # not setdefault: that would build a row for every detection
                row = people[person] = np.full(V, -1, dtype=np.int64)
            if row[v] >= 0:
                raise ValueError(f"label {person} occurs twice in view {v} (detections {row[v]} and {det})")
            row[v] = det
    rows = [people[k] for k in sorted(people) if np.sum(people[k] >= 0) >= min_views]
    return np.stack(rows) if rows else np.zeros((0, V), dtype=np.int64)


@njit(cache=True, error_model="numpy")
def find_root(parent: np.ndarray, i: int) -> int:
    """Root of node i in a union-find forest parent (N,), with path halving."""
    while parent[i] != i:
        parent[i] = parent[parent[i]]
        i = parent[i]
    return i


@njit(cache=True, error_model="numpy")
def _solve_component(ks, li, lj, cost, big, row_at, col_at, keep) -> None:
    """Assign one component, entries ks (rows ascending) -> keep[ks]; row_at (na,), col_at (nb,): -1 scratch."""
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
    """Assign free row cur along the shortest augmenting path; duals u (R,), v (n,) updated in place."""
    spc, path, scanned, seen, rows = work  # spc (n,) inf, scanned (n,) False: left as found; path, seen (n,), rows (R,)
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
        for s in range(n_seen):  # the lowest reached column, a free one among equals (as scipy)
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
    u[cur] += min_val  # the dual variables, then the augmentation
    for s in range(1, n_rows):
        u[rows[s]] += min_val - spc[col4row[rows[s]]]
    for s in range(len(seen) - n_scanned, len(seen)):
        v[seen[s]] -= min_val - spc[seen[s]]
    j = sink  # augment along the path back to row cur (path[j]: the row before column j)
    while True:
        i = path[j]
        row4col[j] = i
        col4row[i], j = j, col4row[i]
        if i == cur:
            break
    for s in range(n_seen):
        spc[seen[s]] = np.inf
    for s in range(len(seen) - n_scanned, len(seen)):
        spc[seen[s]], scanned[seen[s]] = np.inf, False


@njit(cache=True, error_model="numpy")
def _components(s: int, e: int, na: int, nb: int, li, lj) -> tuple:
    """Entries s:e of a view pair by component -> start (na + nb + 1,), order (e - s,) (rows ascending)."""
    parent = np.arange(na + nb)
    for k in range(s, e):
        a, b = find_root(parent, li[k]), find_root(parent, na + lj[k])
        if a != b:
            parent[max(a, b)] = min(a, b)
    start = np.zeros(na + nb + 1, dtype=np.int64)  # counting sort on the root, stable: rows stay ascending
    for k in range(s, e):
        start[find_root(parent, li[k]) + 1] += 1
    for r in range(na + nb):
        start[r + 1] += start[r]
    fill, order = start[:-1].copy(), np.empty(e - s, dtype=np.int64)
    for k in range(s, e):
        r = find_root(parent, li[k])
        order[fill[r]] = k
        fill[r] += 1
    return start, order


@njit(cache=True, error_model="numpy")
def solve_sparse_pairs(starts: np.ndarray, sizes: np.ndarray, li: np.ndarray, lj: np.ndarray, cost: np.ndarray):
    """Gated assignment of view pairs p (sizes[p] = (na, nb)) by entries starts[p]:starts[p + 1] -> accepted (E,)."""
    keep = np.zeros(len(cost), dtype=np.bool_)
    for p in range(len(starts) - 1):
        s, e = starts[p], starts[p + 1]
        na, nb = sizes[p, 0], sizes[p, 1]
        largest = 0.0
        for k in range(s, e):
            largest = max(largest, abs(cost[k]))
        big = (min(na, nb) + 1) * largest + 1.0
        start, order = _components(s, e, na, nb, li, lj)
        row_at, col_at = np.full(na, -1), np.full(nb, -1)
        for r in range(na + nb):
            m = start[r + 1] - start[r]
            if m == 1:  # one allowed pair alone: always taken (its cost - big < 0)
                keep[order[start[r]]] = True
            elif m > 1:
                _solve_component(order[start[r] : start[r + 1]], li, lj, cost, big, row_at, col_at, keep)
    return keep


@njit(cache=True, error_model="numpy")
def swap_regrets(starts: np.ndarray, li: np.ndarray, lj: np.ndarray, cost: np.ndarray, keep: np.ndarray):
    """merge.swap_regret of solve_sparse_pairs' accepted entries -> (E,), inf without alternative or not accepted."""
    regret = np.full(len(cost), np.inf)
    for p in range(len(starts) - 1):
        s, e = starts[p], starts[p + 1]
        if e - s < 2:
            continue
        na, nb = li[s:e].max() + 1, lj[s:e].max() + 1
        by_row, by_col, first = np.full(na, -1), np.full(nb, -1), np.zeros(na + 1, dtype=np.int64)
        for k in range(s, e):
            first[li[k] + 1] += 1
            if keep[k]:
                by_row[li[k]], by_col[lj[k]] = k, k
        for r in range(na):
            first[r + 1] += first[r]
        fill, order = first[:-1].copy(), np.empty(e - s, dtype=np.int64)  # entries grouped by row
        for k in range(s, e):
            order[fill[li[k]]] = k
            fill[li[k]] += 1
        for k in range(s, e):
            kr, kc = by_row[li[k]], by_col[lj[k]]  # the accepted entries holding k's row and column
            if keep[k] or (kr < 0 and kc < 0):
                continue
            if kc < 0 or kr < 0:
                held = max(kr, kc)
                regret[held] = min(regret[held], cost[k] - cost[held])
                continue
            for m in order[first[li[kc]] : first[li[kc] + 1]]:  # the cross entry (row of kc, column of kr)
                if lj[m] == lj[kr]:
                    swap = cost[k] + cost[m] - cost[kr] - cost[kc]
                    regret[kr], regret[kc] = min(regret[kr], swap), min(regret[kc], swap)
    return regret


def warm_up() -> None:
    """Compile (or load) the sparse solver and its regrets on a tiny problem."""
    one = np.zeros(2, dtype=np.int64)
    keep = solve_sparse_pairs(np.array([0, 2]), np.ones((1, 2), np.int64), one, one, np.array([0.0, 1.0]))
    swap_regrets(np.array([0, 2]), one, one, np.array([0.0, 1.0]), keep)
