"""CMU Panoptic loader (data/datasets/panoptic.py) and protocols (evaluation/protocols/panoptic.py)."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from data.datasets.panoptic import DEFAULT_CAMERAS, load_panoptic_sequence
from data.keypoints import FOOT_JOINTS, JOINT_INDEX
from evaluation.protocols.panoptic import (
    AP_THRESHOLDS_MM,
    PanopticAPEvaluator,
    PanopticPoseEvaluator,
    PanopticProtocol,
    average_precision,
    coco23_to_panoptic15,
)

BODIES = {"160906_band1": {168: 3, 169: 3}, "160906_band2": {139: 3, 140: 3}}


@pytest.fixture(scope="module")
def panoptic(shared_data: Path) -> Path:
    """The Panoptic sample folder."""
    return shared_data / "panoptic"


@pytest.fixture(scope="module")
def band1(panoptic: Path):
    """160906_band1 with generated 2D input, default options."""
    return load_panoptic_sequence(panoptic, "160906_band1")


def _person(offset: float = 0.0) -> np.ndarray:
    """A plausible standing Panoptic-15 pose at x = offset (m), all joints valid: (15, 4)."""
    xyz = np.array(
        [
            [0, 0, 1.5],
            [0, 0.1, 1.65],
            [0, 0, 0.95],
            [0.2, 0, 1.45],
            [0.25, 0, 1.15],
            [0.3, 0, 0.9],
            [0.1, 0, 0.95],
            [0.1, 0, 0.5],
            [0.1, 0, 0.08],
            [-0.2, 0, 1.45],
            [-0.25, 0, 1.15],
            [-0.3, 0, 0.9],
            [-0.1, 0, 0.95],
            [-0.1, 0, 0.5],
            [-0.1, 0, 0.08],
        ]
    )
    return np.column_stack([xyz + [offset, 0, 0], np.ones(15)])


def _scene(frames: int = 3, persons: int = 4) -> list[np.ndarray]:
    """GT frames of persons 1 m apart: list of (G, 15, 4)."""
    return [np.stack([_person(1.0 * p + 0.01 * f) for p in range(persons)]) for f in range(frames)]


def test_ground_truth_against_itself_is_perfect() -> None:
    ev = PanopticAPEvaluator()
    for gt in _scene():
        ev.update(gt, gt)
    s = ev.summary()
    assert all(s[f"ap@{t}"] == pytest.approx(100.0) for t in AP_THRESHOLDS_MM)
    assert s["recall@500"] == pytest.approx(100.0) and s["mpjpe_mm"] == pytest.approx(0.0)
    assert s["num_gt"] == 12 and s["num_pred"] == 12


def test_shift_of_30_mm_fails_25_and_passes_50() -> None:
    ev = PanopticAPEvaluator()
    for gt in _scene():
        pred = gt.copy()
        pred[..., :3] += np.array([0.03, 0.0, 0.0])
        ev.update(pred, gt)
    s = ev.summary()
    assert s["ap@25"] == 0.0 and s["recall@25"] == 0.0
    assert all(s[f"ap@{t}"] == pytest.approx(100.0) for t in AP_THRESHOLDS_MM[1:])
    assert s["mpjpe_mm"] == pytest.approx(30.0)


def test_duplicate_ranked_above_a_true_positive_is_a_false_positive() -> None:
    # Two GT persons. Sorted: A (GT0, TP), duplicate of GT0 (FP), B (GT1, TP): precision 1, 1/2, 2/3,
    # interpolated 1, 2/3, 2/3 -> AP = 1/2 * 1 + 1/2 * 2/3 = 5/6.
    gt = _scene(1, 2)[0]
    pred = np.stack([gt[0], gt[0], gt[1]])
    ev = PanopticAPEvaluator()
    ev.update(pred, gt, scores=np.array([0.9, 0.8, 0.7]))
    assert ev.summary()["ap@50"] == pytest.approx(100.0 * 5 / 6)
    low = PanopticAPEvaluator()
    low.update(pred, gt, scores=np.array([0.9, 0.6, 0.7]))  # duplicate last: no effect on AP
    assert low.summary()["ap@50"] == pytest.approx(100.0)


def test_average_precision_by_hand_with_a_miss() -> None:
    # 3 GT; ranked TP, FP (too far), TP; one GT never found: precision 1, 1/2, 2/3 -> AP = (1 + 2/3) / 3.
    ap, recall = average_precision(
        np.array([3.0, 2.0, 1.0]), np.array([10.0, 90.0, 20.0]), np.array([0, 1, 2]), num_gt=3, threshold=50
    )
    assert ap == pytest.approx((1 + 2 / 3) / 3) and recall == pytest.approx(2 / 3)


def test_ground_truth_without_root_is_not_counted() -> None:
    gt = _scene(1, 2)[0]
    gt[1, 2, 3] = 0.0  # mid-hip invalid: VoxelPose skips the person
    ev = PanopticAPEvaluator()
    ev.update(gt[:1], gt)
    assert ev.summary()["num_gt"] == 1 and ev.summary()["ap@25"] == pytest.approx(100.0)


def test_root_aligned_mpjpe_of_a_translated_copy_is_zero() -> None:
    ev = PanopticPoseEvaluator()
    for gt in _scene():
        pred = gt.copy()
        pred[..., :3] += np.array([0.12, -0.05, 0.03])
        ev.update(pred, gt)
    s = ev.summary()
    assert s["root_mpjpe_13_mm"] == pytest.approx(0.0, abs=1e-9)
    assert s["root_mpjpe_average_mm"] == pytest.approx(0.0, abs=1e-9)
    assert s["num_matched"] == 12
    # PCP is absolute: a 13 cm shift breaks the short head part but not the long legs.
    assert s["pcp_head"] == 0.0 and s["pcp_upper_legs"] == 100.0


def test_root_aligned_mpjpe_per_group_and_pcp_of_a_bent_arm() -> None:
    gt = _scene(1, 1)[0]
    pred = gt.copy()
    pred[0, 5, :3] += [0.0, 0.0, 0.26]  # left wrist 26 cm off
    ev = PanopticPoseEvaluator()
    ev.update(pred, gt)
    s = ev.summary()
    assert s["root_mpjpe_wrist_mm"] == pytest.approx(130.0)  # one of the two wrists
    assert s["root_mpjpe_13_mm"] == pytest.approx(260.0 / 13)
    assert s["pcp_lower_arms"] == 50.0 and s["pcp_upper_arms"] == 100.0


def test_coco23_to_panoptic15_builds_neck_and_mid_hip() -> None:
    pose = np.zeros((23, 4))
    pose[:17, :3] = np.arange(51).reshape(17, 3)
    pose[:17, 3] = 1.0
    out = coco23_to_panoptic15(pose)
    assert np.allclose(out[0, :3], (pose[5, :3] + pose[6, :3]) / 2)
    assert np.allclose(out[2, :3], (pose[11, :3] + pose[12, :3]) / 2)
    assert np.allclose(out[1], pose[0]) and np.allclose(out[14], pose[JOINT_INDEX["right_ankle"]])
    pose[11, 3] = 0.0
    assert coco23_to_panoptic15(pose)[2, 3] == 0.0 and pose[11, 3] == 0.0


def test_axes_and_units(band1, panoptic: Path) -> None:
    band2 = load_panoptic_sequence(panoptic, "160906_band2")
    for seq in (band1, band2):
        for frame in seq.frames:
            gt = frame.gt_poses
            assert np.all(gt[:, list(FOOT_JOINTS), 3] == 0)
            ankles = gt[:, 15:17][gt[:, 15:17, 3] > 0]
            assert len(ankles) and np.all((ankles[:, 2] >= -0.05) & (ankles[:, 2] <= 0.25))
            # The band plays seated: noses 0.85-1.3 m, always well above the ankles.
            nose = gt[:, 0]
            assert np.all(nose[:, 3] > 0) and np.all((nose[:, 2] > 0.7) & (nose[:, 2] < 2.0))
            lowest = np.where(gt[:, 15:17, 3] > 0, gt[:, 15:17, 2], np.inf).min(axis=1)
            assert np.all(nose[:, 2] - lowest > 0.6)


def test_sequence_has_bodies_cameras_and_ids(band1, panoptic: Path) -> None:
    assert list(band1.rig.names) == list(DEFAULT_CAMERAS)
    assert {f.index: len(f.gt_poses) for f in band1.frames} == BODIES["160906_band1"]
    for frame in band1.frames:
        assert len(frame.views) == 5 and list(frame.gt_ids) == [0, 1, 2]
        assert band1.protocol_inputs[0]["gt15"][frame.index].shape == (3, 15, 4)
    one = load_panoptic_sequence(panoptic, "160906_band2", cameras=["00_00", "00_16"], frames=[140])
    assert [f.index for f in one.frames] == [140] and list(one.rig.names) == ["00_00", "00_16"]
    assert [f.index for f in load_panoptic_sequence(panoptic, "160906_band2", frames="1:").frames] == [140]
    with pytest.raises(ValueError, match="frame 7 requested"):
        load_panoptic_sequence(panoptic, "160906_band2", frames=[7])


def test_generated_2d_projects_back_within_the_noise(panoptic: Path) -> None:
    seq = load_panoptic_sequence(panoptic, "160906_band1", noise_px=2.0, occlusion=False, seed=3)
    frame = seq.frames[0]
    for camera, view in zip(seq.rig, frame.views):
        assert len(view) == 3 and np.all(view.keypoints[:, list(FOOT_JOINTS), 2] == 0)
        for det in range(len(view)):
            gt = frame.gt_poses[list(frame.gt_ids).index(view.person_ids[det])]
            uv = camera.project(gt[:, :3])
            seen = view.keypoints[det, :, 2] > 0
            assert np.array_equal(seen, (gt[:, 3] > 0) & camera.in_view(gt[:, :3]))
            err = np.linalg.norm(view.keypoints[det, seen, :2] - uv[seen], axis=-1)
            assert err.max() < 5 * 2.0 and 0.5 < err.mean() < 4.0


def test_poses2d_input_round_trip(band1, panoptic: Path, tmp_path: Path) -> None:
    io = pytest.importorskip("data.formats.poses2d_io")
    path = tmp_path / "poses2d.json"
    io.write_poses2d(path, {f.index: f.views for f in band1.frames}, list(band1.rig.names))
    read = load_panoptic_sequence(panoptic, "160906_band1", poses2d=str(path))
    for a, b in zip(band1.frames, read.frames):
        for va, vb in zip(a.views, b.views):
            assert np.allclose(va.keypoints, vb.keypoints, atol=1e-3)
    assert read.meta["frames_without_2d"] == 0


def test_combined_protocol_and_report(band1) -> None:
    protocol = PanopticProtocol(band1.protocol_inputs[0]["gt15"])
    for frame in band1.frames:
        protocol.update(frame, SimpleNamespace(poses3d=frame.gt_poses))
    s = protocol.summary()
    assert s["frames"] == len(band1.frames)
    # COCO-23 GT against the stored Panoptic-15: the synthesised neck is < 1.5 cm off; body 2 has no
    # right hip, so its synthesised mid-hip is missing and its torso (neck -> mid-hip) counts wrong.
    assert s["ap@25"] == pytest.approx(100.0) and s["pcp_upper_arms"] == pytest.approx(100.0)
    assert s["pcp_torso"] == pytest.approx(200.0 / 3)
    text = protocol.report()
    assert "VoxelPose Panoptic protocol" in text and "root-aligned" in text and "PCP" in text
