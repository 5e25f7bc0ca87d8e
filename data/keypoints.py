"""Single source of truth for keypoint metadata: COCO-23 (COCO-17 body + 6 foot joints) and the
index maps from the other skeleton formats this repository reads.

Index maps are *gather* maps: ``coco23[j] = source[MAP[j]]`` where ``MAP[j] >= 0``; joints with
``MAP[j] == -1`` do not exist in the source format and get score 0 (see :func:`to_coco23`).
"""

from __future__ import annotations

import numpy as np

COCO23_NAMES: tuple[str, ...] = (
    "nose",
    "left_eye",
    "right_eye",
    "left_ear",
    "right_ear",
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
    "left_big_toe",
    "left_small_toe",
    "left_heel",
    "right_big_toe",
    "right_small_toe",
    "right_heel",
)
NUM_JOINTS = len(COCO23_NAMES)  # 23
NUM_BODY_JOINTS = 17
JOINT_INDEX: dict[str, int] = {name: i for i, name in enumerate(COCO23_NAMES)}
BODY_JOINTS = tuple(range(NUM_BODY_JOINTS))
FOOT_JOINTS = tuple(range(NUM_BODY_JOINTS, NUM_JOINTS))
LEFT_FOOT = (17, 18, 19)  # big toe, small toe, heel
RIGHT_FOOT = (20, 21, 22)
LEFT_ANKLE, RIGHT_ANKLE = 15, 16

FLIP_PAIRS: tuple[tuple[int, int], ...] = (
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

# OKS sigmas: COCO-17, then the COCO-WholeBody foot sigmas.
OKS_SIGMAS = np.array(
    [
        0.026,
        0.025,
        0.025,
        0.035,
        0.035,
        0.079,
        0.079,
        0.072,
        0.072,
        0.062,
        0.062,
        0.107,
        0.107,
        0.087,
        0.087,
        0.089,
        0.089,
        0.068,
        0.066,
        0.066,
        0.092,
        0.094,
        0.094,
    ]
)

# Limbs drawn in pictures: the COCO skeleton plus heel, big toe and small toe on each foot.
LIMBS: tuple[tuple[int, int], ...] = (
    (15, 13),
    (13, 11),
    (16, 14),
    (14, 12),
    (11, 12),
    (5, 11),
    (6, 12),
    (5, 6),
    (5, 7),
    (6, 8),
    (7, 9),
    (8, 10),
    (1, 2),
    (0, 1),
    (0, 2),
    (1, 3),
    (2, 4),
    (3, 5),
    (4, 6),
    (15, 19),
    (15, 17),
    (17, 18),
    (16, 22),
    (16, 20),
    (20, 21),
)

# Bones of the bone-length prior: segments whose length is fixed for a person.
BONES: dict[str, tuple[int, int]] = {
    "shoulders": (5, 6),
    "hips": (11, 12),
    "left_torso": (5, 11),
    "right_torso": (6, 12),
    "left_upper_arm": (5, 7),
    "right_upper_arm": (6, 8),
    "left_forearm": (7, 9),
    "right_forearm": (8, 10),
    "left_thigh": (11, 13),
    "right_thigh": (12, 14),
    "left_shin": (13, 15),
    "right_shin": (14, 16),
    "left_nose_eye": (0, 1),
    "right_nose_eye": (0, 2),
    "left_eye_ear": (1, 3),
    "right_eye_ear": (2, 4),
    "left_ankle_heel": (15, 19),
    "right_ankle_heel": (16, 22),
    "left_ankle_big_toe": (15, 17),
    "right_ankle_big_toe": (16, 20),
    "left_toes": (17, 18),
    "right_toes": (20, 21),
    "left_heel_big_toe": (19, 17),
    "right_heel_big_toe": (22, 20),
}

# --- index maps into COCO-23 -----------------------------------------------------------------------

# OpenPose BODY_25: 0 Nose 1 Neck 2 RSho 3 RElb 4 RWri 5 LSho 6 LElb 7 LWri 8 MidHip 9 RHip 10 RKnee
# 11 RAnk 12 LHip 13 LKnee 14 LAnk 15 REye 16 LEye 17 REar 18 LEar 19 LBigToe 20 LSmallToe 21 LHeel
# 22 RBigToe 23 RSmallToe 24 RHeel.
BODY25_TO_COCO23 = np.array([0, 16, 15, 18, 17, 5, 2, 6, 3, 7, 4, 12, 9, 13, 10, 14, 11, 19, 20, 21, 22, 23, 24])
# CMU Panoptic coco19: 0 neck 1 nose 2 mid-hip 3 lsho 4 lelb 5 lwri 6 lhip 7 lknee 8 lank 9 rsho
# 10 relb 11 rwri 12 rhip 13 rknee 14 rank 15 leye 16 lear 17 reye 18 rear.
PANOPTIC19_TO_COCO23 = np.array([1, 15, 17, 16, 18, 3, 9, 4, 10, 5, 11, 6, 12, 7, 13, 8, 14, -1, -1, -1, -1, -1, -1])
# Shelf-14: 0 RAnk 1 RKnee 2 RHip 3 LHip 4 LKnee 5 LAnk 6 RWri 7 RElb 8 RSho 9 LSho 10 LElb 11 LWri
# 12 bottom-head (neck) 13 top-head.
SHELF14_NAMES: tuple[str, ...] = (
    "right_ankle",
    "right_knee",
    "right_hip",
    "left_hip",
    "left_knee",
    "left_ankle",
    "right_wrist",
    "right_elbow",
    "right_shoulder",
    "left_shoulder",
    "left_elbow",
    "left_wrist",
    "bottom_head",
    "top_head",
)
SHELF14_TO_COCO23 = np.array([-1, -1, -1, -1, -1, 9, 8, 10, 7, 11, 6, 3, 2, 4, 1, 5, 0, -1, -1, -1, -1, -1, -1])
# CrowdPose-14: 0 LSho 1 RSho 2 LElb 3 RElb 4 LWri 5 RWri 6 LHip 7 RHip 8 LKnee 9 RKnee 10 LAnk
# 11 RAnk 12 head top 13 neck.
CROWDPOSE14_TO_COCO23 = np.array([-1, -1, -1, -1, -1, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, -1, -1, -1, -1, -1, -1])
# COCO-17 (COCO keypoints, torchvision's Keypoint R-CNN): the body joints of COCO-23, no feet.
COCO17_TO_COCO23 = np.array([*range(17), -1, -1, -1, -1, -1, -1])
# COCO-23 -> Shelf-14 for the 12 limb joints; the two head joints are built by coco23_to_shelf14.
COCO23_TO_SHELF14_LIMBS = np.array([16, 14, 12, 11, 13, 15, 10, 8, 6, 5, 7, 9])

# The 10 PCP parts of the Shelf/Campus protocol on Shelf-14; "torso" runs from the mid-hip
# (index 14 after :func:`with_mid_hip`) to the bottom of the head.
SHELF_PCP_PARTS: dict[str, tuple[tuple[int, int], ...]] = {
    "upper_arms": ((8, 7), (9, 10)),
    "lower_arms": ((7, 6), (10, 11)),
    "upper_legs": ((2, 1), (3, 4)),
    "lower_legs": ((1, 0), (4, 5)),
    "head": ((12, 13),),
    "torso": ((14, 12),),
}

# Head construction of the public Shelf evaluations (mvpose, VoxelPose and the works that copy their
# evaluation): the bottom of the head is 3/4 of the way "half-way from the shoulder centre to the
# nose" plus 1/4 of "half-way from the shoulder centre to the ear centre"; the top of the head is 3/4 of
# "the shoulder centre plus the shoulder->nose vector scaled by (0.75, 0.75, 1.5)" (x, y, z world axes,
# z up) plus 1/4 of "the shoulder->ear-centre midpoint mirrored through the ear centre".
SHELF_HEAD_BOTTOM_NOSE_FRACTION = 0.5
SHELF_HEAD_TOP_NOSE_SCALE = np.array([0.75, 0.75, 1.5])
SHELF_HEAD_BLEND = 0.75


def to_coco23(src: np.ndarray, index_map: np.ndarray) -> np.ndarray:
    """Re-index keypoints into COCO-23: (..., J_src, C) -> (..., 23, C); absent joints are all 0."""
    src = np.asarray(src)
    out = np.zeros(src.shape[:-2] + (NUM_JOINTS, src.shape[-1]), dtype=np.result_type(src, np.float64))
    have = index_map >= 0
    out[..., have, :] = src[..., index_map[have], :]
    return out


def coco23_to_shelf14(pose: np.ndarray) -> np.ndarray:
    """COCO-23 world poses to Shelf-14 with the public head construction: (..., 23, 3) -> (..., 14, 3).

    Uses the world z axis as "up" (DESIGN.md); see the SHELF_HEAD_* constants for the coefficients.
    """
    pose = np.asarray(pose, dtype=np.float64)[..., :3]
    out = np.zeros(pose.shape[:-2] + (14, 3))
    out[..., :12, :] = pose[..., COCO23_TO_SHELF14_LIMBS, :]
    nose = pose[..., 0, :]
    mid_shoulder = (pose[..., 5, :] + pose[..., 6, :]) / 2
    ear_centre = (pose[..., 3, :] + pose[..., 4, :]) / 2
    ear_bottom = (mid_shoulder + ear_centre) / 2
    ear_top = 2 * ear_centre - ear_bottom
    bottom = mid_shoulder + SHELF_HEAD_BOTTOM_NOSE_FRACTION * (nose - mid_shoulder)
    top = mid_shoulder + SHELF_HEAD_TOP_NOSE_SCALE * (nose - mid_shoulder)
    a = SHELF_HEAD_BLEND
    out[..., 12, :] = a * bottom + (1 - a) * ear_bottom
    out[..., 13, :] = a * top + (1 - a) * ear_top
    return out


# COCO-23 joints each Shelf-14 + mid-hip joint is built from (coco23_to_shelf14, with_mid_hip).
SHELF15_SOURCES: tuple[tuple[int, ...], ...] = (
    *((int(j),) for j in COCO23_TO_SHELF14_LIMBS),
    (0, 3, 4, 5, 6),
    (0, 3, 4, 5, 6),
    (11, 12),
)


def shelf15_validity(valid23: np.ndarray) -> np.ndarray:
    """Which Shelf-14 + mid-hip joints rest on valid COCO-23 joints only: (..., 23) bool -> (..., 15) bool."""
    valid23 = np.asarray(valid23, dtype=bool)
    return np.stack([valid23[..., list(src)].all(axis=-1) for src in SHELF15_SOURCES], axis=-1)


def with_mid_hip(shelf14: np.ndarray) -> np.ndarray:
    """Append the mid-hip (mean of the two hips) as joint 14: (..., 14, 3) -> (..., 15, 3)."""
    shelf14 = np.asarray(shelf14)
    mid = (shelf14[..., 2:3, :] + shelf14[..., 3:4, :]) / 2
    return np.concatenate([shelf14, mid], axis=-2)


def flip_permutation() -> np.ndarray:
    """Channel permutation of a horizontal flip: (23,) indices, left and right swapped."""
    perm = np.arange(NUM_JOINTS)
    for a, b in FLIP_PAIRS:
        perm[a], perm[b] = b, a
    return perm


# Joint groups of the per-joint error tables (COCO-23 indices).
JOINT_GROUPS: dict[str, tuple[int, ...]] = {
    "head": (0, 1, 2, 3, 4),
    "shoulder": (5, 6),
    "elbow": (7, 8),
    "wrist": (9, 10),
    "hip": (11, 12),
    "knee": (13, 14),
    "ankle": (15, 16),
    "foot": FOOT_JOINTS,
}
