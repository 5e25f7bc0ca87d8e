"""The compiled assignment of the evidence matcher: scipy's solver step for step (its optimum, over the allowed
entries of the gated components), component by component; the dense wrapper the tracker and the evaluation use
gives scipy's rows and columns, transposed and maximised too."""

import numpy as np
import pytest
from scipy.optimize import linear_sum_assignment

from reconstruction.matching import sparse_assignment as assignment
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


def test_the_dense_wrapper_is_scipys_assignment_any_shape_ties_and_maximise_included():
    rng = np.random.default_rng(2)
    for t in range(600):
        nr, nc = (int(n) for n in rng.integers(0, 8, 2))
        cost = rng.integers(0, 3, (nr, nc)).astype(float) if t % 2 else rng.normal(size=(nr, nc))
        maximize = bool(t % 3 == 0)
        ours = assignment.linear_sum_assignment(cost, maximize=maximize)
        ref = linear_sum_assignment(cost, maximize=maximize)
        for a, b in zip(ours, ref):
            np.testing.assert_array_equal(a, b)
            assert a.dtype == np.int64
    strided = rng.normal(size=(6, 10))[:, ::2]  # a view, not contiguous
    np.testing.assert_array_equal(assignment.linear_sum_assignment(strided)[1], linear_sum_assignment(strided)[1])
    with pytest.raises(ValueError, match="non-finite"):
        assignment.linear_sum_assignment(np.array([[1.0, np.inf]]))
    with pytest.raises(ValueError, match="2-D"):
        assignment.linear_sum_assignment(np.zeros(3))
