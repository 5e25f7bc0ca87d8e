"""2D inputs from other detectors: 4D Association BODY_25 candidates, PAF grouping, OpenPose JSON, poses2d.json."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from data.formats.fourd_detections import BODY25_PAF_LIMBS, load_4dassoc_detections
from data.formats.openpose_json import load_openpose_dir, load_openpose_json
from data.formats.poses2d_io import Poses2DError, read_poses2d, write_poses2d
from data.geometry.calibration import load_4dassoc
from data.keypoints import BODY25_TO_COCO23, JOINT_INDEX, to_coco23
from data.multiview import ViewDetections
from models.paf_grouping import group_people, grouped_to_view_detections, limb_connections

SHELF = Path("shelf") / "4d_association"

# A standing BODY_25 person, pixels, facing the camera (its left on the image right).
TEMPLATE = np.array(
    [
        [0, 0],
        [0, 30],
        [-25, 30],
        [-35, 70],
        [-40, 110],
        [25, 30],
        [35, 70],
        [40, 110],
        [0, 110],
        [-15, 110],
        [-15, 170],
        [-15, 230],
        [15, 110],
        [15, 170],
        [15, 230],
        [-6, -5],
        [6, -5],
        [-12, 0],
        [12, 0],
        [22, 245],
        [28, 243],
        [12, 238],
        [-22, 245],
        [-28, 243],
        [-12, 238],
    ],
    dtype=np.float64,
)


def two_people(cross_paf: float = 0.02, true_paf: float = 0.9) -> tuple[list[np.ndarray], list[np.ndarray], np.ndarray]:
    """Two people side by side: candidates, PAFs and the expected persons (2, 25, 3).

    Candidate order alternates per joint so that candidate index never identifies the person.
    """
    people = np.stack([np.c_[TEMPLATE + [200, 100], np.full(25, 0.8)], np.c_[TEMPLATE + [400, 120], np.full(25, 0.7)]])
    order = [(0, 1) if j % 2 else (1, 0) for j in range(25)]
    candidates = [people[list(o), j] for j, o in enumerate(order)]
    pafs = []
    for a, b in BODY25_PAF_LIMBS:
        same = np.array(order[a])[:, None] == np.array(order[b])[None, :]
        pafs.append(np.where(same, true_paf, cross_paf))
    return candidates, pafs, people


def sorted_by_x(persons: np.ndarray) -> np.ndarray:
    """Persons (N, J, 3) in order of their neck x."""
    return persons[np.argsort(persons[:, 1, 0])]


def test_limb_connections_greedy_one_to_one() -> None:
    paf = np.array([[0.9, 0.8, 0.0], [0.85, 0.1, 0.0], [0.0, 0.0, 0.04]])
    conns = limb_connections(paf, min_paf=0.05)
    # 0.9 takes (0, 0); 0.85 and 0.8 reuse a candidate; 0.1 connects (1, 1); 0.04 is under the threshold.
    np.testing.assert_allclose(limb_connections(paf, min_paf=0.0)[:, 2], [0.9, 0.1, 0.04])
    np.testing.assert_allclose(conns, [[0, 0, 0.9], [1, 1, 0.1]])


def test_grouping_recovers_two_people() -> None:
    candidates, pafs, people = two_people()
    persons = group_people(candidates, pafs)
    assert persons.shape == (2, 25, 3)
    np.testing.assert_array_equal(sorted_by_x(persons), people)


def test_grouping_prefers_true_limb_over_moderate_cross_paf() -> None:
    candidates, pafs, people = two_people(cross_paf=0.6, true_paf=0.8)
    np.testing.assert_array_equal(sorted_by_x(group_people(candidates, pafs)), people)
    # Candidate 0 is person 0 for joint 3 (RElbow) but person 1 for joint 4 (RWrist): when the cross
    # PAFs beat the true ones, the wrists swap; grouping follows the PAFs, nothing else.
    pafs[BODY25_PAF_LIMBS.index((3, 4))][:] = [[0.9, 0.8], [0.8, 0.9]]  # cross pairs now win
    swapped = sorted_by_x(group_people(candidates, pafs))
    np.testing.assert_array_equal(swapped[:, 4], people[::-1, 4])


def test_grouping_drops_fragments_and_false_positives() -> None:
    candidates, pafs, people = two_people()
    # A lone extra nose and a three-joint fragment (right arm) far away.
    fragment = {0: [900, 50, 0.9], 2: [900, 300, 0.9], 3: [900, 340, 0.9], 4: [900, 380, 0.9]}
    for j, row in fragment.items():
        candidates[j] = np.vstack([candidates[j], row])
    for k, (a, b) in enumerate(BODY25_PAF_LIMBS):
        grown = np.zeros((len(candidates[a]), len(candidates[b])))
        grown[:2, :2] = pafs[k]
        if a in (2, 3) and b in (3, 4):
            grown[-1, -1] = 0.9
        pafs[k] = grown
    assert len(group_people(candidates, pafs)) == 2
    kept = group_people(candidates, pafs, min_joints=3)
    assert len(kept) == 3 and (kept[..., 2] > 0).sum(axis=1).min() == 3
    assert len(group_people(candidates, pafs, min_mean_score=0.75)) == 1  # only the 0.8 person stays


def test_grouped_to_view_detections_boxes_and_scores() -> None:
    _, _, people = two_people()
    dets = grouped_to_view_detections(people, margin=0.1)
    assert dets.keypoints.shape == (2, 23, 3)
    lo, hi = people[0, :, :2].min(axis=0), people[0, :, :2].max(axis=0)  # neck, mid-hip lie inside
    np.testing.assert_allclose(dets.bboxes[0], [*(lo - 0.1 * (hi - lo)), *(1.2 * (hi - lo))])
    np.testing.assert_allclose(dets.scores, [0.8, 0.7])
    assert list(dets.person_ids) == [-1, -1]


def test_body25_to_coco23_named_joints() -> None:
    body25 = np.zeros((25, 3))
    body25[:, 0] = np.arange(25)
    body25[:, 2] = 1
    coco = to_coco23(body25, BODY25_TO_COCO23)
    expect = {
        "left_big_toe": 19,
        "right_heel": 24,
        "left_shoulder": 5,
        "right_shoulder": 2,
        "nose": 0,
        "left_eye": 16,
        "right_ear": 17,
        "left_hip": 12,
        "right_knee": 10,
        "left_ankle": 14,
        "right_wrist": 4,
        "left_small_toe": 20,
        "right_big_toe": 22,
    }
    for name, b25 in expect.items():
        assert coco[JOINT_INDEX[name], 0] == b25, name
    assert JOINT_INDEX["left_big_toe"] == 17 and JOINT_INDEX["right_heel"] == 22
    assert not {1, 8} & set(coco[:, 0].astype(int))  # neck and mid-hip have no COCO-23 slot


@pytest.fixture(scope="module")
def shelf_detections(shared_data: Path) -> list:
    """The five cameras' 4D Association detection files."""
    return [load_4dassoc_detections(shared_data / SHELF / "detection" / f"{c}.txt") for c in range(5)]


def test_shelf_detection_files_load(shelf_detections: list) -> None:
    for frames in shelf_detections:
        assert len(frames) == 301
        for frame in frames[::30]:
            assert len(frame.candidates) == 25 and len(frame.pafs) == 26
            for (a, b), paf in zip(BODY25_PAF_LIMBS, frame.pafs):
                assert paf.shape == (len(frame.candidates[a]), len(frame.candidates[b]))
            xy = np.concatenate(frame.candidates)
            assert np.all((xy[:, 0] >= 0) & (xy[:, 0] <= 1031) & (xy[:, 1] >= 0) & (xy[:, 1] <= 775))
            assert xy[:, 0].max() > 1.5 and np.all(xy[:, 2] > 0)  # pixels, not normalised


def test_shelf_grouping_frame0_plausible(shelf_detections: list) -> None:
    for camera, frames in enumerate(shelf_detections):
        persons = group_people(frames[0].candidates, frames[0].pafs)
        assert 2 <= len(persons) <= 6, camera
        torso = (persons[:, [2, 5, 9, 12], 2] > 0).all(axis=1)  # both shoulders and hips
        assert torso.mean() >= 0.5, camera
        for pose in persons:
            seen = pose[pose[:, 2] > 0]
            height = seen[:, 1].max() - seen[:, 1].min()
            assert 100 < height < 776, camera
            if pose[1, 2] > 0 and pose[8, 2] > 0:
                assert pose[1, 1] < pose[8, 1], camera  # neck above mid-hip


def test_4dassoc_bad_files(tmp_path: Path) -> None:
    bad_header = tmp_path / "header.txt"
    bad_header.write_text("5 301\n")
    with pytest.raises(ValueError, match=r"header.txt: header skeleton type is 5, expected 4"):
        load_4dassoc_detections(bad_header)
    truncated = tmp_path / "truncated.txt"
    truncated.write_text("4 1\n1\n0.5\n0.5\n0.9\n2\n0.1 0.2\n0.3\n")
    with pytest.raises(ValueError, match=r"truncated.txt: file ends while reading the candidates of frame 0, joint 1"):
        load_4dassoc_detections(truncated)
    garbage = tmp_path / "garbage.txt"
    garbage.write_text("4 1\n" + "0\n" * 3 + "x\n")
    with pytest.raises(ValueError, match=r"garbage.txt: non-numeric .* candidate count of frame 0, joint 3"):
        load_4dassoc_detections(garbage)
    no_pafs = tmp_path / "pafs.txt"
    no_pafs.write_text("4 1\n" + "1\n0.5\n0.5\n0.9\n" * 25 + "0.7\n" * 3)
    with pytest.raises(ValueError, match=r"frame 0, PAF limb 3 \(8, 9\)"):
        load_4dassoc_detections(no_pafs)


def detections(rng: np.random.Generator, n: int, ids: list[int]) -> ViewDetections:
    """n random COCO-23 detections with the given person ids."""
    kps = np.c_[rng.uniform(0, 1000, (n * 23, 2)), rng.uniform(0, 1, n * 23)].reshape(n, 23, 3)
    return ViewDetections(kps, rng.uniform(0, 500, (n, 4)), rng.uniform(0, 1, n), np.array(ids))


def test_poses2d_round_trip(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    names = ["0", "1", "2"]
    frames = {
        300: [detections(rng, 2, [0, -1]), ViewDetections.empty(), detections(rng, 1, [3])],
        302: [ViewDetections.empty(), detections(rng, 3, [-1, -1, 5]), ViewDetections.empty()],
    }
    keypoints_before = frames[300][0].keypoints.copy()
    path = tmp_path / "poses2d.json"
    write_poses2d(path, frames, names)
    np.testing.assert_array_equal(frames[300][0].keypoints, keypoints_before)
    entries = json.loads(path.read_text())
    assert len(entries) == 6 and entries[0]["camera"] == "0" and len(entries[0]["keypoints"]) == 69
    assert "id" not in entries[1] and entries[0]["id"] == 0
    back = read_poses2d(path, names)
    assert sorted(back) == [300, 302]
    for frame, views in frames.items():
        assert len(back[frame]) == 3
        for want, got in zip(views, back[frame]):
            assert len(got) == len(want)
            np.testing.assert_allclose(got.keypoints, want.keypoints, atol=1e-4)
            np.testing.assert_allclose(got.bboxes, want.bboxes, atol=1e-4)
            np.testing.assert_allclose(got.scores, want.scores, atol=1e-4)
            np.testing.assert_array_equal(got.person_ids, want.person_ids)


def test_write_poses2d_names_a_non_finite_detection(tmp_path: Path) -> None:
    view = detections(np.random.default_rng(1), 3, [-1, -1, -1])
    keypoints = view.keypoints.copy()
    keypoints[2, 5, 0] = np.nan
    bad = ViewDetections(keypoints, view.bboxes, view.scores, view.person_ids)
    with pytest.raises(ValueError, match=r"frame 7, camera b, detection 2 has a non-finite value"):
        write_poses2d(tmp_path / "poses2d.json", {7: [view, bad]}, ["a", "b"])
    assert not (tmp_path / "poses2d.json").exists()


def entry(camera: str = "0", values: int = 69, **extra) -> dict:
    """A poses2d.json entry."""
    return {"frame": 300, "camera": camera, "bbox": [1, 2, 3, 4], "score": 0.9, "keypoints": [1.0] * values, **extra}


def test_poses2d_bad_inputs(tmp_path: Path, shared_data: Path) -> None:
    names = load_4dassoc(shared_data / SHELF / "calibration.json").names
    path = tmp_path / "poses2d.json"
    path.write_text(json.dumps([entry("0"), entry("7")]))
    with pytest.raises(
        Poses2DError,
        match=r"poses2d.json: entry 1: camera '7' is not in the calibration "
        r"\(known cameras: 0, 1, 2, 3, 4\)",
    ):
        read_poses2d(path, names)
    path.write_text(json.dumps([entry("1", values=60)]))
    with pytest.raises(
        Poses2DError,
        match=r"entry 0: keypoints has 60 numbers, expected 69 "
        r"\(23 keypoints x, y, score\)",
    ):
        read_poses2d(path, names)
    path.write_text(json.dumps([entry("1", bbox=[0, 0, float("nan"), 1])]))
    with pytest.raises(Poses2DError, match=r"entry 0: bbox has a non-finite value"):
        read_poses2d(path, names)
    broken = entry("1")
    del broken["score"]
    path.write_text(json.dumps([entry("1"), broken]))
    with pytest.raises(Poses2DError, match=r"entry 1 lacks 'score'"):
        read_poses2d(path, names)


def openpose_doc(*lengths: int) -> dict:
    """An OpenPose --write_json document with one person per length (values 0, 1, 2, ...)."""
    return {
        "version": 1.3,
        "people": [
            {"person_id": [-1], "pose_keypoints_2d": list(map(float, range(n))), "face_keypoints_2d": []}
            for n in lengths
        ],
    }


def test_openpose_json(tmp_path: Path) -> None:
    path = tmp_path / "cam0_000000000007_keypoints.json"
    path.write_text(json.dumps(openpose_doc(75, 75)))
    (tmp_path / "cam0_000000000009_keypoints.json").write_text(json.dumps(openpose_doc()))
    (tmp_path / "notes.txt").write_text("ignored")
    poses = load_openpose_json(path)
    assert poses.shape == (2, 23, 3)
    # BODY_25 joint k holds (3k, 3k + 1, 3k + 2): COCO-23 left big toe is BODY_25 19.
    np.testing.assert_array_equal(poses[0, JOINT_INDEX["left_big_toe"]], [57, 58, 59])
    np.testing.assert_array_equal(poses[1, JOINT_INDEX["right_shoulder"]], [6, 7, 8])
    frames = load_openpose_dir(tmp_path)
    assert sorted(frames) == [7, 9] and len(frames[7]) == 2 and len(frames[9]) == 0
    assert frames[7].bboxes.shape == (2, 4) and np.all(frames[7].bboxes[:, 2:] > 0)


def test_openpose_json_bad_length(tmp_path: Path) -> None:
    path = tmp_path / "x_000000000000_keypoints.json"
    path.write_text(json.dumps(openpose_doc(75, 54)))
    with pytest.raises(
        ValueError,
        match=r"x_000000000000_keypoints.json: person 1 has 54 pose_keypoints_2d "
        r"numbers, expected 75",
    ):
        load_openpose_json(path)
