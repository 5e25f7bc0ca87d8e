"""The per-frame data of the pictures over time (frames with ids, roots, a colour per id), one source for both."""

from __future__ import annotations

import colorsys
from dataclasses import dataclass
from typing import Iterable

import numpy as np

from data.keypoints import JOINT_INDEX, NUM_JOINTS
from evaluation.pictures.vis_draw import person_colors

HIP_JOINTS = (JOINT_INDEX["left_hip"], JOINT_INDEX["right_hip"])
TRUNK_JOINTS = (*HIP_JOINTS, JOINT_INDEX["left_shoulder"], JOINT_INDEX["right_shoulder"])
PALETTE_SIZE = 18  # person_colors(n) keeps one fixed palette while n <= 18
GOLDEN_RATIO = 0.618033988749895  # hue steps of the ids beyond the palette (as person_colors beyond 18)
HUE_SATURATION, HUE_VALUES = 0.86, (0.75, 1.0)  # odd and even ids alternate in brightness


@dataclass(frozen=True)
class SequenceFrame:
    """One frame: its number, poses (P, 23, 4) x, y, z (m), score, and ids (P,)."""

    frame: int
    poses: np.ndarray
    ids: np.ndarray


def sequence_frames(frames: Iterable[tuple]) -> tuple[list[SequenceFrame], bool]:
    """(frame, poses (P, 23, 4), ids (P,) or None) tuples -> frames, tracked (no ids: persons by index, untracked)."""
    out, tracked = [], True
    for frame, poses, ids in frames:
        poses = np.asarray(poses, dtype=np.float64).reshape(-1, NUM_JOINTS, 4)
        if ids is None:
            tracked = False
            ids = np.arange(len(poses))
        ids = np.asarray(ids, dtype=np.int64).reshape(-1)
        if len(ids) != len(poses):
            raise ValueError(f"frame {frame}: {len(poses)} poses but {len(ids)} ids")
        out.append(SequenceFrame(int(frame), poses, ids))
    return out, tracked


def valid_joints(poses: np.ndarray) -> np.ndarray:
    """Joints to draw: score > 0 and finite; poses (..., J, 4) -> (..., J) bool."""
    poses = np.asarray(poses, dtype=np.float64)
    return (poses[..., 3] > 0) & np.isfinite(poses).all(axis=-1)


def pose_roots(poses: np.ndarray) -> np.ndarray:
    """Each pose's root, the mid-hip, else the mean of its valid hips and shoulders, else NaN: (P, 23, 4) -> (P, 3)."""
    poses = np.asarray(poses, dtype=np.float64).reshape(-1, NUM_JOINTS, 4)
    ok = valid_joints(poses)
    xyz = np.where(ok[..., None], poses[..., :3], 0.0)
    roots = np.full((len(poses), 3), np.nan)
    for p in range(len(poses)):
        joints = list(HIP_JOINTS) if ok[p, list(HIP_JOINTS)].all() else [j for j in TRUNK_JOINTS if ok[p, j]]
        if joints:
            roots[p] = xyz[p, joints].mean(axis=0)
    return roots


def id_colors(ids: Iterable[int]) -> dict[int, np.ndarray]:
    """A colour per id that depends on the id alone: ids -> {id: (3,) RGB in [0, 1]}."""
    ids = sorted({int(i) for i in ids})
    if ids and ids[0] < 0:
        raise ValueError(f"ids must be >= 0, got {ids[0]}")
    palette = person_colors(PALETTE_SIZE)
    return {
        i: palette[i].copy()
        if i < PALETTE_SIZE
        else np.array(colorsys.hsv_to_rgb((i * GOLDEN_RATIO) % 1.0, HUE_SATURATION, HUE_VALUES[i % 2]))
        for i in ids
    }


def hex_color(rgb: np.ndarray) -> str:
    """(3,) RGB in [0, 1] -> '#rrggbb'."""
    return "#" + "".join(f"{int(round(255 * float(c))):02x}" for c in rgb)
