"""The swap regret of a sparse assignment's pairs (data.assignment.swap_regrets) against the numpy oracle and the
dense reference (merge.swap_regret); the evidence matcher refusing an ambiguous detection."""

import numpy as np
import pytest

from data.assignment import solve_sparse_pairs, swap_regrets
from data.multiview import ViewDetections
from reconstruction.matching import EvidenceMatcher
from reconstruction.matching.merge import solve_pair, swap_regret
from tests.oracles.ambiguity import sparse_swap_regret
from tests.test_triangulation import ring


@pytest.mark.parametrize("seed", range(8))
def test_sparse_swap_regret_equals_the_dense_reference(seed):
    rng = np.random.default_rng(seed)
    q, a, b, cost, kept, expected = [], [], [], [], [], []
    for pair in range(3):  # three view pairs, each a sparse gated cost matrix
        na, nb = rng.integers(1, 7, 2)
        dense = np.where(rng.random((na, nb)) < 0.5, rng.normal(-3.0, 2.0, (na, nb)), np.inf)
        rows, cols = solve_pair(dense)
        expected.append(swap_regret(dense, rows, cols))
        ii, jj = np.nonzero(np.isfinite(dense))
        first = len(cost)
        q += [pair] * len(ii)
        a += list(ii)
        b += list(jj)
        cost += list(dense[ii, jj])
        where = {(i, j): first + n for n, (i, j) in enumerate(zip(ii, jj))}
        kept += [where[i, j] for i, j in zip(rows, cols)]
    q, a, b, cost, kept = (np.asarray(x) for x in (q, a, b, cost, kept))
    np.testing.assert_allclose(sparse_swap_regret(q, a, b, cost.astype(float), kept), np.concatenate(expected))
    starts = np.searchsorted(q, np.arange(4)).astype(np.int64)
    keep = np.zeros(len(cost), dtype=bool)
    keep[kept] = True
    np.testing.assert_allclose(swap_regrets(starts, a, b, cost.astype(float), keep)[kept], np.concatenate(expected))


@pytest.mark.parametrize("seed", range(4))
def test_the_kernel_equals_the_oracle_on_solved_sparse_problems(seed):
    rng = np.random.default_rng(seed)
    sizes = rng.integers(1, 30, (5, 2))
    entries = [np.argwhere(rng.random(size) < 0.3) for size in sizes]
    a = np.concatenate([e[:, 0] for e in entries]).astype(np.int64)
    b = np.concatenate([e[:, 1] for e in entries]).astype(np.int64)
    q = np.repeat(np.arange(len(sizes)), [len(e) for e in entries])
    cost = rng.normal(-3.0, 2.0, len(a))
    starts = np.concatenate([[0], np.cumsum([len(e) for e in entries])]).astype(np.int64)
    keep = solve_sparse_pairs(starts, sizes.astype(np.int64), a, b, cost)
    expected = sparse_swap_regret(q, a, b, cost, np.flatnonzero(keep))
    np.testing.assert_allclose(swap_regrets(starts, a, b, cost, keep)[keep], expected)


def test_two_equally_good_partners_have_no_regret_a_clear_pair_has():
    # detection 0 of view a fits detections 0 and 1 of view b equally well (-5.4 and -5.3); detection 1 is clear
    q, a, b = np.zeros(3, int), np.array([0, 0, 1]), np.array([0, 1, 2])
    cost = np.array([-5.4, -5.3, -6.0])
    np.testing.assert_allclose(sparse_swap_regret(q, a, b, cost, np.array([0, 2])), [0.1, np.inf])


def on_the_baseline_scene() -> tuple[list, object]:
    """Two cameras facing each other (ring(2)); persons A and B 0.8 m apart along their baseline, so every joint of
    A lies in the epipolar plane of B's (a cross pair fits as well as the true one), and C clear of them. Feet and
    ankles unscored (no ground-plane term). -> (views, rig); a detection's person id is its index."""
    rig = ring(2)
    body = np.random.default_rng(3).uniform([-0.2, -0.2, 0.1], [0.2, 0.2, 1.8], (23, 3))
    people = np.stack([body + [-0.4, 0.0, 0.0], body + [0.4, 0.0, 0.0], body + [0.0, 2.0, 0.0]])
    views = []
    for camera in rig:
        uv = camera.project(people)
        scores = np.ones((3, 23, 1))
        scores[:, 15:] = 0.0
        keypoints = np.concatenate([uv, scores], -1)
        lo, hi = uv.min(1), uv.max(1)
        views.append(ViewDetections(keypoints, np.concatenate([lo, hi - lo], -1), np.ones(3), np.arange(3)))
    return views, rig


def test_a_detection_between_two_equally_good_people_stays_unmatched():
    views, rig = on_the_baseline_scene()
    plain = EvidenceMatcher(calibrate=False, ambiguity_margin=0.0)(views, rig)
    assert len(plain.assignment) == 3  # without the margin the cross pairs are a coin toss
    strict = EvidenceMatcher(calibrate=False)(views, rig)  # the default margin, 2.0
    np.testing.assert_array_equal(strict.assignment, [[2, 2]])  # C kept
    assert strict.unmatched == {"ambiguous": 4}
