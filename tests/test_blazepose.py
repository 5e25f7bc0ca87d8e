"""pose2d=blazepose and detector=blazepose (MediaPipe's TFLite models from the optional requirements-models.txt):
crop geometry, decoding, and, where the models are installed, COCO-WholeBody AP and Shelf's real images to 3D."""

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
from omegaconf import OmegaConf

from data.config_checks import ConfigError
from data.datasets.shelf import load_shelf
from data.keypoints import BLAZEPOSE33_NAMES, BLAZEPOSE33_TO_COCO23, COCO23_NAMES, flip_permutation
from data.pose2d.coco_eval import evaluate_keypoints
from data.pose2d.coco_keypoints import load_coco_wholebody
from models.blazepose import LEFT_RIGHT, aligned_rois, crop_to_image, refine_from_heatmap
from models.detectors.blazepose_detector import ssd_anchors, tiles
from models.front_end import Pose2DFrontEnd
from models.tflite_models import INSTALL, interpreter_class, mediapipe_model


def models_installed() -> bool:
    """Whether the optional BlazePose files and a TFLite runtime are installed."""
    try:
        mediapipe_model("pose_landmark_full", "test")
        interpreter_class("test")
    except ConfigError:
        return False
    return True


needs_models = pytest.mark.skipif(not models_installed(), reason=f"optional BlazePose models not installed: {INSTALL}")


class BoxesOnly:
    """A pose2d stand-in that needs person boxes (for the front end's checks)."""

    needs_boxes = True

    def __call__(self, images, boxes):
        raise AssertionError("not run")


def test_crop_geometry_puts_the_body_upright():
    centre, extent = np.array([[400.0, 300.0]]), np.array([[460.0, 220.0]])  # extent up and to the right: tilted
    roi = aligned_rois(centre, extent, 1.25)[0]
    to_image = crop_to_image(roi, 256)
    to_crop = cv2.invertAffineTransform(to_image)
    c, e = (to_crop[:, :2] @ p[0] + to_crop[:, 2] for p in (centre, extent))
    np.testing.assert_allclose(c, [128, 128], atol=1e-9)
    np.testing.assert_allclose(e, [128, 128 - 256 / (2 * 1.25)], atol=1e-9)  # straight above, at the crop's scale
    back = to_image[:, :2] @ e + to_image[:, 2]
    np.testing.assert_allclose(back, extent[0], atol=1e-9)


def test_left_right_and_coco23_maps_follow_the_names():
    # MediaPipe's landmark indices: eye inner 1 / 4, mouth 9 / 10, shoulders 11 / 12, foot index 31 / 32; nose and the
    # two auxiliary landmarks (33, 34) stay
    for a, b in ((1, 4), (2, 5), (3, 6), (7, 8), (9, 10), (11, 12), (23, 24), (29, 30), (31, 32)):
        assert LEFT_RIGHT[a] == b and LEFT_RIGHT[b] == a
    assert LEFT_RIGHT[0] == 0 and LEFT_RIGHT[33] == 33 and LEFT_RIGHT[34] == 34
    assert BLAZEPOSE33_NAMES[9:11] == ("mouth_left", "mouth_right") and len(BLAZEPOSE33_NAMES) == 33
    np.testing.assert_array_equal(LEFT_RIGHT[LEFT_RIGHT], np.arange(len(LEFT_RIGHT)))
    missing = [COCO23_NAMES[j] for j in np.flatnonzero(BLAZEPOSE33_TO_COCO23 < 0)]
    assert missing == ["left_small_toe", "right_small_toe"]  # documented: score 0


def test_heatmap_refinement_is_the_windowed_sigmoid_mean():
    rng = np.random.default_rng(0)
    heatmaps = rng.normal(0.0, 2.0, (2, 64, 64, 5))
    xy = rng.uniform(0, 256, (2, 5, 2))
    got = refine_from_heatmap(xy, heatmaps, 256)
    for b in range(2):
        for j in range(5):
            col, row = (int(v // 4) for v in xy[b, j])
            rows, cols = np.clip(np.arange(row - 3, row + 4), 0, 63), np.clip(np.arange(col - 3, col + 4), 0, 63)
            conf = 1 / (1 + np.exp(-heatmaps[b][np.ix_(rows, cols)][:, :, j]))
            want = xy[b, j]
            if conf.max() >= 0.5:
                want = np.array([(conf * cols[None, :]).sum(), (conf * rows[:, None]).sum()]) / conf.sum() * 4
            np.testing.assert_allclose(got[b, j], want, atol=1e-9)


def test_detector_anchors_and_windows_cover_the_image():
    assert len(ssd_anchors(224)) == 2254  # the model's output count
    for width, height in ((1032, 776), (1920, 1080), (720, 1280)):
        for grid in (1, 2, 3):
            covered = np.zeros((height, width), bool)
            for x, y, side in tiles(width, height, (grid,), 0.5):
                covered[max(y, 0) : y + side, max(x, 0) : x + side] = True
            assert covered.all(), (width, height, grid)


def test_a_missing_package_stops_with_the_pip_command(monkeypatch):
    monkeypatch.setattr("importlib.util.find_spec", lambda name: None)
    with pytest.raises(ConfigError, match="pip install --no-deps -r requirements-models.txt"):
        mediapipe_model("pose_landmark_full", "pose2d=blazepose")


def test_detector_gt_on_images_without_ground_truth_stops(shared_data):
    sequence = load_shelf(shared_data / "shelf", images="images_000572", frames=[572])
    cfg = OmegaConf.create(
        {
            "pose2d": {"_target_": f"{__name__}.BoxesOnly"},
            "detector": {"_target_": "models.detectors.GroundTruthDetector"},
        }
    )
    with pytest.raises(ConfigError, match="detector=gt: .* no ground-truth persons"):
        Pose2DFrontEnd.from_config(cfg, sequence)


@needs_models
def test_coco_wholebody_body_ap_with_ground_truth_boxes(shared_data):
    from models.blazepose import BlazePose

    root = shared_data / "coco_wholebody_sample"
    records = load_coco_wholebody(root / "test_coco_wholebody.json", root)
    stage, predictions = BlazePose(), []
    for record in records:
        boxes = np.column_stack([record.boxes, np.ones(len(record.boxes))])
        view = stage([cv2.imread(str(record.file))], [boxes])[0]
        assert np.all(view.keypoints[:, [18, 21], 2] == 0)  # no small toes
        predictions += [
            {"image_id": record.image_id, "keypoints": k.ravel().tolist(), "score": s}
            for k, s in zip(view.keypoints, view.scores)
        ]
    body, foot = (evaluate_keypoints(records, predictions, s)["AP"] for s in ("body", "foot"))
    assert body >= 0.45, body
    assert foot > 0.05, foot


@needs_models
def test_flip_test_is_mirror_symmetric(shared_data):
    from models.blazepose import BlazePose

    image = cv2.imread(str(shared_data / "coco_wholebody_sample" / "000000040083.jpg"))
    doc = json.loads(Path(shared_data / "coco_wholebody_sample" / "test_coco_wholebody.json").read_text())
    box = next(a["bbox"] for a in doc["annotations"] if a["image_id"] == 40083 and a["num_keypoints"] > 10)
    x, y, w, h = box
    mirrored_box = [image.shape[1] - x - w, y, w, h]
    stage = BlazePose(passes=1, refine=False)
    pose = stage([image], [np.array([[*box, 1.0]])])[0].keypoints[0]
    other = stage([image[:, ::-1].copy()], [np.array([[*mirrored_box, 1.0]])])[0].keypoints[0]
    other = other[flip_permutation()]
    other[:, 0] = image.shape[1] - other[:, 0]
    seen = (pose[:, 2] > 0) & (other[:, 2] > 0)
    assert np.median(np.linalg.norm(pose[seen, :2] - other[seen, :2], axis=1)) < 0.02 * max(w, h)


@needs_models
def test_shelf_real_images_to_3d_within_10_pcp_of_the_shipped_openpose(shared_data):
    from benchmarks.real_images import SHELF_572, SHELF_ROWS, run_report

    pcp, reports = {}, {}
    for name, overrides in SHELF_ROWS.items():
        reports[name] = run_report([*SHELF_572, f"paths.data_dir={shared_data}", *overrides])
        ours = reports[name].protocols["shelf"]["ours"]
        pcp[name] = ours["strict"]["average"]["average"]
        found = ours["lenient"]["actors"]  # lenient counts the frames where the actor has a prediction
        assert found[1]["frames"] == found[3]["frames"] == 1, name
    openpose, images, uncompleted = pcp.values()
    assert images >= openpose - 10 and images >= uncompleted, pcp
    report = list(reports.values())[1]
    # dataset=images on the same files and calibration (README's command) gives the same 3D poses
    shelf = f"{shared_data}/shelf"
    plain = run_report(
        [
            "dataset=images",
            f"dataset.cameras={shelf}/4d_association/calibration.json",
            f"dataset.images={shelf}/images_000572",
            "dataset.pattern='cam{i}.png'",
            "pose2d=blazepose",
            "detector=blazepose",
        ]
    )
    np.testing.assert_array_equal(plain.results[0].poses3d, report.results[0].poses3d)
