"""Keypoint metadata by name (COCO-23 = COCO-17 + 6 feet); maps gather ``coco23[j] = source[MAP[j]]`` (-1: score 0)."""

from __future__ import annotations

from typing import Iterable

import numpy as np

# COCO-23 joints in order, with their OKS sigmas: COCO-17, then the COCO-WholeBody foot sigmas.
COCO23_NAMES: tuple[str, ...] = tuple(
    "nose left_eye right_eye left_ear right_ear left_shoulder right_shoulder left_elbow right_elbow left_wrist"
    " right_wrist left_hip right_hip left_knee right_knee left_ankle right_ankle left_big_toe left_small_toe left_heel"
    " right_big_toe right_small_toe right_heel".split()
)
OKS_SIGMAS = np.array([0.026, 0.025, 0.025, 0.035, 0.035, 0.079, 0.079, 0.072, 0.072, 0.062, 0.062, 0.107, 0.107])
OKS_SIGMAS = np.append(OKS_SIGMAS, [0.087, 0.087, 0.089, 0.089, 0.068, 0.066, 0.066, 0.092, 0.094, 0.094])
NUM_JOINTS = len(COCO23_NAMES)  # 23
NUM_BODY_JOINTS = 17
JOINT_INDEX: dict[str, int] = {name: i for i, name in enumerate(COCO23_NAMES)}


def joint_indices(names: Iterable[str]) -> tuple[int, ...]:
    """COCO-23 indices of joint names: names (K,) -> (K,)."""
    return tuple(JOINT_INDEX[name] for name in names)


def name_pairs(pairs: Iterable[tuple[str, str]]) -> tuple[tuple[int, int], ...]:
    """COCO-23 index pairs of joint-name pairs: (K, 2) names -> (K, 2) indices."""
    return tuple((JOINT_INDEX[a], JOINT_INDEX[b]) for a, b in pairs)


def index_map(source_names: Iterable[str], target_names: Iterable[str] = COCO23_NAMES) -> np.ndarray:
    """The gather map of a format's joint names into the target's: (J_target,) source index, -1 where absent."""
    where = {name: i for i, name in enumerate(source_names)}
    return np.array([where.get(name, -1) for name in target_names])


BODY_JOINTS = tuple(range(NUM_BODY_JOINTS))
FOOT_JOINTS = tuple(range(NUM_BODY_JOINTS, NUM_JOINTS))
LEFT_FOOT = joint_indices(("left_big_toe", "left_small_toe", "left_heel"))
RIGHT_FOOT = joint_indices(("right_big_toe", "right_small_toe", "right_heel"))
LEFT_ANKLE, RIGHT_ANKLE = joint_indices(("left_ankle", "right_ankle"))

# Every left joint with its right partner, in COCO-23 order of the left joint.
FLIP_PAIRS = name_pairs((n, "right_" + n[5:]) for n in COCO23_NAMES if n.startswith("left_"))

LIMBS = name_pairs(  # drawn in pictures: the COCO skeleton plus heel, big toe and small toe on each foot
    tuple(pair.split("-"))
    for pair in "left_ankle-left_knee left_knee-left_hip right_ankle-right_knee right_knee-right_hip left_hip-right_hip"
    " left_shoulder-left_hip right_shoulder-right_hip left_shoulder-right_shoulder left_shoulder-left_elbow"
    " right_shoulder-right_elbow left_elbow-left_wrist right_elbow-right_wrist left_eye-right_eye nose-left_eye"
    " nose-right_eye left_eye-left_ear right_eye-right_ear left_ear-left_shoulder right_ear-right_shoulder"
    " left_ankle-left_heel left_ankle-left_big_toe left_big_toe-left_small_toe right_ankle-right_heel"
    " right_ankle-right_big_toe right_big_toe-right_small_toe".split()
)

# Bones of the bone-length prior: segments whose length is fixed for a person (name -> joint names).
BONE_JOINTS: dict[str, tuple[str, str]] = {
    "shoulders": ("left_shoulder", "right_shoulder"),
    "hips": ("left_hip", "right_hip"),
}
BONE_JOINTS |= {  # a sided bone: the left one, then the right one ({s} = left, right)
    bone.format(s=s): (a.format(s=s), b.format(s=s))
    for bone, (a, b) in {
        "{s}_torso": ("{s}_shoulder", "{s}_hip"),
        "{s}_upper_arm": ("{s}_shoulder", "{s}_elbow"),
        "{s}_forearm": ("{s}_elbow", "{s}_wrist"),
        "{s}_thigh": ("{s}_hip", "{s}_knee"),
        "{s}_shin": ("{s}_knee", "{s}_ankle"),
        "{s}_nose_eye": ("nose", "{s}_eye"),
        "{s}_eye_ear": ("{s}_eye", "{s}_ear"),
        "{s}_ankle_heel": ("{s}_ankle", "{s}_heel"),
        "{s}_ankle_big_toe": ("{s}_ankle", "{s}_big_toe"),
        "{s}_toes": ("{s}_big_toe", "{s}_small_toe"),
        "{s}_heel_big_toe": ("{s}_heel", "{s}_big_toe"),
    }.items()
    for s in ("left", "right")
}
BONES: dict[str, tuple[int, int]] = dict(zip(BONE_JOINTS, name_pairs(BONE_JOINTS.values())))

JOINT_GROUPS: dict[str, tuple[int, ...]] = {  # of the per-joint error tables
    "head": joint_indices(("nose", "left_eye", "right_eye", "left_ear", "right_ear")),
    **{g: joint_indices((f"left_{g}", f"right_{g}")) for g in ("shoulder", "elbow", "wrist", "hip", "knee", "ankle")},
    "foot": FOOT_JOINTS,
}

# --- other formats' published joint orders (names absent from COCO-23 are the format's own) -----------------------
BODY25_NAMES: tuple[str, ...] = tuple(
    "nose neck right_shoulder right_elbow right_wrist left_shoulder left_elbow left_wrist mid_hip right_hip right_knee"
    " right_ankle left_hip left_knee left_ankle right_eye left_eye right_ear left_ear left_big_toe left_small_toe"
    " left_heel right_big_toe right_small_toe right_heel".split()
)
PANOPTIC19_NAMES: tuple[str, ...] = tuple(
    "neck nose mid_hip left_shoulder left_elbow left_wrist left_hip left_knee left_ankle right_shoulder right_elbow"
    " right_wrist right_hip right_knee right_ankle left_eye left_ear right_eye right_ear".split()
)
SHELF14_NAMES: tuple[str, ...] = tuple(
    "right_ankle right_knee right_hip left_hip left_knee left_ankle right_wrist right_elbow right_shoulder"
    " left_shoulder left_elbow left_wrist bottom_head top_head".split()
)
CROWDPOSE14_NAMES: tuple[str, ...] = tuple(
    "left_shoulder right_shoulder left_elbow right_elbow left_wrist right_wrist left_hip right_hip left_knee"
    " right_knee left_ankle right_ankle top_head neck".split()
)

BODY25_TO_COCO23 = index_map(BODY25_NAMES)
# BlazePose's 33 landmarks (MediaPipe): its foot index (the tip of the foot) is named as the big toe; no small toe
BLAZEPOSE33_NAMES: tuple[str, ...] = tuple(
    "nose left_eye_inner left_eye left_eye_outer right_eye_inner right_eye right_eye_outer left_ear right_ear mouth_left"
    " mouth_right left_shoulder right_shoulder left_elbow right_elbow left_wrist right_wrist left_pinky right_pinky"
    " left_index right_index left_thumb right_thumb left_hip right_hip left_knee right_knee left_ankle right_ankle"
    " left_heel right_heel left_big_toe right_big_toe".split()
)
BLAZEPOSE33_TO_COCO23 = index_map(BLAZEPOSE33_NAMES)
PANOPTIC19_TO_COCO23 = index_map(PANOPTIC19_NAMES)
SHELF14_TO_COCO23 = index_map(SHELF14_NAMES)
CROWDPOSE14_TO_COCO23 = index_map(CROWDPOSE14_NAMES)
# COCO-17 (COCO keypoints, torchvision's Keypoint R-CNN): the body joints of COCO-23, no feet.
COCO17_TO_COCO23 = index_map(COCO23_NAMES[:NUM_BODY_JOINTS])
# COCO-23 -> Shelf-14 for the 12 limb joints; the two head joints are built by coco23_to_shelf14.
COCO23_TO_SHELF14_LIMBS = index_map(COCO23_NAMES, SHELF14_NAMES[:12])

# The 10 PCP parts of the Shelf/Campus protocol on Shelf-14 + mid-hip (index 14 after :func:`with_mid_hip`).
_SHELF15 = {name: i for i, name in enumerate((*SHELF14_NAMES, "mid_hip"))}
SHELF_PCP_PARTS: dict[str, tuple[tuple[int, int], ...]] = {
    part: tuple((_SHELF15[a], _SHELF15[b]) for a, b in pairs)
    for part, pairs in {
        "upper_arms": (("right_shoulder", "right_elbow"), ("left_shoulder", "left_elbow")),
        "lower_arms": (("right_elbow", "right_wrist"), ("left_elbow", "left_wrist")),
        "upper_legs": (("right_hip", "right_knee"), ("left_hip", "left_knee")),
        "lower_legs": (("right_knee", "right_ankle"), ("left_knee", "left_ankle")),
        "head": (("bottom_head", "top_head"),),
        "torso": (("mid_hip", "bottom_head"),),
    }.items()
}

# Head construction of the public Shelf evaluations (mvpose, VoxelPose and the works that copy them): each head
# joint is SHELF_HEAD_BLEND of a point set off from the shoulder centre by the nose, the rest of one by the ears.
SHELF_HEAD_BOTTOM_NOSE_FRACTION = 0.5
SHELF_HEAD_TOP_NOSE_SCALE = np.array([0.75, 0.75, 1.5])  # x, y, z (z up)
SHELF_HEAD_BLEND = 0.75
_HEAD_SOURCES = joint_indices(("nose", "left_ear", "right_ear", "left_shoulder", "right_shoulder"))
_NOSE, _L_EAR, _R_EAR, _L_SHOULDER, _R_SHOULDER = _HEAD_SOURCES


def to_coco23(src: np.ndarray, index_map: np.ndarray) -> np.ndarray:
    """Re-index keypoints into COCO-23: (..., J_src, C) -> (..., 23, C); absent joints are all 0."""
    src = np.asarray(src)
    out = np.zeros(src.shape[:-2] + (NUM_JOINTS, src.shape[-1]), dtype=np.result_type(src, np.float64))
    have = index_map >= 0
    out[..., have, :] = src[..., index_map[have], :]
    return out


def coco23_to_shelf14(pose: np.ndarray) -> np.ndarray:
    """COCO-23 world poses (z up) to Shelf-14 with the public head construction: (..., 23, 3) -> (..., 14, 3)."""
    pose = np.asarray(pose, dtype=np.float64)[..., :3]
    out = np.zeros(pose.shape[:-2] + (14, 3))
    out[..., :12, :] = pose[..., COCO23_TO_SHELF14_LIMBS, :]
    nose = pose[..., _NOSE, :]
    mid_shoulder = (pose[..., _L_SHOULDER, :] + pose[..., _R_SHOULDER, :]) / 2
    ear_centre = (pose[..., _L_EAR, :] + pose[..., _R_EAR, :]) / 2
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
    _HEAD_SOURCES,
    _HEAD_SOURCES,
    JOINT_GROUPS["hip"],
)


def shelf15_validity(valid23: np.ndarray) -> np.ndarray:
    """Which Shelf-14 + mid-hip joints rest on valid COCO-23 joints only: (..., 23) bool -> (..., 15) bool."""
    valid23 = np.asarray(valid23, dtype=bool)
    return np.stack([valid23[..., list(src)].all(axis=-1) for src in SHELF15_SOURCES], axis=-1)


def with_mid_hip(shelf14: np.ndarray) -> np.ndarray:
    """Append the mid-hip (mean of the two hips) as joint 14: (..., 14, 3) -> (..., 15, 3)."""
    shelf14 = np.asarray(shelf14)
    hips = [_SHELF15["left_hip"], _SHELF15["right_hip"]]
    return np.concatenate([shelf14, shelf14[..., hips, :].mean(axis=-2, keepdims=True)], axis=-2)


def flip_permutation(names: tuple[str, ...] = COCO23_NAMES) -> np.ndarray:
    """Channel permutation of a horizontal flip: (J,) indices, each left joint's name swapped with its right one's."""
    swapped = (n.replace("left", "#").replace("right", "left").replace("#", "right") for n in names)
    return np.array([names.index(n) for n in swapped])
