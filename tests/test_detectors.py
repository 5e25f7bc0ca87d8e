"""Person detectors (models/detectors): ground truth with jitter, a COCO detections file, torchvision models."""

from __future__ import annotations

import json
from pathlib import Path
from urllib.error import URLError

import numpy as np
import pytest
import torch
from torchvision.models import WeightsEnum

from data.config_checks import ConfigError
from data.multiview import Frame, ViewDetections
from models.detectors import FileDetector, GroundTruthDetector, TorchvisionDetector, person_boxes
from models.tv_detection import image_tensor
from models.tv_weights import WeightsUnavailable

SMALL_TV = {"num_classes": 2, "box_score_thresh": 0.0}  # random weights: every box is a "person"


def _view(boxes: list[list[float]], labelled: list[int]) -> ViewDetections:
    """A view whose person i has box boxes[i] and labelled[i] scored joints."""
    n = len(boxes)
    kps = np.zeros((n, 23, 3))
    for i, count in enumerate(labelled):
        kps[i, :count] = [10.0, 10.0, 0.9]
    return ViewDetections(kps, np.array(boxes, float).reshape(n, 4), np.ones(n), np.arange(n))


def _frame(index: int = 5, image_ids: list[int] | None = None) -> Frame:
    views = [_view([[10, 20, 30, 60], [50, 5, 20, 40], [0, 0, 5, 5]], [17, 3, 0]), _view([[100, 50, 40, 80]], [23])]
    return Frame(index=index, views=views, image_ids=image_ids)


def _iou(a: np.ndarray, b: np.ndarray) -> float:
    """IoU of two x, y, w, h boxes."""
    w = max(0.0, min(a[0] + a[2], b[0] + b[2]) - max(a[0], b[0]))
    h = max(0.0, min(a[1] + a[3], b[1] + b[3]) - max(a[1], b[1]))
    return w * h / (a[2] * a[3] + b[2] * b[3] - w * h)


# --- gt --------------------------------------------------------------------------------------------------------


def test_gt_boxes_exact_with_score_one_and_min_joints() -> None:
    frame = _frame()
    before = [v.bboxes.copy() for v in frame.views]
    out = GroundTruthDetector(min_joints=1)(None, frame)
    np.testing.assert_array_equal(out[0], [[10, 20, 30, 60, 1], [50, 5, 20, 40, 1]])  # the unlabelled one dropped
    np.testing.assert_array_equal(out[1], [[100, 50, 40, 80, 1]])
    assert [len(b) for b in GroundTruthDetector(min_joints=4)(None, frame)] == [1, 1]
    assert [len(b) for b in GroundTruthDetector(min_joints=0)(None, frame)] == [3, 1]
    out[0][:] = -1
    assert all(np.array_equal(v.bboxes, b) for v, b in zip(frame.views, before))


def test_gt_clips_to_the_image_and_drops_boxes_outside() -> None:
    frame = Frame(index=0, views=[_view([[-10, 5, 30, 40], [200, 5, 10, 10]], [5, 5])])
    out = GroundTruthDetector()([np.zeros((100, 150, 3), np.uint8)], frame)
    np.testing.assert_array_equal(out[0], [[0, 5, 20, 40, 1]])


def test_gt_jitter_is_deterministic_per_frame_and_view() -> None:
    detector = GroundTruthDetector(jitter=0.1, seed=3)
    first, again = detector(None, _frame(index=5)), detector(None, _frame(index=5))
    assert all(np.array_equal(a, b) for a, b in zip(first, again))
    other_frame = detector(None, _frame(index=6))
    other_seed = GroundTruthDetector(jitter=0.1, seed=4)(None, _frame(index=5))
    assert not np.allclose(first[0], other_frame[0]) and not np.allclose(first[0], other_seed[0])
    boxes = np.tile([[10.0, 20.0, 30.0, 60.0]], (4, 1))
    views = [detector.jittered(boxes, 5, v) for v in range(2)]
    assert not np.allclose(views[0], views[1])


def test_gt_jitter_is_bounded_and_has_the_asked_spread() -> None:
    jitter, clip = 0.1, 2.0
    boxes = np.tile([[100.0, 200.0, 50.0, 120.0]], (4000, 1))
    out = GroundTruthDetector(jitter=jitter, jitter_clip=clip).jittered(boxes, 0, 0)
    shift = (out[:, :2] + out[:, 2:] / 2 - (boxes[:, :2] + boxes[:, 2:] / 2)) / boxes[:, 2:]
    log_scale = np.log(out[:, 2:] / boxes[:, 2:])
    assert np.all(np.abs(shift) <= clip * jitter + 1e-12) and np.all(np.abs(log_scale) <= clip * jitter + 1e-12)
    assert np.abs(shift).max() > 0.9 * clip * jitter  # the clip is reached, not a smaller bound
    # a standard Gaussian clipped at +-2 has standard deviation 0.9078 (scipy.stats.truncnorm is the reference
    # for the part inside, plus the clipped mass at the bounds)
    from scipy import stats

    inside = stats.truncnorm(-clip, clip).var() * (1 - 2 * stats.norm.sf(clip))
    expected_std = np.sqrt(inside + 2 * stats.norm.sf(clip) * clip**2)
    np.testing.assert_allclose(shift.std(axis=0), jitter * expected_std, rtol=0.05)
    np.testing.assert_allclose(log_scale.std(axis=0), jitter * expected_std, rtol=0.05)


@pytest.mark.parametrize("kwargs, key", [({"jitter": -0.1}, "detector.jitter"), ({"min_joints": 1.5}, "min_joints")])
def test_gt_bad_keys_name_the_key(kwargs: dict, key: str) -> None:
    with pytest.raises(ConfigError, match=key):
        GroundTruthDetector(**kwargs)


# --- file ------------------------------------------------------------------------------------------------------


def _write(tmp_path: Path, entries: list | str, name: str = "dets.json") -> Path:
    path = tmp_path / name
    path.write_text(entries if isinstance(entries, str) else json.dumps(entries))
    return path


def _entry(image_id: int, bbox: list, score: float = 0.9, category_id: int = 1) -> dict:
    return {"image_id": image_id, "category_id": category_id, "bbox": bbox, "score": score}


def test_file_boxes_by_image_id_person_category_and_threshold(tmp_path: Path) -> None:
    path = _write(
        tmp_path,
        [
            _entry(7, [1, 2, 3, 4], 0.9),
            _entry(8, [5, 6, 7, 8], 0.8),
            _entry(7, [10, 20, 30, 40], 0.3),
            _entry(7, [0, 0, 9, 9], 0.95, category_id=3),
        ],
    )
    frame = Frame(index=0, views=[ViewDetections.empty()] * 3, image_ids=[7, 8, 9])
    out = FileDetector(path)(None, frame)
    np.testing.assert_array_equal(out[0], [[1, 2, 3, 4, 0.9], [10, 20, 30, 40, 0.3]])
    np.testing.assert_array_equal(out[1], [[5, 6, 7, 8, 0.8]])
    assert out[2].shape == (0, 5)
    strict = FileDetector(path, score_threshold=0.5)(None, frame)
    assert [len(b) for b in strict] == [1, 1, 0]
    cars = FileDetector(path, category_id=3)(None, frame)
    np.testing.assert_array_equal(cars[0], [[0, 0, 9, 9, 0.95]])
    out[0][:] = 0  # the caller's copy
    np.testing.assert_array_equal(FileDetector(path)(None, frame)[1], [[5, 6, 7, 8, 0.8]])


@pytest.mark.parametrize(
    "bad, phrase",
    [
        ({"image_id": 1, "category_id": 1, "bbox": [1, 2, 3]}, r"entry 1 lacks the key\(s\) \['score'\]"),
        (_entry(1, [1, 2, 3]), "entry 1 bbox must be 4 finite numbers"),
        (_entry(1, [1, 2, "3", 4]), "entry 1 bbox must be 4 finite numbers"),
        (_entry(1, [1, 2, 0, 4]), r"entry 1 bbox width and height must be > 0"),
        (_entry(1, [1, 2, 3, -4]), r"entry 1 bbox width and height must be > 0"),
        (_entry(1, [1, 2, 3, 4], score=None), "entry 1 score must be a finite number"),
        (_entry(True, [1, 2, 3, 4]), "entry 1 image_id must be a 64-bit integer"),
        ([1, 2, 3, 4], "entry 1 is not an object"),
    ],
)
def test_file_malformed_entry_names_file_and_entry(tmp_path: Path, bad: object, phrase: str) -> None:
    path = _write(tmp_path, [_entry(1, [0, 0, 1, 1]), bad])
    with pytest.raises(ValueError, match=r"dets\.json: " + phrase):
        FileDetector(path)


@pytest.mark.parametrize("text", ["NaN", "Infinity"])
def test_file_non_finite_numbers_are_named(tmp_path: Path, text: str) -> None:
    path = _write(tmp_path, '[{"image_id": 1, "category_id": 1, "bbox": [0, 0, 1, 1], "score": %s}]' % text)
    with pytest.raises(ValueError, match=r"dets\.json: entry 0 score must be a finite number"):
        FileDetector(path)
    path = _write(tmp_path, '[{"image_id": 1, "category_id": 1, "bbox": [0, %s, 1, 1], "score": 1}]' % text)
    with pytest.raises(ValueError, match=r"dets\.json: entry 0 bbox must be 4 finite numbers"):
        FileDetector(path)


def test_file_not_a_list_or_unreadable(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match=r"dets\.json: a detections file is a JSON list"):
        FileDetector(_write(tmp_path, {"annotations": []}))
    with pytest.raises(ValueError, match=r"dets\.json: not a valid JSON"):
        FileDetector(_write(tmp_path, "[{"))
    with pytest.raises(ValueError, match=r"absent\.json: cannot read"):
        FileDetector(tmp_path / "absent.json")


def test_file_unknown_image_id_is_named_with_its_entry(tmp_path: Path) -> None:
    path = _write(tmp_path, [_entry(1, [0, 0, 1, 1]), _entry(2, [0, 0, 1, 1]), _entry(9, [0, 0, 1, 1], 0.01)])
    detector = FileDetector(path, score_threshold=0.5)
    detector.check_image_ids({1, 2, 9})
    with pytest.raises(ValueError, match=r"dets\.json: entry 2: image_id 9 is not an image of the dataset"):
        detector.check_image_ids({1, 2, 3})
    with pytest.raises(ValueError, match=r"dets\.json: frame 4 has no image ids"):
        detector(None, Frame(index=4, views=[]))


# --- torchvision -----------------------------------------------------------------------------------------------


def _images(count: int, size: tuple[int, int] = (96, 128)) -> list[np.ndarray]:
    return [np.random.default_rng(i).integers(0, 256, (*size, 3), dtype=np.uint8) for i in range(count)]


@pytest.mark.parametrize("name", ["ssdlite320_mobilenet_v3_large", "fasterrcnn_mobilenet_v3_large_320_fpn"])
def test_torchvision_random_weights_give_valid_boxes(name: str) -> None:
    torch.manual_seed(0)
    kwargs = dict(SMALL_TV) if name.startswith("faster") else {"num_classes": 2, "score_thresh": 0.0}
    detector = TorchvisionDetector(
        name, weights=None, score_threshold=0.0, batch_size=2, device="cpu", model_kwargs=kwargs
    )
    images = _images(3)
    out = detector(images, Frame(index=0, views=[]))
    assert len(out) == 3
    for boxes in out:
        assert boxes.ndim == 2 and boxes.shape[1] == 5 and len(boxes) > 0 and boxes.dtype == np.float64
        assert np.all(boxes[:, 2:4] > 0) and np.all(boxes[:, :2] >= 0)
        assert np.all(boxes[:, 0] + boxes[:, 2] <= 128 + 1e-6) and np.all(boxes[:, 1] + boxes[:, 3] <= 96 + 1e-6)
        assert np.all((boxes[:, 4] >= 0) & (boxes[:, 4] <= 1)) and np.all(np.diff(boxes[:, 4]) <= 0)
        assert max(_iou(a, b) for i, a in enumerate(boxes) for b in boxes[i + 1 :]) <= 0.5 + 1e-6


class _StubModel(torch.nn.Module):
    """Returns fixed outputs; records the batches it was given."""

    def __init__(self, outputs: list[dict]) -> None:
        super().__init__()
        self.outputs, self.batches = outputs, []

    def forward(self, batch: list[torch.Tensor]) -> list[dict]:
        start = sum(len(b) for b in self.batches)
        self.batches.append(batch)
        return self.outputs[start : start + len(batch)]


def test_torchvision_keeps_persons_above_threshold_after_nms() -> None:
    boxes = torch.tensor(
        [[0, 0, 10, 20], [1, 0, 11, 20], [50, 50, 60, 80], [0, 0, 10, 20], [30, 30, 40, 40], [100, 0, 110, 9]],
        dtype=torch.float32,
    )
    labels = torch.tensor([1, 1, 1, 3, 1, 1])
    scores = torch.tensor([0.9, 0.8, 0.7, 0.99, 0.2, 0.6])
    detector = TorchvisionDetector(
        "ssdlite320_mobilenet_v3_large", weights=None, score_threshold=0.5, nms_iou=0.5, device="cpu"
    )
    detector.model = _StubModel([{"boxes": boxes, "labels": labels, "scores": scores}] * 3)
    detector.batch_size = 2
    out = detector(_images(3), Frame(index=0, views=[]))
    # box 1 overlaps box 0 at IoU 0.82 (suppressed), box 3 is not a person, box 4 is below the threshold
    expected = [[0, 0, 10, 20, 0.9], [50, 50, 10, 30, 0.7], [100, 0, 10, 9, 0.6]]
    for view in out:
        np.testing.assert_allclose(view, expected, rtol=1e-6)
    assert [len(b) for b in detector.model.batches] == [2, 1]
    loose = person_boxes(boxes.numpy(), labels.numpy(), scores.numpy(), 1, 0.5, nms_iou=0.9)
    assert len(loose) == 4  # at IoU 0.9 the pair overlapping at 0.82 both stay


def test_image_tensor_is_rgb_in_unit_range() -> None:
    image = np.zeros((4, 5, 3), np.uint8)
    image[1, 2] = (10, 20, 255)  # BGR
    tensor = image_tensor(image, 0)
    assert tensor.shape == (3, 4, 5) and tensor.dtype == torch.float32
    np.testing.assert_allclose(tensor[:, 1, 2].numpy(), np.array([255, 20, 10]) / 255.0)
    assert image[1, 2, 0] == 10  # the caller's array untouched
    with pytest.raises(ValueError, match="image of view 3: expected an \\(H, W, 3\\) uint8 BGR array"):
        image_tensor(np.zeros((4, 5, 3), np.float32), 3)


def test_torchvision_state_dict_file_round_trip(tmp_path: Path) -> None:
    torch.manual_seed(1)
    name = "fasterrcnn_mobilenet_v3_large_320_fpn"
    source = TorchvisionDetector(name, weights=None, score_threshold=0.0, device="cpu", model_kwargs=SMALL_TV)
    state = {k: v for k, v in source.model.state_dict().items() if not k.endswith("num_batches_tracked")}
    torch.save(state, tmp_path / "det.pth")  # as torchvision's COCO files: frozen BatchNorm, no counters
    torch.manual_seed(2)
    loaded = TorchvisionDetector(
        name, weights=str(tmp_path / "det.pth"), score_threshold=0.0, device="cpu", model_kwargs=SMALL_TV
    )
    images = _images(1)
    np.testing.assert_allclose(loaded(images)[0], source(images)[0], rtol=1e-5, atol=1e-4)
    del state["roi_heads.box_predictor.cls_score.weight"]
    torch.save(state, tmp_path / "broken.pth")
    with pytest.raises(ValueError, match=r"broken\.pth does not fit .*cls_score\.weight"):
        TorchvisionDetector(name, weights=str(tmp_path / "broken.pth"), device="cpu", model_kwargs=SMALL_TV)


def test_torchvision_coco_offline_is_one_line(monkeypatch: pytest.MonkeyPatch) -> None:
    def offline(*args, **kwargs) -> dict:
        raise URLError("[Errno -3] Temporary failure in name resolution")

    monkeypatch.setattr(WeightsEnum, "get_state_dict", offline)
    with pytest.raises(WeightsUnavailable) as info:
        TorchvisionDetector("ssdlite320_mobilenet_v3_large", weights="coco", device="cpu")
    message = str(info.value)
    assert "\n" not in message and info.value.__cause__ is None
    assert message.startswith("detector.weights: cannot download SSDLite320_MobileNet_V3_Large_Weights.COCO_V1")
    assert "this machine cannot download" in message and "checkpoints" in message


def test_torchvision_bad_keys_are_named() -> None:
    with pytest.raises(ConfigError, match=r"detector\.model='yolo': not a torchvision detection model"):
        TorchvisionDetector("yolo", weights=None)
    with pytest.raises(ConfigError, match=r"detector\.nms_iou=0"):
        TorchvisionDetector(weights=None, nms_iou=0)
    if not torch.cuda.is_available():
        with pytest.raises(ConfigError, match=r"detector\.device='cuda': CUDA is not available"):
            TorchvisionDetector(weights=None, device="cuda")


# --- configs ---------------------------------------------------------------------------------------------------


def test_detector_configs_build_their_detector(tmp_path: Path) -> None:
    from hydra.utils import instantiate
    from omegaconf import OmegaConf

    configs = Path(__file__).resolve().parents[1] / "configs" / "detector"
    path = _write(tmp_path, [_entry(3, [1, 2, 3, 4])])
    overrides = {
        "gt": {"jitter": 0.05},
        "file": {"path": str(path)},
        "torchvision": {"weights": None, "model": "ssdlite320_mobilenet_v3_large", "device": "cpu"},
    }
    built = {
        name: instantiate(OmegaConf.merge(OmegaConf.load(configs / f"{name}.yaml"), keys))
        for name, keys in overrides.items()
    }
    assert isinstance(built["gt"], GroundTruthDetector) and built["gt"].jitter == 0.05
    assert isinstance(built["file"], FileDetector) and len(built["file"].boxes_of(3)) == 1
    assert isinstance(built["torchvision"], TorchvisionDetector) and built["torchvision"].nms_iou == 0.5
    assert [d.needs_images for d in built.values()] == [False, False, True]
