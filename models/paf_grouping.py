"""Greedy part-affinity grouping of BODY_25 joint candidates into persons, as OpenPose does (numba kernels)."""

from __future__ import annotations

import numba
import numpy as np

from data.formats.fourd_detections import (
    BODY25_LIMB_ARRAY,
    BODY25_NUM_JOINTS,
    BODY25_PAF_LIMBS,
    FrameCandidates,
    PackedCandidates,
)
from data.formats.openpose_json import keypoints_to_view_detections
from data.keypoints import BODY25_TO_COCO23, to_coco23
from data.multiview import ViewDetections


def limb_connections(paf: np.ndarray, min_paf: float) -> np.ndarray:
    """Greedy one-to-one pairs of a PAF matrix (n_a, n_b) -> (C, 3) rows (i, j, score), best first."""
    paf = np.ascontiguousarray(paf, dtype=np.float64)
    pairs = np.empty((min(paf.shape), 2), dtype=np.int64)
    count = _greedy_pairs(paf.ravel(), 0, paf.shape[0], paf.shape[1], float(min_paf), pairs)
    rows = pairs[:count]
    return np.column_stack([rows.astype(np.float64), paf[rows[:, 0], rows[:, 1]]]).reshape(-1, 3)


@numba.njit(cache=True)
def _greedy_pairs(flat: np.ndarray, start: int, n_a: int, n_b: int, min_paf: float, out: np.ndarray) -> int:
    """Greedy one-to-one pairs of the (n_a, n_b) block flat[start:], best first (ties row-major) -> out (C, 2), C."""
    used_a = np.zeros(n_a, dtype=np.bool_)
    used_b = np.zeros(n_b, dtype=np.bool_)
    count = 0
    while True:
        best, best_i, best_j = min_paf, -1, -1
        for i in range(n_a):
            if used_a[i]:
                continue
            for j in range(n_b):
                value = flat[start + i * n_b + j]
                if not used_b[j] and value > best:
                    best, best_i, best_j = value, i, j
        if best_i < 0:
            return count
        used_a[best_i] = True
        used_b[best_j] = True
        out[count, 0] = best_i
        out[count, 1] = best_j
        count += 1


@numba.njit(cache=True)
def _assemble(
    paf_flat: np.ndarray, paf_start: np.ndarray, limbs: np.ndarray, cand_start: np.ndarray, min_paf: float
) -> np.ndarray:
    """Fold every limb's greedy connections into persons -> slots (P, J): candidate index per joint or -1."""
    num_joints = len(cand_start) - 1
    owner = np.full(cand_start[-1], -1, dtype=np.int64)
    slots = np.full((cand_start[-1] // 2 + 1, num_joints), -1, dtype=np.int64)
    num = 0
    pairs = np.empty((cand_start[-1] + 1, 2), dtype=np.int64)
    for k in range(len(limbs)):
        a, b = limbs[k, 0], limbs[k, 1]
        n_a, n_b = cand_start[a + 1] - cand_start[a], cand_start[b + 1] - cand_start[b]
        for c in range(_greedy_pairs(paf_flat, paf_start[k], n_a, n_b, min_paf, pairs)):
            ca, cb = cand_start[a] + pairs[c, 0], cand_start[b] + pairs[c, 1]
            pa, pb = owner[ca], owner[cb]
            if pa < 0 and pb < 0:
                slots[num, a], slots[num, b] = pairs[c, 0], pairs[c, 1]
                owner[ca], owner[cb] = num, num
                num += 1
            elif pb < 0:
                if slots[pa, b] < 0:
                    slots[pa, b], owner[cb] = pairs[c, 1], pa
            elif pa < 0:
                if slots[pb, a] < 0:
                    slots[pb, a], owner[ca] = pairs[c, 0], pb
            elif pa != pb and not np.any((slots[pa] >= 0) & (slots[pb] >= 0)):
                for joint in range(num_joints):
                    if slots[pb, joint] >= 0:
                        slots[pa, joint] = slots[pb, joint]
                        owner[cand_start[joint] + slots[pb, joint]] = pa
                        slots[pb, joint] = -1
    return slots[:num]


def group_people(
    candidates: list[np.ndarray],
    pafs: list[np.ndarray],
    limbs: tuple[tuple[int, int], ...] = BODY25_PAF_LIMBS,
    min_paf: float = 0.05,
    min_joints: int = 8,  # fewer: dropped (8: the dip between fragments and bodies on Shelf)
    min_mean_score: float = 0.4,
) -> np.ndarray:
    """Candidates (J arrays (n_j, 3) x, y, score), limb PAFs (L arrays (n_a, n_b)) -> persons (N, J, 3), missing 0."""
    packed = pack_candidates(candidates, pafs, limbs)
    return group_packed(packed, np.array(limbs).reshape(-1, 2), min_paf, min_joints, min_mean_score)


def pack_candidates(
    candidates: list[np.ndarray], pafs: list[np.ndarray], limbs: tuple[tuple[int, int], ...] = BODY25_PAF_LIMBS
) -> PackedCandidates:
    """J candidate arrays (n_j, 3) and L PAF matrices (n_a, n_b) -> PackedCandidates; ValueError for a bad shape."""
    if len(pafs) != len(limbs):
        raise ValueError(f"group_people: {len(pafs)} PAF matrices for {len(limbs)} limbs")
    cands = [np.asarray(c, dtype=np.float64).reshape(-1, 3) for c in candidates]
    sizes = [len(c) for c in cands]
    pafs = [np.asarray(p, dtype=np.float64) for p in pafs]
    for (a, b), paf in zip(limbs, pafs):
        if paf.shape != (sizes[a], sizes[b]):
            raise ValueError(
                f"group_people: PAF of limb ({a}, {b}) has shape {paf.shape}, expected ({sizes[a]}, {sizes[b]})"
            )
    return PackedCandidates(
        np.concatenate(cands),
        np.cumsum([0, *sizes]),
        np.concatenate([p.reshape(-1) for p in pafs] or [np.zeros(0)]),
        np.cumsum([0] + [p.size for p in pafs]),
    )


def group_packed(
    packed: PackedCandidates, limbs: np.ndarray, min_paf: float, min_joints: int, min_mean_score: float
) -> np.ndarray:
    """:func:`group_people` of packed candidates, limbs (L, 2) int -> (N, J, 3)."""
    slots = _assemble(packed.paf_values, packed.paf_start, limbs, packed.joint_start, float(min_paf))
    return _persons(slots, packed.points, packed.joint_start, min_joints, min_mean_score)


def _persons(
    slots: np.ndarray, cand_flat: np.ndarray, cand_start: np.ndarray, min_joints: int, min_mean_score: float
) -> np.ndarray:
    """The kept persons' keypoints: slots (P, J), candidates (M, 3) stacked by joint -> (N, J, 3)."""
    have = slots >= 0
    count = have.sum(axis=1)
    index = np.where(have, cand_start[:-1] + slots, 0)
    poses = np.where(have[..., None], cand_flat.reshape(-1, 3)[index], 0.0)
    keep = (count > 0) & (count >= min_joints)
    mean = np.zeros(len(slots))
    mean[keep] = [poses[p, have[p], 2].mean() for p in np.flatnonzero(keep)]
    return poses[keep & (mean >= min_mean_score)].reshape(-1, len(cand_start) - 1, 3)


def grouped_to_view_detections(persons: np.ndarray, margin: float = 0.1) -> ViewDetections:
    """BODY_25 persons (N, 25, 3) -> COCO-23 ViewDetections, boxes grown by margin x their size on each side."""
    persons = np.asarray(persons, dtype=np.float64).reshape(-1, BODY25_NUM_JOINTS, 3)
    return keypoints_to_view_detections(to_coco23(persons, BODY25_TO_COCO23), margin)


def group_view(
    frame: FrameCandidates, min_paf: float = 0.05, min_joints: int = 8, min_mean_score: float = 0.4, margin: float = 0.1
) -> ViewDetections:
    """One camera frame's BODY_25 candidates grouped into persons -> COCO-23 ViewDetections (the Shelf grouper)."""
    packed = frame.packed if frame.packed is not None else pack_candidates(frame.candidates, frame.pafs)
    persons = group_packed(packed, BODY25_LIMB_ARRAY, min_paf, min_joints, min_mean_score)
    return grouped_to_view_detections(persons, margin)


def warm_up() -> None:
    """Compile (or load from numba's cache) the two kernels on a tiny view."""
    one = np.array([[10.0, 10.0, 0.9]])
    group_people([one] * BODY25_NUM_JOINTS, [np.ones((1, 1))] * len(BODY25_PAF_LIMBS), min_joints=1)
