"""COCO-format keypoint loaders on the real COCO-WholeBody and CrowdPose samples, writing, bad input."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from data.keypoints import CROWDPOSE14_TO_COCO23, NUM_JOINTS
from data.pose2d.coco_keypoints import (
    load_coco23,
    load_coco_wholebody,
    load_crowdpose,
    load_detections,
    load_keypoint_dataset,
    training_persons,
    write_coco_keypoints,
)


@pytest.fixture()
def wholebody(shared_data: Path) -> tuple[Path, Path]:
    folder = shared_data / "coco_wholebody_sample"
    return folder / "test_coco_wholebody.json", folder


@pytest.fixture()
def crowdpose(shared_data: Path) -> tuple[Path, Path, Path]:
    folder = shared_data / "crowdpose_sample"
    return folder / "test_crowdpose.json", folder, folder / "test_crowdpose_det_AP_40.json"


def _annotations_by_image(path: Path) -> dict[int, list[dict]]:
    doc = json.loads(path.read_text())
    out: dict[int, list[dict]] = {}
    for ann in doc["annotations"]:
        out.setdefault(ann["image_id"], []).append(ann)
    return out


def test_wholebody_persons_body_and_feet(wholebody):
    ann_file, folder = wholebody
    records = load_coco_wholebody(ann_file, folder)
    assert len(records) == 4 and sum(len(r) for r in records) == 14
    by_image = _annotations_by_image(ann_file)
    for record in records:
        assert record.file.is_file() and record.labelled.all()
        anns = by_image[record.image_id]
        assert len(anns) == len(record)
        for kps, box, ann in zip(record.keypoints, record.boxes, anns):
            np.testing.assert_allclose(kps[:17].ravel(), ann["keypoints"])
            np.testing.assert_allclose(kps[17:].ravel(), ann["foot_kpts"])
            np.testing.assert_allclose(box, ann["bbox"])
    first = records[0]
    assert first.image_id == 785 and (first.width, first.height) == (640, 425)
    np.testing.assert_allclose(first.keypoints[0, 17], [439, 378, 2])  # left big toe of annotation 442619
    np.testing.assert_allclose(first.areas, [27789.11055])


def test_coco17_file_leaves_feet_unlabelled(wholebody):
    _, folder = wholebody
    records = load_coco23(folder / "test_coco.json", folder)
    assert sum(len(r) for r in records) == 14
    for record in records:
        assert record.labelled[:17].all() and not record.labelled[17:].any()
        assert np.all(record.keypoints[:, 17:] == 0)


def test_crowdpose_joints_follow_the_index_map(crowdpose):
    ann_file, folder, _ = crowdpose
    records = load_crowdpose(ann_file, folder)
    np.testing.assert_array_equal(records[0].labelled, CROWDPOSE14_TO_COCO23 >= 0)
    by_image = _annotations_by_image(ann_file)
    mapped = np.flatnonzero(CROWDPOSE14_TO_COCO23 >= 0)
    for record in records:
        for kps, ann in zip(record.keypoints, by_image[record.image_id]):
            src = np.array(ann["keypoints"], float).reshape(14, 3)
            np.testing.assert_array_equal(kps[mapped], src[CROWDPOSE14_TO_COCO23[mapped]])
            assert np.all(kps[~(CROWDPOSE14_TO_COCO23 >= 0)] == 0)  # eyes, ears, feet; head/neck dropped
    person = {r.image_id: r for r in records}[103319].keypoints[0]  # annotation 127068
    np.testing.assert_array_equal(person[5], [388, 205, 2])  # CrowdPose 0 = left shoulder
    np.testing.assert_array_equal(person[16], [359, 408, 1])  # CrowdPose 11 = right ankle
    assert {r.image_id: r for r in records}[106848].areas[0] == pytest.approx(273.15 * 352.42)  # no area: w*h


def test_detections_attach_to_their_images(crowdpose):
    ann_file, folder, det_file = crowdpose
    records = load_crowdpose(ann_file, folder)
    with_dets = {r.image_id: r for r in load_detections(det_file, records)}
    assert len(with_dets[106848].det_boxes) == 3 and len(with_dets[103319].det_boxes) == 3
    np.testing.assert_allclose(with_dets[103319].det_boxes[2, :2], [-0.10778862237930298, 238.81455993652344])
    np.testing.assert_allclose(with_dets[106848].det_scores[0], 0.9999284744262695)
    strict = {r.image_id: r for r in load_detections(det_file, records, score_threshold=0.98)}
    assert len(strict[103319].det_boxes) == 2 and len(strict[106848].det_boxes) == 3
    assert all(len(r.det_boxes) == 0 for r in records)  # the inputs are left alone


def test_keypoint_dataset_keeps_every_person_of_kept_images(crowdpose):
    ann_file, folder, det_file = crowdpose
    records = load_keypoint_dataset("crowdpose", ann_file, folder, det_file=det_file, min_keypoints=1)
    first = {r.image_id: r for r in records}[106848]
    assert len(first) == 3  # annotation 131039 has no keypoint
    np.testing.assert_array_equal(training_persons(first, 1), [0, 2])
    assert len(first.det_boxes) == 3
    strict = load_keypoint_dataset("crowdpose", ann_file, folder, min_keypoints=11)
    assert [r.image_id for r in strict] == [103319]
    with pytest.raises(ValueError, match="unknown keypoint dataset kind 'mpii'"):
        load_keypoint_dataset("mpii", ann_file, folder)


def test_crowd_annotations_are_skipped(tmp_path, wholebody):
    ann_file, folder = wholebody
    doc = json.loads(ann_file.read_text())
    doc["annotations"][0]["iscrowd"] = 1
    path = tmp_path / "crowd.json"
    path.write_text(json.dumps(doc))
    assert len(load_coco_wholebody(path, folder)[0]) == 0
    assert len(load_coco_wholebody(path, folder, skip_crowd=False)[0]) == 1


def test_write_then_load_round_trip(tmp_path, wholebody):
    ann_file, folder = wholebody
    records = load_coco_wholebody(ann_file, folder)
    out = tmp_path / "sub" / "coco23.json"
    write_coco_keypoints(out, records, image_root=folder)
    doc = json.loads(out.read_text())
    assert len(doc["categories"][0]["keypoints"]) == NUM_JOINTS
    assert all(len(a["keypoints"]) == 3 * NUM_JOINTS for a in doc["annotations"])
    again = load_coco23(out, folder)
    assert [r.image_id for r in again] == [r.image_id for r in records]
    for a, b in zip(records, again):
        assert a.file == b.file and (a.width, a.height) == (b.width, b.height)
        np.testing.assert_array_equal(a.keypoints, b.keypoints)
        np.testing.assert_array_equal(a.boxes, b.boxes)
        np.testing.assert_array_equal(a.areas, b.areas)
    assert not list(out.parent.glob("*.tmp"))


def _broken(tmp_path: Path, source: Path, edit) -> Path:
    doc = json.loads(source.read_text())
    edit(doc)
    path = tmp_path / "broken.json"
    path.write_text(json.dumps(doc))
    return path


def test_bad_files_name_the_file_and_annotation(tmp_path, wholebody, crowdpose):
    ann_file, folder = wholebody
    missing = tmp_path / "nope.json"
    with pytest.raises(ValueError, match="nope.json"):
        load_coco_wholebody(missing, folder)
    short = _broken(tmp_path, ann_file, lambda d: d["annotations"][1]["keypoints"].pop())
    with pytest.raises(ValueError, match=r"broken.json: annotation id 198196 has 50 numbers in 'keypoints'"):
        load_coco_wholebody(short, folder)
    no_feet = _broken(tmp_path, ann_file, lambda d: d["annotations"][2].pop("foot_kpts"))
    with pytest.raises(ValueError, match="annotation id 230195 has no list 'foot_kpts'"):
        load_coco_wholebody(no_feet, folder)
    cp_file, cp_folder, _ = crowdpose
    wrong = _broken(tmp_path, cp_file, lambda d: d["annotations"][3]["keypoints"].extend([0, 0, 0]))
    with pytest.raises(ValueError, match="annotation id 127068 has 45 numbers"):
        load_crowdpose(wrong, cp_folder)
    orphan = _broken(tmp_path, cp_file, lambda d: d["annotations"][0].update(image_id=5))
    with pytest.raises(ValueError, match="annotation id 123803 refers to image id 5"):
        load_crowdpose(orphan, cp_folder)


def test_bad_detections_name_the_entry(tmp_path, crowdpose):
    ann_file, folder, det_file = crowdpose
    dets = json.loads(det_file.read_text())
    dets[4]["bbox"] = [1, 2, 3]
    path = tmp_path / "dets.json"
    path.write_text(json.dumps(dets))
    with pytest.raises(ValueError, match=r"dets.json: entry 4 bbox must be 4 finite numbers"):
        load_detections(path, load_crowdpose(ann_file, folder))
