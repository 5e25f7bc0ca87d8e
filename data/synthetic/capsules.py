"""Bodies as capsules, and which joints a camera cannot see because another body is in the way."""

from __future__ import annotations

from types import MappingProxyType
from typing import Mapping

import numpy as np

from data.keypoints import LIMBS

# Capsule radii (m) of the LIMBS segments: rough half-thicknesses of adult body parts (thigh ~15 cm,
# calf ~10 cm, upper arm ~9 cm, forearm ~7 cm across); face segments are thin, the head sphere covers them.
_LIMB_RADII: Mapping[frozenset[int], float] = MappingProxyType(
    {
        frozenset((15, 13)): 0.05,
        frozenset((16, 14)): 0.05,  # shins
        frozenset((13, 11)): 0.075,
        frozenset((14, 12)): 0.075,  # thighs
        frozenset((11, 12)): 0.09,  # pelvis
        frozenset((5, 11)): 0.08,
        frozenset((6, 12)): 0.08,  # flanks
        frozenset((5, 6)): 0.07,  # shoulder line
        frozenset((5, 7)): 0.045,
        frozenset((6, 8)): 0.045,  # upper arms
        frozenset((7, 9)): 0.035,
        frozenset((8, 10)): 0.035,  # forearms
        frozenset((3, 5)): 0.05,
        frozenset((4, 6)): 0.05,  # neck sides
    }
)
FACE_RADIUS_M = 0.03  # nose-eye-ear segments
FOOT_RADIUS_M = 0.04  # ankle-heel, ankle-toe, toe-toe segments
TORSO_RADIUS_M = 0.12  # mid-shoulder -> mid-hip capsule (chest depth ~ 23 cm)
HEAD_RADIUS_M = 0.10  # sphere at the ear centre (head breadth ~ 15 cm, length ~ 19 cm)

_LIMB_A, _LIMB_B = np.array(LIMBS).T  # the ends of every LIMBS segment


def capsule_radii() -> np.ndarray:
    """Radius (m) of every capsule of :func:`body_capsules`: (K,) with K = len(LIMBS) + 2."""
    radii = [FOOT_RADIUS_M if max(a, b) >= 17 else _LIMB_RADII.get(frozenset((a, b)), FACE_RADIUS_M) for a, b in LIMBS]
    return np.array(radii + [TORSO_RADIUS_M, HEAD_RADIUS_M])


def body_capsules(poses: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Capsule axes of bodies: (P, 23, 3) -> ends A (P, K, 3), B (P, K, 3); the head is a sphere (A = B)."""
    poses = np.asarray(poses, dtype=np.float64)
    mid_shoulder = (poses[:, 5] + poses[:, 6]) / 2
    mid_hip = (poses[:, 11] + poses[:, 12]) / 2
    head = (poses[:, 3] + poses[:, 4]) / 2
    ends_a = np.concatenate([poses[:, _LIMB_A], mid_shoulder[:, None], head[:, None]], axis=1)
    ends_b = np.concatenate([poses[:, _LIMB_B], mid_hip[:, None], head[:, None]], axis=1)
    return ends_a, ends_b


def segment_distance(p1: np.ndarray, q1: np.ndarray, p2: np.ndarray, q2: np.ndarray) -> np.ndarray:
    """Least distance between segments [p1, q1] and [p2, q2] (Ericson 5.1.9, points too): (..., 3) x 4 -> (...,)."""
    eps = 1e-12
    d1, d2, r = np.broadcast_arrays(q1 - p1, q2 - p2, p1 - p2)
    a = np.einsum("...i,...i->...", d1, d1)
    e = np.einsum("...i,...i->...", d2, d2)
    f = np.einsum("...i,...i->...", d2, r)
    c = np.einsum("...i,...i->...", d1, r)
    b = np.einsum("...i,...i->...", d1, d2)
    safe_a = np.where(a > eps, a, 1.0)
    safe_e = np.where(e > eps, e, 1.0)
    denom = a * e - b * b
    parallel = denom <= eps * np.maximum(a * e, eps)
    s = np.where(parallel, 0.0, np.clip((b * f - c * e) / np.where(parallel, 1.0, denom), 0, 1))
    t = (b * s + f) / safe_e
    # t outside [0, 1]: clamp it and recompute s for the clamped t.
    s = np.where(t < 0, np.clip(-c / safe_a, 0, 1), np.where(t > 1, np.clip((b - c) / safe_a, 0, 1), s))
    t = np.clip(t, 0, 1)
    point2 = e <= eps  # degenerate segments
    s = np.where(point2, np.clip(-c / safe_a, 0, 1), s)
    t = np.where(point2, 0.0, t)
    point1 = a <= eps
    s = np.where(point1, 0.0, s)
    t = np.where(point1, np.where(point2, 0.0, np.clip(f / safe_e, 0, 1)), t)
    diff = (p1 + s[..., None] * d1) - (p2 + t[..., None] * d2)
    return np.sqrt(np.einsum("...i,...i->...", diff, diff))


def occluded_joints(center: np.ndarray, poses: np.ndarray) -> np.ndarray:
    """Joints (P, J) bool of poses (P, J, 3) whose sight line from the camera centre (3,) crosses another body."""
    poses = np.asarray(poses, dtype=np.float64)
    num, joints = poses.shape[:2]
    hidden = np.zeros((num, joints), dtype=bool)
    if num < 2:
        return hidden
    center = np.asarray(center, dtype=np.float64)
    ends_a, ends_b = body_capsules(poses)
    radii = capsule_radii()
    sphere_c = (ends_a.mean(axis=1) + ends_b.mean(axis=1)) / 2  # (P, 3)
    reach_a, reach_b = (np.linalg.norm(ends - sphere_c[:, None], axis=-1) for ends in (ends_a, ends_b))
    sphere_r = (np.maximum(reach_a, reach_b) + radii).max(axis=1)  # (P,)

    targets = poses.reshape(-1, 3)  # (N, 3)
    owner = np.repeat(np.arange(num), joints)
    ray = targets - center
    ray_len2 = np.maximum(np.sum(ray * ray, axis=1), 1e-12)
    t = np.clip(((sphere_c - center) @ ray.T).T / ray_len2[:, None], 0.0, 1.0)  # (N, P)
    closest = center + t[..., None] * ray[:, None]
    near = np.sum((closest - sphere_c[None]) ** 2, axis=-1) < sphere_r[None] ** 2
    near[np.arange(len(owner)), owner] = False
    rows, persons = np.nonzero(near)
    if len(rows) == 0:
        return hidden
    # Second cull, per capsule, by the sphere around each capsule.
    cap_c = (ends_a + ends_b) / 2  # (P, K, 3)
    cap_r = np.linalg.norm(ends_b - ends_a, axis=-1) / 2 + radii  # (P, K)
    rel = cap_c[persons] - center  # (M, K, 3)
    ray_m = ray[rows]
    t = np.clip(np.einsum("mki,mi->mk", rel, ray_m) / ray_len2[rows, None], 0.0, 1.0)
    off = rel - t[..., None] * ray_m[:, None]
    pair, cap = np.nonzero(np.einsum("mki,mki->mk", off, off) < cap_r[persons] ** 2)
    who = persons[pair]
    dist = segment_distance(center, targets[rows[pair]], ends_a[who, cap], ends_b[who, cap])
    hit = np.zeros(len(targets), dtype=bool)
    hit[rows[pair[dist < radii[cap]]]] = True
    return hit.reshape(num, joints)
