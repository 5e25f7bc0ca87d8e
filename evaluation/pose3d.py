"""Sequence-level 3D pose metrics: absolute MPJPE by joint group and Shelf-protocol PCP."""

from __future__ import annotations

import numpy as np

from data.keypoints import BODY_JOINTS, JOINT_GROUPS, coco23_to_shelf14, shelf15_validity, with_mid_hip
from evaluation.association import match_to_ground_truth
from evaluation.mpjpe import joint_errors
from evaluation.pcp import PART_JOINTS, correct_parts, part_validity, pcp_by_part


class Pose3DEvaluator:
    """Accumulates frames of COCO-23 predictions and GT: one-to-one matched absolute MPJPE and Shelf-parts PCP."""

    def __init__(self, max_dist_m: float = 0.5, alpha: float = 0.5) -> None:
        self.max_dist_m = max_dist_m
        self.alpha = alpha
        self.errors: list[np.ndarray] = []
        self.parts: list[np.ndarray] = []
        self.parts_valid: list[np.ndarray] = []
        self.num_gt = 0
        self.num_pred = 0
        self.num_matched = 0

    def update(self, pred: np.ndarray, gt: np.ndarray) -> None:
        """Add one frame: pred (P, 23, 4) with confidence, gt (G, 23, 4) with validity."""
        pairs = match_to_ground_truth(pred, gt, self.max_dist_m)
        self.num_gt += len(gt)
        self.num_pred += len(pred)
        self.num_matched += len(pairs)
        self.errors.append(joint_errors(pred[pairs[:, 0]], gt[pairs[:, 1]]))
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
        out = {"mpjpe_mm": _mean_mm(err, range(err.shape[1])), "mpjpe_body_mm": _mean_mm(err, BODY_JOINTS)}
        for name, cols in JOINT_GROUPS.items():
            out[f"mpjpe_{name}_mm"] = _mean_mm(err, cols)
        parts = np.concatenate(self.parts) if self.parts else np.zeros((0, len(PART_JOINTS)), bool)
        valid = np.concatenate(self.parts_valid) if self.parts_valid else parts.copy()
        out.update({f"pcp_{k}": v for k, v in pcp_by_part(parts, valid).items()})
        out.update(
            num_gt=self.num_gt,
            num_pred=self.num_pred,
            num_matched=self.num_matched,
            recall=100.0 * self.num_matched / max(self.num_gt, 1),
            precision=100.0 * self.num_matched / max(self.num_pred, 1),
        )
        return out


def _mean_mm(errors: np.ndarray, cols) -> float:
    """Mean of the valid errors (m) of some joint columns, in mm: (K, J) -> scalar, NaN if none."""
    sub = errors[:, list(cols)]
    return 1000.0 * float(np.nanmean(sub)) if np.any(np.isfinite(sub)) else float("nan")
