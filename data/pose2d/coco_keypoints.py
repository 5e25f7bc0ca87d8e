"""COCO-format keypoint files (COCO-WholeBody, COCO-23, CrowdPose) to and from ImageRecords, one per image."""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path
from typing import Any, Callable

import numpy as np

from data.formats.atomic_io import atomic_write_text
from data.formats.coco_detections import read_coco_detections
from data.keypoints import COCO23_NAMES, CROWDPOSE14_TO_COCO23, LIMBS, NUM_BODY_JOINTS, NUM_JOINTS, to_coco23
from data.pose2d.records import ImageRecord

KINDS = ("coco_wholebody", "coco23", "crowdpose")
NUM_FOOT_JOINTS = NUM_JOINTS - NUM_BODY_JOINTS
CROWDPOSE_JOINTS = len(CROWDPOSE14_TO_COCO23[CROWDPOSE14_TO_COCO23 >= 0]) + 2  # 12 limb joints, head, neck

Converter = Callable[[dict], np.ndarray]


def _read_coco(path: Path) -> dict:
    """The parsed COCO annotation file (a dict with lists "images" and "annotations"), or a ValueError naming it."""
    try:
        doc = json.loads(path.read_text())
    except OSError as exc:
        raise ValueError(f"{path}: cannot read annotation file ({exc.strerror or exc})") from None
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path}: not valid JSON ({exc})") from None
    if not isinstance(doc, dict) or not all(isinstance(doc.get(key), list) for key in ("images", "annotations")):
        raise ValueError(f"{path}: not a COCO annotation file (needs the lists 'images' and 'annotations')")
    return doc


def _numbers(path: Path, ann: dict, key: str, count: int) -> np.ndarray:
    """The annotation's list ``key`` as a (count,) float array, or a ValueError naming the annotation."""
    value = ann.get(key)
    if not isinstance(value, list):
        raise ValueError(f"{path}: annotation id {ann.get('id')!r} has no list {key!r}")
    if len(value) != count:
        expected = f"{count} ({count // 3} keypoints x 3)" if key != "bbox" else str(count)
        raise ValueError(
            f"{path}: annotation id {ann.get('id')!r} has {len(value)} numbers in {key!r}, expected {expected}"
        )
    try:
        arr = np.array(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{path}: annotation id {ann.get('id')!r} has a non-numeric value in {key!r}") from None
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{path}: annotation id {ann.get('id')!r} has a non-finite value in {key!r}")
    return arr


def _load(
    path: Path, doc: dict, image_dir: str | Path, convert: Converter, labelled: np.ndarray, skip_crowd: bool
) -> list[ImageRecord]:
    """Records of a file read by :func:`_read_coco`; convert maps one annotation to its (23, 3) keypoints."""
    persons: dict[Any, list[tuple[np.ndarray, np.ndarray, float]]] = {}
    for img in doc["images"]:
        if not isinstance(img, dict) or not all(k in img for k in ("id", "file_name", "width", "height")):
            raise ValueError(f"{path}: image entry {img!r:.80} lacks one of id, file_name, width, height")
        persons[img["id"]] = []
    person = {c.get("id") for c in doc.get("categories", []) if isinstance(c, dict) and c.get("name") == "person"}
    category_ids = person or {1}  # the file lists no person category: COCO's id 1
    for ann in doc["annotations"]:
        if not isinstance(ann, dict):
            raise ValueError(f"{path}: annotation {ann!r:.80} is not an object")
        if ann.get("category_id", 1) not in category_ids or (skip_crowd and ann.get("iscrowd", 0)):
            continue
        if ann.get("image_id") not in persons:
            raise ValueError(
                f"{path}: annotation id {ann.get('id')!r} refers to image id "
                f"{ann.get('image_id')!r}, which is not in 'images'"
            )
        keypoints = convert(ann)
        box = _numbers(path, ann, "bbox", 4)
        persons[ann["image_id"]].append((keypoints, box, _area(path, ann, box)))
    image_dir = Path(image_dir)
    return [_record(img, image_dir, persons[img["id"]], labelled) for img in doc["images"]]


def _area(path: Path, ann: dict, box: np.ndarray) -> float:
    """The annotation's COCO area, else (missing or 0) the box area w * h."""
    try:
        area = float(ann.get("area") or 0.0)
    except (TypeError, ValueError):
        raise ValueError(f"{path}: annotation id {ann.get('id')!r} has a non-numeric 'area'") from None
    if not math.isfinite(area) or area < 0:
        raise ValueError(f"{path}: annotation id {ann.get('id')!r} has an invalid 'area' {area}")
    return area if area > 0 else float(box[2] * box[3])


def _record(img: dict, image_dir: Path, persons: list, labelled: np.ndarray) -> ImageRecord:
    """One ImageRecord of an image entry and its (keypoints (23, 3), box (4,), area) persons."""
    keypoints, boxes, areas = (np.array([p[i] for p in persons]) for i in range(3))
    size = int(img["width"]), int(img["height"])
    keypoints, boxes = keypoints.reshape(-1, NUM_JOINTS, 3), boxes.reshape(-1, 4)
    return ImageRecord(int(img["id"]), image_dir / img["file_name"], *size, keypoints, boxes, areas, labelled.copy())


def load_coco_wholebody(ann_file: str | Path, image_dir: str | Path, skip_crowd: bool = True) -> list[ImageRecord]:
    """COCO-WholeBody: ``keypoints`` (17 x 3) + ``foot_kpts`` (6 x 3, COCO-23 foot order) -> records, 23 labelled."""
    path = Path(ann_file)

    def convert(ann: dict) -> np.ndarray:
        body = _numbers(path, ann, "keypoints", 3 * NUM_BODY_JOINTS).reshape(-1, 3)
        feet = _numbers(path, ann, "foot_kpts", 3 * NUM_FOOT_JOINTS).reshape(-1, 3)
        return np.concatenate([body, feet])

    return _load(path, _read_coco(path), image_dir, convert, np.ones(NUM_JOINTS, dtype=bool), skip_crowd)


def load_coco23(ann_file: str | Path, image_dir: str | Path, skip_crowd: bool = True) -> list[ImageRecord]:
    """COCO-format keypoints of 23 x 3 numbers (or COCO-17's 17 x 3, feet unlabelled) -> records."""
    path = Path(ann_file)
    doc = _read_coco(path)
    count = _coco23_count(path, doc)
    labelled = np.arange(NUM_JOINTS) < count

    def convert(ann: dict) -> np.ndarray:
        kps = _numbers(path, ann, "keypoints", 3 * count).reshape(-1, 3)
        return np.concatenate([kps, np.zeros((NUM_JOINTS - count, 3))])

    return _load(path, doc, image_dir, convert, labelled, skip_crowd)


def _coco23_count(path: Path, doc: dict) -> int:
    """Keypoints per person of a COCO-23 / COCO-17 file: 23 or 17."""
    for cat in doc.get("categories", []):
        if isinstance(cat, dict) and len(cat.get("keypoints", [])) in (NUM_BODY_JOINTS, NUM_JOINTS):
            return len(cat["keypoints"])
    for ann in doc.get("annotations", []):
        if isinstance(ann, dict) and isinstance(ann.get("keypoints"), list):
            n = len(ann["keypoints"])
            if n not in (3 * NUM_BODY_JOINTS, 3 * NUM_JOINTS):
                raise ValueError(
                    f"{path}: annotation id {ann.get('id')!r} has {n} numbers in 'keypoints', "
                    f"expected {3 * NUM_JOINTS} (23 x 3) or {3 * NUM_BODY_JOINTS} (17 x 3)"
                )
            return n // 3
    return NUM_JOINTS


def load_crowdpose(ann_file: str | Path, image_dir: str | Path, skip_crowd: bool = True) -> list[ImageRecord]:
    """CrowdPose-14 (14 x 3) -> COCO-23 records through CROWDPOSE14_TO_COCO23; only mapped joints labelled."""
    path = Path(ann_file)

    def convert(ann: dict) -> np.ndarray:
        kps = _numbers(path, ann, "keypoints", 3 * CROWDPOSE_JOINTS).reshape(-1, 3)
        return to_coco23(kps, CROWDPOSE14_TO_COCO23)

    return _load(path, _read_coco(path), image_dir, convert, CROWDPOSE14_TO_COCO23 >= 0, skip_crowd)


def load_detections(
    det_file: str | Path, records: list[ImageRecord], score_threshold: float = 0.0, category_id: int = 1
) -> list[ImageRecord]:
    """Records with det_boxes (M, 4) / det_scores (M,) of a COCO detection file's category_id >= score_threshold."""
    dets = read_coco_detections(det_file)  # every entry checked; a bad one is named
    keep = (dets.category_ids == category_id) & (dets.scores >= score_threshold)
    found: dict[int, list[tuple[np.ndarray, float]]] = {r.image_id: [] for r in records}
    for image_id, box, score in zip(dets.image_ids[keep], dets.boxes[keep], dets.scores[keep]):
        if int(image_id) in found:
            found[int(image_id)].append((box, float(score)))
    return [
        dataclasses.replace(
            r,
            det_boxes=np.array([b for b, _ in found[r.image_id]]).reshape(-1, 4),
            det_scores=np.array([s for _, s in found[r.image_id]]),
        )
        for r in records
    ]


def training_persons(record: ImageRecord, min_keypoints: int = 1) -> np.ndarray:
    """Indices (K,) of the persons with >= min_keypoints labelled joints (v > 0 on a joint the dataset annotates)."""
    labelled = np.sum((record.keypoints[..., 2] > 0) & record.labelled[None], axis=1)
    return np.flatnonzero(labelled >= min_keypoints)


def load_keypoint_dataset(
    kind: str,
    ann_file: str | Path,
    image_dir: str | Path,
    det_file: str | Path | None = None,
    min_keypoints: int = 1,
    skip_crowd: bool = True,
    det_score_threshold: float = 0.0,
) -> list[ImageRecord]:
    """Records of a keypoint dataset's images with a person of >= min_keypoints labelled joints (<= 0: all)."""
    loaders = {"coco_wholebody": load_coco_wholebody, "coco23": load_coco23, "crowdpose": load_crowdpose}
    if kind not in loaders:
        raise ValueError(f"unknown keypoint dataset kind {kind!r}; expected one of {', '.join(KINDS)}")
    records = loaders[kind](ann_file, image_dir, skip_crowd=skip_crowd)
    if min_keypoints > 0:
        records = [r for r in records if len(training_persons(r, min_keypoints))]
    if det_file is not None:
        records = load_detections(det_file, records, score_threshold=det_score_threshold)
    return records


def coco23_document(records: list[ImageRecord], image_root: str | Path | None = None, info: dict | None = None) -> dict:
    """The COCO-23 annotation document of records; file_name is relative to image_root, else the base name."""
    images, annotations = [], []
    for record in records:
        name = _file_name(record, image_root)
        images.append({"id": record.image_id, "file_name": name, "width": record.width, "height": record.height})
        for kps, box, area in zip(record.keypoints, record.boxes, record.areas):
            flat = [v for x, y, vis in kps.tolist() for v in (x, y, int(vis))]
            ann = {"id": len(annotations) + 1, "image_id": record.image_id, "category_id": 1, "iscrowd": 0}
            ann |= {"num_keypoints": int(np.sum(kps[:, 2] > 0)), "keypoints": flat, "bbox": box.tolist()}
            annotations.append(ann | {"area": float(area)})
    skeleton = [[a + 1, b + 1] for a, b in LIMBS]  # 1-based
    person = {"supercategory": "person", "id": 1, "name": "person", "keypoints": [*COCO23_NAMES], "skeleton": skeleton}
    return {"info": dict(info or {}), "categories": [person], "images": images, "annotations": annotations}


def _file_name(record: ImageRecord, image_root: str | Path | None) -> str:
    """The file_name of a record: its path relative to image_root, else its base name."""
    if image_root is None:
        return record.file.name
    try:
        return record.file.relative_to(image_root).as_posix()
    except ValueError:
        raise ValueError(f"image id {record.image_id}: {record.file} is not inside {image_root}") from None


def write_coco_keypoints(
    path: str | Path, records: list[ImageRecord], image_root: str | Path | None = None, info: dict | None = None
) -> None:
    """Write records as a COCO-23 annotation file (atomic, ids 1..N; ``labelled`` not stored)."""
    atomic_write_text(path, json.dumps(coco23_document(records, image_root, info)))
