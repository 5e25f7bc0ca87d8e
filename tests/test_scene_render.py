"""Rendered synthetic scenes (dataset=synthetic render=true): deterministic images at the calibration size whose
ground-truth 2D agrees with the projection and the painting, constant looks, COCO round trips."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from data.datasets.synthetic import load_synthetic
from data.geometry.calibration import load_rig
from data.image_ids import coco_image_id
from data.multiview import ViewDetections
from data.pose2d.coco_eval import evaluate_keypoints
from data.pose2d.render import PART_GROUPS, SHIRT
from data.pose2d.scene_render import Scene, render_view
from data.pose2d.view_coco import ground_truth_document, results
from data.synthetic import SyntheticConfig, generate_sequence
from reconstruction.matching import OracleMatcher
from reconstruction.pipeline import MultiViewPipeline
from reconstruction.reconstructors import VanillaTriangulation

SMALL = dict(num_frames=3, num_persons=6, num_cameras=4, image_size=(320, 200), focal_px=280.0)


@pytest.fixture(scope="module")
def rendered():
    return load_synthetic(render=True, seed=1, **SMALL)


def test_same_seed_same_images_other_seed_other_look(rendered):
    again = load_synthetic(render=True, seed=1, **SMALL)
    other = load_synthetic(render=True, render_seed=2, seed=1, **SMALL)
    for a, b, c in zip(rendered.frames[0].images(), again.frames[0].images(), other.frames[0].images()):
        np.testing.assert_array_equal(a, b)
        assert np.mean(np.abs(a.astype(int) - c)) > 10
    # the scene is the scene seed's: the other render seed paints the same persons in the same places
    for a, c in zip(rendered.frames[0].views, other.frames[0].views):
        np.testing.assert_array_equal(np.sort(a.person_ids), np.sort(c.person_ids))


def test_render_false_is_the_plain_synthetic_sequence(rendered):
    plain = load_synthetic(seed=1, **SMALL)
    reference = generate_sequence(SyntheticConfig(seed=1, **SMALL))
    for a, b, r in zip(plain.frames, reference.frames, rendered.frames):
        assert a.images is None and a.image_ids is None
        for va, vb in zip(a.views, b.views):
            np.testing.assert_array_equal(va.keypoints, vb.keypoints)
        np.testing.assert_array_equal(a.gt_poses, r.gt_poses)
        np.testing.assert_array_equal(a.gt_ids, r.gt_ids)
    assert plain.description.startswith("Synthetic crowd (seed 1): 6 persons, ring of cameras, 2D noise")
    with pytest.raises(ValueError, match="render='yes' must be true or false"):
        load_synthetic(render="yes", **SMALL)


def test_images_have_the_calibration_size_on_a_real_rig(shared_data):
    rig = load_rig(shared_data / "shelf" / "calibration_shelf.json")
    seq = load_synthetic(
        render=True,
        rig=str(shared_data / "shelf" / "calibration_shelf.json"),
        num_frames=1,
        num_persons=4,
        area=[-1, 1, -1, 1],
    )
    images = seq.frames[0].images()
    assert [im.shape for im in images] == [(c.size[1], c.size[0], 3) for c in rig] == [(776, 1032, 3)] * 5
    assert sum(len(v) for v in seq.frames[0].views) >= 10


def test_labels_agree_with_the_projection_and_the_painting(rendered):
    seq = rendered
    scene = Scene(seq.rig, 1, seq.area)
    checked = 0
    for frame in seq.frames:
        poses, ids = frame.gt_poses[..., :3], frame.gt_ids
        for v, (cam, view) in enumerate(zip(seq.rig, frame.views)):
            render = render_view(scene, v, frame.index, poses, ids)
            row = {pid: i for i, pid in enumerate(ids)}
            for n, pid in enumerate(view.person_ids):
                labelled = view.keypoints[n, :, 2] > 0
                truth = cam.project(poses[row[pid]])
                np.testing.assert_allclose(view.keypoints[n, labelled, :2], truth[labelled], atol=1e-9)
                seen = labelled & ~view.occluded[n]
                px = np.round(view.keypoints[n, seen, :2]).astype(int)
                owner = (render.owner[px[:, 1], px[:, 0]].astype(int) - 1) // len(PART_GROUPS)
                assert np.all(owner == row[pid])  # a seen joint's pixel is painted by its own person
                x, y, w, h = view.bboxes[n]
                assert np.all((px[:, 0] >= x) & (px[:, 0] < x + w) & (px[:, 1] >= y) & (px[:, 1] < y + h))
                checked += int(seen.sum())
            assert np.all(view.scores == 1) and set(np.unique(view.keypoints[..., 2])) <= {0.0, 1.0}
    assert checked > 300
    assert sum(int(v.occluded.sum()) for f in seq.frames for v in f.views) > 10


def test_a_person_keeps_its_colours_across_views_and_frames(rendered):
    seq = rendered
    scene = Scene(seq.rig, 1, seq.area)
    hues: dict[int, list[float]] = {}
    for frame in seq.frames:
        poses, ids = frame.gt_poses[..., :3], frame.gt_ids
        for v in range(len(seq.rig)):
            render = render_view(scene, v, frame.index, poses, ids)
            hsv = cv2.cvtColor(render.image, cv2.COLOR_BGR2HSV)
            part = render.owner.astype(int) - 1
            shirt = (part >= 0) & (PART_GROUPS[part % len(PART_GROUPS)] == SHIRT)
            for p, pid in enumerate(ids):
                mine = shirt & (part // len(PART_GROUPS) == p)
                mine = cv2.erode(mine.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0  # no anti-aliased edges
                if mine.sum() >= 30:
                    hues.setdefault(int(pid), []).append(_circular_median(hsv[..., 0][mine]))
    spreads = [_circular_spread(h) for h in hues.values() if len(h) >= 3]
    assert len(spreads) >= 4
    assert max(spreads) < 8  # OpenCV hue units (2 degrees)
    medians = [h[0] for h in hues.values()]
    assert max(_circular_spread([a, b]) for a in medians for b in medians) > 20  # persons differ


def _circular_median(hue: np.ndarray) -> float:
    angles = hue.astype(float) * np.pi / 90
    return float(np.angle(np.mean(np.exp(1j * angles))) * 90 / np.pi) % 180


def _circular_spread(values: list[float]) -> float:
    values = np.asarray(values)
    diffs = np.abs(values[:, None] - values[None, :]) % 180
    return float(np.max(np.minimum(diffs, 180 - diffs)))


def test_coco_ground_truth_round_trips_through_evaluate_keypoints(rendered):
    doc = ground_truth_document(rendered.frames, rendered.rig)
    assert len(doc["images"]) == 3 * 4 and doc["images"][5]["id"] == coco_image_id(1, 1, 4)
    flags = np.array([a["keypoints"][2::3] for a in doc["annotations"]])
    assert {1.0, 2.0} <= set(np.unique(flags)) <= {0.0, 1.0, 2.0}
    perfect = evaluate_keypoints(doc, results(rendered.frames, rendered.rig))
    assert perfect["AP"] == pytest.approx(1.0) and perfect["AR"] == pytest.approx(1.0)
    rng = np.random.default_rng(0)
    noisy_views = [
        [ViewDetections(_jitter(v.keypoints, rng, 4.0), v.bboxes, v.scores, v.person_ids) for v in f.views]
        for f in rendered.frames
    ]
    noisy = evaluate_keypoints(doc, results(rendered.frames, rendered.rig, noisy_views))
    assert 0.0 < noisy["AP"] < 0.95


def _jitter(keypoints: np.ndarray, rng: np.random.Generator, sd: float) -> np.ndarray:
    out = keypoints.copy()
    out[..., :2] += rng.normal(0, sd, out[..., :2].shape)
    return out


def test_ground_truth_views_triangulate_to_the_3d_ground_truth(rendered):
    pipeline = MultiViewPipeline(rendered.rig, OracleMatcher(min_views=2), VanillaTriangulation(min_views=2))
    for frame in rendered.frames:
        result = pipeline(frame)
        for pose in result.poses3d:
            if np.count_nonzero(pose[:, 3] > 0) < 10:
                continue
            gap = np.linalg.norm(frame.gt_poses[..., :3] - pose[None, :, :3], axis=-1)
            best = np.argmin(np.nanmean(np.where(pose[:, 3] > 0, gap, np.nan), axis=1))
            assert np.max(gap[best][pose[:, 3] > 0]) < 1e-6
