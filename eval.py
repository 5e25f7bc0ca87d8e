"""Evaluate the pipeline on the configured dataset: ``python eval.py [dataset=shelf] [matching=...] [key=value ...]``;
``python eval.py checkpoint=<.ckpt/.pth>`` evaluates a 2D checkpoint of train.py instead."""

from __future__ import annotations

import json
import sys
import time
import warnings
from collections.abc import Iterable, Iterator
from pathlib import Path

import hydra
from hydra.core.hydra_config import HydraConfig
from hydra.utils import instantiate
from omegaconf import DictConfig
from omegaconf.errors import MissingMandatoryValue

from data.config_checks import ConfigError, check_bool, check_int, check_number, check_target
from data.formats.atomic_io import atomic_write_text, exit_on_sigterm
from data.formats.image_sources import ImageSourceError
from data.formats.poses2d_io import Poses2DError, write_poses2d
from data.formats.poses_io import write_poses3d
from data.formats.strict_json import finite
from data.frame_inputs import InputWarning, clean_frames
from data.geometry.calibration import CalibrationError
from data.geometry.check_rig import RigWarning
from data.multiview import Sequence
from evaluation.pose3d import Pose3DEvaluator
from evaluation.protocols import attach_protocols
from evaluation.sequence_eval import SequenceReport, evaluate_sequence, format_report
from models.front_end import Pose2DFrontEnd
from reconstruction.pipeline import FrameResult, MultiViewPipeline
from reconstruction.precompile import precompile
from run_folders import one_line_errors, register_resolvers

PROTOCOL = (
    "absolute MPJPE (mm, no root alignment) over all frames; each GT person matched one-to-one "
    "to a prediction by Hungarian on mean joint distance (unmatched beyond {max_dist_m} m); "
    "PCP alpha={alpha} on the 10 Shelf parts of Shelf-14 built from COCO-23, unmatched GT "
    "persons count all parts wrong; matching precision/recall over pairs of detections placed "
    "in one person, against ground-truth identities; every output joint is scored, those seen in fewer than 2 "
    "views where the pipeline placed them (poses3d.json gives them score 0 unless output.fill=true)"
)


def check_config(cfg: DictConfig) -> None:
    """Stop with one line naming the key when a top-level, evaluation or stage value has the wrong type or range."""
    for group in ("dataset", "noise_model", "matching", "reconstruction", "tracking"):
        check_target(cfg, group)
    for key in ("evaluation.max_dist_m", "evaluation.alpha", "vis_sequence_max_mb"):
        check_number(cfg, key)
    check_number(cfg, "coincident_m", 0.0, strict=False)
    check_int(cfg, "vis_frame", 0, nullable=True)
    for key in ("vis", "vis_sequence", "progress", "overwrite", "output.fill", "viewer_spawn"):
        check_bool(cfg, key)
    check_int(cfg, "inputs.max_detections_per_frame", 1)
    check_number(cfg, "inputs.near_duplicate", strict=False)
    if cfg.viewer is not None:  # before the frames run, not after
        from evaluation.pictures.rerun_view import check_viewer

        check_viewer(cfg.viewer, cfg.viewer_spawn)


def check_sequence(cfg: DictConfig, sequence: Sequence) -> None:
    """Stop with one line when the dataset cannot be evaluated as configured (before the frames are run)."""
    if len(sequence.rig) < 2:
        key = "dataset.num_cameras" if "num_cameras" in cfg.dataset else "dataset"
        raise ConfigError(f"{key}: the rig has {len(sequence.rig)} camera; triangulation needs at least 2")
    numbers = [f.index for f in sequence.frames]
    back = next((i for i in range(1, len(numbers)) if numbers[i] <= numbers[i - 1]), None)
    if cfg.tracking.get("_target_") and back is not None:
        raise ConfigError(
            f"dataset.frames: frame {numbers[back]} comes after frame {numbers[back - 1]}; tracking needs "
            "increasing frame numbers (sort or de-duplicate the frames, or tracking=off)"
        )


def run(cfg: DictConfig, out_dir: Path) -> SequenceReport:
    """Evaluate the configured dataset, matcher and reconstruction; write outputs and report.txt into out_dir."""
    check_config(cfg)
    precompile()  # numba's kernels from its cache, or compiled once under a notice (first run after an install)
    t0 = time.perf_counter()
    sequence = attach_protocols(instantiate(cfg.dataset, _convert_="all"))  # protocols: evaluation/protocols
    t_data = time.perf_counter() - t0
    check_sequence(cfg, sequence)
    sequence, repaired = clean_frames(sequence, cfg.inputs.max_detections_per_frame, cfg.inputs.near_duplicate)
    sequence, front_timings, view_report = run_2d_stage(cfg, sequence, out_dir)
    pipeline = MultiViewPipeline.from_config(cfg, sequence.rig)
    report = evaluate_sequence(sequence, pipeline, Pose3DEvaluator(**cfg.evaluation), cfg.progress)
    stage_s = sequence.stage_seconds  # e.g. 2D grouping done while loading
    report.inputs = repaired
    report.timings = {"dataset": t_data - sum(stage_s.values()), **stage_s, **front_timings, **report.timings}
    if view_report is not None:
        report.metrics.update(view_report[0])
        report.protocol_reports.insert(0, view_report[1])
    write_outputs(cfg, out_dir, sequence, report)
    draw_pictures(cfg, out_dir, sequence, report, pipeline)
    return report


def poses3d_rows(results: Iterable[FrameResult]) -> Iterator[tuple]:
    """write_poses3d's rows of FrameResults: (frame, poses3d (P, 23, 4), assignment (P, V), ids, joint views, sources)."""
    return ((r.frame, r.poses3d, r.assignment, r.ids, r.joint_views, r.joint_source) for r in results)


def write_outputs(cfg: DictConfig, out_dir: Path, sequence: Sequence, report: SequenceReport) -> None:
    """Write poses3d.json, metrics.json, the protocols' files and report.txt into out_dir; print the report."""
    rows = poses3d_rows(report.results)
    write_poses3d(
        out_dir / cfg.output.poses3d, rows, sequence.rig.names, fill=cfg.output.fill, fps=sequence.meta.get("fps")
    )
    summary = {"metrics": report.metrics, **report.protocols, "skipped": dict(report.skipped)}
    summary.update(inputs=dict(report.inputs), unmatched=dict(report.unmatched), timings_s=report.timings)
    summary["noise_model"] = report.noise_model  # the self-calibrated 2D noise model in words (null: a fixed one)
    atomic_write_text(out_dir / cfg.metrics_file, json.dumps(finite(summary), indent=2))  # NaN -> null
    for protocol in sequence.protocols:
        if hasattr(protocol, "write"):  # e.g. the Shelf-14 predictions that were scored
            protocol.write(out_dir)
    text = (
        f"{sequence.description or 'dataset'}: {len(sequence.frames)} frames, "
        f"{len(sequence.rig)} cameras\n{format_report(report, len(sequence.frames), PROTOCOL.format(**cfg.evaluation))}"
    )
    atomic_write_text(out_dir / cfg.report_file, text + "\n")
    print(
        f"\n{text}\n\nWrote {out_dir / cfg.output.poses3d}, {cfg.poses2d_output}, {cfg.metrics_file} and {cfg.report_file}"
    )


def draw_pictures(
    cfg: DictConfig, out_dir: Path, sequence: Sequence, report: SequenceReport, pipeline: MultiViewPipeline
) -> None:
    """Pictures of one frame (vis=true), over time (vis_sequence=true) and the rerun recording (viewer) into vis_dir."""
    if cfg.vis:
        from evaluation.pictures.visualize import save_run_pictures  # matplotlib: only for runs that draw

        try:
            pictures = save_run_pictures(
                out_dir / cfg.vis_dir,
                sequence,
                report.results,
                cfg.vis_frame,
                cfg.vis_images,
                cfg.vis_pattern,
                pipeline.matcher,
            )
        except ValueError as err:  # e.g. vis_frame was skipped: the report above stands, the pictures are missing
            raise ConfigError(
                f"vis_frame={cfg.vis_frame}: {err}; no pictures drawn (the outputs and the report above are written)"
            ) from None
        print("Pictures: " + ", ".join(str(p) for p in pictures))
    if cfg.vis_sequence and not report.results:
        print("Pictures over time: none, no frame was reconstructed")
    elif cfg.vis_sequence:
        from evaluation.pictures.sequence_view import save_sequence_pictures

        title = f"{sequence.description or 'dataset'}: {out_dir.name}"
        pictures = save_sequence_pictures(
            out_dir / cfg.vis_dir, report.results, sequence.rig, title, cfg.vis_sequence_max_mb
        )
        print("Pictures over time: " + ", ".join(str(p) for p in pictures))
    if cfg.viewer is not None:
        from evaluation.pictures.rerun_view import save_rerun_recording  # rerun only for runs that ask for it

        path = save_rerun_recording(out_dir / cfg.vis_dir, sequence, report.results, cfg.viewer, cfg.viewer_spawn)
        print(f"Rerun recording: {path} (open it: rerun {path})")


def run_2d_stage(
    cfg: DictConfig, sequence: Sequence, out_dir: Path
) -> tuple[Sequence, dict[str, float], tuple[dict, str] | None]:
    """(sequence with pose2d's 2D poses, its timings, per-view COCO AP/AR and line or None); writes them."""
    front_end = Pose2DFrontEnd.from_config(cfg, sequence)
    if front_end is None:  # the dataset's 2D poses, written as they were used (e.g. boxes for detector=file)
        write_poses2d(out_dir / cfg.poses2d_output, {f.index: f.views for f in sequence.frames}, sequence.rig.names)
        return sequence, {}, None
    # pycocotools and the view scoring only for runs with a 2D stage
    from evaluation.pose2d_views import estimate_2d, format_view_metrics, view_metrics

    estimated, gt_views = estimate_2d(sequence, front_end, cfg.progress)
    write_poses2d(out_dir / cfg.poses2d_output, {f.index: f.views for f in estimated.frames}, sequence.rig.names)
    if gt_views is None:
        return estimated, front_end.timings, None
    metrics = view_metrics(estimated, gt_views)
    return estimated, front_end.timings, (metrics, format_view_metrics(metrics, len(gt_views) * len(sequence.rig)))


def _why_missing(name: str, value: float) -> str:
    """The reason printed beside a COCO metric of -1 (pycocotools' value when nothing could be scored)."""
    if value != -1:
        return ""
    subset = name.split("_", 1)[-1]
    return f"  (-1: the set has no annotated {subset} keypoints to score)"


def run_pose2d(cfg: DictConfig, out_dir: Path) -> dict:
    """Evaluate the 2D checkpoint cfg.checkpoint; print and return its metrics (a bad file: one-line error)."""
    from evaluation.pose2d_eval import evaluate_checkpoint  # torch only for this mode

    with one_line_errors(FileNotFoundError, ValueError):
        metrics = evaluate_checkpoint(cfg, out_dir)
    text = (
        f"{cfg.checkpoint} ({cfg.coco2d.decode} decoding): COCO OKS, COCO-23 sigmas; feet: 6 sigmas, person "
        "area\n" + "\n".join(f"  {k:8s} {v:.4f}" + _why_missing(k, v) for k, v in metrics.items())
    )
    atomic_write_text(out_dir / cfg.report_file, text + "\n")
    outputs = f"{out_dir / cfg.coco2d.output}, {cfg.coco2d.results_file}, {cfg.metrics_file} and {cfg.report_file}"
    print(f"{text}\n\nWrote {outputs}")
    return metrics


def one_line_warning(message, category, filename, lineno, file=None, line=None) -> None:
    """warnings.showwarning for the run: RigWarning and InputWarning as one line 'warning: ...', others as Python prints them."""
    if issubclass(category, (RigWarning, InputWarning)):
        print(f"warning: {message}", file=sys.stderr if file is None else file)
    else:
        _show_warning(message, category, filename, lineno, file, line)


_show_warning = warnings.showwarning


@hydra.main(config_path="configs", config_name="eval", version_base="1.3")
def main(cfg: DictConfig) -> dict:
    """Hydra entry point -> the metrics (for sweeps); bad input files and config values stop with one line."""
    out_dir = Path(HydraConfig.get().runtime.output_dir)
    warnings.showwarning = one_line_warning
    if cfg.checkpoint:
        return run_pose2d(cfg, out_dir)
    try:
        with one_line_errors(ConfigError, CalibrationError, Poses2DError, ImageSourceError, config=cfg):
            return run(cfg, out_dir).metrics
    except MissingMandatoryValue as err:  # e.g. dataset=files without dataset.cameras=...
        raise SystemExit(
            f"error: {err.full_key} is not set: give it on the command line "
            f"({err.full_key}=...; see configs/{err.full_key.split('.')[0]}/)"
        ) from None


register_resolvers()  # ${run_id:} in the run folder names, before hydra.main composes the config

if __name__ == "__main__":
    exit_on_sigterm()
    main()
