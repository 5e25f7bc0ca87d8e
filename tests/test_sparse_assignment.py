"""The gated sparse assignment (data.assignment.solve_sparse_pairs): scipy's dense gated optimum (solve_pair), solved
component by component over the allowed entries."""

import numpy as np

from data.assignment import solve_sparse_pairs
from reconstruction.matching.merge import solve_pair


def test_the_sparse_solver_keeps_scipys_pairs_of_large_gated_problems():
    # gated problems as the matcher builds them (a few allowed pairs per row, a big cost elsewhere), larger than
    # the test below and often one component: the allowed pairs of scipy's dense optimum
    rng = np.random.default_rng(2)
    for _ in range(1500):
        na, nb = int(rng.integers(1, 40)), int(rng.integers(1, 40))
        allowed = rng.random((na, nb)) < rng.integers(1, 8) / nb
        cost = np.where(allowed, rng.normal(size=(na, nb)) * 3 - 20, np.inf)
        i, j = np.nonzero(allowed)
        keep = solve_sparse_pairs(np.array([0, len(i)]), np.array([[na, nb]]), i, j, cost[i, j])
        rows, cols = solve_pair(cost)
        assert sorted(zip(i[keep].tolist(), j[keep].tolist())) == sorted(zip(rows.tolist(), cols.tolist()))


def test_the_sparse_pairs_are_solved_as_the_dense_gated_assignment():
    rng = np.random.default_rng(1)
    costs, entries = [], []
    for _ in range(60):
        na, nb = rng.integers(0, 9, 2)
        cost = np.where(rng.random((na, nb)) < 0.3, rng.normal(0, 10, (na, nb)), np.inf)
        costs.append(cost)
        i, j = np.nonzero(np.isfinite(cost))
        entries.append((i, j, cost[i, j]))
    starts = np.concatenate([[0], np.cumsum([len(e[0]) for e in entries])])
    sizes = np.array([c.shape for c in costs], dtype=np.int64)
    li, lj, c = (np.concatenate([e[k] for e in entries]) for k in range(3))
    keep = solve_sparse_pairs(starts, sizes, li.astype(np.int64), lj.astype(np.int64), c)
    for p, cost in enumerate(costs):
        rows, cols = solve_pair(cost)
        k = slice(starts[p], starts[p + 1])
        got = sorted(zip(li[k][keep[k]].tolist(), lj[k][keep[k]].tolist()))
        assert got == sorted(zip(rows.tolist(), cols.tolist())), p
