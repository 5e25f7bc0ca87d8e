"""The real-image tables of ``python -m benchmarks.images_to_3d --real``: Shelf frame 572 images to 3D, COCO AP."""

from __future__ import annotations

import time
from pathlib import Path

import cv2
import numpy as np

from benchmarks.images_to_3d import run_report
from data.pose2d.coco_eval import evaluate_keypoints
from data.pose2d.coco_keypoints import load_coco_wholebody
from data.pose2d.records import ImageRecord
from evaluation.report import format_table
from models.front_end import PersonDetector, Pose2DSource

SHELF_572 = ["dataset=shelf", "dataset.frames=[572]"]
IMAGES = ["dataset.images=images_000572", "pose2d=blazepose", "detector=blazepose"]
SHELF_ROWS = {
    "shipped OpenPose BODY_25 detections": [],
    "images: detector=blazepose + pose2d=blazepose": IMAGES,
    "images, without view completion": [*IMAGES, "complete_views.enabled=false"],
}


def shelf_table() -> str:
    """Shelf frame 572: strict PCP and MPJPE of actors 1 and 3, persons output, seconds per stage, per 2D source."""
    rows = []
    for name, overrides in SHELF_ROWS.items():
        report = run_report(SHELF_572 + overrides)
        ours, t = report.protocols["shelf"]["ours"], report.timings
        actors, mpjpe = ours["strict"]["actors"], ours["mpjpe_mm"]["actors"]
        two_d = [t.get(k) for k in ("images", "detector", "pose2d", "view completion")]
        rest = sum(t.get(k, 0.0) for k in ("noise calibration", "matching", "reconstruction", "tracking"))
        persons = len(report.results[0].poses3d) if report.results else 0
        rows.append(
            [
                name,
                ours["strict"]["average"]["average"],
                actors[1]["average"],
                actors[3]["average"],
                mpjpe[1],
                mpjpe[3],
                persons,
                *("-" if v is None else v for v in two_d),
                rest,
            ]
        )
    header = [
        "2D source",
        "PCP avg",
        "PCP 1",
        "PCP 3",
        "MPJPE 1 mm",
        "MPJPE 3 mm",
        "persons",
        "images s",
        "detector s",
        "pose2d s",
        "completion s",
        "3D s",
    ]
    text = "Shelf frame 572 (5 real views, 1032 x 776): strict Shelf PCP (alpha 0.5; actors 1 and 3, actor 2 absent), "
    return (
        text
        + f"MPJPE of the selected prediction; one CPU core's seconds for the frame\n\n{format_table(header, rows, floatfmt='.2f')}"
    )


def coco_predictions(
    stage: Pose2DSource, detector: PersonDetector | None, records: list[ImageRecord]
) -> tuple[list[dict], float, float]:
    """COCO results of a pose stage on every record (ground-truth boxes, or the detector's), detector and pose s."""
    out, t_det, t_pose = [], 0.0, 0.0
    for record in records:
        image = cv2.imread(str(record.file))
        t0 = time.perf_counter()
        boxes = detector([image])[0] if detector else np.column_stack([record.boxes, np.ones(len(record.boxes))])
        t1 = time.perf_counter()
        view = stage([image], [boxes])[0]
        t_det, t_pose = t_det + t1 - t0, t_pose + time.perf_counter() - t1
        out += [
            {"image_id": record.image_id, "keypoints": k.ravel().tolist(), "score": float(s)}
            for k, s in zip(view.keypoints, view.scores)
        ]
    return out, t_det, t_pose


def coco_table(root: Path, checkpoint: str | None) -> str:
    """COCO OKS AP (all / body / foot) and AR body of each pose model on the COCO-WholeBody sample, per box source."""
    from models.blazepose import BlazePose
    from models.detectors.blazepose_detector import BlazePoseDetector

    records = load_coco_wholebody(root / "test_coco_wholebody.json", root)
    models = {"blazepose (flip test)": BlazePose(), "blazepose, no flip test": BlazePose(flip_test=False)}
    if checkpoint:
        from models.sppe_stage import SppeStage

        models[f"sppe {Path(checkpoint).name}"] = SppeStage(checkpoint, device="cpu")
    rows = []
    for name, stage in models.items():
        box_sources = (("ground truth", None), ("detector=blazepose", BlazePoseDetector()))
        for boxes, detector in box_sources if "no flip" not in name else box_sources[:1]:
            predictions, t_det, t_pose = coco_predictions(stage, detector, records)
            ap = [evaluate_keypoints(records, predictions, s) for s in ("all", "body", "foot")]
            rows.append([name, boxes, *(a["AP"] for a in ap), ap[1]["AR"], t_det / len(records), t_pose / len(records)])
    header = ["pose model", "boxes", "AP all", "AP body", "AP foot", "AR body", "detector s/img", "pose s/img"]
    text = f"COCO-WholeBody sample ({len(records)} images, {sum(len(r.boxes) for r in records)} persons): COCO OKS AP "
    return text + f"(pycocotools; COCO-23 sigmas)\n\n{format_table(header, rows, floatfmt='.3f')}"


def real_tables(checkpoint: str | None) -> str:
    """Both real-image tables as printed text."""
    from hydra import compose, initialize_config_dir

    from benchmarks.images_to_3d import CONFIG_DIR

    with initialize_config_dir(str(CONFIG_DIR), version_base="1.3"):
        data_dir = Path(compose("eval").paths.data_dir)
    return f"{shelf_table()}\n\n{coco_table(data_dir / 'coco_wholebody_sample', checkpoint)}"
