"""COCO OKS AP/AR on the COCO-23 subsets: self-evaluation on real COCO-WholeBody, known OKS thresholds."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from data.keypoints import BODY_JOINTS, NUM_JOINTS, OKS_SIGMAS
from data.pose2d.coco_eval import STAT_NAMES, SUBSET_JOINTS, evaluate_keypoints, write_coco_results
from data.pose2d.coco_keypoints import load_coco_wholebody
from data.pose2d.records import ImageRecord


@pytest.fixture(scope="module")
def wholebody_file(shared_data) -> Path:
    """The real COCO-WholeBody sample annotations."""
    return shared_data / "coco_wholebody_sample" / "test_coco_wholebody.json"


@pytest.fixture(scope="module")
def wholebody(wholebody_file) -> dict:
    """The raw COCO-WholeBody document."""
    return json.loads(wholebody_file.read_text())


@pytest.fixture(scope="module")
def records(wholebody_file) -> list[ImageRecord]:
    """The sample as COCO-23 ImageRecords (keypoints 17 + foot_kpts 6)."""
    return load_coco_wholebody(wholebody_file, wholebody_file.parent)


def gt_predictions(records: list[ImageRecord], subset: str) -> list[dict]:
    """The ground truth as predictions, for the persons labelled in the subset, scores decreasing."""
    joints = list(SUBSET_JOINTS[subset])
    persons = [(r.image_id, k) for r in records for k in r.keypoints if (k[joints, 2] > 0).any()]
    return [{"image_id": i, "keypoints": k.copy(), "score": 1.0 - 0.01 * n} for n, (i, k) in enumerate(persons)]


@pytest.mark.parametrize("subset", ["all", "body", "foot"])
def test_ground_truth_against_itself_is_perfect(wholebody, records, subset):
    stats = evaluate_keypoints(records, gt_predictions(records, subset), subset)
    assert set(stats) == set(STAT_NAMES)
    assert all(v == pytest.approx(1.0) for v in stats.values()), stats
    assert evaluate_keypoints(wholebody, gt_predictions(records, subset), subset) == stats


def test_one_person_lost_drops_ap50_by_the_known_amount(records):
    preds = gt_predictions(records, "body")
    preds[-1]["keypoints"][:, :2] += 1000.0  # the lowest-scored one: 11 TPs, then 1 FP
    stats = evaluate_keypoints(records, preds, "body")
    n = len(preds)
    recall = (n - 1) / n
    assert stats["AP50"] == pytest.approx(np.sum(np.linspace(0, 1, 101) <= recall + 1e-12) / 101)
    assert stats["AR50"] == pytest.approx(recall)


def test_foot_subset_ignores_body_errors(records):
    preds = gt_predictions(records, "foot")
    for p in preds:
        p["keypoints"][list(BODY_JOINTS), :2] += 300.0
    assert evaluate_keypoints(records, preds, "foot")["AP"] == pytest.approx(1.0)
    assert evaluate_keypoints(records, preds, "body")["AP"] == pytest.approx(0.0)


def single_person(oks: float, subset: str) -> tuple[list[ImageRecord], list[dict]]:
    """One gt person and one prediction whose subset joints are shifted to the given OKS."""
    rng = np.random.default_rng(0)
    gt = np.concatenate([rng.uniform(100, 300, (NUM_JOINTS, 2)), np.full((NUM_JOINTS, 1), 2.0)], axis=1)
    area = 150.0 * 250.0
    joints = list(SUBSET_JOINTS[subset])
    # exp(-d^2 / (2 area k^2)) = oks for every shifted joint, k = 2 sigma
    shift = 2 * OKS_SIGMAS[joints] * np.sqrt(2 * area * -np.log(oks))
    pred = gt.copy()
    pred[joints, 0] += shift
    record = ImageRecord(7, "x.jpg", 640, 480, gt[None], [[100, 100, 150, 250]], [area])
    return [record], [{"image_id": 7, "keypoints": pred, "score": 0.9}]


@pytest.mark.parametrize("subset", ["all", "body", "foot"])
def test_oks_threshold_at_one_half(subset):
    stats = evaluate_keypoints(*single_person(0.502, subset), subset)
    assert stats["AP50"] == pytest.approx(1.0)
    assert stats["AP75"] == pytest.approx(0.0)
    assert stats["AP"] == pytest.approx(0.1)  # matched at t = .50 only of .50:.05:.95
    assert stats["APm"] == -1  # no medium-sized person
    below = evaluate_keypoints(*single_person(0.498, subset), subset)
    assert below["AP50"] == pytest.approx(0.0)
    assert below["AR"] == pytest.approx(0.0)


def test_bad_predictions_are_named():
    records, preds = single_person(0.9, "all")
    with pytest.raises(ValueError, match="prediction 0: image_id 8"):
        evaluate_keypoints(records, [{**preds[0], "image_id": 8}])
    with pytest.raises(ValueError, match="prediction 0: keypoints"):
        evaluate_keypoints(records, [{**preds[0], "keypoints": np.zeros((17, 3))}])
    with pytest.raises(ValueError, match="subset"):
        evaluate_keypoints(records, preds, "hands")


def test_write_coco_results_round_trip(tmp_path):
    _, preds = single_person(0.9, "all")
    preds[0]["bbox"] = [1, 2, 3, 4]
    path = tmp_path / "results" / "keypoints.json"
    write_coco_results(path, preds)
    (entry,) = json.loads(path.read_text())
    assert entry["image_id"] == 7 and entry["category_id"] == 1 and entry["bbox"] == [1, 2, 3, 4]
    np.testing.assert_allclose(np.reshape(entry["keypoints"], (NUM_JOINTS, 3)), preds[0]["keypoints"], atol=1e-4)
    assert [p.name for p in path.parent.iterdir()] == ["keypoints.json"]
