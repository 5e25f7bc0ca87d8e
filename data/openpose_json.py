"""OpenPose's own JSON output (``--write_json``): BODY_25 people per image, read as COCO-23 detections."""
from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np

from data.keypoints import BODY25_TO_COCO23, to_coco23
from data.multiview import ViewDetections

BODY25_VALUES = 25 * 3
# OpenPose names its per-image files <image name>_<frame, 12 digits>_keypoints.json.
OPENPOSE_FILE = re.compile(r"^(?P<name>.*)_(?P<frame>\d{12})_keypoints\.json$")


def keypoints_to_view_detections(keypoints: np.ndarray, margin: float = 0.1) -> ViewDetections:
    """Detections (N, J, 3) x, y, score -> ViewDetections with boxes around the joints with score > 0.

    The tight box is grown by `margin` times its width and height on each side, because joints miss
    the top of the head, the hands and the outline of the body. score = mean score of those joints;
    a person without joints gets a zero box and score 0. person_ids are all -1.
    """
    keypoints = np.asarray(keypoints, dtype=np.float64)
    boxes, scores = np.zeros((len(keypoints), 4)), np.zeros(len(keypoints))
    for n, pose in enumerate(keypoints):
        have = pose[:, 2] > 0
        if not have.any():
            continue
        lo, hi = pose[have, :2].min(axis=0), pose[have, :2].max(axis=0)
        pad = margin * (hi - lo)
        boxes[n] = [*(lo - pad), *(hi - lo + 2 * pad)]
        scores[n] = pose[have, 2].mean()
    return ViewDetections(keypoints.copy(), boxes, scores, np.full(len(keypoints), -1, dtype=np.int64))


def load_openpose_json(path: str | Path) -> np.ndarray:
    """One OpenPose JSON file (BODY_25, ``people[].pose_keypoints_2d``) -> (N, 23, 3) px + score, COCO-23."""
    path = Path(path)
    try:
        doc = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ValueError(f"{path}: cannot read OpenPose JSON ({exc})") from None
    people = doc.get("people") if isinstance(doc, dict) else None
    if not isinstance(people, list):
        raise ValueError(f"{path}: no 'people' list (not an OpenPose --write_json file)")
    poses = [_body25(path, n, person) for n, person in enumerate(people)]
    return to_coco23(np.array(poses, dtype=np.float64).reshape(-1, 25, 3), BODY25_TO_COCO23)


def _body25(path: Path, n: int, person: object) -> np.ndarray:
    """The checked BODY_25 keypoints of person n: (25, 3)."""
    values = person.get("pose_keypoints_2d") if isinstance(person, dict) else None
    if not isinstance(values, list):
        raise ValueError(f"{path}: person {n} has no 'pose_keypoints_2d' list")
    if len(values) != BODY25_VALUES:
        raise ValueError(f"{path}: person {n} has {len(values)} pose_keypoints_2d numbers, expected "
                         f"{BODY25_VALUES} (BODY_25: 25 keypoints x, y, score)")
    try:
        pose = np.array(values, dtype=np.float64).reshape(25, 3)
    except (TypeError, ValueError):
        raise ValueError(f"{path}: person {n} has a non-numeric pose_keypoints_2d value") from None
    if not np.all(np.isfinite(pose)):
        raise ValueError(f"{path}: person {n} has a non-finite pose_keypoints_2d value")
    return pose


def load_openpose_dir(directory: str | Path, margin: float = 0.1) -> dict[int, ViewDetections]:
    """A folder of ``<name>_<frame:012d>_keypoints.json`` files of one camera -> {frame: ViewDetections}.

    Files not named that way are ignored; `margin` as in keypoints_to_view_detections.
    """
    directory = Path(directory)
    if not directory.is_dir():
        raise ValueError(f"{directory}: not a folder of OpenPose JSON files")
    frames: dict[int, ViewDetections] = {}
    sources: dict[int, Path] = {}
    for path in sorted(directory.iterdir()):
        match = OPENPOSE_FILE.match(path.name)
        if match is None:
            continue
        frame = int(match["frame"])
        if frame in sources:
            raise ValueError(f"{directory}: frame {frame} appears twice ({sources[frame].name}, {path.name})")
        sources[frame] = path
        frames[frame] = keypoints_to_view_detections(load_openpose_json(path), margin)
    if not frames:
        raise ValueError(f"{directory}: no <name>_<frame:012d>_keypoints.json files")
    return frames
