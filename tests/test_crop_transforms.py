import cv2
import numpy as np
import pytest

from data.keypoints import flip_permutation
from data.pose2d import crop_transforms as ct


def blob_image(width: int, height: int, point: np.ndarray, sigma: float = 3.0) -> np.ndarray:
    """A float32 image with a Gaussian blob centred at the sub-pixel point (pixel centres at integers)."""
    xs, ys = np.meshgrid(np.arange(width), np.arange(height))
    return np.exp(-((xs - point[0]) ** 2 + (ys - point[1]) ** 2) / (2 * sigma**2)).astype(np.float32)


def centroid(image: np.ndarray) -> np.ndarray:
    ys, xs = np.mgrid[: image.shape[0], : image.shape[1]]
    return np.array([(xs * image).sum(), (ys * image).sum()]) / image.sum()


def test_box_to_center_scale_grows_to_aspect_then_pads():
    center, scale = ct.box_to_center_scale(np.array([10.0, 20.0, 30.0, 100.0]), aspect=0.75, padding=1.25)
    np.testing.assert_allclose(center, [25.0, 70.0])
    np.testing.assert_allclose(scale, [75.0 * 1.25, 100.0 * 1.25])  # too narrow: width grows
    _, scale = ct.box_to_center_scale([0, 0, 90, 60], aspect=0.75, padding=1.0)
    np.testing.assert_allclose(scale, [90.0, 120.0])  # too wide: height grows


@pytest.mark.parametrize("rotation", [0.0, 25.0, -130.0])
def test_crop_affine_matches_cv2_get_affine_transform(rotation):
    center, scale, out = np.array([140.3, 95.7]), np.array([90.0, 120.0]), (192, 256)
    affine = ct.crop_affine(center, scale, rotation, out)
    theta = np.deg2rad(rotation)
    # The crop's axes in the image: content turned counter-clockwise = axes turned clockwise (y down).
    right = np.array([np.cos(theta), np.sin(theta)]) * scale[0] / 2
    down = np.array([-np.sin(theta), np.cos(theta)]) * scale[1] / 2
    src = np.float32([center, center + right, center + down])
    dst = np.float32([[95.5, 127.5], [95.5 + 96, 127.5], [95.5, 127.5 + 128]])
    np.testing.assert_allclose(affine, cv2.getAffineTransform(src, dst), atol=1e-3)


def test_crop_rotation_sign_matches_cv2_rotation_matrix():
    center, out = np.array([50.0, 60.0]), (100, 100)
    affine = ct.crop_affine(center, np.array([50.0, 50.0]), 30.0, out)
    reference = cv2.getRotationMatrix2D((50.0, 60.0), 30.0, 2.0)
    np.testing.assert_allclose(affine[:, :2], reference[:, :2], atol=1e-12)
    np.testing.assert_allclose(ct.transform_points(center, affine), [49.5, 49.5])


def test_inverse_affine_round_trip():
    rng = np.random.default_rng(0)
    points = rng.uniform(-50, 400, size=(7, 5, 2))
    args = (np.array([140.3, 95.7]), np.array([90.0, 120.0]), 37.0, (192, 256))
    forward, backward = ct.crop_affine(*args), ct.crop_affine(*args, inverse=True)
    np.testing.assert_allclose(ct.transform_points(ct.transform_points(points, forward), backward), points, atol=1e-9)
    np.testing.assert_allclose(backward, cv2.invertAffineTransform(forward), atol=1e-9)


def test_warped_image_and_transformed_point_agree():
    """cv2.warpAffine of a blob lands where ct.transform_points sends its centre (pixel-centre convention)."""
    point = np.array([123.3, 87.6])
    image = blob_image(320, 240, point, sigma=6.0)
    affine = ct.crop_affine(np.array([130.0, 90.0]), np.array([96.0, 128.0]), 20.0, (96, 128))
    crop = cv2.warpAffine(image, affine, (96, 128), flags=cv2.INTER_LINEAR)
    np.testing.assert_allclose(centroid(crop), ct.transform_points(point, affine), atol=0.02)


def test_flip_keypoints_matches_cv2_flip_and_swaps_sides():
    width, point = 64, np.array([20.3, 23.8])  # blob well inside: centroid unbiased
    flipped_image = cv2.flip(blob_image(width, 48, point), 1)
    keypoints = np.zeros((2, 23, 3))
    keypoints[1, 17] = [*point, 2]  # left big toe of person 1
    keypoints[0, 5] = [3.0, 4.0, 1]
    before = keypoints.copy()
    flipped = ct.flip_keypoints(keypoints, width)
    np.testing.assert_array_equal(keypoints, before)  # caller's array untouched
    np.testing.assert_allclose(flipped[1, 20, :2], centroid(flipped_image), atol=1e-3)  # now the right big toe
    np.testing.assert_allclose(flipped[0, 6], [width - 1 - 3.0, 4.0, 1])
    assert flipped[1, 17, 2] == 0 and np.all(flipped[1, 17, :2] == 0)  # unlabelled stays (0, 0, 0)
    np.testing.assert_allclose(ct.flip_keypoints(flipped, width), keypoints)
    np.testing.assert_allclose(ct.flip_points(ct.flip_points(point, width), width), point)
    assert np.all(flipped[:, flip_permutation(), 2] == keypoints[..., 2])


def test_sample_augmentation_respects_ranges_and_probabilities():
    rng = np.random.default_rng(1)
    settings = ct.CropAugmentation(scale_factor=0.25, rotation_factor=30.0, rotation_prob=0.6, flip_prob=0.5)
    draws = np.array([ct.sample_augmentation(rng, settings) for _ in range(4000)], dtype=np.float64)
    scale, rotation, flip = draws.T
    assert scale.min() >= 0.75 and scale.max() <= 1.25 and scale.std() > 0.1
    assert np.abs(rotation).max() <= 60.0
    assert abs((rotation != 0).mean() - 0.6) < 0.03 and abs(flip.mean() - 0.5) < 0.03
    no_aug = ct.sample_augmentation(rng, ct.CropAugmentation(0.0, 0.0, 0.0, 0.0))
    assert no_aug == (1.0, 0.0, False)


def test_box_shift_and_colour_jitter_known_answers_and_geometry_unchanged():
    from data.pose2d.photometric import JitterDraw, jitter_colour, sample_jitter, shift_box

    box = np.array([10.0, 20.0, 40.0, 80.0])
    moved = shift_box(box, JitterDraw(shift=(0.5, -0.25)))
    np.testing.assert_allclose(moved, [30.0, 0.0, 40.0, 80.0])
    np.testing.assert_allclose(box, [10.0, 20.0, 40.0, 80.0])  # the caller's box is not modified
    rgb = np.full((4, 4, 3), 100, np.uint8)
    np.testing.assert_array_equal(jitter_colour(rgb, JitterDraw(brightness=1.5)), 150)
    np.testing.assert_array_equal(jitter_colour(rgb, JitterDraw()), rgb)
    grey_stays_grey = jitter_colour(rgb, JitterDraw(saturation=2.0, hue_deg=40))
    np.testing.assert_array_equal(grey_stays_grey, rgb)
    red = np.zeros((2, 2, 3), np.uint8)
    red[..., 0] = 200
    hue_turned = jitter_colour(red, JitterDraw(hue_deg=120))  # red -> green
    assert hue_turned[0, 0, 1] > 150 and hue_turned[0, 0, 0] < 30
    draws = [sample_jitter(np.random.default_rng(i), 0.05, 0.2, 10.0) for i in range(500)]
    shifts = np.array([d.shift for d in draws])
    assert np.abs(shifts).max() <= 0.1 + 1e-12 and 0.03 < shifts.std() < 0.06
    assert all(0.8 <= d.brightness <= 1.2 and abs(d.hue_deg) <= 10 for d in draws)
