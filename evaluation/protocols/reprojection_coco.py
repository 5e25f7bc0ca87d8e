"""The paper's Table 1 metric: COCO keypoint AP/AR of reconstructed 3D poses reprojected into every view."""

from __future__ import annotations

import contextlib
import io
from typing import TYPE_CHECKING

import numpy as np
from pycocotools.cocoeval import COCOeval

from data.geometry.camera import Camera, Rig
from data.keypoints import NUM_JOINTS, OKS_SIGMAS
from data.pose2d.coco_eval import _CATEGORIES, STAT_NAMES, SUBSET_JOINTS, _coco
from evaluation.report import format_table

if TYPE_CHECKING:
    from data.multiview import Frame
    from reconstruction.pipeline import FrameResult

COCO_MAX_DETS = 20


def project_poses(camera: Camera, poses: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Poses (P, 23, 4) in one camera -> keypoints (P, 23, 3), in_image (P, 23), boxes (P, 4), areas (P,)."""
    poses = np.asarray(poses, dtype=np.float64).reshape(-1, NUM_JOINTS, 4)
    valid = (poses[..., 3] > 0) & np.all(np.isfinite(poses[..., :3]), axis=-1)
    xyz = np.where(valid[..., None], poses[..., :3], 0.0)
    projectable = valid & camera.in_view(xyz, margin=np.inf)
    uv = np.where(projectable[..., None], camera.project(xyz), 0.0)
    w, h = camera.size
    in_image = projectable & (uv[..., 0] >= 0) & (uv[..., 0] <= w - 1) & (uv[..., 1] >= 0) & (uv[..., 1] <= h - 1)
    keypoints = np.concatenate([uv, np.where(in_image, poses[..., 3], 0.0)[..., None]], axis=-1)
    lo = np.where(projectable[..., None], uv, np.inf).min(axis=1)
    hi = np.where(projectable[..., None], uv, -np.inf).max(axis=1)
    seen = projectable.any(axis=1)[:, None]
    boxes = np.where(seen, np.concatenate([lo, hi - lo], axis=-1), 0.0)
    limit = np.array([w - 1, h - 1], dtype=np.float64)
    clipped = np.where(seen, np.clip(hi, 0, limit) - np.clip(lo, 0, limit), 0.0)
    return keypoints, in_image, boxes, np.prod(clipped, axis=1)


def view_annotations(
    camera: Camera, poses: np.ndarray, image_id: int, min_joints: int = 1, gt: bool = False
) -> list[dict]:
    """COCO dicts of the poses (P, 23, 4) seen in one view: keypoints (23, 3), bbox, area, score (GT: v = 2 instead)."""
    poses = np.asarray(poses, dtype=np.float64).reshape(-1, NUM_JOINTS, 4)
    keypoints, in_image, boxes, areas = project_poses(camera, poses)
    if gt:
        keypoints[..., 2] = 2.0
        keypoints = np.where(in_image[..., None], keypoints, 0.0)
    scores = np.where(poses[..., 3] > 0, poses[..., 3], 0.0).mean(axis=1)  # a detection's: its mean confidence
    return [
        {"image_id": image_id, "keypoints": kp, "bbox": box, "area": float(a)} | ({} if gt else {"score": float(s)})
        for kp, seen, s, box, a in zip(keypoints, in_image, scores, boxes, areas)
        if seen.sum() >= min_joints
    ]


def coco_keypoint_stats(
    image_ids: list[int], gt: list[dict], predictions: list[dict], subset: str = "all", max_dets: int = 100
) -> dict[str, float]:
    """pycocotools OKS AP/AR (fractions, STAT_NAMES; -1: nothing to average) of gt and prediction dicts."""
    if subset not in SUBSET_JOINTS:
        raise ValueError(f"subset must be one of {sorted(SUBSET_JOINTS)}, got {subset!r}")
    joints = np.array(SUBSET_JOINTS[subset])
    images = [{"id": int(i)} for i in image_ids]
    gt_anns = [_annotation(k, a, joints) for k, a in enumerate(gt)]
    dt_anns = [{**_annotation(k, d, joints), "score": float(d["score"])} for k, d in enumerate(predictions)]
    dt_anns = [d for d in dt_anns if d["num_keypoints"] > 0]
    with contextlib.redirect_stdout(io.StringIO()):
        coco_gt, coco_dt = (
            _coco({"images": images, "annotations": a, "categories": _CATEGORIES}) for a in (gt_anns, dt_anns)
        )
        evaluator = COCOeval(coco_gt, coco_dt, "keypoints")
        evaluator.params.kpt_oks_sigmas = OKS_SIGMAS[joints]
        evaluator.params.imgIds = [img["id"] for img in images]
        evaluator.params.maxDets = [int(max_dets)]
        evaluator.evaluate()
        evaluator.accumulate()
    return _stats(evaluator)


def _annotation(k: int, entry: dict, joints: np.ndarray) -> dict:
    """A pycocotools annotation of the subset's joints, num_keypoints counted, bbox and area as given."""
    kps = np.asarray(entry["keypoints"], dtype=np.float64).reshape(NUM_JOINTS, 3)[joints]
    bbox = [float(v) for v in entry.get("bbox", (0.0, 0.0, 0.0, 0.0))]
    return {
        "id": k + 1,
        "image_id": int(entry["image_id"]),
        "category_id": 1,
        "iscrowd": 0,
        "keypoints": kps.ravel().tolist(),
        "num_keypoints": int(np.count_nonzero(kps[:, 2] > 0)),
        "area": float(entry["area"]),
        "bbox": bbox,
    }


def _stats(evaluator: COCOeval) -> dict[str, float]:
    """The ten keypoint stats (AP|AR, then 50|75: one OKS threshold, m|l: area) of a COCOeval with one maxDets."""
    p = evaluator.params
    out = {}
    for name in STAT_NAMES:
        values = evaluator.eval["precision" if name.startswith("AP") else "recall"]  # (T, R, K, A, M) / (T, K, A, M)
        if name[2:] in ("50", "75"):
            values = values[np.flatnonzero(np.isclose(p.iouThrs, int(name[2:]) / 100))]
        area = {"m": "medium", "l": "large"}.get(name[2:], "all")
        values = values[..., p.areaRngLbl.index(area), 0]
        out[name] = float(np.mean(values[values > -1])) if np.any(values > -1) else -1.0
    return out


class ReprojectionCOCOProtocol:
    """COCO AP/AR of reprojected 3D poses (module docstring) as a dataset protocol for eval.py."""

    name = "reprojection_coco"

    def __init__(
        self, rig: Rig, min_joints: int = 1, max_dets: int = 100, subsets: tuple[str, ...] = ("all", "body", "foot")
    ) -> None:
        if int(min_joints) < 1 or int(max_dets) < 1:
            raise ValueError(f"reprojection COCO: min_joints ({min_joints}) and max_dets ({max_dets}) must be >= 1")
        unknown = [s for s in subsets if s not in SUBSET_JOINTS]
        if unknown:
            raise ValueError(
                f"reprojection COCO: unknown subset {unknown[0]!r}, expected some of {list(SUBSET_JOINTS)}"
            )
        self.rig, self.min_joints, self.max_dets, self.subsets = rig, int(min_joints), int(max_dets), tuple(subsets)
        self.image_ids: list[int] = []
        self.gt: list[dict] = []
        self.predictions: list[dict] = []
        self.frames_without_gt = 0
        self._summary: dict | None = None  # pycocotools runs once per state, for summary() and report()

    def update(self, frame: Frame, result: FrameResult) -> None:
        """Add one COCO image per camera: GT from frame.gt_poses (G, 23, 4), detections from result.poses3d."""
        self._summary = None
        if frame.gt_poses is None:
            self.frames_without_gt += 1
            return
        for camera in self.rig:
            image_id = len(self.image_ids) + 1
            self.image_ids.append(image_id)
            self.gt += view_annotations(camera, frame.gt_poses, image_id, self.min_joints, gt=True)
            self.predictions += view_annotations(camera, result.poses3d, image_id, self.min_joints)

    def summary(self) -> dict:
        """{subset: {stat: % or None}} for every subset, and the counts and settings."""
        if self._summary is not None:
            return self._summary
        out: dict = {}
        for subset in self.subsets:
            stats = coco_keypoint_stats(self.image_ids, self.gt, self.predictions, subset, self.max_dets)
            out[subset] = {k: (100.0 * v if v >= 0 else None) for k, v in stats.items()}
        per_image = np.bincount([a["image_id"] for a in self.gt], minlength=len(self.image_ids) + 1)
        out.update(images=len(self.image_ids), gt_persons=len(self.gt), predictions=len(self.predictions))
        out.update(max_gt_per_image=int(per_image.max()), max_dets=self.max_dets, min_joints=self.min_joints)
        out["frames_without_gt"] = self.frames_without_gt
        self._summary = out
        return out

    def report(self) -> str:
        """The protocol name, the AP/AR table of every subset and the counts."""
        return format_reprojection_report(self.summary())


def format_reprojection_report(summary: dict) -> str:
    """Console table of a ReprojectionCOCOProtocol summary, under its protocol name."""
    subsets = [s for s in SUBSET_JOINTS if s in summary]
    rows = [[s, *("-" if summary[s][k] is None else summary[s][k] for k in STAT_NAMES)] for s in subsets]
    capped = summary["max_gt_per_image"] > summary["max_dets"]
    warning = f"; WARNING: more GT persons in an image than max_dets={summary['max_dets']}, recall is capped"
    warning = warning if capped else ""
    return "\n\n".join(
        [
            "reprojection_coco (paper Table 1 protocol): COCO keypoint AP/AR (%) of the 3D poses reprojected into every view "
            "(with distortion) against the noise-free projections of the GT poses; OKS with the COCO-23 "
            "sigmas; one image per (frame, camera); GT area = projected GT box clipped to the image; "
            f"score = mean joint confidence; persons with >= {summary['min_joints']} joints in the image; "
            f"up to {summary['max_dets']} detections per image (COCO: {COCO_MAX_DETS})",
            format_table(["subset", *STAT_NAMES], rows),
            f"{summary['images']} images, {summary['gt_persons']} GT persons (at most {summary['max_gt_per_image']} "
            f"in one image), {summary['predictions']} reprojected predictions{warning}",
        ]
    )
