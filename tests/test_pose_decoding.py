"""The batched decoding (torch candidates, vectorised association) against the numpy loop it replaced
(tests/oracles/decoding.py), on random heatmaps and on real-ish ones (multi-modal targets of real
COCO-WholeBody crowds, plus noise)."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from torch.utils.data import DataLoader

from data.keypoints import NUM_JOINTS
from data.pose2d.coco_keypoints import load_coco_wholebody
from data.pose2d.topdown_dataset import TopDownDataset
from models.candidates import candidates_to_image, find_candidates
from models.heatmap_codec import MultiModalHeatmapCodec
from models.joint_association import associate_joints
from models.pose_decoding import associate_by_image, joint_candidates
from tests.oracles import decoding as reference


@pytest.fixture(scope="module")
def realish(shared_data) -> tuple[torch.Tensor, dict]:
    """Multi-modal targets (mu = 0.5: every crop also peaks at its neighbours' joints) of the real COCO-WholeBody
    sample's persons, with uniform noise, float32 as a network gives them; and the batch."""
    folder = shared_data / "coco_wholebody_sample"
    records = load_coco_wholebody(folder / "test_coco_wholebody.json", folder)
    codec = MultiModalHeatmapCodec((192, 256), (48, 64), sigma=2.0, mu=0.5)
    batch = next(iter(DataLoader(TopDownDataset(records, codec, (192, 256), train=False), batch_size=64)))
    noise = torch.from_numpy(np.random.default_rng(0).uniform(0, 0.05, batch["target"].shape).astype(np.float32))
    return batch["target"] + noise, batch


def test_candidates_equal_the_reference_on_random_heatmaps():
    hm = np.random.default_rng(1).uniform(0, 1, (3, NUM_JOINTS, 16, 12)).astype(np.float32)
    xy, scores = find_candidates(torch.from_numpy(hm), threshold=0.2, top_m=5)
    ref_xy, ref_scores = reference.find_candidates(hm, threshold=0.2, top_m=5)
    np.testing.assert_array_equal(scores.numpy(), ref_scores)
    np.testing.assert_allclose(xy.numpy(), ref_xy, rtol=0, atol=1e-12)
    assert (ref_scores > 0).sum() > 100  # many candidates compared


def test_candidates_and_association_equal_the_reference_on_realish_heatmaps(realish):
    heatmaps, batch = realish
    codec = MultiModalHeatmapCodec((192, 256), (48, 64))
    cands = joint_candidates(codec, heatmaps, batch["affine_inv"], threshold=0.1, top_m=3)
    ref_xy, ref_scores = reference.find_candidates(heatmaps, threshold=0.1, top_m=3)
    ref_image = reference.candidates_to_image(ref_xy, batch["affine_inv"].numpy(), 4)
    np.testing.assert_array_equal(cands[..., 2], ref_scores)
    np.testing.assert_allclose(cands[..., :2], ref_image, rtol=0, atol=1e-9)
    assert (np.sum(ref_scores > 0.1, axis=-1) >= 2).any()  # neighbours' peaks: the association has work to do
    boxes, images = batch["box"].numpy(), batch["image_id"].numpy()
    got = associate_by_image(cands, boxes, images)
    for image in np.unique(images):
        here = images == image
        expected = reference.associate_joints(ref_image[here], ref_scores[here], boxes[here])
        np.testing.assert_allclose(got[here], expected, rtol=0, atol=1e-9)


def crowd(rng: np.random.Generator, n: int, m: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """n overlapping persons whose m candidates include neighbours' joints, some slots empty: xy, scores, boxes."""
    joints = rng.uniform(0, 40, (n, NUM_JOINTS, 2)) + np.arange(n)[:, None, None] * 12.0
    others = (np.arange(n)[:, None] + np.arange(m)[None, :]) % max(n, 1)  # slot k: the joint of person p + k
    xy = joints[others].transpose(0, 2, 1, 3) + rng.normal(0, 0.5, (n, NUM_JOINTS, m, 2))
    scores = rng.uniform(0.05, 1.0, (n, NUM_JOINTS, m)) * (rng.random((n, NUM_JOINTS, m)) > 0.2)
    boxes = np.concatenate([joints.min(1), rng.uniform(60, 100, (n, 2))], axis=1)
    return xy, scores, boxes


@pytest.mark.parametrize("n, m", [(0, 3), (1, 3), (2, 1), (6, 3), (15, 4)])
def test_association_equals_the_reference(n, m):
    rng = np.random.default_rng(n * 10 + m)
    for _ in range(3):
        xy, scores, boxes = crowd(rng, n, m)
        copies = xy.copy(), scores.copy(), boxes.copy()
        got = associate_joints(xy, scores, boxes)
        np.testing.assert_array_equal(got, reference.associate_joints(xy, scores, boxes))
        for before, after in zip(copies, (xy, scores, boxes)):
            np.testing.assert_array_equal(before, after)
    if n >= 6:  # the crowd has conflicts: some person lost its best candidate to a neighbour
        assert np.any(got[..., 2] < scores.max(-1))


def test_back_projection_equals_the_reference():
    rng = np.random.default_rng(4)
    xy, affines = rng.uniform(0, 40, (5, NUM_JOINTS, 3, 2)), rng.normal(0, 2, (5, 2, 3))
    got = candidates_to_image(torch.from_numpy(xy), torch.from_numpy(affines), (4.0, 3.5)).numpy()
    np.testing.assert_allclose(got, reference.candidates_to_image(xy, affines, (4.0, 3.5)), rtol=1e-12)


def test_separate_pairs_moves_one_of_two_joints_on_one_spot_to_its_other_candidate():
    from models.pose_decoding import separate_pairs

    kp = np.zeros((1, 23, 3))
    kp[0, :, :2], kp[0, :, 2] = [50.0, 100.0], 0.9
    kp[0, 9], kp[0, 10] = [40.0, 120.0, 0.8], [41.0, 121.0, 0.7]  # both wrists on the left arm
    cands = np.zeros((1, 23, 3, 3))
    cands[0, :, 0] = kp[0]
    cands[0, 10, 1] = [70.0, 120.0, 0.6]  # the right wrist channel's second peak: the other arm
    cands[0, 9, 1] = [300.0, 120.0, 0.9]  # a strong peak outside the box: a neighbour's, never taken
    boxes = np.array([[20.0, 20.0, 80.0, 200.0]])
    out = separate_pairs(kp, cands, boxes)
    np.testing.assert_array_equal(out[0, 10], [70.0, 120.0, 0.6])
    np.testing.assert_array_equal(np.delete(out, 10, axis=1), np.delete(kp, 10, axis=1))
    apart = kp.copy()
    apart[0, 10] = [70.0, 121.0, 0.7]
    np.testing.assert_array_equal(separate_pairs(apart, cands, boxes), apart)  # already apart: unchanged
    lonely = cands.copy()
    lonely[0, 10, 1] = 0.0
    np.testing.assert_array_equal(separate_pairs(kp, lonely, boxes), kp)  # no other candidate: unchanged
    eyes = lonely.copy()
    eyes[0, 2, 1] = [70.0, 100.0, 0.9]  # the right eye channel's strong other peak
    np.testing.assert_array_equal(separate_pairs(kp, eyes, boxes), kp)  # the face's pairs are left alone
