"""Pictures of a frame: reprojected joints land on their projected pixels in their person's colour,
the four PNGs are written, and the real Shelf frame 572 is drawn where its ground truth projects."""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")

import cv2  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

from data.formats.fourd_skeletons import load_4dassoc_skeletons  # noqa: E402
from data.geometry.calibration import load_4dassoc  # noqa: E402
from data.geometry.camera import Camera, Rig  # noqa: E402
from data.keypoints import LIMBS, SHELF14_TO_COCO23, to_coco23  # noqa: E402
from data.synthetic import SyntheticConfig, generate_sequence  # noqa: E402
from evaluation.pictures.vis_draw import CANVAS_GREY, UNMATCHED_COLOR, image_grid, person_colors  # noqa: E402
from evaluation.pictures.visualize import (  # noqa: E402
    draw_reprojections,
    image_png,
    load_view_images,
    plot_feet_on_ground,
    plot_scene_3d,
    plot_top_view,
    save_frame_pictures,
    save_run_pictures,
    write_png,
)
from reconstruction.matching import FeetMatcher, OracleMatcher  # noqa: E402
from reconstruction.pipeline import MultiViewPipeline  # noqa: E402
from reconstruction.reconstructors import VanillaTriangulation  # noqa: E402

SHELF_FRAME = 572  # gt.txt frame index 272


def _camera(dist=(0.0, 0.0, 0.0, 0.0, 0.0), size=(640, 480)) -> Camera:
    """A camera at (0, -6, 1) looking along +y, world z up."""
    R = np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]])
    K = np.array([[500.0, 0, size[0] / 2], [0, 500, size[1] / 2], [0, 0, 1]])
    return Camera("c", K, np.array(dist), R, -R @ np.array([0.0, -6.0, 1.0]), size)


def _single_joint_poses(points: np.ndarray, joint: int = 0) -> np.ndarray:
    """Poses (P, 23, 4) with only ``joint`` scored, at the given world points (P, 3)."""
    poses = np.zeros((len(points), 23, 4))
    poses[:, joint, :3] = points
    poses[:, joint, 3] = 1.0
    return poses


def _rgb(color) -> np.ndarray:
    return np.round(255 * np.asarray(color)).astype(int)


def test_person_colours_are_distinct_and_never_the_unmatched_grey():
    for n in (2, 10, 18, 30):
        colors = person_colors(n)
        assert colors.shape == (n, 3) and np.all((0 <= colors) & (colors <= 1))
        gaps = np.linalg.norm(colors[:, None] - colors[None], axis=-1) + np.eye(n) * 9
        assert gaps.min() > 0.05
        assert np.all(np.ptp(colors, axis=1) > 0.1)  # no grey
    assert np.allclose(person_colors(5), person_colors(12)[:5])  # person p keeps its colour


def test_a_joint_is_drawn_at_its_distorted_projection_in_its_persons_colour():
    cam = _camera(dist=(-0.3, 0.1, 0.0, 0.0, 0.0))
    points = np.array([[-2.8, 0.0, -0.2], [2.6, 1.0, 2.4]])  # far from the centre: distortion > 8 px
    out = draw_reprojections([None], Rig((cam,)), _single_joint_poses(points))[0]
    assert out.shape == (480, 640, 3) and out.dtype == np.uint8
    for point, color in zip(points, person_colors(2)):
        u, v = np.round(cam.project(point)).astype(int)
        assert np.array_equal(out[v, u], _rgb(color))
        und = np.round(cam.undistort_points(cam.project(point))).astype(int)
        assert np.linalg.norm(und - [u, v]) > 8 and np.all(out[und[1], und[0]] == CANVAS_GREY)
    drawn = np.any(out != CANVAS_GREY, axis=-1)
    assert 10 < drawn.sum() < 400  # two dots, nothing else


def test_scale_moves_the_drawing_onto_a_resized_image_and_caller_images_stay_untouched():
    cam = _camera()
    image = np.zeros((240, 1280, 3), dtype=np.uint8)  # camera 640x480 stretched by (2, 0.5)
    point = np.array([[0.8, 0.5, 1.4]])
    out = draw_reprojections([image], Rig((cam,)), _single_joint_poses(point), image_scale=[(2.0, 0.5)])[0]
    u, v = np.round(cam.project(point[0]) * [2.0, 0.5]).astype(int)
    assert np.array_equal(out[v, u], _rgb(person_colors(1)[0]))
    assert not image.any() and out.shape == image.shape


def test_joints_with_score_zero_or_behind_the_camera_are_skipped_and_limbs_join_joints():
    cam = _camera()
    poses = np.zeros((1, 23, 4))
    poses[0, :, :3] = [0.0, 0.0, 1.0]
    poses[0, 5, :] = [-0.2, 0.0, 1.4, 1.0]  # left shoulder
    poses[0, 6, :] = [0.2, 0.0, 1.4, 1.0]  # right shoulder: limb (5, 6)
    poses[0, 0, :] = [0.0, -8.0, 1.0, 1.0]  # nose behind the camera
    out = draw_reprojections([None], Rig((cam,)), poses)[0]
    (u5, v5), (u6, v6) = np.round(cam.project(poses[0, [5, 6], :3])).astype(int)
    assert np.array_equal(out[v5, (u5 + u6) // 2], _rgb(person_colors(1)[0]))  # the limb between them
    drawn = np.argwhere(np.any(out != CANVAS_GREY, axis=-1))
    assert drawn[:, 1].min() >= u5 - 8 and drawn[:, 1].max() <= u6 + 8  # nothing else drawn


@pytest.fixture(scope="module")
def synthetic_frame():
    seq = generate_sequence(
        SyntheticConfig(seed=3, num_frames=1, num_persons=3, density=0.2, image_size=[640, 360], focal_px=500.0)
    )
    result = MultiViewPipeline(seq.rig, OracleMatcher(), VanillaTriangulation())(seq.frames[0])
    return seq, result


def test_save_frame_pictures_writes_the_four_pngs_atomically(tmp_path, synthetic_frame):
    seq, result = synthetic_frame
    assert len(result.poses3d) == 3
    paths = save_frame_pictures(tmp_path, seq, result, seq.frames[0])
    assert [p.name for p in paths] == ["frame_0_views.png", "frame_0_3d.png", "frame_0_top.png", "frame_0_feet.png"]
    images = [cv2.imread(str(p)) for p in paths]
    assert all(im is not None and im.shape[0] > 200 and im.shape[1] > 200 for im in images)
    assert images[0].shape == (2 * 540, 3 * 960, 3)  # 5 views of 640x360 on a 3 x 2 grid of 960 px tiles
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(p.name for p in paths)  # no temporary left
    assert save_run_pictures(tmp_path / "run", seq, [result], frame=0)[0].exists()
    with pytest.raises(ValueError, match="frame 7"):
        save_run_pictures(tmp_path, seq, [result], frame=7)


def test_feet_plot_colours_each_detection_by_its_person_and_unmatched_as_grey_crosses(synthetic_frame):
    seq, result = synthetic_frame
    frame = seq.frames[0]
    assignment = result.assignment.copy()
    lost_person, lost_view = 1, int(np.flatnonzero(assignment[1] >= 0)[0])
    assignment[lost_person, lost_view] = -1
    features = FeetMatcher().features(frame.views, seq.rig)
    ax = plot_feet_on_ground(frame.views, seq.rig, assignment, features).axes[0]
    markers = [ln for ln in ax.lines if ln.get_marker() not in ("None", "^") and len(ln.get_xdata()) == 1]
    crosses = [ln for ln in markers if ln.get_marker() == "x"]
    assert len(markers) == sum(int(f.has_p.sum()) for f in features)
    assert len(crosses) == 1 and np.allclose(crosses[0].get_color(), UNMATCHED_COLOR)
    lost_det = result.assignment[lost_person, lost_view]
    assert np.allclose(np.ravel(crosses[0].get_xydata()), features[lost_view].p[lost_det])
    colors = person_colors(len(assignment))
    p, v = 0, int(np.flatnonzero(assignment[0] >= 0)[0])
    at = features[v].p[assignment[p, v]]
    mine = [ln for ln in markers if np.allclose(np.ravel(ln.get_xydata()), at)]
    assert mine and np.allclose(matplotlib.colors.to_rgb(mine[0].get_color()), colors[0])


def test_3d_and_top_views_draw_estimates_solid_per_person_and_ground_truth_dashed(synthetic_frame):
    seq, result = synthetic_frame
    gt = seq.frames[0].gt_poses
    for fig in (plot_scene_3d(result.poses3d, gt, seq.rig), plot_top_view(result.poses3d, gt, seq.rig)):
        lines = fig.axes[0].lines
        dashed = [ln for ln in lines if ln.get_linestyle() == "--"]
        solid = [ln for ln in lines if ln.get_linestyle() == "-"]
        assert len(dashed) == len(gt) * len(LIMBS)
        assert len(solid) == len(result.poses3d) * len(LIMBS)
        assert len({tuple(matplotlib.colors.to_rgb(ln.get_color())) for ln in solid}) == len(result.poses3d)


def test_load_view_images_scales_by_image_over_camera_size(tmp_path):
    rig = Rig((_camera(size=(100, 50)), Camera("d", np.eye(3), np.zeros(5), np.eye(3), np.ones(3), (10, 10))))
    cv2.imwrite(str(tmp_path / "cam0.png"), np.zeros((100, 300, 3), np.uint8))
    images, scales = load_view_images(tmp_path, rig)
    assert images[0].shape == (100, 300, 3) and images[1] is None
    assert scales == [(3.0, 2.0), (1.0, 1.0)]


def test_shelf_frame_572_ground_truth_lands_inside_the_stretched_images(shared_data, tmp_path):
    shelf = shared_data / "shelf"
    rig = load_4dassoc(shelf / "4d_association" / "calibration.json")
    gt = load_4dassoc_skeletons(shelf / "4d_association" / "gt.txt")[SHELF_FRAME - 300]
    poses = np.stack([to_coco23(person[:14], SHELF14_TO_COCO23) for person in gt.values()])  # (P, 23, 4)
    images, scales = load_view_images(shelf / "images_000572", rig)
    assert np.allclose(scales, [(1920 / 1032, 1080 / 776)] * 5)
    drawn = draw_reprojections(images, rig, poses, scales)
    colors = [_rgb(c) for c in person_colors(len(poses))]
    reach_right = 0
    for v, (cam, image, out) in enumerate(zip(rig, images, drawn)):
        changed = np.argwhere(np.any(out != image, axis=-1))
        assert len(changed) > 500, f"view {v}: nothing drawn"
        (y0, x0), (y1, x1) = changed.min(axis=0), changed.max(axis=0)
        assert y1 < 1080 and x1 < 1920 and x1 - x0 > 100 and y1 - y0 > 150  # persons, not a dot
        reach_right += x1 > 1032 + 50
        for p, pose in enumerate(poses):
            ok = (pose[:, 3] > 0) & cam.in_view(pose[:, :3])
            uv = np.round(cam.project(pose[ok, :3]) * scales[v]).astype(int)
            hits = [np.array_equal(out[y, x], colors[p]) for x, y in uv]
            assert np.mean(hits) > 0.5, f"view {v} person {p}: joints not at their scaled projection"
    assert reach_right >= 2  # without the stretch everything would sit in the top-left 1032 x 776
    path = write_png(tmp_path / "shelf_572_views.png", image_png(image_grid(drawn, rig.names)))
    assert cv2.imread(str(path)).shape == (2 * 540, 3 * 960, 3)
