"""CMU Panoptic protocols on 15 joints: VoxelPose's AP / recall / MPJPE, the paper's root-aligned MPJPE and PCP."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from data.keypoints import JOINT_INDEX
from evaluation.association import PairedEvaluator, mean_joint_distance, mpjpe
from evaluation.pcp import correct_parts
from evaluation.report import format_table

if TYPE_CHECKING:
    from data.multiview import Frame
    from reconstruction.pipeline import FrameResult

PANOPTIC15_NAMES: tuple[str, ...] = tuple(
    "neck nose mid_hip left_shoulder left_elbow left_wrist left_hip left_knee left_ankle "
    "right_shoulder right_elbow right_wrist right_hip right_knee right_ankle".split()
)
NECK, NOSE, MID_HIP = 0, 1, 2
ROOT = (6, 12)  # root-aligned MPJPE: mean of left and right hip, the same construction on both sides
AP_THRESHOLDS_MM: tuple[int, ...] = (25, 50, 75, 100, 125, 150)
RECALL_THRESHOLD_MM = 500
# Table 4 joint groups (Panoptic-15 indices: the head is the nose, the left and right joints of each other group).
MPJPE_GROUPS: dict[str, tuple[int, ...]] = {"head": (NOSE,)} | {
    name: (j, j + 6) for j, name in enumerate(("shoulder", "elbow", "wrist", "hip", "knee", "foot"), start=3)
}
# Table 5 parts (Panoptic-15 joint pairs): head = neck -> nose, torso = neck -> mid-hip, then left and right limbs.
PCP_PARTS: dict[str, tuple[tuple[int, int], ...]] = {"head": ((NECK, NOSE),), "torso": ((NECK, MID_HIP),)} | {
    name: ((j, j + 1), (j + 6, j + 7))
    for j, name in zip((3, 4, 6, 7), ("upper_arms", "lower_arms", "upper_legs", "lower_legs"))
}


def coco23_to_panoptic15(poses: np.ndarray) -> np.ndarray:
    """COCO-23 poses (..., 23, 4) -> (..., 15, 4); neck, mid-hip: the means of shoulders, hips."""
    poses = np.asarray(poses, dtype=np.float64)
    out = np.zeros(poses.shape[:-2] + (15, poses.shape[-1]))
    for j, name in enumerate(PANOPTIC15_NAMES):
        if name in JOINT_INDEX:
            out[..., j, :] = poses[..., JOINT_INDEX[name], :]
    for j, (a, b) in ((NECK, ("left_shoulder", "right_shoulder")), (MID_HIP, ("left_hip", "right_hip"))):
        pa, pb = poses[..., JOINT_INDEX[a], :], poses[..., JOINT_INDEX[b], :]
        both = (pa[..., 3] > 0) & (pb[..., 3] > 0)
        out[..., j, :3] = np.where(both[..., None], (pa[..., :3] + pb[..., :3]) / 2, 0.0)
        out[..., j, 3] = np.where(both, np.minimum(pa[..., 3], pb[..., 3]), 0.0)
    return out


def average_precision(
    scores: np.ndarray, errors: np.ndarray, gt_index: np.ndarray, num_gt: int, threshold: float
) -> tuple[float, float]:
    """VoxelPose AP and recall (fractions) at one threshold: scores, errors, gt_index (N,) -> (ap, recall)."""
    if num_gt == 0:
        return float("nan"), float("nan")
    order, hits = _true_positives(scores, errors, gt_index, threshold)
    tp = hits.astype(np.float64)
    cum_tp = np.cumsum(tp)
    precision = cum_tp / np.arange(1, len(order) + 1)
    envelope = np.maximum.accumulate(precision[::-1])[::-1]
    return float(np.sum(tp * envelope) / num_gt), float(cum_tp[-1] / num_gt) if len(order) else 0.0


class PanopticAPEvaluator:
    """VoxelPose's Panoptic AP protocol (docs/design.md), accumulated frame by frame."""

    def __init__(self) -> None:
        self.scores: list[float] = []
        self.errors: list[float] = []
        self.gt_index: list[int] = []
        self.num_gt = 0
        self.num_pred = 0

    def update(self, pred: np.ndarray, gt: np.ndarray, scores: np.ndarray | None = None) -> None:
        """Add a frame: pred (P, 15, 4), gt (G, 15, 4); scores (P,), default the mean of pred[..., 3]."""
        pred, gt = np.asarray(pred, dtype=np.float64), np.asarray(gt, dtype=np.float64)
        scores = pred[..., 3].mean(axis=-1) if scores is None else np.asarray(scores, dtype=np.float64)
        if len(scores) != len(pred):
            raise ValueError(f"{len(scores)} scores for {len(pred)} predictions")
        gt = gt[gt[:, MID_HIP, 3] > 0]
        keep = np.any(pred[..., 3] > 0, axis=-1)
        pred, scores = pred[keep], scores[keep]
        if len(gt) == 0:
            return
        self.num_pred += len(pred)
        if len(pred):
            dist = mean_joint_distance(pred, gt)
            nearest = np.argmin(dist, axis=1)
            self.errors += (1000.0 * dist[np.arange(len(pred)), nearest]).tolist()
            self.gt_index += (self.num_gt + nearest).tolist()
            self.scores += scores.tolist()
        self.num_gt += len(gt)

    def summary(self) -> dict[str, float]:
        """ap@<t> and recall@<t> (%), mAP, mAR, recall@500 (%), mpjpe_mm, num_gt, num_pred."""
        scores, errors, gt_index = (np.array(x) for x in (self.scores, self.errors, self.gt_index))
        out: dict[str, float] = {}
        for t in AP_THRESHOLDS_MM:
            ap, recall = average_precision(scores, errors, gt_index, self.num_gt, t)
            out[f"ap@{t}"], out[f"recall@{t}"] = 100.0 * ap, 100.0 * recall
        out["mAP"] = float(np.mean([out[f"ap@{t}"] for t in AP_THRESHOLDS_MM]))
        out["mAR"] = float(np.mean([out[f"recall@{t}"] for t in AP_THRESHOLDS_MM]))
        near = np.unique(gt_index[errors < RECALL_THRESHOLD_MM]) if len(errors) else []
        out[f"recall@{RECALL_THRESHOLD_MM}"] = 100.0 * len(near) / self.num_gt if self.num_gt else float("nan")
        order, hits = _true_positives(scores, errors, gt_index, RECALL_THRESHOLD_MM)  # MPJPE of the TPs at 500 mm
        out["mpjpe_mm"] = float(np.mean(errors[order][hits])) if hits.any() else float("nan")
        out.update(num_gt=self.num_gt, num_pred=self.num_pred)
        return out


def _true_positives(
    scores: np.ndarray, errors: np.ndarray, gt_index: np.ndarray, threshold: float
) -> tuple[np.ndarray, np.ndarray]:
    """Score order (N,) and which predictions in it are TPs (N,) bool: error < threshold, their GT not yet taken."""
    order = np.argsort(-np.asarray(scores, dtype=np.float64), kind="stable")
    taken: set[int] = set()
    hits = np.zeros(len(order), dtype=bool)
    for rank, i in enumerate(order):
        if errors[i] < threshold and int(gt_index[i]) not in taken:
            hits[rank] = True
            taken.add(int(gt_index[i]))
    return order, hits


class PanopticPoseEvaluator(PairedEvaluator):
    """Root-aligned 13-joint MPJPE and PCP by part on Hungarian-paired persons (docs/design.md)."""

    def update(self, pred: np.ndarray, gt: np.ndarray) -> None:
        """Add a frame: pred (P, 15, 4), gt (G, 15, 4)."""
        pred, gt = np.asarray(pred, dtype=np.float64), np.asarray(gt, dtype=np.float64)
        pairs = self.pair(pred, gt, root=ROOT)
        # NaN = part not evaluable (invalid GT end); unpaired GT persons keep their parts wrong.
        parts = part_correct(np.zeros_like(gt), gt, self.alpha)
        parts[pairs[:, 1]] = part_correct(pred[pairs[:, 0]], gt[pairs[:, 1]], self.alpha)
        self.parts.append(parts)

    def summary(self) -> dict[str, float]:
        """root_mpjpe_<group>_mm, root_mpjpe_13_mm, root_mpjpe_average_mm, pcp_<part>, pcp_average (%), counts."""
        err = 1000.0 * np.concatenate(self.errors) if self.errors else np.zeros((0, 15))
        out: dict[str, float] = {}
        for name, cols in MPJPE_GROUPS.items():
            out[f"root_mpjpe_{name}_mm"] = mpjpe(err[:, list(cols)])
        out["root_mpjpe_13_mm"] = mpjpe(err[:, [j for cols in MPJPE_GROUPS.values() for j in cols]])
        out["root_mpjpe_average_mm"] = float(np.mean([out[f"root_mpjpe_{g}_mm"] for g in MPJPE_GROUPS]))
        parts = np.concatenate(self.parts) if self.parts else np.zeros((0, _NUM_PARTS))
        for i, name in enumerate(PCP_PARTS):
            out[f"pcp_{name}"] = 100.0 * mpjpe(parts[:, _PART_GROUP == i])
        out["pcp_average"] = float(np.mean([out[f"pcp_{p}"] for p in PCP_PARTS]))
        out.update(num_gt=self.num_gt, num_matched=self.num_matched)
        return out


_PART_PAIRS = np.array([pair for pairs in PCP_PARTS.values() for pair in pairs])
_PART_GROUP = np.array([i for i, pairs in enumerate(PCP_PARTS.values()) for _ in pairs])
_NUM_PARTS = len(_PART_PAIRS)


def part_correct(pred: np.ndarray, gt: np.ndarray, alpha: float = 0.5) -> np.ndarray:
    """PCP of the 10 parts of paired poses: (K, 15, 4), (K, 15, 4) -> (K, 10) of 1 / 0 / NaN (not evaluable)."""
    a, b = _PART_PAIRS[:, 0], _PART_PAIRS[:, 1]
    correct = correct_parts(pred, gt, alpha, _PART_PAIRS) & (pred[:, a, 3] > 0) & (pred[:, b, 3] > 0)
    return np.where((gt[:, a, 3] > 0) & (gt[:, b, 3] > 0), correct.astype(np.float64), np.nan)


def format_panoptic_report(s: dict[str, float]) -> str:
    """Console tables of a PanopticProtocol summary, each metric under its protocol name."""
    ts, groups = AP_THRESHOLDS_MM, list(MPJPE_GROUPS)
    ap_rows = [
        ["AP (%)", *(s[f"ap@{t}"] for t in ts), s["mAP"]],
        ["recall (%)", *(s[f"recall@{t}"] for t in ts), s["mAR"]],
    ]
    counts = [
        [f"recall@{RECALL_THRESHOLD_MM}mm (%)", s[f"recall@{RECALL_THRESHOLD_MM}"]],
        [f"MPJPE of TPs at {RECALL_THRESHOLD_MM}mm, absolute (mm)", s["mpjpe_mm"]],
        ["GT persons / predictions", f"{s['num_gt']} / {s['num_pred']}"],
    ]
    root_mpjpe = [s["root_mpjpe_average_mm"], s["root_mpjpe_13_mm"], *(s[f"root_mpjpe_{g}_mm"] for g in groups)]
    pcp = [s["pcp_average"], *(s[f"pcp_{p}"] for p in PCP_PARTS)]
    return "\n\n".join(
        [
            "VoxelPose Panoptic protocol (15 joints; AP/recall over the sequence, prediction -> nearest "
            "GT by MPJPE, score-ordered, TP if MPJPE < t and GT not yet taken)",
            format_table(["", *(f"@{t}mm" for t in ts), "mean"], ap_rows),
            format_table(["metric", "value"], counts),
            "Paper Table 4 protocol: root-aligned MPJPE (mm, root = mean of the hips, Hungarian-paired persons; "
            "head = nose, foot = ankle)",
            format_table(["average of groups", "13 joints", *groups], [root_mpjpe]),
            "Paper Table 5 protocol: PCP (%), alpha 0.5, absolute; head = neck->nose, torso = neck->mid-hip",
            format_table(["average", *PCP_PARTS], [pcp]),
        ]
    )


class PanopticProtocol:
    """Both Panoptic protocols as a dataset protocol; gt15 {frame: (G, 15, 4)}, predictions scored by mean confidence."""

    name = "panoptic"

    def __init__(self, gt15: dict[int, np.ndarray], max_dist_m: float = 0.5, alpha: float = 0.5) -> None:
        self.gt15 = gt15
        self.ap, self.pose = PanopticAPEvaluator(), PanopticPoseEvaluator(max_dist_m, alpha)
        self.frames = 0

    def update(self, frame: Frame, result: FrameResult) -> None:
        """Score one frame: result.poses3d (P, 23, 4) against gt15[frame.index] (G, 15, 4)."""
        gt = self.gt15.get(frame.index)
        if gt is None:
            return
        pred15 = coco23_to_panoptic15(result.poses3d)
        self.ap.update(pred15, gt)
        self.pose.update(pred15, gt)
        self.frames += 1

    def summary(self) -> dict[str, float]:
        """PanopticAPEvaluator's summary, PanopticPoseEvaluator's (its counts as pose_*) and the frames scored."""
        pose = self.pose.summary()
        pose["pose_num_gt"], pose["pose_num_matched"] = pose.pop("num_gt"), pose.pop("num_matched")
        return {**self.ap.summary(), **pose, "frames": self.frames}

    def report(self) -> str:
        """The console tables of :func:`format_panoptic_report`."""
        return format_panoptic_report(self.summary())
