"""The compiled assignment of the evidence matcher: scipy's solver step for step, component by component."""

import numpy as np
from scipy.optimize import linear_sum_assignment

from reconstruction.matching.merge import solve_pair
from reconstruction.matching.sparse_assignment import lsap, solve_sparse_pairs


def test_lsap_is_scipys_solver_ties_included():
    rng = np.random.default_rng(0)
    for t in range(400):
        nr = int(rng.integers(1, 7))
        nc = int(rng.integers(nr, 9))
        # small integer costs: many ties, which a different solver would break differently
        cost = rng.integers(0, 4, (nr, nc)).astype(float) if t % 2 else rng.normal(size=(nr, nc))
        np.testing.assert_array_equal(lsap(cost), linear_sum_assignment(cost)[1])


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
