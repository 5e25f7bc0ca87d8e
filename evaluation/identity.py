"""Identity metrics of a tracker against ground-truth ids: switches (MOT IDSW), IDF1-like share, fragmentations."""

from __future__ import annotations

from collections import Counter, defaultdict

import numpy as np

from evaluation.association import match_to_ground_truth


class IdentityEvaluator:
    """Accumulates, frame by frame, which track id each ground-truth person got; ``summary()`` the metrics."""

    def __init__(self, max_dist_m: float = 0.5) -> None:
        self.max_dist_m = max_dist_m
        self.history: dict[int, list[int]] = defaultdict(list)  # GT id -> track id per frame (-1 unmatched)

    def update(self, pred: np.ndarray, ids: np.ndarray, gt: np.ndarray, gt_ids: np.ndarray) -> None:
        """One frame: predictions (P, J, 4) with track ids (P,), ground truth (G, J, 4) with ids (G,)."""
        got = np.full(len(gt), -1, dtype=np.int64)
        pairs = match_to_ground_truth(np.asarray(pred), np.asarray(gt), self.max_dist_m)
        got[pairs[:, 1]] = np.asarray(ids, dtype=np.int64)[pairs[:, 0]]
        for g, track in zip(np.asarray(gt_ids, dtype=np.int64), got):
            self.record(int(g), int(track))

    def record(self, gt_id: int, track_id: int) -> None:
        """One ground-truth person-frame: the track id its prediction carries, -1 if it has none."""
        self.history[gt_id].append(track_id)

    def summary(self, gt_ids: tuple[int, ...] | None = None) -> dict[str, float]:
        """GT ids (default all) -> id_switches, id_switches_per_100, idf1_like %, fragmentations, frames."""
        switches = fragments = kept = total = 0
        for gt_id, tracks in self.history.items():
            if gt_ids is not None and gt_id not in gt_ids:
                continue
            total += len(tracks)
            matched = [t for t in tracks if t >= 0]
            if matched:
                kept += Counter(matched).most_common(1)[0][1]
            switches += sum(a != b for a, b in zip(matched, matched[1:]))
            runs = np.diff(np.r_[0, np.asarray(tracks) >= 0, 0].astype(int))
            fragments += max(int(np.sum(runs == 1)) - 1, 0)
        return {
            "id_switches": switches,
            "id_switches_per_100": 100.0 * switches / max(total, 1),
            "idf1_like": 100.0 * kept / max(total, 1),
            "fragmentations": fragments,
            "gt_person_frames": total,
        }
