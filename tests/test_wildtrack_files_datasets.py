"""dataset=wildtrack (reprojection COCO protocol), dataset=files (own rig), and the Panoptic protocol adapter."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from hydra import compose, initialize_config_dir

import eval as eval_script
from data.datasets.files import load_files
from data.datasets.panoptic import load_panoptic_sequence as _load_panoptic
from data.datasets.wildtrack import load_wildtrack_crowd as _load_wildtrack
from data.formats.poses2d_io import Poses2DError, write_poses2d
from data.formats.poses_io import read_poses3d
from data.geometry.calibration import load_wildtrack_positions, save_cameras_json
from data.multiview import Frame
from data.pose2d.coco_eval import STAT_NAMES, evaluate_keypoints
from data.synthetic import SyntheticConfig, generate_sequence
from evaluation.protocols import attach_protocols
from evaluation.protocols.panoptic import PanopticProtocol
from evaluation.protocols.reprojection_coco import ReprojectionCOCOProtocol, coco_keypoint_stats
from reconstruction.pipeline import FrameResult


def load_panoptic_sequence(*args, **kwargs):
    """The Panoptic loader with its protocol attached, as eval.py does."""
    return attach_protocols(_load_panoptic(*args, **kwargs))


def load_wildtrack_crowd(*args, **kwargs):
    """The Wildtrack loader with its protocol attached, as eval.py does."""
    return attach_protocols(_load_wildtrack(*args, **kwargs))


ROOT = Path(__file__).resolve().parents[1]
CONFIGS = str(ROOT / "configs")
EXAMPLE = ROOT / "examples" / "own_rig"


@pytest.fixture(scope="module")
def wildtrack(shared_data: Path):
    """Two annotated Wildtrack frames with synthetic bodies."""
    return load_wildtrack_crowd(shared_data / "wildtrack", frames=2)


@pytest.fixture(scope="module")
def ring():
    """The default synthetic scene, 3 frames."""
    return generate_sequence(SyntheticConfig(num_frames=3))


def _protocol(sequence, poses_of=lambda frame: frame.gt_poses, **options) -> ReprojectionCOCOProtocol:
    """A ReprojectionCOCOProtocol fed predictions poses_of(frame) (P, 23, 4) on every frame."""
    protocol = ReprojectionCOCOProtocol(sequence.rig, **options)
    for frame in sequence.frames:
        protocol.update(frame, FrameResult(frame.index, poses_of(frame), np.zeros((0, len(sequence.rig)))))
    return protocol


def _score(sequence, poses_of=lambda frame: frame.gt_poses, **options) -> dict:
    """The summary of :func:`_protocol`."""
    return _protocol(sequence, poses_of, **options).summary()


def _shifted(dx_m: float):
    """A prediction function: the GT poses moved dx_m along world x (a new array)."""

    def poses(frame: Frame) -> np.ndarray:
        out = frame.gt_poses.copy()
        out[..., 0] += dx_m
        return out

    return poses


# --- reprojection COCO protocol -------------------------------------------------------------------
@pytest.mark.parametrize("name", ["wildtrack", "ring"])
def test_ground_truth_reprojected_scores_ap_1_in_every_subset(name, request):
    summary = _score(request.getfixturevalue(name))
    for subset in ("all", "body", "foot"):
        assert all(summary[subset][k] == pytest.approx(100.0) for k in STAT_NAMES if summary[subset][k] is not None)
        assert summary[subset]["AP"] == pytest.approx(100.0)
    assert summary["gt_persons"] == summary["predictions"] > 0


def test_wildtrack_views_hold_more_people_than_coco_keeps(wildtrack):
    coco = _protocol(wildtrack, max_dets=20)
    summary = coco.summary()
    assert summary["max_gt_per_image"] > 20 and summary["all"]["AR"] < 90.0  # COCO's 20 detections per image
    assert "recall is capped" in coco.report() and "recall is capped" not in _protocol(wildtrack).report()


def test_shifted_poses_score_lower_the_farther_they_move(wildtrack):
    ap = [_score(wildtrack, _shifted(dx))["all"]["AP"] for dx in (0.0, 0.05, 0.15, 2.0)]
    assert ap[0] == pytest.approx(100.0) and ap[0] > ap[1] > ap[2] > ap[3]
    assert ap[3] < 1.0


def test_gt_frame_without_predictions_has_zero_recall_and_frames_without_gt_are_counted(ring):
    summary = _score(ring, lambda frame: np.zeros((0, 23, 4)))
    assert summary["all"]["AR"] == 0.0 and summary["predictions"] == 0
    protocol = ReprojectionCOCOProtocol(ring.rig)
    protocol.update(Frame(0, ring.frames[0].views), FrameResult(0, ring.frames[0].gt_poses, np.zeros((0, 5))))
    assert protocol.summary()["frames_without_gt"] == 1 and protocol.summary()["images"] == 0


def test_stats_with_coco_max_dets_equal_evaluate_keypoints():
    rng = np.random.default_rng(3)
    gt, preds = [], []
    for image in (1, 2, 3):
        for _ in range(4):
            kp = np.column_stack([rng.uniform(100, 400, (23, 2)), np.full(23, 2.0)])
            gt.append({"image_id": image, "keypoints": kp, "bbox": [100, 100, 300, 300], "area": 90000.0})
            pred = kp.copy()
            pred[:, :2] += rng.normal(0, 8, (23, 2))
            pred[:, 2] = 0.9
            x0, y0 = pred[:, :2].min(axis=0)
            x1, y1 = pred[:, :2].max(axis=0)
            preds.append(
                {"image_id": image, "keypoints": pred, "score": rng.uniform(), "area": float((x1 - x0) * (y1 - y0))}
            )
    doc = {
        "images": [{"id": i} for i in (1, 2, 3)],
        "annotations": [{**a, "keypoints": a["keypoints"].ravel().tolist()} for a in gt],
    }
    for subset in ("all", "foot"):
        ours = coco_keypoint_stats([1, 2, 3], gt, preds, subset, max_dets=20)
        assert ours == pytest.approx(evaluate_keypoints(doc, preds, subset))
        assert 0.0 < ours["AP"] < 1.0


# --- dataset=wildtrack ----------------------------------------------------------------------------
def test_wildtrack_crowd_has_7_views_and_persons_at_the_annotated_positions(wildtrack, shared_data):
    positions = load_wildtrack_positions(shared_data / "wildtrack" / "gt_positions_mvdet.txt")
    assert len(wildtrack.rig) == 7 and [f.index for f in wildtrack.frames] == [0, 5]
    assert [p.name for p in wildtrack.protocols] == ["reprojection_coco"]
    for frame in wildtrack.frames:
        assert len(frame.views) == 7 and sum(len(v) for v in frame.views) > 0
        hips = (frame.gt_poses[:, 11, :2] + frame.gt_poses[:, 12, :2]) / 2
        np.testing.assert_allclose(hips, positions[frame.index], atol=1e-9)
        assert frame.gt_poses[..., 2].min() >= 0.0 and np.all(frame.gt_poses[..., 3] == 1)


def test_wildtrack_frames_by_number_and_unannotated_frame_named(shared_data):
    seq = load_wildtrack_crowd(shared_data / "wildtrack", frames=[10], seed=1)
    assert [f.index for f in seq.frames] == [10]
    with pytest.raises(ValueError, match="frame 12 is not annotated"):
        load_wildtrack_crowd(shared_data / "wildtrack", frames=[10, 12])


# --- dataset=files --------------------------------------------------------------------------------
def test_files_round_trip_reproduces_keypoints_and_rig(ring, tmp_path):
    detections = {10 + f.index: f.views for f in ring.frames}
    write_poses2d(tmp_path / "poses2d.json", detections, ring.rig.names)
    save_cameras_json(ring.rig, tmp_path / "cameras.json")
    seq = load_files(str(tmp_path / "cameras.json"), str(tmp_path / "poses2d.json"))
    assert seq.rig.names == ring.rig.names and [f.index for f in seq.frames] == [10, 11, 12]
    for a, b in zip(seq.rig, ring.rig):
        for key in ("K", "dist", "R", "t"):
            np.testing.assert_allclose(getattr(a, key), getattr(b, key), atol=1e-12)
        assert a.size == b.size
    for frame in seq.frames:
        assert frame.gt_poses is None
        for got, want in zip(frame.views, detections[frame.index]):
            np.testing.assert_allclose(got.keypoints, want.keypoints, atol=1e-4)
            np.testing.assert_allclose(got.bboxes, want.bboxes, atol=1e-4)
            np.testing.assert_array_equal(got.person_ids, want.person_ids)


def test_files_frame_list_keeps_frames_without_detections_a_range_stays_within_the_files_frames(capsys):
    seq = load_files(str(EXAMPLE / "cameras.json"), str(EXAMPLE / "poses2d.json"), frames=[99, 100, 101, 102, 140])
    assert [f.index for f in seq.frames] == [99, 100, 101, 102, 140]  # the example holds frames 100..139
    assert [sum(len(v) for v in f.views) == 0 for f in seq.frames] == [True, False, False, False, True]
    assert seq.meta["frames_without_detections"] == 2
    seq = load_files(str(EXAMPLE / "cameras.json"), str(EXAMPLE / "poses2d.json"), frames="99:104")
    assert [f.index for f in seq.frames] == [100, 101, 102, 103] and seq.meta["frames_without_detections"] == 0
    assert capsys.readouterr().err == "warning: dataset.frames: 5 frames clamped to the file's 100..139\n"


def test_files_bad_entry_is_named(tmp_path):
    entries = json.loads((EXAMPLE / "poses2d.json").read_text())
    entries[4]["keypoints"] = entries[4]["keypoints"][:60]
    bad = tmp_path / "poses2d.json"
    bad.write_text(json.dumps(entries))
    with pytest.raises(Poses2DError, match=r"entry 4: keypoints has 60 numbers, expected 69"):
        load_files(str(EXAMPLE / "cameras.json"), str(bad))


def _compose(overrides: list[str]):
    with initialize_config_dir(config_dir=CONFIGS, version_base="1.3"):
        return compose(config_name="eval", overrides=["progress=false", *overrides])


def test_eval_on_the_example_folder_writes_poses3d(tmp_path, capsys):
    cfg = _compose(
        [
            "dataset=files",
            f"dataset.cameras={EXAMPLE / 'cameras.json'}",
            f"dataset.poses2d={EXAMPLE / 'poses2d.json'}",
            "matching=feet",
        ]
    )
    report = eval_script.run(cfg, tmp_path)
    poses = read_poses3d(tmp_path / "poses3d.json")
    assert sorted(poses) == list(range(100, 140)) and all(p.shape == (3, 23, 4) for p in poses.values())
    assert "mpjpe_mm" not in report.metrics and sum(report.skipped.values()) == 0
    assert "no ground truth" in capsys.readouterr().out


def _bad_poses2d(tmp_path: Path, kind: str) -> tuple[Path, str]:
    """A broken copy of the example's poses2d.json and the message expected for it."""
    entries = json.loads((EXAMPLE / "poses2d.json").read_text())
    path = tmp_path / f"{kind}.json"
    if kind == "unknown_camera":
        entries[4]["camera"] = "cam_z"
        message = f"{path}: entry 4: camera 'cam_z' is not in the calibration (known cameras: cam_a, cam_b, cam_c)"
    else:
        entries[5]["keypoints"] = entries[5]["keypoints"][:60]
        message = f"{path}: entry 5: keypoints has 60 numbers, expected 69 (23 keypoints x, y, score)"
    path.write_text(json.dumps(entries))
    return path, message


@pytest.mark.parametrize("kind", ["unknown_camera", "60_numbers"])
def test_eval_bad_poses2d_stops_with_one_line_naming_the_entry(tmp_path, kind):
    path, message = _bad_poses2d(tmp_path, kind)
    cmd = [
        sys.executable,
        "eval.py",
        "dataset=files",
        f"dataset.cameras={EXAMPLE / 'cameras.json'}",
        f"dataset.poses2d={path}",
        "progress=false",
        f"hydra.run.dir={tmp_path / 'run'}",
    ]
    proc = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT, timeout=120)
    assert proc.returncode != 0 and message in proc.stderr
    assert proc.stderr.strip() == f"error: {message}"


# --- Panoptic protocol adapter --------------------------------------------------------------------
def test_panoptic_sequence_carries_its_protocol_and_gt_scores_perfectly(shared_data):
    seq = load_panoptic_sequence(shared_data / "panoptic", "160906_band1")
    (protocol,) = seq.protocols
    assert isinstance(protocol, PanopticProtocol) and protocol.name == "panoptic"
    for frame in seq.frames:
        protocol.update(frame, FrameResult(frame.index, frame.gt_poses, np.zeros((0, 5))))
    summary = protocol.summary()
    assert summary["frames"] == len(seq.frames) and summary["num_gt"] == summary["num_pred"] > 0
    assert summary["recall@500"] == pytest.approx(100.0) and summary["recall@150"] == pytest.approx(100.0)
    assert "VoxelPose Panoptic protocol" in protocol.report() and "Paper Table 4" in protocol.report()
