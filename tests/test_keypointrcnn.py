"""Keypoint R-CNN as a 2D source (models/keypointrcnn.py): COCO-23 with the feet missing, scores in [0, 1]."""

from __future__ import annotations

from urllib.error import URLError

import numpy as np
import pytest
import torch
from torchvision.models import WeightsEnum

from data.keypoints import NUM_BODY_JOINTS, NUM_JOINTS
from data.multiview import ViewDetections
from models.keypointrcnn import KeypointRCNN, keypoint_scores
from models.tv_weights import WeightsUnavailable

SMALL = {"min_size": 128, "max_size": 160, "box_score_thresh": 0.0, "box_detections_per_img": 5}


@pytest.fixture(scope="module")
def stage() -> KeypointRCNN:
    torch.manual_seed(0)
    return KeypointRCNN(weights=None, score_threshold=0.0, device="cpu", model_kwargs=SMALL)


def test_random_weights_give_coco23_with_feet_missing(stage: KeypointRCNN) -> None:
    images = [np.random.default_rng(i).integers(0, 256, (96, 128, 3), dtype=np.uint8) for i in range(2)]
    out = stage(images, None)
    assert stage.needs_boxes is False and len(out) == 2
    for view in out:
        assert isinstance(view, ViewDetections) and len(view) > 0
        n = len(view)
        assert view.keypoints.shape == (n, NUM_JOINTS, 3) and view.bboxes.shape == (n, 4)
        assert view.scores.shape == (n,) and np.all(view.person_ids == -1)
        assert np.all(view.keypoints[:, NUM_BODY_JOINTS:] == 0)
        body = view.keypoints[:, :NUM_BODY_JOINTS, 2]
        assert np.all((body >= 0) & (body <= 1)) and body.std() > 0
        assert np.all(view.bboxes[:, 2:] > 0)
    ignored = stage(images, [np.array([[0.0, 0.0, 10.0, 10.0, 1.0]])] * 2)
    for given, found in zip(ignored, out):
        np.testing.assert_array_equal(given.keypoints, found.keypoints)


def test_output_conversion_keeps_joint_order_and_filters(stage: KeypointRCNN) -> None:
    kps = torch.zeros(3, 17, 3)
    kps[:, :, 0] = torch.arange(17.0)  # x = COCO-17 joint index
    kps[:, :, 1] = torch.arange(3.0)[:, None] * 100
    logits = torch.linspace(-5, 9, 17).repeat(3, 1)
    output = {
        "boxes": torch.tensor([[0, 0, 10, 20], [5, 5, 30, 45], [0, 0, 1, 1]], dtype=torch.float32),
        "labels": torch.tensor([1, 1, 2]),
        "scores": torch.tensor([0.9, 0.3, 0.99]),
        "keypoints": kps,
        "keypoints_scores": logits,
    }
    stage.score_threshold = 0.5
    try:
        view = stage.to_view(output)
    finally:
        stage.score_threshold = 0.0
    assert len(view) == 1  # the 0.3 person below the threshold, label 2 is not a person
    np.testing.assert_array_equal(view.keypoints[0, :17, 0], np.arange(17))
    np.testing.assert_allclose(view.keypoints[0, :17, 2], 1 / (1 + np.exp(2.0 - logits[0].double().numpy())))
    np.testing.assert_array_equal(view.bboxes, [[0, 0, 10, 20]])
    np.testing.assert_allclose(view.scores, [0.9])


def test_keypoint_scores_is_a_shifted_scaled_sigmoid() -> None:
    logits = np.array([-30.0, -3.0, 0.0, 2.0, 4.5, 30.0])
    np.testing.assert_allclose(keypoint_scores(logits, 2.0, 1.5), 1 / (1 + np.exp(-(logits - 2.0) / 1.5)))
    extreme = keypoint_scores(np.array([-800.0, 800.0]), 2.0, 1.0)
    assert extreme[0] >= 0 and extreme[1] == 1 and np.all(np.isfinite(extreme))
    assert keypoint_scores(np.array(2.0), 2.0, 1.0) == 0.5


def test_coco_offline_is_one_line(monkeypatch: pytest.MonkeyPatch) -> None:
    def offline(*args, **kwargs) -> dict:
        raise URLError("[Errno -3] Temporary failure in name resolution")

    monkeypatch.setattr(WeightsEnum, "get_state_dict", offline)
    with pytest.raises(WeightsUnavailable) as info:
        KeypointRCNN(weights="coco", device="cpu")
    message = str(info.value)
    assert "\n" not in message and message.startswith("pose2d.weights: cannot download KeypointRCNN_ResNet50_FPN")


def test_config_builds_the_stage() -> None:
    from pathlib import Path

    from hydra.utils import instantiate
    from omegaconf import OmegaConf

    cfg = OmegaConf.load(Path(__file__).resolve().parents[1] / "configs" / "pose2d" / "keypointrcnn.yaml")
    stage = instantiate(OmegaConf.merge(cfg, {"weights": None, "device": "cpu", "model_kwargs": {"min_size": 64}}))
    assert isinstance(stage, KeypointRCNN) and stage.logit_center == 2.0 and stage.model.transform.min_size == (64,)
