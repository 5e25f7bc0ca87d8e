"""Evaluate the multi-view pipeline: ``python eval.py [dataset=synthetic] [matching=oracle] ...``,
or a 2D checkpoint of train.py: ``python eval.py checkpoint=<.ckpt/.pth> [coco2d.ann_file=...]``.

Builds the dataset's sequence, matches persons across views, reconstructs them in 3D, prints the
metrics with their protocol and the time of each stage, and writes poses3d.json, metrics.json and the
printed report (report.txt) into the Hydra run directory.
"""

from __future__ import annotations

import gc
import importlib

if __name__ == "__main__":
    # The imports and Hydra's config leave ~1.1 x 10^5 long-lived objects; the collector would rescan them again and again
    # (0.1-0.2 s of a Shelf run). Off until main() moves them out of its reach (settle_startup_objects).
    gc.disable()

import json
import logging
import os
import sys
import time
import warnings
from pathlib import Path

import hydra
import numpy as np
from hydra.core.hydra_config import HydraConfig
from hydra.errors import InstantiationException
from hydra.types import RunMode
from hydra.utils import instantiate
from omegaconf import DictConfig, OmegaConf
from omegaconf.errors import MissingMandatoryValue

from data.config_checks import ConfigError, check_bool, check_int, check_number
from data.formats.atomic_io import atomic_write_text, exit_on_sigterm
from data.formats.poses2d_io import Poses2DError, write_poses2d
from data.formats.poses_io import write_poses3d
from data.geometry.calibration import CalibrationError
from data.geometry.check_rig import RigWarning
from data.multiview import Sequence
from evaluation.pose3d import Pose3DEvaluator
from evaluation.protocols import attach_protocols
from evaluation.sequence_eval import SequenceReport, evaluate_sequence, format_report
from models.front_end import Pose2DFrontEnd
from reconstruction.compile_ahead import interpret_until_compiled
from reconstruction.pipeline import MultiViewPipeline
from reconstruction.solver.pose_kernels import solve_all
from run_folders import register_resolvers

AS_SCRIPT = __name__ == "__main__"  # python eval.py (not a module that imported eval)
FIRST_RUN_COMPILE = "eval:compile_kernels"  # the background compile of a first run (compile_ahead.py)
KERNEL_PACKAGES = ("data", "models", "reconstruction", "tracking", "evaluation")  # where the numba kernels are held
_SINGLE_RUN: list[
    Path
] = []  # main() notes a plain (not multirun) run here: only then may the process skip its teardown
PROTOCOL = (
    "absolute MPJPE (mm, no root alignment) over all frames; each GT person matched one-to-one "
    "to a prediction by Hungarian on mean joint distance (unmatched beyond {max_dist_m} m); "
    "PCP alpha={alpha} on the 10 Shelf parts of Shelf-14 built from COCO-23, unmatched GT "
    "persons count all parts wrong; matching precision/recall over pairs of detections placed "
    "in one person, against ground-truth identities"
)


def check_config(cfg: DictConfig) -> None:
    """Stop with one line naming the key when a top-level or evaluation value has the wrong type or range."""
    check_number(cfg, "evaluation.max_dist_m")
    check_number(cfg, "evaluation.alpha")
    check_number(cfg, "vis_sequence_max_mb")
    check_int(cfg, "vis_frame", 0, nullable=True)
    for key in ("vis", "vis_sequence", "progress", "overwrite", "compile_ahead"):
        check_bool(cfg, key)


def check_sequence(cfg: DictConfig, sequence) -> None:
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


def settle_startup_objects() -> None:
    """Freeze the objects made so far (modules, Hydra's config) into the collector's permanent generation, then turn
    collection back on if the start-up turned it off: later collections scan only what the run itself makes."""
    if not gc.isenabled():
        gc.freeze()
        gc.enable()


def start_compiles(cfg: DictConfig) -> None:
    """On a first run (numba's cache cold), every kernel compiles in a background process that outlives this one,
    while this run uses them as Python and the MAP's numpy solver until it ends (``compile_ahead``;
    reconstruction/compile_ahead.py): a small first job does not wait for the compiler. The configured stages'
    modules are loaded first, so that theirs are swapped too (a module loaded later would compile in the run). Only
    when eval.py runs as a script: a module that imports it (the tests) keeps its kernels as they are and compiles
    them as it goes."""
    if not (cfg.compile_ahead and AS_SCRIPT):
        return
    for module in stage_modules(cfg):  # loaded now, so that their kernels run as Python too (not compiled here)
        importlib.import_module(module)
    if interpret_until_compiled(FIRST_RUN_COMPILE, solve_all, KERNEL_PACKAGES):
        print(
            "numba's cache is empty (first run after an install or a change of the kernels): the kernels compile in "
            "a background process (about 20 s of CPU; later runs load them); until then they run as Python.",
            flush=True,
        )


def stage_modules(cfg: DictConfig) -> list[str]:
    """The modules of the configured dataset, matcher, reconstruction and tracker (their ``_target_``s, nested ones
    included, e.g. the dataset's grouper) that belong to KERNEL_PACKAGES."""
    found: list[str] = []

    def walk(node: object) -> None:
        if isinstance(node, dict):
            target = node.get("_target_")
            if isinstance(target, str) and "." in target and target.split(".")[0] in KERNEL_PACKAGES:
                found.append(target.rsplit(".", 1)[0])
            for value in node.values():
                walk(value)
        elif isinstance(node, list):
            for value in node:
                walk(value)

    for group in (
        "dataset",
        "matching",
        "reconstruction",
        "tracking",
    ):  # unresolved: a bad value is instantiate's to name
        walk(OmegaConf.to_container(cfg[group], resolve=False, throw_on_missing=False) if group in cfg else None)
    return list(dict.fromkeys(found))


def compile_kernels() -> None:
    """Compile (or load) every numba kernel a run uses, on tiny inputs: the background process of a first run."""
    from models.paf_grouping import BODY25_PAF_LIMBS, group_people
    from reconstruction import pipeline
    from reconstruction.matching import evidence
    from reconstruction.matching.sparse_assignment import linear_sum_assignment
    from reconstruction.solver import map_solver
    from tracking import tracker

    evidence.warm_up()
    pipeline.warm_up()
    map_solver.warm_up()
    tracker.warm_up()
    linear_sum_assignment(np.ones((2, 3)))
    one = np.array([[10.0, 10.0, 0.9]])
    group_people([one] * 25, [np.ones((1, 1))] * len(BODY25_PAF_LIMBS), min_joints=1)


def run(cfg: DictConfig, out_dir: Path) -> SequenceReport:
    """Evaluate the configured dataset, matcher and reconstruction; write outputs and report.txt into out_dir."""
    check_config(cfg)
    start_compiles(cfg)
    t0 = time.perf_counter()
    sequence = attach_protocols(instantiate(cfg.dataset, _convert_="all"))  # protocols: evaluation/protocols
    t_data = time.perf_counter() - t0
    check_sequence(cfg, sequence)
    sequence, front_timings, view_report = run_2d_stage(cfg, sequence, out_dir)
    pipeline = MultiViewPipeline.from_config(cfg, sequence.rig)
    report = evaluate_sequence(sequence, pipeline, Pose3DEvaluator(**cfg.evaluation), cfg.progress)
    stage_s = sequence.stage_seconds  # e.g. 2D grouping done while loading
    report.timings = {"dataset": t_data - sum(stage_s.values()), **stage_s, **front_timings, **report.timings}
    if view_report is not None:
        report.metrics.update(view_report[0])
        report.protocol_reports.insert(0, view_report[1])

    frames = ((r.frame, r.poses3d, r.assignment, r.ids) for r in report.results)
    write_poses3d(out_dir / cfg.output, frames, sequence.rig.names)
    atomic_write_text(
        out_dir / cfg.metrics_file,
        json.dumps(
            {
                "metrics": report.metrics,
                **report.protocols,
                "skipped": dict(report.skipped),
                "unmatched": dict(report.unmatched),
                "timings_s": report.timings,
            },
            indent=2,
        ),
    )
    for protocol in sequence.protocols:
        if hasattr(protocol, "write"):  # e.g. the Shelf-14 predictions that were scored
            protocol.write(out_dir)
    text = (
        f"{sequence.description or 'dataset'}: {len(sequence.frames)} frames, "
        f"{len(sequence.rig)} cameras\n{format_report(report, len(sequence.frames), PROTOCOL.format(**cfg.evaluation))}"
    )
    atomic_write_text(out_dir / cfg.report_file, text + "\n")
    print(f"\n{text}\n\nWrote {out_dir / cfg.output}, {cfg.poses2d_output}, {cfg.metrics_file} and {cfg.report_file}")
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
    return report


def run_2d_stage(
    cfg: DictConfig, sequence: Sequence, out_dir: Path
) -> tuple[Sequence, dict[str, float], tuple[dict, str] | None]:
    """With a 2D stage (pose2d=sppe | keypointrcnn): the sequence with the predicted 2D poses, the stage timings
    and, where the frames carry ground-truth 2D (render=true), the per-view COCO AP/AR and its printed line.
    Without one: the sequence as it is, no timings, None. The 2D poses used are written to cfg.poses2d_output."""
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
    """Evaluate the 2D checkpoint cfg.checkpoint (evaluation/pose2d_eval.py), print and return its metrics;
    a missing or bad file stops with one line."""
    from evaluation.pose2d_eval import evaluate_checkpoint  # torch only for this mode

    try:
        metrics = evaluate_checkpoint(cfg, out_dir)
    except (FileNotFoundError, ValueError) as err:
        raise SystemExit(f"error: {err}") from None
    text = (
        f"{cfg.checkpoint} ({cfg.coco2d.decode} decoding): COCO OKS, COCO-23 sigmas; feet: 6 sigmas, person "
        "area\n" + "\n".join(f"  {k:8s} {v:.4f}" + _why_missing(k, v) for k, v in metrics.items())
    )
    atomic_write_text(out_dir / cfg.report_file, text + "\n")
    print(
        f"{text}\n\nWrote {out_dir / cfg.coco2d.output}, {cfg.coco2d.results_file}, {cfg.metrics_file} and "
        f"{cfg.report_file}"
    )
    return metrics


def _one_line_warning(message, category, filename, lineno, file=None, line=None) -> None:
    """warnings.showwarning for the run: RigWarning as one line 'warning: ...', others as Python prints them."""
    if issubclass(category, RigWarning):
        print(f"warning: {message}", file=sys.stderr if file is None else file)
    else:
        _show_warning(message, category, filename, lineno, file, line)


_show_warning = warnings.showwarning


@hydra.main(config_path="configs", config_name="eval", version_base="1.3")
def main(cfg: DictConfig) -> dict:
    """Hydra entry point; returns the metrics (for sweeps). Bad input files and bad config values stop
    with one message (a ValueError while building the dataset, matcher or reconstruction is one of them)."""
    settle_startup_objects()
    out_dir = Path(HydraConfig.get().runtime.output_dir)
    if HydraConfig.get().mode == RunMode.RUN:
        _SINGLE_RUN.append(out_dir)
    warnings.showwarning = _one_line_warning
    if cfg.checkpoint:
        return run_pose2d(cfg, out_dir)
    try:
        return run(cfg, out_dir).metrics
    except MissingMandatoryValue as err:  # e.g. dataset=files without dataset.cameras=...
        raise SystemExit(
            f"error: {err.full_key} is not set: give it on the command line "
            f"({err.full_key}=...; see configs/{err.full_key.split('.')[0]}/)"
        ) from None
    except ConfigError as err:
        raise SystemExit(f"error: {err}") from None
    except (CalibrationError, Poses2DError, InstantiationException) as err:
        cause = err.__cause__ if isinstance(err, InstantiationException) else err
        if isinstance(cause, (ValueError, FileNotFoundError)):  # CalibrationError, Poses2DError are ValueErrors
            raise SystemExit(f"error: {cause}") from None
        raise


register_resolvers()  # ${run_id:} in the run folder names, before hydra.main composes the config


def quick_exit() -> None:
    """Leave without the interpreter's teardown (about 0.4 s of freeing numba's, scipy's and torch's objects
    module by module): every output is written and closed by now; the streams and Hydra's log file are flushed.
    Only after a single run: a sweep's launcher (joblib) has worker processes to shut down first."""
    logging.shutdown()
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(0)


if __name__ == "__main__":
    exit_on_sigterm()
    main()
    if _SINGLE_RUN:
        quick_exit()
