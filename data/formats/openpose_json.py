"""OpenPose ``--write_json`` output as COCO-23 detections (scores clipped to [0, 1]); a CLI to poses2d.json."""

from __future__ import annotations

import argparse
import glob
import json
import re
import sys
from pathlib import Path
from typing import Sequence

import numpy as np

from data.keypoints import BODY25_TO_COCO23, to_coco23
from data.multiview import ViewDetections

BODY25_VALUES = 25 * 3
# OpenPose names its per-image files <image name>_<frame, 12 digits>_keypoints.json.
OPENPOSE_FILE = re.compile(r"^(?P<name>.*)_(?P<frame>\d{12})_keypoints\.json$")


def keypoints_to_view_detections(keypoints: np.ndarray, margin: float = 0.1) -> ViewDetections:
    """Detections (N, J, 3) -> ViewDetections: scored joints' boxes grown by margin per side, mean scores, ids -1."""
    keypoints = np.asarray(keypoints, dtype=np.float64)
    have = keypoints[..., 2] > 0
    seen = have.any(axis=1)
    lo = np.where(have[..., None], keypoints[..., :2], np.inf).min(axis=1, initial=np.inf)
    hi = np.where(have[..., None], keypoints[..., :2], -np.inf).max(axis=1, initial=-np.inf)
    pad = margin * (hi - lo)
    boxes = np.where(seen[:, None], np.concatenate([lo - pad, hi - lo + 2 * pad], axis=1), 0.0)
    # numpy's mean of each person's own joints (not a masked sum), so scores stay bit-identical
    scores = np.array([pose[h, 2].mean() if s else 0.0 for pose, h, s in zip(keypoints, have, seen)])
    return ViewDetections(keypoints.copy(), boxes, scores.reshape(-1), np.full(len(keypoints), -1, dtype=np.int64))


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
        expected = f"{BODY25_VALUES} (BODY_25: 25 keypoints x, y, score)"
        raise ValueError(f"{path}: person {n} has {len(values)} pose_keypoints_2d numbers, expected {expected}")
    try:
        pose = np.array(values, dtype=np.float64).reshape(25, 3)
    except (TypeError, ValueError):
        raise ValueError(f"{path}: person {n} has a non-numeric pose_keypoints_2d value") from None
    if not np.all(np.isfinite(pose)):
        raise ValueError(f"{path}: person {n} has a non-finite pose_keypoints_2d value")
    return pose


def load_openpose_dir(directory: str | Path, margin: float = 0.1) -> dict[int, ViewDetections]:
    """A folder of one camera's ``<name>_<frame:012d>_keypoints.json`` files -> {frame: ViewDetections}."""
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


def camera_folders(specs: Sequence[str]) -> dict[str, Path]:
    """{camera name: folder} of ``name=folder``, folder or glob-pattern arguments (name = folder name)."""
    out: dict[str, Path] = {}
    for spec in specs:
        name, sep, folder = spec.partition("=")
        if sep and name and not glob.has_magic(name):
            pairs = [(name, Path(folder))]
        else:
            matches = sorted(glob.glob(spec)) if glob.has_magic(spec) else [spec]
            pairs = [(Path(m).name, Path(m)) for m in matches if Path(m).is_dir() or not glob.has_magic(spec)]
            if not pairs:
                raise ValueError(f"{spec}: no folder matches this pattern")
        for cam, path in pairs:
            if cam in out:
                raise ValueError(f"camera {cam!r} is given twice ({out[cam]}, {path}); name them: name=folder")
            out[cam] = path
    return out


def convert(folders: dict[str, Path], margin: float = 0.1) -> dict[int, list[ViewDetections]]:
    """OpenPose folders per camera -> {frame: V ViewDetections (N, 23, 3) in folders' order}, scores clipped to 0..1."""
    per_camera = [load_openpose_dir(folder, margin) for folder in folders.values()]
    frames: dict[int, list[ViewDetections]] = {}
    for v, views in enumerate(per_camera):
        for frame, dets in views.items():
            dets.keypoints[..., 2] = np.clip(dets.keypoints[..., 2], 0.0, 1.0)
            dets.scores = np.clip(dets.scores, 0.0, 1.0)
            frames.setdefault(frame, [ViewDetections.empty() for _ in per_camera])[v] = dets
    return dict(sorted(frames.items()))


def main(argv: Sequence[str] | None = None) -> int:
    """Command line (docs/usage.md); a bad folder or file stops with one line 'error: ...'."""
    from data.formats.poses2d_io import read_poses2d, write_poses2d

    parser = argparse.ArgumentParser(
        prog="python -m data.formats.openpose_json",
        description="OpenPose BODY_25 JSON folders (one per camera) -> poses2d.json (COCO-23)",
    )
    parser.add_argument("folders", nargs="+", help="name=folder, folder or glob pattern per camera")
    parser.add_argument("-o", "--output", required=True, help="poses2d.json to write")
    parser.add_argument("--cameras", help="calibration whose camera names and image sizes to check against")
    parser.add_argument("--margin", type=float, default=0.1, help="box margin around the joints (fraction)")
    args = parser.parse_args(argv)
    try:
        folders = camera_folders(args.folders)
        frames = convert(folders, args.margin)
        names = list(folders)
        write_poses2d(args.output, frames, names)
        if args.cameras:
            from data.geometry.calibration import load_rig

            rig = load_rig(args.cameras)
            read_poses2d(args.output, rig.names, [c.size for c in rig])
    except ValueError as err:  # the loaders' errors name the file or folder
        print(f"error: {err}", file=sys.stderr)
        return 1
    count = sum(len(d) for views in frames.values() for d in views)
    print(f"Wrote {args.output}: {count} detections in {len(frames)} frames of cameras {', '.join(names)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
