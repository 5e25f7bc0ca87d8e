"""The SPPE stage (models/sppe_stage.py) on a tiny random FastPose-18 checkpoint written as train.py writes one:
ViewDetections per view, the same poses as the checkpoint evaluation on the same boxes, left/right-consistent
output for a symmetric person under the flip test, pose-NMS of a duplicated box, one-line errors."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
import torch
from hydra import compose, initialize_config_dir
from hydra.utils import instantiate
from omegaconf import OmegaConf
from torch.utils.data import DataLoader

from data.config_checks import ConfigError
from data.keypoints import FLIP_PAIRS, NUM_JOINTS
from data.pose2d.coco_keypoints import load_coco_wholebody
from data.pose2d.topdown_dataset import TopDownDataset
from evaluation.pose2d_eval import predict
from models.checkpoint_io import load_trained_model
from models.sppe_stage import SppeStage
from models.training import TrainState, build_codec, save_weights

CONFIGS = Path(__file__).resolve().parents[1] / "configs"


def write_tiny_checkpoint(path: Path, padding: float) -> Path:
    """best.pth of a random FastPose-18 on 64 x 64 crops, saved as train.py saves it; the head's weights are
    drawn larger than at initialisation so that the heatmaps cross the candidate threshold."""
    with initialize_config_dir(config_dir=str(CONFIGS), version_base="1.3"):
        cfg = compose("train", overrides=["model=fastpose_r18", "data.input_size=[64,64]", f"data.padding={padding}"])
    torch.manual_seed(0)
    model = instantiate(cfg.model)
    torch.nn.init.normal_(model.conv_out.weight, std=0.05)
    save_weights(path, model, TrainState(), {}, OmegaConf.to_container(cfg, resolve=True))
    return path


@pytest.fixture(scope="module")
def checkpoint(tmp_path_factory) -> Path:
    return write_tiny_checkpoint(tmp_path_factory.mktemp("sppe") / "best.pth", padding=1.25)


def stage_config(checkpoint: Path, **overrides) -> SppeStage:
    """configs/pose2d/sppe.yaml with this checkpoint and overrides, instantiated as Hydra does, on the CPU."""
    cfg = OmegaConf.load(CONFIGS / "pose2d" / "sppe.yaml")
    cfg.checkpoint, cfg.device = str(checkpoint), "cpu"
    for key, value in overrides.items():
        OmegaConf.update(cfg, key, value)
    return instantiate(cfg)


def test_views_with_different_box_counts(checkpoint):
    stage = stage_config(checkpoint)
    assert stage.needs_boxes is True
    rng = np.random.default_rng(0)
    images = [rng.integers(0, 256, (240, 320, 3), dtype=np.uint8) for _ in range(2)]
    boxes = [np.array([[10, 20, 50, 120, 0.9], [120, 30, 60, 150, 0.8], [240, 10, 40, 100, 0.5]]), np.zeros((0, 5))]
    views = stage(images, boxes)
    assert [len(v) for v in views] == [3, 0]
    assert views[0].keypoints.shape == (3, NUM_JOINTS, 3) and views[1].keypoints.shape == (0, NUM_JOINTS, 3)
    np.testing.assert_array_equal(views[0].bboxes, boxes[0][:, :4])
    assert np.all(views[0].person_ids == -1) and views[0].scores.shape == (3,)
    assert np.all((views[0].scores >= 0) & (views[0].scores <= boxes[0][:, 4]))
    assert (views[0].keypoints[..., 2] > 0).any()  # candidates were found
    # every joint lies on its crop: the box grown to the 1:1 input, times the checkpoint's padding 1.25
    centre = boxes[0][:, :2] + boxes[0][:, 2:4] / 2
    half = 1.25 * boxes[0][:, 2:4].max(axis=1, keepdims=True) / 2
    assert np.all(np.abs(views[0].keypoints[..., :2] - centre[:, None]) <= half[:, None] + 1e-6)
    assert set(stage.last_timings) == {"crop", "network", "decode"}
    assert [len(v) for v in stage([images[0]] * 2, [np.zeros((0, 5))] * 2)] == [0, 0]


def test_same_poses_as_the_checkpoint_evaluation_on_the_same_boxes(checkpoint, shared_data):
    folder = shared_data / "coco_wholebody_sample"
    records = load_coco_wholebody(folder / "test_coco_wholebody.json", folder)
    model, train_cfg = load_trained_model(checkpoint, torch.device("cpu"))
    codec = build_codec(train_cfg)
    dataset = TopDownDataset(records, codec, (64, 64), train=False, padding=train_cfg.data.padding)
    expected = predict(model, DataLoader(dataset, batch_size=8), codec, torch.device("cpu"), "association")
    stage = stage_config(checkpoint, **{"pose_nms.enabled": False, "batch_size": 5})
    images = [cv2.imread(str(r.file)) for r in records]
    boxes = [np.array([np.append(box, 1.0) for ri, _, box, _, _ in dataset.samples if ri == r]) for r in range(4)]
    got = np.concatenate([v.keypoints for v in stage(images, boxes)])  # four images as four views of one frame
    np.testing.assert_allclose(got, np.stack([p["keypoints"] for p in expected]), rtol=0, atol=1e-6)


@pytest.mark.parametrize("decode", ["association", "single"])
def test_flip_test_on_a_symmetric_person_gives_mirrored_left_and_right_joints(tmp_path, decode):
    # image columns x and 201 - x are equal (mirror axis x = 100.5); with padding 1 the 64 x 64 box centred on the
    # axis crops exactly (an integer shift), so the crop equals its own mirror
    checkpoint = write_tiny_checkpoint(tmp_path / "best.pth", padding=1.0)
    half = np.random.default_rng(3).integers(0, 256, (160, 101, 3), dtype=np.uint8)
    image = np.concatenate([half, half[:, ::-1]], axis=1)
    box = np.array([[100.5 - 32, 48.5, 64, 64, 1.0]])
    for flip_test in (True, False):
        stage = stage_config(checkpoint, decode=decode, flip_test=flip_test, threshold=0.05)
        kps = stage([image], [box])[0].keypoints[0]
        left, right = np.array(FLIP_PAIRS).T
        assert {17, 18, 19} <= set(left) and {20, 21, 22} <= set(right)  # feet pairs included
        mirrored = np.column_stack([201.0 - kps[left, 0], kps[left, 1:]])
        seen = kps[left, 2] > 0
        assert seen.sum() >= 5
        if flip_test:
            np.testing.assert_allclose(kps[right][seen], mirrored[seen], atol=1e-4)
        else:  # the random network alone is not mirror-consistent
            assert np.abs(kps[right][seen] - mirrored[seen]).max() > 0.5


def test_pose_nms_merges_a_duplicated_box(checkpoint):
    image = np.random.default_rng(1).integers(0, 256, (200, 200, 3), dtype=np.uint8)
    boxes = np.array([[40, 30, 60, 140, 0.9], [40, 30, 60, 140, 0.7]])
    merged = stage_config(checkpoint)([image], [boxes])[0]
    kept = stage_config(checkpoint, **{"pose_nms.enabled": False})([image], [boxes])[0]
    assert len(merged) == 1 and len(kept) == 2
    np.testing.assert_array_equal(merged.bboxes, boxes[:1, :4])
    assert merged.scores[0] >= kept.scores.max()


def test_bad_input_and_config_stop_with_one_line(checkpoint, tmp_path):
    stage = stage_config(checkpoint)
    image = np.zeros((100, 100, 3), np.uint8)
    with pytest.raises(ValueError, match=r"view 1: boxes must be \(N, 5\)"):
        stage([image, image], [np.zeros((0, 5)), np.ones((2, 4))])
    with pytest.raises(ValueError, match="view 0: box 1 .* w or h <= 0"):
        stage([image], [np.array([[0, 0, 10, 10, 1.0], [0, 0, 0, 10, 1.0]])])
    with pytest.raises(ValueError, match="2 images but 1 box arrays"):
        stage([image, image], [np.zeros((0, 5))])
    with pytest.raises(ValueError, match=r"view 0: the image must be \(H, W, 3\) uint8"):
        stage([image.astype(np.float32)], [np.array([[0, 0, 10, 10, 1.0]])])
    with pytest.raises(ConfigError, match="pose2d.decode='peaks': must be one of single, association"):
        SppeStage(checkpoint, decode="peaks", device="cpu")
    with pytest.raises(ConfigError, match=r"pose2d.pose_nms.oks=1.5: must be a number in \(0, 1\)"):
        SppeStage(checkpoint, device="cpu", pose_nms={"enabled": True, "oks": 1.5})
    with pytest.raises(FileNotFoundError, match="absent.pth: no such checkpoint"):
        SppeStage(tmp_path / "absent.pth", device="cpu")
