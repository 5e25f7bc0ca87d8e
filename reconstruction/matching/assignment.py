"""The assignment array shared by all matchers: (P, V) detection indices, -1 where absent."""

from __future__ import annotations

import numpy as np


def assignment_from_labels(labels: list[np.ndarray], min_views: int = 2) -> np.ndarray:
    """Group detections by a person label per view: V arrays (N_v,) int, -1 = none -> (P, V).

    Persons are ordered by label; a person seen in fewer than ``min_views`` views is dropped. A label
    that occurs twice in one view is an error (a person is at most one detection per view).
    """
    V = len(labels)
    people: dict[int, np.ndarray] = {}
    for v, lab in enumerate(labels):
        lab = np.asarray(lab, dtype=np.int64)
        for det, person in enumerate(lab):
            if person < 0:
                continue
            row = people.get(int(person))
            if row is None:  # not setdefault: that would build a row for every detection
                row = people[int(person)] = np.full(V, -1, dtype=np.int64)
            if row[v] >= 0:
                raise ValueError(f"label {person} occurs twice in view {v} (detections {row[v]} and {det})")
            row[v] = det
    rows = [people[k] for k in sorted(people) if np.sum(people[k] >= 0) >= min_views]
    return np.stack(rows) if rows else np.zeros((0, V), dtype=np.int64)
