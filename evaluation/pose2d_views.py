"""The 2D stage of a run on images, scored per view with COCO OKS AP/AR against the render's ground truth."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from scipy.optimize import linear_sum_assignment
from tqdm import tqdm

from data.keypoints import OKS_SIGMAS
from data.multiview import Sequence, ViewDetections
from data.pose2d.coco_eval import evaluate_keypoints
from data.pose2d.view_coco import ground_truth_document, results
from models.front_end import Pose2DFrontEnd
from models.pose_nms import joint_similarity

MIN_OKS = 0.5


def oks_matrix(pred: ViewDetections, gt: ViewDetections) -> np.ndarray:
    """OKS of every prediction against every ground-truth person -> (N_pred, N_gt); over the GT's labelled joints."""
    out = np.zeros((len(pred), len(gt)))
    for g in range(len(gt)):
        labelled = gt.keypoints[g, :, 2] > 0
        if labelled.any() and len(pred):
            area = gt.bboxes[g, 2] * gt.bboxes[g, 3]
            out[:, g] = joint_similarity(gt.keypoints[g], pred.keypoints, area, OKS_SIGMAS)[:, labelled].mean(1)
    return out


def label_with_gt_ids(pred: ViewDetections, gt: ViewDetections, min_oks: float = MIN_OKS) -> ViewDetections:
    """A copy of pred whose person_ids (N,) are those of the GT persons matched one-to-one by OKS >= min_oks."""
    ids = np.full(len(pred), -1, dtype=np.int64)
    if len(pred) and len(gt):
        oks = oks_matrix(pred, gt)
        rows, cols = linear_sum_assignment(-oks)
        keep = oks[rows, cols] >= min_oks
        ids[rows[keep]] = gt.person_ids[cols[keep]]
    return replace(pred, person_ids=ids)


def estimate_2d(
    sequence: Sequence, front_end: Pose2DFrontEnd, progress: bool = True
) -> tuple[Sequence, list[list[ViewDetections]] | None]:
    """Run the 2D stage on every frame -> (a new Sequence of predicted views, the GT views per frame (V each) or None)."""
    has_gt = sequence.views_are_ground_truth
    frames, gt_views = [], []
    for frame in tqdm(sequence.frames, desc="2D poses", unit="frame", disable=not progress):
        predicted = front_end(frame)
        if has_gt:
            predicted = [label_with_gt_ids(p, g) for p, g in zip(predicted, frame.views)]
            gt_views.append(list(frame.views))
        frames.append(replace(frame, views=predicted))
    return replace(sequence, frames=frames), (gt_views if has_gt else None)


def view_metrics(sequence: Sequence, gt_views: list[list[ViewDetections]]) -> dict[str, float]:
    """Per-view COCO OKS AP/AR (all 23, body 17, foot 6) of the sequence's predicted views against gt_views."""
    doc = ground_truth_document([replace(f, views=g) for f, g in zip(sequence.frames, gt_views)], sequence.rig)
    predictions = results(sequence.frames, sequence.rig)
    metrics = {}
    for subset in ("all", "body", "foot"):
        stats = evaluate_keypoints(doc, predictions, subset)
        metrics.update({f"pose2d_AP_{subset}": stats["AP"], f"pose2d_AR_{subset}": stats["AR"]})
        if subset == "all":
            metrics.update({f"pose2d_{k}_all": stats[k] for k in ("AP50", "AP75", "APm", "APl")})
    return metrics


def format_view_metrics(metrics: dict[str, float], num_images: int) -> str:
    """The printed lines of view_metrics."""
    row = lambda s: f"AP {metrics[f'pose2d_AP_{s}']:.3f}  AR {metrics[f'pose2d_AR_{s}']:.3f}"
    return (
        f"2D poses per view (COCO OKS, COCO-23 sigmas, pycocotools; {num_images} camera images, ground truth of the "
        f"render, hidden joints labelled v=1): all 23 {row('all')} (AP50 {metrics['pose2d_AP50_all']:.3f}, "
        f"AP75 {metrics['pose2d_AP75_all']:.3f}); body 17 {row('body')}; foot 6 {row('foot')}"
    )
