"""The multi-view training set: every camera's render of the synthetic scene, written with its COCO-23 labels."""

from __future__ import annotations

import cv2
import numpy as np

from data.pose2d.coco_keypoints import load_coco23
from data.pose2d.multiview_images import generate_multiview_dataset, main
from data.pose2d.scene_render import render_sequence
from data.synthetic import SyntheticConfig, generate_sequence


def test_multiview_training_set_holds_the_render_ground_truth(tmp_path):
    cfg = SyntheticConfig(seed=3, num_frames=2, num_persons=5, num_cameras=3, image_size=(256, 160), focal_px=220.0)
    ann = generate_multiview_dataset(tmp_path, cfg, progress=False)
    records = load_coco23(ann, tmp_path / "images")
    seq = render_sequence(generate_sequence(cfg), 3)
    assert [r.image_id for r in records] == [i for f in seq.frames for i in f.image_ids]
    for record, view in zip(records, [v for f in seq.frames for v in f.views]):
        image = cv2.imread(str(record.file))
        assert image.shape == (160, 256, 3) and len(record) == len(view)
        np.testing.assert_allclose(record.keypoints[..., :2], view.keypoints[..., :2], atol=1e-9)
        np.testing.assert_array_equal(record.keypoints[..., 2] == 1, view.occluded)
    main(["--out", str(tmp_path / "cli"), "--num-frames", "1", "--cameras", "2", "--size", "160x100"])
    assert len(load_coco23(tmp_path / "cli" / "annotations.json", tmp_path / "cli" / "images")) == 2
