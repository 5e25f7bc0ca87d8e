"""The numba PAF grouping (models/paf_grouping.py) against the frozen pure-Python reference."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from data.formats.fourd_detections import BODY25_PAF_LIMBS, FrameCandidates, load_4dassoc_detections
from data.formats.openpose_json import keypoints_to_view_detections
from models.paf_grouping import group_people, group_view, limb_connections, pack_candidates
from tests.oracles import grouping as reference

SHELF = Path("shelf") / "4d_association"


def random_view(rng: np.random.Generator, max_candidates: int) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Random BODY_25 candidates and PAFs whose scores come in steps of 0.1, so that ties are common."""
    sizes = rng.integers(0, max_candidates + 1, size=25)
    candidates = [np.column_stack([rng.uniform(0, 500, (n, 2)), rng.integers(1, 11, n) / 10]) for n in sizes]
    pafs = [rng.integers(0, 11, (sizes[a], sizes[b])) / 10 for a, b in BODY25_PAF_LIMBS]
    return candidates, pafs


@pytest.mark.parametrize("seed", range(40))
def test_grouping_matches_reference_on_random_views(seed: int) -> None:
    rng = np.random.default_rng(seed)
    candidates, pafs = random_view(rng, max_candidates=int(rng.integers(1, 7)))
    for min_joints, min_score in ((8, 0.4), (1, 0.0), (3, 0.6)):
        got = group_people(candidates, pafs, min_joints=min_joints, min_mean_score=min_score)
        want = reference.group_people(candidates, pafs, min_joints=min_joints, min_mean_score=min_score)
        np.testing.assert_array_equal(got, want)


@pytest.mark.parametrize("seed", range(20))
def test_limb_connections_match_reference_with_ties(seed: int) -> None:
    rng = np.random.default_rng(seed)
    paf = rng.integers(0, 6, (int(rng.integers(0, 6)), int(rng.integers(0, 6)))) / 5
    np.testing.assert_array_equal(limb_connections(paf, 0.1), reference.limb_connections(paf, 0.1))


def test_grouping_matches_reference_on_every_shelf_frame(shared_data: Path) -> None:
    for camera in range(5):
        for n, frame in enumerate(load_4dassoc_detections(shared_data / SHELF / "detection" / f"{camera}.txt")):
            got = group_people(frame.candidates, frame.pafs)
            np.testing.assert_array_equal(got, reference.group_people(frame.candidates, frame.pafs), f"{camera}/{n}")


def test_grouping_of_an_empty_view() -> None:
    candidates = [np.zeros((0, 3)) for _ in range(25)]
    pafs = [np.zeros((0, 0)) for _ in BODY25_PAF_LIMBS]
    assert group_people(candidates, pafs).shape == (0, 25, 3)


def test_view_detections_of_persons_with_and_without_joints() -> None:
    keypoints = np.zeros((3, 23, 3))
    keypoints[0, [0, 5], :] = [[10, 20, 0.5], [30, 60, 1.0]]
    keypoints[2, 7] = [100, 200, 0.25]
    dets = keypoints_to_view_detections(keypoints, margin=0.1)
    np.testing.assert_allclose(dets.bboxes, [[8, 16, 24, 48], [0, 0, 0, 0], [100, 200, 0, 0]])
    np.testing.assert_allclose(dets.scores, [0.75, 0.0, 0.25])
    assert keypoints[1].sum() == 0 and dets.keypoints is not keypoints


def test_group_view_of_the_readers_packed_arrays_and_of_lists(shared_data: Path) -> None:
    frames = load_4dassoc_detections(shared_data / SHELF / "detection" / "1.txt")[::20]
    for frame in frames:
        assert frame.packed is not None
        from_lists = FrameCandidates(frame.candidates, frame.pafs)  # packed by the grouping
        a, b = group_view(frame), group_view(from_lists)
        np.testing.assert_array_equal(a.keypoints, b.keypoints)
        np.testing.assert_array_equal(a.bboxes, b.bboxes)
        packed = pack_candidates(frame.candidates, frame.pafs)
        for field in ("points", "joint_start", "paf_values", "paf_start"):
            np.testing.assert_array_equal(getattr(frame.packed, field), getattr(packed, field))
