"""The distinctiveness margin of the pairwise solve (merge.swap_regret, solve_pair(margin=...)) and its
matcher keys: an ambiguous pair is refused, a clear one kept."""

from pathlib import Path

import numpy as np
import pytest
from omegaconf import OmegaConf

from benchmarks.matching import FEET_DISTINCT
from reconstruction.matching import FeetEpipolarMatcher, FeetMatcher
from reconstruction.matching.merge import match_pairs, solve_pair, swap_regret
from tests.test_feet_matching import matched_id_sets, ring_rig
from tests.test_feet_matching_extra import feet_only

# Two neighbours A, B whose costs hardly tell them apart (a swap costs 1 more), and a clear C.
AMBIGUOUS_AND_CLEAR = np.array([[1.0, 1.5, 9.0], [1.5, 1.0, 9.0], [9.0, 9.0, 1.0]])


def test_swap_regret_known_answers():
    rows, cols = solve_pair(AMBIGUOUS_AND_CLEAR, gate=3.0)
    np.testing.assert_array_equal(rows, [0, 1, 2])
    np.testing.assert_array_equal(cols, [0, 1, 2])
    # A-A: swap with B-B costs 1.5 + 1.5 - 1 - 1 = 1; with C-C 9 + 9 - 2 = 16. C-C: 16.
    np.testing.assert_allclose(swap_regret(AMBIGUOUS_AND_CLEAR, rows, cols), [1.0, 1.0, 16.0])


def test_swap_regret_counts_free_partners_and_gated_competitors_but_not_infinite_ones():
    cost = np.array([[1.0, 3.4, np.inf]])  # column 1 is above the gate, still a competitor
    rows, cols = solve_pair(cost, gate=3.0)
    np.testing.assert_allclose(swap_regret(cost, rows, cols), [2.4])
    cost = np.array([[1.0, np.inf], [np.inf, 1.0]])
    rows, cols = solve_pair(cost, gate=3.0)
    assert np.all(np.isinf(swap_regret(cost, rows, cols)))
    assert swap_regret(cost, rows[:0], cols[:0]).shape == (0,)


@pytest.mark.parametrize("margin, kept", [(0.0, [0, 1, 2]), (0.5, [0, 1, 2]), (2.0, [2]), (20.0, [])])
def test_margin_refuses_the_ambiguous_pairs_and_keeps_the_clear_one(margin, kept):
    rows, cols = solve_pair(AMBIGUOUS_AND_CLEAR, gate=3.0, margin=margin)
    np.testing.assert_array_equal(rows, kept)
    np.testing.assert_array_equal(cols, kept)


def test_margin_is_applied_by_match_pairs_of_every_view_pair():
    persons = match_pairs(lambda a, b: AMBIGUOUS_AND_CLEAR, [3, 3, 3], gate=3.0, min_views=2, margin=2.0)
    np.testing.assert_array_equal(persons, [[2, 2, 2]])
    assert len(match_pairs(lambda a, b: AMBIGUOUS_AND_CLEAR, [3, 3, 3], gate=3.0, min_views=2)) == 3


def test_feet_matcher_margin_end_to_end():
    # Euclidean costs in metres: A and B 0.3 m apart are seen 0.1 / 0.05 m off (a swap costs 0.3 m
    # more); C stands 3 m away. margin 0.5 m leaves A and B unmatched and keeps C.
    rig = ring_rig(2)
    views = [
        feet_only(rig[0], [(0.0, 0.0), (0.3, 0.0), (3.0, 0.0)], [0, 1, 2]),
        feet_only(rig[1], [(0.1, 0.0), (0.25, 0.0), (3.0, 0.0)], [0, 1, 2]),
    ]
    plain = FeetMatcher(location_metric="euclidean", k2=0.0, k3=0.0, gate=0.6)
    assert matched_id_sets(plain(views, rig).assignment, views) == {frozenset({(0, i), (1, i)}) for i in range(3)}
    strict = FeetMatcher(location_metric="euclidean", k2=0.0, k3=0.0, gate=0.6, margin=0.5)
    assert matched_id_sets(strict(views, rig).assignment, views) == {frozenset({(0, 2), (1, 2)})}


def test_negative_margins_are_refused():
    with pytest.raises(ValueError, match="margin"):
        FeetMatcher(margin=-1.0)
    with pytest.raises(ValueError, match="margin"):
        FeetEpipolarMatcher(margin=-1.0)


def test_benchmark_feet_distinct_row_uses_the_config_preset():
    preset = OmegaConf.load(Path(__file__).parents[1] / "configs/matching/feet_distinct.yaml")
    assert {k: preset[k] for k in FEET_DISTINCT} == FEET_DISTINCT
    assert OmegaConf.load(Path(__file__).parents[1] / "configs/matching/feet.yaml").margin == 0.0
