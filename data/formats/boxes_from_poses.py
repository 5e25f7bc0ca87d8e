"""Person boxes from 2D poses: poses2d.json -> a COCO detection-results file for ``detector=file``, keyed by the
image ids of an images dataset, in the image file's pixels (the poses are in the calibration's)::

    python -m data.datasets.images --cameras C --images DIR -o coco_images.json      # the image ids
    python -m data.formats.boxes_from_poses poses2d.json --cameras C --images coco_images.json \\
        -o detections.json [--frame-map 572:0] [--margin 0.1] [--min-joints 3]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Sequence

import numpy as np

from data.formats.atomic_io import atomic_write_text
from data.formats.poses2d_io import read_poses2d
from data.geometry.calibration import load_rig


def pose_box(keypoints: np.ndarray, margin: float) -> np.ndarray | None:
    """(J, 3) x, y, score -> (4,) x, y, w, h of the scored joints grown by margin per side; None if none scored."""
    xy = keypoints[keypoints[:, 2] > 0, :2]
    if len(xy) == 0:
        return None
    low, high = xy.min(0), xy.max(0)
    pad = margin * (high - low)
    return np.concatenate([low - pad, high - low + 2 * pad])


def detections(
    poses: dict,
    names: list[str],
    calib_sizes: list,
    images: list[dict],
    frame_map: dict,
    margin: float,
    min_joints: int,
) -> list[dict]:
    """COCO detection results of every person of ``poses`` ({frame: V ViewDetections (N, 23, 3)}) in ``images``."""
    ids = {(int(im["frame"]), str(im["camera"])): im for im in images}
    out = []
    for frame, views in poses.items():
        for v, view in enumerate(views):
            image = ids.get((frame_map.get(frame, frame), names[v]))
            if image is None:
                continue
            scale = np.array([image["width"] / calib_sizes[v][0], image["height"] / calib_sizes[v][1]] * 2)
            for n in range(len(view)):
                box = pose_box(view.keypoints[n], margin)
                if box is None or np.sum(view.keypoints[n, :, 2] > 0) < min_joints:
                    continue
                bbox = [round(float(b), 2) for b in box * scale]
                out.append(
                    {"image_id": int(image["id"]), "category_id": 1, "bbox": bbox, "score": float(view.scores[n])}
                )
    return out


def _frame_map(items: list[str]) -> dict[int, int]:
    try:
        return {int(a): int(b) for a, b in (item.split(":") for item in items)}
    except ValueError:
        raise SystemExit(f"error: --frame-map takes SRC:DST frame numbers, got {items}") from None


def main(argv: Sequence[str] | None = None) -> None:
    """Command line (module docstring): write the detection-results file."""
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("poses2d", help="poses2d.json (docs/formats.md)")
    parser.add_argument("--cameras", required=True, help="the calibration (its image sizes, camera names)")
    parser.add_argument("--images", required=True, help="COCO images list of python -m data.datasets.images")
    parser.add_argument("-o", "--out", required=True, help="the detections .json to write")
    parser.add_argument("--frame-map", nargs="*", default=[], help="SRC:DST: poses of frame SRC box images of DST")
    parser.add_argument("--margin", type=float, default=0.1, help="growth per side, fraction of the box size")
    parser.add_argument("--min-joints", type=int, default=3, help="persons with fewer scored joints get no box")
    args = parser.parse_args(argv)
    try:
        rig = load_rig(args.cameras)
        poses = read_poses2d(args.poses2d, rig.names)
        doc = json.loads(Path(args.images).read_text())
        images = doc["images"] if isinstance(doc, dict) else doc
        sizes = [cam.size for cam in rig]
        dets = detections(poses, rig.names, sizes, images, _frame_map(args.frame_map), args.margin, args.min_joints)
    except (OSError, ValueError, KeyError) as err:
        raise SystemExit(f"error: {err}") from None
    atomic_write_text(args.out, json.dumps(dets))
    print(f"wrote {len(dets)} boxes of {len(images)} images to {args.out}")


if __name__ == "__main__":
    main()
