"""The pure-Python PAF grouping that models/paf_grouping.py replaced by numba kernels, frozen as the reference.

tests/test_paf_grouping.py checks that the kernels give the same persons on every Shelf frame and on
random candidate sets with tied scores. Do not change it.
"""

from __future__ import annotations

import numpy as np

from data.formats.fourd_detections import BODY25_PAF_LIMBS


def limb_connections(paf: np.ndarray, min_paf: float) -> np.ndarray:
    """Greedy one-to-one pairs of a PAF matrix (n_a, n_b) -> (C, 3) rows (i, j, score), best first."""
    paf = np.asarray(paf, dtype=np.float64)
    flat = paf.ravel()
    order = np.argsort(-flat, kind="stable")  # ties: row-major order, so the result is deterministic
    used_a, used_b = set(), set()
    rows = []
    for idx in order:
        if not flat[idx] > min_paf:
            break
        i, j = divmod(int(idx), paf.shape[1])
        if i in used_a or j in used_b:
            continue
        used_a.add(i)
        used_b.add(j)
        rows.append((i, j, flat[idx]))
    return np.array(rows, dtype=np.float64).reshape(-1, 3)


class _Assembly:
    """Persons under construction: slots[p][joint] = candidate index or -1, plus who owns each candidate."""

    def __init__(self, sizes: list[int]) -> None:
        self.slots: list[np.ndarray] = []
        self.owner = [np.full(n, -1, dtype=np.int64) for n in sizes]

    def assign(self, p: int, joint: int, cand: int) -> None:
        """Put a candidate into person p's slot."""
        self.slots[p][joint] = cand
        self.owner[joint][cand] = p

    def connect(self, a: int, i: int, b: int, j: int) -> None:
        """Fold the connection (joint a, candidate i) - (joint b, candidate j) into the persons."""
        pa, pb = self.owner[a][i], self.owner[b][j]
        if pa < 0 and pb < 0:
            self.slots.append(np.full(len(self.owner), -1, dtype=np.int64))
            self.assign(len(self.slots) - 1, a, i)
            self.assign(len(self.slots) - 1, b, j)
        elif pb < 0:
            if self.slots[pa][b] < 0:  # a filled slot is a conflict: keep the earlier (stronger) link
                self.assign(pa, b, j)
        elif pa < 0:
            if self.slots[pb][a] < 0:
                self.assign(pb, a, i)
        elif pa != pb and not np.any((self.slots[pa] >= 0) & (self.slots[pb] >= 0)):
            self.merge(pa, pb)

    def merge(self, keep: int, gone: int) -> None:
        """Move person `gone`'s joints to `keep`; `gone` is left empty."""
        for joint in np.flatnonzero(self.slots[gone] >= 0):
            self.assign(keep, int(joint), int(self.slots[gone][joint]))
        self.slots[gone][:] = -1


def group_people(
    candidates: list, pafs: list, limbs: tuple = BODY25_PAF_LIMBS, min_paf: float = 0.05, **keys
) -> np.ndarray:
    """The persons of models.paf_grouping.group_people: J arrays (n_j, 3), L arrays (n_a, n_b) -> (N, J, 3)."""
    cands = [np.asarray(c, dtype=np.float64).reshape(-1, 3) for c in candidates]
    assembly = _Assembly([len(c) for c in cands])
    for (a, b), paf in zip(limbs, pafs):
        if np.shape(paf) != (len(cands[a]), len(cands[b])):
            raise ValueError(
                f"group_people: PAF of limb ({a}, {b}) has shape {np.shape(paf)}, "
                f"expected ({len(cands[a])}, {len(cands[b])})"
            )
        for i, j, _ in limb_connections(paf, min_paf):
            assembly.connect(a, int(i), b, int(j))
    return _persons(assembly.slots, cands, keys.get("min_joints", 8), keys.get("min_mean_score", 0.4))


def _persons(slots: list[np.ndarray], cands: list[np.ndarray], min_joints: int, min_mean_score: float) -> np.ndarray:
    """Fill the kept persons' keypoints: P slot arrays (J,) -> (N, J, 3)."""
    people = []
    for slot in slots:
        have = np.flatnonzero(slot >= 0)
        if len(have) == 0 or len(have) < min_joints:
            continue
        pose = np.zeros((len(cands), 3))
        for joint in have:
            pose[joint] = cands[joint][slot[joint]]
        if pose[have, 2].mean() >= min_mean_score:
            people.append(pose)
    return np.array(people, dtype=np.float64).reshape(-1, len(cands), 3)
