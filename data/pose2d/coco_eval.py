"""COCO OKS keypoint AP/AR through pycocotools, on COCO-23 or its body (COCO-17) or foot (6 joints) subset."""

from __future__ import annotations

import contextlib
import io
import json
from pathlib import Path
from typing import Iterable, Sequence

import numpy as np
from pycocotools.coco import COCO
from pycocotools.cocoeval import COCOeval

from data.formats.atomic_io import atomic_write_text
from data.keypoints import BODY_JOINTS, FOOT_JOINTS, NUM_BODY_JOINTS, NUM_JOINTS, OKS_SIGMAS
from data.pose2d.coco_keypoints import coco23_document
from data.pose2d.records import ImageRecord

SUBSET_JOINTS: dict[str, tuple[int, ...]] = {"all": tuple(range(NUM_JOINTS)), "body": BODY_JOINTS, "foot": FOOT_JOINTS}
STAT_NAMES = ("AP", "AP50", "AP75", "APm", "APl", "AR", "AR50", "AR75", "ARm", "ARl")
_CATEGORIES = [{"id": 1, "name": "person", "supercategory": "person"}]


def evaluate_keypoints(
    gt: Sequence[ImageRecord] | dict, predictions: Iterable[dict], subset: str = "all"
) -> dict[str, float]:
    """COCO OKS AP/AR (10 STAT_NAMES, -1 where empty) of predictions on one subset; gt: records or a COCO dict."""
    if subset not in SUBSET_JOINTS:
        raise ValueError(f"subset must be one of {sorted(SUBSET_JOINTS)}, got {subset!r}")
    joints = np.array(SUBSET_JOINTS[subset])
    gt_doc = _ground_truth(gt, joints)
    image_ids = {img["id"] for img in gt_doc["images"]}
    dt_anns = _detections(predictions, image_ids, joints)
    with contextlib.redirect_stdout(io.StringIO()):
        coco_gt = _coco(gt_doc)
        coco_dt = _coco({"images": gt_doc["images"], "categories": _CATEGORIES, "annotations": dt_anns})
        evaluator = COCOeval(coco_gt, coco_dt, "keypoints")
        evaluator.params.kpt_oks_sigmas = OKS_SIGMAS[joints]
        evaluator.params.imgIds = sorted(image_ids)
        evaluator.evaluate()
        evaluator.accumulate()
        evaluator.summarize()
    return {name: float(v) for name, v in zip(STAT_NAMES, evaluator.stats)}


def _ground_truth(gt: Sequence[ImageRecord] | dict, joints: np.ndarray) -> dict:
    """A COCO-format gt dict (images, annotations of the subset's joints, categories)."""
    doc = gt if isinstance(gt, dict) else coco23_document(list(gt))
    images = doc.get("images") or [{"id": i} for i in sorted({a["image_id"] for a in doc["annotations"]})]
    anns = []
    for ann in doc["annotations"]:
        bbox = [float(v) for v in ann["bbox"]]
        kps = _annotation_keypoints(ann)[joints]
        # pycocotools treats id 0 as "no match"
        entry = {"id": len(anns) + 1, "image_id": int(ann["image_id"]), "category_id": 1, "bbox": bbox}
        entry |= {"keypoints": kps.ravel().tolist(), "num_keypoints": int(np.count_nonzero(kps[:, 2] > 0))}
        anns.append(entry | {"area": float(ann.get("area", bbox[2] * bbox[3])), "iscrowd": int(ann.get("iscrowd", 0))})
    return {"images": [dict(img) for img in images], "annotations": anns, "categories": _CATEGORIES}


def _annotation_keypoints(ann: dict) -> np.ndarray:
    """COCO-23 keypoints (23, 3) of a COCO-23, COCO-17 or COCO-WholeBody annotation."""
    kps = np.asarray(ann["keypoints"], dtype=np.float64).ravel()
    if kps.size == 3 * NUM_JOINTS:
        return kps.reshape(NUM_JOINTS, 3)
    if kps.size != 3 * NUM_BODY_JOINTS:
        raise ValueError(
            f"annotation {ann.get('id')}: {kps.size} keypoint numbers; need 51 (COCO-17) or {3 * NUM_JOINTS} (COCO-23)"
        )
    foot = np.asarray(ann.get("foot_kpts", np.zeros(3 * len(FOOT_JOINTS))), dtype=np.float64)
    return np.concatenate([kps, foot.ravel()]).reshape(NUM_JOINTS, 3)


def _detections(predictions: Iterable[dict], image_ids: set[int], joints: np.ndarray) -> list[dict]:
    """Validated detection annotations of the subset's joints, with loadRes-style bbox/area of all 23."""
    anns = []
    for i, pred in enumerate(predictions):
        kps = np.asarray(pred["keypoints"], dtype=np.float64)
        if kps.size != 3 * NUM_JOINTS or not np.all(np.isfinite(kps)):
            raise ValueError(f"prediction {i}: keypoints must be {NUM_JOINTS} finite (x, y, score) triples")
        if int(pred["image_id"]) not in image_ids:
            raise ValueError(f"prediction {i}: image_id {pred['image_id']} is not in the ground truth")
        kps = kps.reshape(NUM_JOINTS, 3)
        x0, y0 = kps[:, :2].min(axis=0)
        x1, y1 = kps[:, :2].max(axis=0)
        entry = {"id": i + 1, "image_id": int(pred["image_id"]), "category_id": 1}
        entry |= {"keypoints": kps[joints].ravel().tolist(), "score": float(pred["score"])}
        anns.append(entry | {"bbox": [x0, y0, x1 - x0, y1 - y0], "area": float((x1 - x0) * (y1 - y0))})
    return anns


def _coco(dataset: dict) -> COCO:
    """An in-memory pycocotools COCO object."""
    coco = COCO()
    coco.dataset = dataset
    coco.createIndex()
    return coco


def write_coco_results(path: str | Path, predictions: Iterable[dict]) -> None:
    """Write predictions ({image_id, keypoints (23, 3), score, bbox?}) as a COCO results JSON, atomically."""
    out = []
    for pred in predictions:
        keypoints = np.round(np.asarray(pred["keypoints"], dtype=np.float64).ravel(), 4).tolist()
        entry = {"image_id": int(pred["image_id"]), "category_id": 1, "keypoints": keypoints}
        entry["score"] = float(pred["score"])
        if pred.get("bbox") is not None:
            entry["bbox"] = np.round(np.asarray(pred["bbox"], dtype=np.float64), 4).tolist()
        out.append(entry)
    atomic_write_text(path, json.dumps(out))
