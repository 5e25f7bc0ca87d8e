"""Synthetic adult bodies and their COCO-23 joints when standing or walking (sources: docs/design.md)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from types import MappingProxyType
from typing import Mapping

import numpy as np

from data.keypoints import LEFT_FOOT, NUM_JOINTS, RIGHT_FOOT

STATURE_MEAN_M = 1.70
STATURE_SD_M = 0.09
STATURE_RANGE_M = (1.52, 1.95)
PROPORTION_SD = 0.02  # relative SD of every segment fraction, clipped at 2 SD

# Segment lengths as fractions of stature (Drillis & Contini; docs/design.md).
FRACTIONS: Mapping[str, float] = MappingProxyType(
    {
        "thigh": 0.530 - 0.285,  # hip -> knee
        "shin": 0.285 - 0.039,  # knee -> ankle
        "ankle_height": 0.039,  # ankle above the sole
        "heel_back": 0.025,  # ankle -> back of the heel, horizontally
        "big_toe": 0.125,  # ankle -> big toe tip, forward (foot length ~ .15 H)
        "small_toe": 0.100,  # ankle -> small toe, forward
        "big_toe_medial": 0.010,  # big toe towards the midline of the foot
        "small_toe_lateral": 0.030,  # small toe away from the midline of the foot
        "torso": 0.818 - 0.530,  # hip -> shoulder, vertically
        "shoulder_width": 0.220,  # between the shoulder joint centres
        "hip_width": 0.110,  # between the hip joint centres
        "upper_arm": 0.186,
        "forearm": 0.146,
        "ear_up": 0.107,
        "ear_half_width": 0.0425,
        "ear_forward": 0.005,  # from the shoulder centre
        "eye_up": 0.122,
        "eye_half_width": 0.019,
        "eye_forward": 0.050,
        "nose_up": 0.100,
        "nose_forward": 0.065,
    }
)

# Normal-gait keyframes over one stride of one leg (phase 0 = heel strike, ~0.62 = toe off).
_HIP_KEYS = ((0.0, 0.12, 0.30, 0.50, 0.62, 0.73, 0.87, 1.0), (30, 26, 5, -15, -2, 15, 32, 30))
_KNEE_KEYS = ((0.0, 0.12, 0.35, 0.50, 0.62, 0.73, 0.87, 1.0), (5, 18, 5, 20, 40, 60, 25, 5))
_FOOT_PITCH_KEYS = ((0.0, 0.10, 0.45, 0.62, 0.75, 0.90, 1.0), (14, 0, 0, -34, -11, 11, 14))  # toes up +

_STAND_KNEE_DEG = 3.0
_STAND_LEG_ABDUCTION = 0.037  # rad; feet ~6 cm wider than the hips
_WALK_LEG_ADDUCTION = -0.045  # rad; step width ~10 cm
_TOE_OUT = 0.10  # rad of foot yaw away from the midline
_ARM_ABDUCTION = 0.14  # rad; keeps the hands off the hips
_ARM_SWING_GAIN = 0.6  # arm flexion per degree of opposite-leg hip flexion
_WALK_LEAN = 0.05  # rad of forward trunk lean while walking


@dataclass(frozen=True)
class BodyShape:
    """Segment lengths (m) of one person; build with :func:`sample_body` or :func:`mean_body`."""

    stature: float
    lengths: tuple[tuple[str, float], ...]  # (name, m)


def mean_body(stature: float = STATURE_MEAN_M) -> BodyShape:
    """The body with the mean proportions at a given stature (m)."""
    return BodyShape(float(stature), tuple((k, f * stature) for k, f in FRACTIONS.items()))


def sample_body(rng: np.random.Generator) -> BodyShape:
    """One random adult body: stature ~ N(1.70, 0.09) clipped, fractions jittered by 2 %."""
    stature = float(np.clip(rng.normal(STATURE_MEAN_M, STATURE_SD_M), *STATURE_RANGE_M))
    jitter = 1.0 + np.clip(rng.normal(0.0, PROPORTION_SD, len(FRACTIONS)), -2 * PROPORTION_SD, 2 * PROPORTION_SD)
    lengths = tuple((k, float(f * stature * j)) for (k, f), j in zip(FRACTIONS.items(), jitter))
    return BodyShape(stature, lengths)


def _periodic(keys: tuple[tuple[float, ...], tuple[float, ...]], phase: float) -> float:
    """Piecewise-linear periodic curve through keyframes, in radians."""
    return math.radians(float(np.interp(phase % 1.0, keys[0], keys[1])))


def _leg(b: dict[str, float], side: int, hip: float, knee: float, pitch: float, roll: float) -> np.ndarray:
    """Hip, knee, ankle, big toe, small toe, heel of one leg relative to the pelvis centre: (6, 3)."""
    hip_pos = np.array([0.0, side * b["hip_width"] / 2, 0.0])
    thigh = b["thigh"] * np.array([math.sin(hip), 0.0, -math.cos(hip)])
    shin = b["shin"] * np.array([math.sin(hip - knee), 0.0, -math.cos(hip - knee)])
    c, s = math.cos(side * roll), math.sin(side * roll)
    rot_x = np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])
    knee_pos = hip_pos + rot_x @ thigh
    ankle = knee_pos + rot_x @ shin
    # Foot points with the sole flat, then pitched (toes up > 0) and yawed outwards.
    forward = [b["big_toe"], b["small_toe"], -b["heel_back"]]
    left = [-side * b["big_toe_medial"], side * b["small_toe_lateral"], 0.0]
    foot = np.column_stack([forward, left, np.full(3, -b["ankle_height"])])
    cp, sp = math.cos(pitch), math.sin(pitch)
    foot = np.column_stack([foot[:, 0] * cp - foot[:, 2] * sp, foot[:, 1], foot[:, 0] * sp + foot[:, 2] * cp])
    cy, sy = math.cos(side * _TOE_OUT), math.sin(side * _TOE_OUT)
    foot = foot @ np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]]).T
    return np.vstack([hip_pos, knee_pos, ankle, ankle + foot])


def _arm(b: dict[str, float], shoulder: np.ndarray, side: int, flexion: float, elbow: float) -> np.ndarray:
    """Elbow and wrist of one arm hanging from the shoulder: (2, 3)."""
    c, s = math.cos(side * _ARM_ABDUCTION), math.sin(side * _ARM_ABDUCTION)
    rot_x = np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])
    upper = rot_x @ (b["upper_arm"] * np.array([math.sin(flexion), 0.0, -math.cos(flexion)]))
    fore = rot_x @ (b["forearm"] * np.array([math.sin(flexion + elbow), 0.0, -math.cos(flexion + elbow)]))
    return np.vstack([shoulder + upper, shoulder + upper + fore])


def local_pose(body: BodyShape, phase: float, walking: bool) -> np.ndarray:
    """COCO-23 joints in the local body frame (x forward, y left, z up), lowest sole at z = 0: (23, 3)."""
    b = dict(body.lengths)
    joints = np.zeros((NUM_JOINTS, 3))
    if walking:  # the left leg is at `phase`, the right leg half a stride later; each arm swings with the other leg
        legs, arm_flex, hip_rest = {}, {}, math.radians(8.0)
        for side, ph in ((1, phase), (-1, phase + 0.5)):
            hip = _periodic(_HIP_KEYS, ph)
            knee, pitch = _periodic(_KNEE_KEYS, ph), _periodic(_FOOT_PITCH_KEYS, ph)
            legs[side] = _leg(b, side, hip, knee, pitch, _WALK_LEG_ADDUCTION)
            arm_flex[side] = -_ARM_SWING_GAIN * (hip - hip_rest)
        lean = _WALK_LEAN
    else:
        legs = {side: _leg(b, side, 0.0, math.radians(_STAND_KNEE_DEG), 0.0, _STAND_LEG_ABDUCTION) for side in (1, -1)}
        arm_flex, lean = {1: 0.0, -1: 0.0}, 0.0
    for side, (hip_j, knee_j, ankle_j, foot_j) in ((1, (11, 13, 15, LEFT_FOOT)), (-1, (12, 14, 16, RIGHT_FOOT))):
        joints[[hip_j, knee_j, ankle_j]] = legs[side][:3]
        joints[list(foot_j)] = legs[side][3:]  # (big toe, small toe, heel), as LEFT_FOOT / RIGHT_FOOT

    # Trunk and head are one rigid block rotated forward by `lean` about the mid-hip.
    cl, sl = math.cos(lean), math.sin(lean)
    rot_lean = np.array([[cl, 0.0, sl], [0.0, 1.0, 0.0], [-sl, 0.0, cl]])
    shoulder_mid = rot_lean @ np.array([0.0, 0.0, b["torso"]])
    head = np.array(
        [
            [b["nose_forward"], 0.0, b["nose_up"]],
            [b["eye_forward"], b["eye_half_width"], b["eye_up"]],
            [b["eye_forward"], -b["eye_half_width"], b["eye_up"]],
            [b["ear_forward"], b["ear_half_width"], b["ear_up"]],
            [b["ear_forward"], -b["ear_half_width"], b["ear_up"]],
            [0.0, b["shoulder_width"] / 2, 0.0],
            [0.0, -b["shoulder_width"] / 2, 0.0],
        ]
    )
    joints[[0, 1, 2, 3, 4, 5, 6]] = shoulder_mid + head @ rot_lean.T
    for side, (sh, el, wr) in ((1, (5, 7, 9)), (-1, (6, 8, 10))):
        flex = arm_flex[side]
        elbow = math.radians(12.0) + 0.8 * max(flex, 0.0)
        joints[[el, wr]] = _arm(b, joints[sh], side, flex, elbow)

    soles = joints[list(LEFT_FOOT) + list(RIGHT_FOOT), 2]
    joints[:, 2] -= soles.min()
    return joints


def pose_joints(
    body: BodyShape, x: float, y: float, theta: float, phase: float = 0.0, walking: bool = False
) -> np.ndarray:
    """COCO-23 world joints (23, 3) at ground (x, y), heading theta (rad), gait phase; the lowest sole on z = 0."""
    local = local_pose(body, phase, walking)
    c, s = math.cos(theta), math.sin(theta)
    rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    out = local @ rot.T
    out[:, :2] += (x, y)
    return out


def stride_length(body: BodyShape) -> float:
    """Distance (m) one foot travels relative to the pelvis over a stride: two step lengths."""
    front = local_pose(body, 0.0, True)[15, 0]  # left ankle at left heel strike
    back = local_pose(body, 0.5, True)[15, 0]  # left ankle half a stride later
    return float(2.0 * (front - back))
