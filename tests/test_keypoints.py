import numpy as np

from data import keypoints as kp


def test_coco23_layout_and_sigmas():
    assert kp.NUM_JOINTS == 23 and len(kp.OKS_SIGMAS) == 23
    assert kp.COCO23_NAMES[17:] == (
        "left_big_toe",
        "left_small_toe",
        "left_heel",
        "right_big_toe",
        "right_small_toe",
        "right_heel",
    )
    np.testing.assert_allclose(kp.OKS_SIGMAS[17:], [0.068, 0.066, 0.066, 0.092, 0.094, 0.094])


def test_flip_pairs_swap_left_and_right_names():
    perm = kp.flip_permutation()
    np.testing.assert_array_equal(perm[perm], np.arange(23))
    for a, b in kp.FLIP_PAIRS:
        assert kp.COCO23_NAMES[a].replace("left", "right") == kp.COCO23_NAMES[b]


def test_bones_and_limbs_connect_valid_joints():
    for a, b in [*kp.BONES.values(), *kp.LIMBS]:
        assert 0 <= a < 23 and 0 <= b < 23 and a != b


BODY25 = [
    "nose",
    "neck",
    "right_shoulder",
    "right_elbow",
    "right_wrist",
    "left_shoulder",
    "left_elbow",
    "left_wrist",
    "mid_hip",
    "right_hip",
    "right_knee",
    "right_ankle",
    "left_hip",
    "left_knee",
    "left_ankle",
    "right_eye",
    "left_eye",
    "right_ear",
    "left_ear",
    "left_big_toe",
    "left_small_toe",
    "left_heel",
    "right_big_toe",
    "right_small_toe",
    "right_heel",
]
PANOPTIC19 = [
    "neck",
    "nose",
    "mid_hip",
    "left_shoulder",
    "left_elbow",
    "left_wrist",
    "left_hip",
    "left_knee",
    "left_ankle",
    "right_shoulder",
    "right_elbow",
    "right_wrist",
    "right_hip",
    "right_knee",
    "right_ankle",
    "left_eye",
    "left_ear",
    "right_eye",
    "right_ear",
]
CROWDPOSE14 = [
    "left_shoulder",
    "right_shoulder",
    "left_elbow",
    "right_elbow",
    "left_wrist",
    "right_wrist",
    "left_hip",
    "right_hip",
    "left_knee",
    "right_knee",
    "left_ankle",
    "right_ankle",
    "head",
    "neck",
]


def test_index_maps_agree_with_joint_names():
    for names, index_map in (
        (BODY25, kp.BODY25_TO_COCO23),
        (PANOPTIC19, kp.PANOPTIC19_TO_COCO23),
        (list(kp.SHELF14_NAMES), kp.SHELF14_TO_COCO23),
        (CROWDPOSE14, kp.CROWDPOSE14_TO_COCO23),
    ):
        for j, src in enumerate(index_map):
            if src >= 0:
                assert names[src] == kp.COCO23_NAMES[j]
            else:
                assert kp.COCO23_NAMES[j] not in names


def test_to_coco23_gathers_and_zeroes_missing():
    src = np.arange(25 * 3, dtype=float).reshape(25, 3) + 1
    out = kp.to_coco23(src[None], kp.BODY25_TO_COCO23)[0]
    np.testing.assert_array_equal(out[1], src[16])  # left eye
    pan = kp.to_coco23(np.ones((19, 4)), kp.PANOPTIC19_TO_COCO23)
    assert np.all(pan[17:] == 0) and np.all(pan[:17] == 1)


def test_shelf14_head_construction_known_answer():
    pose = np.zeros((23, 3))
    pose[5], pose[6] = [-0.2, 0, 1.4], [0.2, 0, 1.4]  # shoulders: centre (0, 0, 1.4)
    pose[0] = [0, 0.1, 1.6]  # nose
    pose[3], pose[4] = [-0.08, 0, 1.6], [0.08, 0, 1.6]  # ears: centre (0, 0, 1.6)
    shelf = kp.coco23_to_shelf14(pose)
    # bottom = .75 * (shoulder + .5 (nose - shoulder)) + .25 * (shoulder + ear) / 2
    np.testing.assert_allclose(shelf[12], 0.75 * np.array([0, 0.05, 1.5]) + 0.25 * np.array([0, 0, 1.5]))
    # top = .75 * (shoulder + (.75, .75, 1.5) * (nose - shoulder)) + .25 * (2 ear - ear_bottom)
    np.testing.assert_allclose(shelf[13], 0.75 * np.array([0, 0.075, 1.7]) + 0.25 * np.array([0, 0, 1.7]))
    np.testing.assert_array_equal(shelf[8], pose[6])  # right shoulder
    np.testing.assert_array_equal(shelf[0], pose[16])  # right ankle
    assert kp.with_mid_hip(shelf).shape == (15, 3)
