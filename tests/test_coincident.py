"""Persons reconstructed twice (reconstruction/coincident.py): a person split over views is joined, touching
bodies and distinct neighbours kept; the k-d tree prefilter of large frames finds what comparing every pair finds."""

from collections import Counter

import numpy as np
import pytest

from data.multiview import Frame, ViewDetections
from reconstruction import coincident
from reconstruction.coincident import close_pairs, merge_coincident
from reconstruction.pipeline import MultiViewPipeline
from reconstruction.reconstructors import VanillaTriangulation
from reconstruction.results import Matches
from tests.test_triangulation import ring

BODY = np.random.default_rng(1).uniform([-0.2, -0.2, 0.0], [0.2, 0.2, 1.8], (23, 3))


def scene(offsets_m: list[float]) -> tuple[np.ndarray, np.ndarray]:
    """Persons of BODY's shape shifted along x by offsets_m -> poses (P, 23, 4) scored 1, views (P, 23) all 3."""
    poses = np.stack([np.concatenate([BODY + [dx, 0, 0], np.ones((23, 1))], -1) for dx in offsets_m])
    return poses, np.full(poses.shape[:2], 3)


def test_a_person_split_over_views_is_joined_and_distinct_neighbours_are_kept():
    poses, views = scene([0.0, 0.05, 0.5])
    assignment = np.array([[0, 1, -1, -1], [-1, -1, 2, 0], [1, 0, 0, 1]])
    merged = merge_coincident(poses, views, assignment, 0.2)
    np.testing.assert_array_equal(merged, [[0, 1, 2, 0], [1, 0, 0, 1]])
    np.testing.assert_array_equal(assignment[0], [0, 1, -1, -1])  # the caller's array is left as it was
    same = assignment[[0, 2]]
    assert merge_coincident(poses[[0, 2]], views[[0, 2]], same, 0.2) is same  # 0.5 m apart: untouched


def test_persons_with_detections_in_one_view_are_both_kept():
    poses, views = scene([0.0, 0.05])
    assignment = np.array([[0, 1, -1], [1, 0, 2]])  # two detections in views 0 and 1: two bodies, touching
    assert merge_coincident(poses, views, assignment, 0.2) is assignment


def test_joints_placed_without_two_views_do_not_count():
    poses, views = scene([0.0, 0.05])
    views[1] = 1  # the second person's joints all placed by a prior
    assignment = np.array([[0, 1, -1], [-1, -1, 0]])
    assert merge_coincident(poses, views, assignment, 0.2) is assignment


def test_the_k_d_tree_prefilter_finds_every_close_pair(monkeypatch):
    rng = np.random.default_rng(0)
    offsets = list(rng.uniform(0, 30, 40))
    offsets += [offsets[3] + 0.03, offsets[10] + 0.1, offsets[20] + 0.19]
    poses, views = scene(offsets)
    poses[:, :, 1] += rng.normal(0, 0.002, poses.shape[:2])
    placed = views >= 2
    monkeypatch.setattr(coincident, "ALL_PAIRS_UP_TO", 1000)
    every_pair = close_pairs(poses, placed, 0.2)
    monkeypatch.setattr(coincident, "ALL_PAIRS_UP_TO", 2)
    prefiltered = close_pairs(poses, placed, 0.2)
    assert len(every_pair[0]) >= 3
    np.testing.assert_array_equal(every_pair[0], prefiltered[0])
    np.testing.assert_allclose(every_pair[1], prefiltered[1])


class SplittingMatcher:
    """Puts one person's 4 views into two persons of 2 views each (the detection index is the person's)."""

    def __call__(self, views: list[ViewDetections], rig: object) -> Matches:
        return Matches(np.array([[0, 0, -1, -1], [-1, -1, 0, 0]]), Counter())


@pytest.mark.parametrize("coincident_m, persons", [(0.3, 1), (0.0, 2)])
def test_the_pipeline_reconstructs_a_split_person_once(coincident_m, persons):
    rig = ring(4)
    uv = [np.concatenate([rig[v].project(BODY[None]), np.ones((1, 23, 1))], -1) for v in range(4)]
    views = [ViewDetections(k, np.ones((1, 4)), np.ones(1), np.zeros(1)) for k in uv]
    pipeline = MultiViewPipeline(rig, SplittingMatcher(), VanillaTriangulation(), coincident_m=coincident_m)
    result = pipeline(Frame(0, views))
    assert len(result.poses3d) == persons
    np.testing.assert_allclose(result.poses3d[0, :, :3], BODY, atol=1e-6)
    if persons == 1:
        np.testing.assert_array_equal(result.assignment, [[0, 0, 0, 0]])
        assert np.all(result.joint_views == 4)
