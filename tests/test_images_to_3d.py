"""eval.py with a 2D stage: rendered synthetic frames -> detector -> SPPE -> matching -> MAP, per-view COCO AP,
poses2d.json; the 2D stage's config errors; ground-truth ids of predicted 2D poses; boxes from 2D poses."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from hydra import compose, initialize_config_dir

import eval as eval_script
from data.config_checks import ConfigError
from data.formats.boxes_from_poses import detections, pose_box
from data.multiview import ViewDetections
from evaluation.pose2d_views import label_with_gt_ids
from run_folders import register_resolvers
from tests.test_sppe_stage import write_tiny_checkpoint

CONFIGS = Path(__file__).resolve().parents[1] / "configs"
SCENE = ["dataset.num_frames=2", "dataset.num_persons=3", "dataset.num_cameras=3", "progress=false"]


def config(overrides: list[str]):
    register_resolvers()
    with initialize_config_dir(config_dir=str(CONFIGS), version_base="1.3"):
        return compose("eval", overrides=overrides)


@pytest.fixture(scope="module")
def checkpoint(tmp_path_factory) -> Path:
    return write_tiny_checkpoint(tmp_path_factory.mktemp("e2e") / "best.pth", padding=1.25)


def test_rendered_scene_through_the_sppe_writes_2d_and_3d_and_scores_the_views(checkpoint, tmp_path):
    cfg = config([*SCENE, "dataset.render=true", "pose2d=sppe", f"pose2d.checkpoint={checkpoint}", "detector=gt"])
    cfg.pose2d.device = "cpu"
    report = eval_script.run(cfg, tmp_path)
    assert {"images", "detector", "pose2d"} <= set(report.timings)
    assert 0.0 <= report.metrics["pose2d_AP_all"] <= 1.0 and "pose2d_AP_foot" in report.metrics
    entries = json.loads((tmp_path / "poses2d.json").read_text())
    assert {e["frame"] for e in entries} <= {0, 1} and all(len(e["keypoints"]) == 69 for e in entries)
    assert "2D poses per view" in (tmp_path / "report.txt").read_text()


def test_the_render_ground_truth_2d_is_the_upper_bound_row(tmp_path):
    report = eval_script.run(config([*SCENE, "dataset.render=true"]), tmp_path)
    assert report.metrics["mpjpe_mm"] < 1.0 and report.metrics["pcp_average"] == 100.0
    assert len(json.loads((tmp_path / "poses2d.json").read_text())) > 0  # the 2D the run used


@pytest.mark.filterwarnings("ignore::data.geometry.check_rig.RigWarning")  # a toy rig: only the config error counts
def test_a_2d_stage_without_images_and_images_without_a_2d_stage_stop_with_one_line(checkpoint, tmp_path):
    with pytest.raises(ConfigError, match="dataset.render=true"):
        eval_script.run(config([*SCENE, "pose2d=sppe", f"pose2d.checkpoint={checkpoint}"]), tmp_path / "a")
    images = tmp_path / "frames"
    images.mkdir()
    rig = tmp_path / "cams.json"
    cams = {n: {"K": [[500, 0, 32], [0, 500, 24], [0, 0, 1]], "dist": [0] * 5, "R": np.eye(3).tolist(), "t": [x, 0, -5],
                "size": [64, 48]} for n, x in (("a", 0.0), ("b", 1.0))}  # fmt: skip
    rig.write_text(json.dumps(cams))
    import cv2

    for name in cams:
        cv2.imwrite(str(images / f"{name}.png"), np.zeros((48, 64, 3), np.uint8))
    overrides = ["dataset=images", f"dataset.cameras={rig}", f"dataset.images={images}", "dataset.pattern='{name}.png'"]
    with pytest.raises(ConfigError, match="pose2d=none: the dataset gives images"):
        eval_script.run(config([*overrides, "progress=false"]), tmp_path / "b")


def test_predicted_poses_get_the_ids_of_the_ground_truth_they_overlap():
    rng = np.random.default_rng(0)
    kp = np.concatenate([rng.uniform(0, 500, (3, 23, 2)), np.ones((3, 23, 1))], axis=-1)
    boxes = np.array([[0, 0, 100, 200]] * 3, float)
    gt = ViewDetections(kp, boxes, np.ones(3), np.array([7, 8, 9]))
    order = [2, 0]
    pred = ViewDetections(kp[order] + 0.5, boxes[order], np.ones(2), -np.ones(2, int))
    labelled = label_with_gt_ids(pred, gt)
    np.testing.assert_array_equal(labelled.person_ids, [9, 7])
    np.testing.assert_array_equal(pred.person_ids, [-1, -1])  # the input is not modified
    far = ViewDetections(kp[:1] + 300, boxes[:1], np.ones(1), -np.ones(1, int))
    np.testing.assert_array_equal(label_with_gt_ids(far, gt).person_ids, [-1])


def test_boxes_from_poses_known_answer_in_file_pixels():
    kp = np.zeros((1, 23, 3))
    kp[0, :3] = [[10, 20, 1], [30, 60, 1], [20, 40, 0.5]]
    np.testing.assert_allclose(pose_box(kp[0], 0.1), [8, 16, 24, 48])
    view = ViewDetections(kp, np.zeros((1, 4)), np.array([0.9]), np.array([-1]))
    images = [{"id": 5, "frame": 0, "camera": "a", "width": 200, "height": 100}]
    dets = detections({572: [view]}, ["a"], [(100, 100)], images, {572: 0}, 0.1, 3)
    assert dets == [{"image_id": 5, "category_id": 1, "bbox": [16.0, 16.0, 48.0, 48.0], "score": 0.9}]


def test_file_detector_boxes_are_rescaled_from_the_file_pixels_to_the_images_seen(tmp_path):
    from data.multiview import Frame
    from models.detectors import FileDetector

    path = tmp_path / "dets.json"
    path.write_text(json.dumps([{"image_id": 3, "category_id": 1, "bbox": [100, 50, 40, 80], "score": 0.8}]))
    detector = FileDetector(path)
    frame = Frame(0, [], image_ids=[3])
    np.testing.assert_allclose(detector(None, frame)[0], [[100, 50, 40, 80, 0.8]])
    detector.set_file_sizes({3: (1920, 1080)})
    small = [np.zeros((540, 960, 3), np.uint8)]
    np.testing.assert_allclose(detector(small, frame)[0], [[50, 25, 20, 40, 0.8]])


def test_the_side_fixes_run_through_the_whole_chain(checkpoint, tmp_path):
    overrides = ["dataset.render=true", "pose2d=sppe", f"pose2d.checkpoint={checkpoint}", "detector=gt"]
    cfg = config([*SCENE, *overrides, "pose2d.separate_pairs=true", "reconstruction.fix_sides=true"])
    cfg.pose2d.device = "cpu"
    report = eval_script.run(cfg, tmp_path)
    assert report.metrics["num_gt"] == 6 and "pose2d_AP_all" in report.metrics
