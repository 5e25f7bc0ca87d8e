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
    assert kp.COCO23_NAMES[perm[kp.JOINT_INDEX["left_big_toe"]]] == "right_big_toe"


def test_bones_and_limbs_connect_valid_joints():
    for a, b in [*kp.BONES.values(), *kp.LIMBS]:
        assert 0 <= a < 23 and 0 <= b < 23 and a != b


# COCO's published 17-keypoint order (person_keypoints annotations' "keypoints" list).
COCO17 = (
    "nose left_eye right_eye left_ear right_ear left_shoulder right_shoulder left_elbow right_elbow left_wrist"
    " right_wrist left_hip right_hip left_knee right_knee left_ankle right_ankle".split()
)


def test_names_round_trip_and_coco17_order():
    assert kp.COCO23_NAMES[:17] == tuple(COCO17)
    assert kp.JOINT_INDEX["nose"] == 0 and kp.JOINT_INDEX["right_heel"] == 22
    assert kp.FLIP_PAIRS == (
        (1, 2),
        (3, 4),
        (5, 6),
        (7, 8),
        (9, 10),
        (11, 12),
        (13, 14),
        (15, 16),
        (17, 20),
        (18, 21),
        (19, 22),
    )
    assert (kp.LEFT_FOOT, kp.RIGHT_FOOT, kp.LEFT_ANKLE, kp.RIGHT_ANKLE) == ((17, 18, 19), (20, 21, 22), 15, 16)
    assert kp.JOINT_GROUPS["head"] == (0, 1, 2, 3, 4) and kp.JOINT_GROUPS["knee"] == (13, 14)
    assert kp.BONES["left_heel_big_toe"] == (19, 17) and kp.LIMBS[:3] == ((15, 13), (13, 11), (16, 14))


def test_derived_maps_equal_the_published_orders():
    """The maps derived from the names equal the integer orders of the formats' documentation."""
    n = -1
    published = {
        "BODY25_TO_COCO23": [0, 16, 15, 18, 17, 5, 2, 6, 3, 7, 4, 12, 9, 13, 10, 14, 11, 19, 20, 21, 22, 23, 24],
        "PANOPTIC19_TO_COCO23": [1, 15, 17, 16, 18, 3, 9, 4, 10, 5, 11, 6, 12, 7, 13, 8, 14, n, n, n, n, n, n],
        "SHELF14_TO_COCO23": [n, n, n, n, n, 9, 8, 10, 7, 11, 6, 3, 2, 4, 1, 5, 0, n, n, n, n, n, n],
        "CROWDPOSE14_TO_COCO23": [n, n, n, n, n, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, n, n, n, n, n, n],
        "COCO17_TO_COCO23": [*range(17), n, n, n, n, n, n],
        "COCO23_TO_SHELF14_LIMBS": [16, 14, 12, 11, 13, 15, 10, 8, 6, 5, 7, 9],
    }
    for name, order in published.items():
        np.testing.assert_array_equal(getattr(kp, name), order, err_msg=name)
    assert kp.SHELF_PCP_PARTS["upper_arms"] == ((8, 7), (9, 10)) and kp.SHELF_PCP_PARTS["torso"] == ((14, 12),)
    assert kp.SHELF15_SOURCES[12] == (0, 3, 4, 5, 6) and kp.SHELF15_SOURCES[14] == (11, 12)


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
