"""Run the multi-view pipeline over a sequence and report metrics, skipped frames and timings."""

from __future__ import annotations

import time
from collections import Counter
from dataclasses import dataclass, field

import numpy as np
from tqdm import tqdm

from data.keypoints import JOINT_GROUPS
from data.multiview import Sequence
from evaluation.correspondence import CorrespondenceCounts, correspondence_counts
from evaluation.identity import IdentityEvaluator
from evaluation.pcp import PART_NAMES
from evaluation.pose3d import Pose3DEvaluator
from evaluation.protocols import attach_protocols
from evaluation.report import format_table
from evaluation.reprojection import frame_reprojection_errors, reprojection_stats
from reconstruction.matching.epipolar import TOO_FEW_JOINTS
from reconstruction.matching.evidence import AMBIGUOUS, NON_FINITE_KEYPOINTS, TOO_LITTLE_EVIDENCE
from reconstruction.matching.feet import FEET_ABOVE_HORIZON, NO_COUNTERPART, NO_FOOT_JOINTS
from reconstruction.pipeline import FrameResult, MultiViewPipeline


@dataclass
class SequenceReport:
    """Per-frame results, metrics, skipped frames and unmatched detections by reason, timings, protocol summaries."""

    results: list[FrameResult]
    metrics: dict[str, float]
    skipped: Counter
    timings: dict[str, float] = field(default_factory=dict)
    unmatched: Counter = field(default_factory=Counter)
    protocols: dict[str, dict] = field(default_factory=dict)
    protocol_reports: list[str] = field(default_factory=list)
    detections: int = 0  # 2D detections over every view and frame run
    inputs: Counter = field(default_factory=Counter)  # detections dropped or merged before matching, by reason
    noise_model: str | None = None  # the self-calibrated 2D noise model, in words (None: a fixed one)


# the likeliest cause of a run that reconstructs nobody, by the matcher's commonest reason for leaving detections out
FEW_SCORED = "too few joints scored >= matching.min_score (another detector's score scale?)"
NOBODY_CAUSES = {
    NO_COUNTERPART: "no two views agree on a person, so the calibration does not fit the detections (a camera's "
    "R given camera -> world, swapped camera names, mirrored or flipped images, another image size): "
    "python -m data.geometry.check_rig cameras.json poses2d.json names the camera",
    TOO_LITTLE_EVIDENCE: FEW_SCORED,
    TOO_FEW_JOINTS: FEW_SCORED,
    NON_FINITE_KEYPOINTS: "the keypoints are NaN or infinite",
    AMBIGUOUS: "every pair was refused as ambiguous (matching.ambiguity_margin)",
    NO_FOOT_JOINTS: "no foot or ankle joints scored: a feet matcher needs them (matching=evidence does not)",
    FEET_ABOVE_HORIZON: "the feet meet no ground plane in front of the cameras: the calibration's up axis or "
    "units do not fit (docs/formats.md)",
}


def evaluate_sequence(
    sequence: Sequence, pipeline: MultiViewPipeline, evaluator: Pose3DEvaluator, progress: bool = True
) -> SequenceReport:
    """Reconstruct every frame; score it against the GT where there is some and against its 2D detections (Table 3)."""
    attach_protocols(sequence)  # the dataset's own protocols (protocol_inputs), unless attached already
    results, skipped, pairs, reprojection = [], Counter(), CorrespondenceCounts(), []
    has_ids = any(np.any(v.person_ids >= 0) for f in sequence.frames for v in f.views)
    # identity metrics where a tracker runs and the sequence's ground-truth ids persist across frames
    tracked = pipeline.tracker is not None and sequence.persistent_ids
    tracked = tracked and all(f.gt_ids is not None for f in sequence.frames if f.gt_poses is not None)
    identities = IdentityEvaluator(evaluator.max_dist_m) if tracked else None
    t_eval, detections = 0.0, 0
    t0 = time.perf_counter()
    noise = pipeline.calibrate_noise(sequence.frames)
    if noise is not None:  # matching and reconstructing the first frames with the start model, then the fit
        pipeline.timings["noise calibration"] += time.perf_counter() - t0
    for frame in tqdm(sequence.frames, desc="frames", unit="frame", disable=not progress):
        result = pipeline(frame)
        detections += sum(len(v) for v in frame.views)
        results.append(result)
        if len(result.poses3d) == 0:
            skipped["no person matched in two or more views"] += 1
        t0 = time.perf_counter()
        if frame.gt_poses is not None:
            evaluator.update(result.poses3d, frame.gt_poses)
            if identities is not None:
                identities.update(result.poses3d, result.ids, frame.gt_poses, frame.gt_ids)
        if has_ids:
            pairs = pairs + correspondence_counts(result.assignment, [v.person_ids for v in frame.views])
        for protocol in sequence.protocols:
            protocol.update(frame, result)
        if len(result.poses3d):
            reprojection.append(
                frame_reprojection_errors(result.poses3d, result.assignment, frame.views, sequence.rig).ravel()
            )
        t_eval += time.perf_counter() - t0
    metrics = evaluator.summary() if any(f.gt_poses is not None for f in sequence.frames) else {}
    if has_ids:
        metrics.update({f"matching_{k}": v for k, v in pairs.as_dict().items()})
    if identities is not None:
        metrics.update({f"tracking_{k}": v for k, v in identities.summary().items()})
    stats = reprojection_stats(np.concatenate(reprojection) if reprojection else np.zeros(0))
    metrics.update({f"reprojection_{k}_px": stats[k] for k in ("mean", "min", "max")})
    metrics["reprojection_var_px2"] = stats["var"]
    timings = dict(pipeline.timings, evaluation=t_eval)
    protocols = {p.name: p.summary() for p in sequence.protocols}
    reports = [p.report() for p in sequence.protocols]
    return SequenceReport(
        results,
        metrics,
        skipped,
        timings,
        Counter(pipeline.unmatched),
        protocols,
        reports,
        detections,
        noise_model=noise,
    )


def nobody_diagnosis(report: SequenceReport) -> str | None:
    """For a run that reconstructed nobody: one line naming the stage that lost the people and the likeliest cause."""
    if any(len(r.poses3d) for r in report.results):
        return None
    if not report.detections:
        return "Nobody reconstructed: the frames run hold no 2D detection (dataset.frames, the 2D input)"
    if not report.unmatched:
        return f"Nobody reconstructed from {report.detections} detections: the matcher placed some, the reconstruction none"
    reason, count = report.unmatched.most_common(1)[0]
    cause = NOBODY_CAUSES.get(reason, "see docs/usage.md")
    return (
        f"Nobody reconstructed from {report.detections} detections: the matcher left them out "
        f"({count} {reason}); likeliest cause: {cause}"
    )


def format_report(report: SequenceReport, num_frames: int, protocol: str) -> str:
    """The console summary: metrics with their protocol, per-group MPJPE, PCP, skipped frames, timings."""
    m = report.metrics
    blocks = []
    if "mpjpe_mm" in m:
        blocks += [
            f"Protocol: {protocol}",
            format_table(
                ["metric", "value"],
                [
                    ["MPJPE all 23 joints (mm)", m["mpjpe_mm"]],
                    ["MPJPE body 17 joints (mm)", m["mpjpe_body_mm"]],
                    ["PCP average (%)", m["pcp_average"]],
                    ["GT persons recalled (%)", m["recall"]],
                    ["predictions matched to GT (%)", m["precision"]],
                    ["GT persons / predictions", f"{m['num_gt']} / {m['num_pred']}"],
                    *_identity_rows(m),
                ],
            ),
            format_table(["MPJPE (mm)", *JOINT_GROUPS], [["", *(m[f"mpjpe_{g}_mm"] for g in JOINT_GROUPS)]]),
            format_table(["PCP (%)", *PART_NAMES], [["", *(m[f"pcp_{p}"] for p in PART_NAMES)]]),
        ]
    if "reprojection_mean_px" in m:
        blocks.append(
            "Reprojection error of the reconstructed joints against the 2D detections (undistorted px, "
            "every joint with score > 0 in every view; paper Table 3): mean {reprojection_mean_px:.2f}, "
            "min {reprojection_min_px:.3f}, max {reprojection_max_px:.1f}, "
            "variance {reprojection_var_px2:.2f} px^2".format(**m)
        )
    lines = [report.noise_model] if report.noise_model else []
    if report.inputs:
        lines.append("Detections before matching: " + ", ".join(f"{n} {why}" for why, n in report.inputs.items()))
    if report.unmatched:
        unmatched = ", ".join(f"{n} {why}" for why, n in sorted(report.unmatched.items()))
        lines.append(f"Detections left unmatched by the matcher: {unmatched}")
    diagnosis = nobody_diagnosis(report)
    lines += [diagnosis] if diagnosis is not None else []
    skipped = "".join(f"; {n} {why}" for why, n in report.skipped.items())
    lines.append(f"Frames: {num_frames} evaluated, {sum(report.skipped.values())} skipped{skipped}")
    blocks += [*report.protocol_reports, "\n".join(lines)]
    per_frame = [[stage, 1000.0 * sec / max(num_frames, 1), sec] for stage, sec in report.timings.items()]
    blocks.append(format_table(["stage", "ms / frame", "total s"], per_frame, floatfmt=".2f"))
    return "\n\n".join(blocks)


def _identity_rows(m: dict[str, float]) -> list[list[object]]:
    """Report rows of the correspondence metrics and of the tracker's identity metrics, where the metrics have them."""
    rows: list[list[object]] = []
    if "matching_precision" in m:
        rows.append(["matching precision, pairs (%)", 100.0 * m["matching_precision"]])
        rows.append(["matching recall, pairs (%)", 100.0 * m["matching_recall"]])
        rows.append(["GT persons matched pure and complete (%)", 100.0 * m["matching_recovered_share"]])
    if "tracking_id_switches" in m:
        switches = f"{m['tracking_id_switches']} ({m['tracking_id_switches_per_100']:.2f})"
        rows.append(["identity switches (per 100 GT person-frames)", switches])
        rows.append(["GT person-frames with their most frequent track id (%)", m["tracking_idf1_like"]])
        rows.append(["track fragmentations", m["tracking_fragmentations"]])
    return rows
