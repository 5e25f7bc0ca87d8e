"""Sequence-level 3D pose metrics: absolute MPJPE by joint group and Shelf-protocol PCP."""

from __future__ import annotations

import numpy as np

from data.keypoints import BODY_JOINTS, JOINT_GROUPS, coco23_to_shelf14, shelf15_validity, with_mid_hip
from evaluation.association import PairedEvaluator, mpjpe
from evaluation.pcp import PART_JOINTS, correct_parts, part_validity, pcp_by_part


class Pose3DEvaluator(PairedEvaluator):
    """Accumulates frames of COCO-23 predictions and GT: one-to-one matched absolute MPJPE and Shelf-parts PCP."""

    def __init__(self, max_dist_m: float = 0.5, alpha: float = 0.5) -> None:
        super().__init__(max_dist_m, alpha)
        self.parts_valid: list[np.ndarray] = []
        self.num_pred = 0

    def update(self, pred: np.ndarray, gt: np.ndarray) -> None:
        """Add one frame: pred (P, 23, 4) with confidence, gt (G, 23, 4) with validity."""
        pairs = self.pair(pred, gt)
        self.num_pred += len(pred)
        parts = np.zeros((len(gt), len(PART_JOINTS)), dtype=bool)
        if len(pairs):
            p15 = with_mid_hip(coco23_to_shelf14(pred[pairs[:, 0], :, :3]))
            g15 = with_mid_hip(coco23_to_shelf14(gt[pairs[:, 1], :, :3]))
            parts[pairs[:, 1]] = correct_parts(p15, g15, self.alpha)
        self.parts.append(parts)
        self.parts_valid.append(part_validity(shelf15_validity(np.asarray(gt)[..., 3] > 0)))

    def summary(self) -> dict[str, float]:
        """Metrics: mpjpe_mm (23 joints), mpjpe_body_mm (17), mpjpe_<group>_mm, pcp_<part>, counts."""
        err = np.concatenate(self.errors) if self.errors else np.zeros((0, 23))
        out = {"mpjpe_mm": 1000.0 * mpjpe(err), "mpjpe_body_mm": 1000.0 * mpjpe(err[:, list(BODY_JOINTS)])}
        for name, cols in JOINT_GROUPS.items():
            out[f"mpjpe_{name}_mm"] = 1000.0 * mpjpe(err[:, list(cols)])
        parts = np.concatenate(self.parts) if self.parts else np.zeros((0, len(PART_JOINTS)), bool)
        valid = np.concatenate(self.parts_valid) if self.parts_valid else parts.copy()
        out.update({f"pcp_{k}": v for k, v in pcp_by_part(parts, valid).items()})
        out.update(num_gt=self.num_gt, num_pred=self.num_pred, num_matched=self.num_matched)
        recall, precision = (100.0 * self.num_matched / max(n, 1) for n in (self.num_gt, self.num_pred))
        return {**out, "recall": recall, "precision": precision}
