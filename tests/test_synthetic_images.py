"""Synthetic crowded images: determinism, COCO-23 annotations, labels that match what is drawn."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from data.pose2d.coco_keypoints import load_coco23
from data.pose2d.synthetic_images import ImageOptions, generate_dataset, image_rng, main, save_preview, synthetic_image

SMALL = ImageOptions(size=(192, 144), persons=(3, 6))


def test_same_seed_same_dataset(tmp_path):
    a = generate_dataset(tmp_path / "a", 2, seed=7, options=SMALL, progress=False)
    b = generate_dataset(tmp_path / "b", 2, seed=7, options=SMALL, progress=False)
    c = generate_dataset(tmp_path / "c", 2, seed=8, options=SMALL, progress=False)
    assert a.read_bytes() == b.read_bytes()
    assert a.read_bytes() != c.read_bytes()
    for name in ("000000.jpg", "000001.jpg"):
        image_a = cv2.imread(str(tmp_path / "a" / "images" / name))
        np.testing.assert_array_equal(image_a, cv2.imread(str(tmp_path / "b" / "images" / name)))
        assert image_a.shape == (144, 192, 3)


def test_annotations_load_and_match_the_renderer(tmp_path):
    ann = generate_dataset(tmp_path, 2, seed=3, options=SMALL, progress=False)
    records = load_coco23(ann, tmp_path / "images")
    assert [r.image_id for r in records] == [1, 2]
    for i, record in enumerate(records):
        assert record.file.is_file() and (record.width, record.height) == (192, 144)
        sample = synthetic_image(image_rng(3, i), SMALL)
        np.testing.assert_allclose(record.keypoints, sample.keypoints)
        np.testing.assert_allclose(record.areas, record.boxes[:, 2] * record.boxes[:, 3])
        assert 1 <= len(record) <= 6


@pytest.mark.parametrize("index", range(3))
def test_visible_joints_are_drawn_in_their_box(index):
    sample = synthetic_image(image_rng(11, index), ImageOptions(persons=(8, 12)), with_background=True)
    h, w = sample.image.shape[:2]
    kps, boxes = sample.keypoints, sample.boxes
    seen = kps[..., 2] == 2
    assert seen.sum() > 20
    x, y = kps[seen][:, 0], kps[seen][:, 1]
    assert np.all((x >= 0) & (x <= w - 1) & (y >= 0) & (y <= h - 1))
    px, py = np.round(x).astype(int), np.round(y).astype(int)
    diff = np.abs(sample.image[py, px].astype(int) - sample.background[py, px].astype(int)).sum(axis=1)
    assert np.all(diff > 0) and np.mean(diff > 15) > 0.9
    box = np.repeat(boxes[:, None], kps.shape[1], axis=1)[seen]
    assert np.all((x >= box[:, 0] - 1) & (x <= box[:, 0] + box[:, 2] + 1))
    assert np.all((y >= box[:, 1] - 1) & (y <= box[:, 1] + box[:, 3] + 1))
    outside = kps[..., 2] == 0
    assert np.all(kps[outside][:, :2] == 0)


def test_crowds_have_occluded_joints():
    hidden = [
        np.sum(synthetic_image(image_rng(5, i), ImageOptions(persons=(12, 12))).keypoints[..., 2] == 1)
        for i in range(2)
    ]
    assert min(hidden) > 10


def test_cli_and_preview(tmp_path, capsys):
    out = tmp_path / "set"
    main(["--out", str(out), "--num-images", "2", "--seed", "1", "--size", "160x120", "--persons", "2", "4"])
    assert len(load_coco23(out / "annotations.json", out / "images")) == 2
    png = save_preview(tmp_path / "preview.png", out / "annotations.json", out / "images", count=2, columns=2)
    assert cv2.imread(str(png)).shape == (120, 320, 3)
    with pytest.raises(SystemExit):
        main(["--out", str(out), "--num-images", "1", "--persons", "5", "2"])
