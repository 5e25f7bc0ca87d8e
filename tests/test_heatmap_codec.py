import numpy as np
import pytest
import torch

from data.keypoints import FOOT_JOINTS, flip_permutation
from data.pose2d.crop_transforms import crop_affine, flip_keypoints, flip_points, transform_points
from models.heatmap_codec import MultiModalHeatmapCodec

LABELLED = np.ones(23, dtype=bool)
RATIO = np.array([48 / 192, 64 / 256])  # heatmap pixels per input pixel of the default codec


def person(rng: np.random.Generator, low=(0.0, 0.0), high=(191.0, 255.0)) -> np.ndarray:
    """(23, 3) keypoints, uniformly random sub-pixel positions, all labelled (v = 2)."""
    xy = rng.uniform(low, high, size=(23, 2))
    return np.concatenate([xy, np.full((23, 1), 2.0)], axis=1)


def test_gaussian_peaks_at_one_with_sigma_in_heatmap_pixels():
    codec = MultiModalHeatmapCodec(sigma=2.0, mu=0.0)
    own = np.zeros((23, 3))
    own[4] = [*codec.heatmap_to_input([10.0, 20.0]), 1]  # exactly on heatmap pixel (10, 20)
    target, weight = codec.encode(own, np.zeros((0, 23, 3)), LABELLED)
    assert target.shape == (23, 64, 48) and target.dtype == np.float32
    assert target[4, 20, 10] == 1.0
    np.testing.assert_allclose(target[4, 20, 12], np.exp(-4 / 8), rtol=1e-6)
    np.testing.assert_array_equal(weight, np.eye(23)[4])
    assert np.all(target[np.arange(23) != 4] == 0)


@pytest.mark.parametrize("modulate", [False, True])
def test_round_trip_within_half_a_heatmap_pixel(modulate):
    rng = np.random.default_rng(0)
    codec = MultiModalHeatmapCodec(mu=0.0)
    people = [person(rng, (-0.5, -0.5), (191.5, 255.5)) for _ in range(6)]
    targets = np.stack([codec.encode(p, np.zeros((0, 23, 3)), LABELLED)[0] for p in people])
    keypoints, scores = codec.decode(torch.from_numpy(targets), modulate=modulate)
    assert keypoints.shape == (6, 23, 2) and scores.shape == (6, 23)
    # Euclidean distance in heatmap pixels: the integer argmax alone is up to 0.71 px off, so this fails
    # without the sub-pixel step (border joints, where no step is possible, stay within 0.5 px)
    error = np.linalg.norm((keypoints - np.stack(people)[..., :2]) * RATIO, axis=-1)
    assert error.max() <= 0.5
    assert scores.min() > 0.88  # the peak's value, at most half a pixel off the centre


def test_newton_step_is_exact_for_interior_gaussians():
    rng = np.random.default_rng(1)
    codec = MultiModalHeatmapCodec(mu=0.0)
    own = person(rng, (8.0, 8.0), (183.0, 247.0))  # argmax at least one heatmap pixel from the border
    target, _ = codec.encode(own, np.zeros((0, 23, 3)), LABELLED)
    keypoints, _ = codec.decode(target, modulate=False)
    np.testing.assert_allclose(keypoints * RATIO, own[:, :2] * RATIO, atol=1e-3)


@pytest.mark.parametrize("mu", [0.25, 0.5, 1.0])
def test_mu_zero_is_the_single_person_target_and_mu_adds_max_of_others(mu):
    rng = np.random.default_rng(2)
    own, others = person(rng), np.stack([person(rng), person(rng), person(rng)])
    plain = MultiModalHeatmapCodec(mu=0.0)
    single, _ = plain.encode(own, np.zeros((0, 23, 3)), LABELLED)
    with_others, _ = plain.encode(own, others, LABELLED)
    np.testing.assert_array_equal(with_others, single)
    multi, _ = MultiModalHeatmapCodec(mu=mu).encode(own, others, LABELLED)
    each = np.stack([plain.encode(o, np.zeros((0, 23, 3)), LABELLED)[0] for o in others])
    np.testing.assert_allclose(multi - single, mu * each.max(axis=0), atol=1e-6)
    assert multi.max() <= 1 + mu + 1e-6


def test_others_combine_by_maximum_not_sum():
    codec = MultiModalHeatmapCodec(mu=0.5)
    own = np.zeros((23, 3))
    other = np.zeros((23, 3))
    other[0] = [101.5, 121.5, 2]  # on heatmap pixel (25, 30)
    one, _ = codec.encode(own, other[None], LABELLED)
    two, _ = codec.encode(own, np.stack([other, other]), LABELLED)
    np.testing.assert_array_equal(two, one)
    assert one.max() == pytest.approx(0.5, abs=0.01)  # mu times a unit peak, not 1.0
    near = other.copy()
    near[0, 0] += 6.0  # 1.5 heatmap pixels apart: the Gaussians overlap
    both, _ = codec.encode(own, np.stack([other, near]), LABELLED)
    apart, _ = codec.encode(own, near[None], LABELLED)
    np.testing.assert_allclose(both[0], np.maximum(one[0], apart[0]), atol=1e-7)
    assert np.any(both[0] < one[0] + apart[0] - 1e-3)


def test_weighting_rule():
    codec = MultiModalHeatmapCodec(mu=0.5)
    own, other = np.zeros((23, 3)), np.zeros((23, 3))
    own[0] = [50.0, 60.0, 2]  # own present
    own[1] = [50.0, 60.0, 0]  # own unlabelled, another person's present -> 1
    other[1] = [80.0, 90.0, 2]
    own[2] = [500.0, 60.0, 2]  # own off the crop, nobody else -> 0
    own[3] = [-40.0, 60.0, 2]  # own off the crop, another person's present -> 1
    other[3] = [20.0, 30.0, 1]
    other[4] = [-20.0, 30.0, 2]  # only another person's, off the crop -> 0
    own[5], other[5] = [50.0, 60.0, 2], [60.0, 60.0, 2]  # the dataset does not label joint 5 -> 0
    labelled = LABELLED.copy()
    labelled[5] = False
    target, weight = codec.encode(own, other[None], labelled)
    np.testing.assert_array_equal(weight[:6], [1, 1, 0, 1, 0, 0])
    assert np.all(weight[6:] == 0)
    assert target[1].max() == pytest.approx(0.5, abs=0.01)  # only mu C: "not my joint"
    assert np.all(target[[2, 4, 5]] == 0)


def test_encode_crop_transforms_everyone_and_leaves_input_alone():
    rng = np.random.default_rng(3)
    codec = MultiModalHeatmapCodec(mu=0.5)
    image_kps = np.stack([person(rng, (200, 100), (300, 300)) for _ in range(3)])
    before = image_kps.copy()
    affine = crop_affine(np.array([250.0, 200.0]), np.array([150.0, 200.0]), 15.0, codec.input_size)
    target, weight = codec.encode_crop(image_kps, 1, affine, LABELLED)
    crop_kps = image_kps.copy()
    crop_kps[..., :2] = transform_points(image_kps[..., :2], affine)
    expected, expected_weight = codec.encode(crop_kps[1], crop_kps[[0, 2]], LABELLED)
    np.testing.assert_array_equal(target, expected)
    np.testing.assert_array_equal(weight, expected_weight)
    np.testing.assert_array_equal(image_kps, before)


@pytest.mark.parametrize("rotation", [0.0, 20.0])
def test_flipped_image_gives_mirrored_target_with_swapped_channels(rotation):
    rng = np.random.default_rng(4)
    codec, width = MultiModalHeatmapCodec(mu=0.5), 640
    image_kps = np.stack([person(rng, (250, 150), (350, 400)), person(rng, (280, 150), (380, 400))])
    image_kps[0, 18, 2] = 0  # an unlabelled own foot joint: its channel is mu C only
    center, scale = np.array([300.3, 270.6]), np.array([180.0, 240.0])
    affine = crop_affine(center, scale, rotation, codec.input_size)
    target, weight = codec.encode_crop(image_kps, 0, affine, LABELLED)
    flipped_affine = crop_affine(flip_points(center, width), scale, -rotation, codec.input_size)
    flipped, flipped_weight = codec.encode_crop(flip_keypoints(image_kps, width), 0, flipped_affine, LABELLED)
    perm = flip_permutation()
    np.testing.assert_allclose(flipped, target[perm, :, ::-1], atol=1e-6)
    np.testing.assert_array_equal(flipped_weight, weight[perm])
    np.testing.assert_allclose(flipped[20, :, ::-1], target[17], atol=1e-6)  # left big toe -> right
    assert weight[list(FOOT_JOINTS)].sum() > 0 and target[17].max() > 0.9


def test_decode_of_empty_heatmap_is_finite_with_zero_score():
    codec = MultiModalHeatmapCodec()
    keypoints, scores = codec.decode(np.zeros((2, 23, 64, 48), dtype=np.float32))
    assert np.all(np.isfinite(keypoints)) and np.all(scores == 0)


def test_modulation_helps_on_noisy_heatmaps():
    rng = np.random.default_rng(5)
    codec = MultiModalHeatmapCodec(mu=0.0)
    people = np.stack([person(rng, (30.0, 30.0), (161.0, 225.0)) for _ in range(20)])
    targets = np.stack([codec.encode(p, np.zeros((0, 23, 3)), LABELLED)[0] for p in people])
    noisy = targets + rng.normal(0.0, 0.03, targets.shape)
    errors = [np.linalg.norm(codec.decode(noisy, modulate=m)[0] - people[..., :2], axis=-1) for m in (False, True)]
    rms_raw, rms_modulated = (np.sqrt(np.mean(e**2)) for e in errors)
    assert rms_modulated < 0.7 * rms_raw
