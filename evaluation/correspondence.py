"""Cross-view correspondence metrics of a matcher's assignment against GT ids: pair precision / recall, recovery."""

from __future__ import annotations

from dataclasses import asdict, astuple, dataclass

import numpy as np


@dataclass(frozen=True)
class CorrespondenceCounts:
    """Counts of one or more frames; add them over frames, then read the ratios (NaN when undefined)."""

    predicted_pairs: int = 0
    correct_pairs: int = 0
    true_pairs: int = 0
    persons: int = 0
    persons_recovered: int = 0

    def __add__(self, other: "CorrespondenceCounts") -> "CorrespondenceCounts":
        return CorrespondenceCounts(*(a + b for a, b in zip(astuple(self), astuple(other))))

    @property
    def precision(self) -> float:
        """Correct predicted pairs / predicted pairs."""
        return self.correct_pairs / self.predicted_pairs if self.predicted_pairs else float("nan")

    @property
    def recall(self) -> float:
        """Correct predicted pairs / ground-truth pairs."""
        return self.correct_pairs / self.true_pairs if self.true_pairs else float("nan")

    @property
    def recovered_share(self) -> float:
        """Share of ground-truth persons (ids in >= 2 views) recovered pure and complete."""
        return self.persons_recovered / self.persons if self.persons else float("nan")

    def as_dict(self) -> dict[str, float]:
        """Counts and ratios, for reports."""
        return {**asdict(self), **{k: getattr(self, k) for k in ("precision", "recall", "recovered_share")}}


def _validate(assignment: np.ndarray, person_ids: list[np.ndarray]) -> tuple[np.ndarray, list[np.ndarray]]:
    """Check shapes and indices: (P, V), V arrays (N_v,) -> int64 copies."""
    a = np.asarray(assignment, dtype=np.int64).reshape(-1, len(person_ids))
    ids = [np.asarray(p, dtype=np.int64).reshape(-1) for p in person_ids]
    for v, view_ids in enumerate(ids):
        if np.any(a[:, v] >= len(view_ids)) or np.any(a[:, v] < -1):
            raise ValueError(f"assignment column {v} indexes outside the {len(view_ids)} detections of view {v}")
        used = a[a[:, v] >= 0, v]
        if len(np.unique(used)) != len(used):
            raise ValueError(f"a detection of view {v} is assigned to two persons")
    return a, ids


def _pairs(n: np.ndarray) -> np.ndarray:
    """Number of unordered pairs among n items: (...,) -> (...,)."""
    return n * (n - 1) // 2


def correspondence_counts(assignment: np.ndarray, person_ids: list[np.ndarray]) -> CorrespondenceCounts:
    """Pair and person counts of one frame: assignment (P, V), V arrays person_ids (N_v,) -> counts."""
    a, ids = _validate(assignment, person_ids)
    V = len(ids)
    row_ids = np.full(a.shape, -1, dtype=np.int64)
    for v in range(V):
        have = a[:, v] >= 0
        row_ids[have, v] = ids[v][a[have, v]]
    held = np.sum(a >= 0, axis=1)
    predicted = int(_pairs(held).sum())
    correct = 0
    for row in row_ids:
        _, c = np.unique(row[row >= 0], return_counts=True)
        correct += int(_pairs(c).sum())

    all_ids = np.concatenate([np.zeros(0, np.int64), *ids])
    gt = np.unique(all_ids[all_ids >= 0])
    per_view = np.zeros((len(gt), V), dtype=np.int64)  # (G, V): detections of each GT person in each view
    for v in range(V):
        per_view[:, v] = np.sum(ids[v][None, :] == gt[:, None], axis=1)
    total = per_view.sum(axis=1)
    true_pairs = int(((total**2 - np.sum(per_view**2, axis=1)) // 2).sum())
    persons = gt[np.sum(per_view > 0, axis=1) >= 2]
    total_of = dict(zip(gt.tolist(), total.tolist()))

    recovered = 0
    for row, mask, n in zip(row_ids, a >= 0, held):
        vals = row[mask]  # a false positive (id -1) in the row makes it impure
        if n and np.all(vals == vals[0]) and vals[0] in persons and total_of[int(vals[0])] == n:
            recovered += 1
    return CorrespondenceCounts(predicted, correct, true_pairs, len(persons), recovered)
