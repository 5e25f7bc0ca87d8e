"""Re-estimate the bone-length table of the MAP prior from 3D ground truth (Shelf and/or CMU Panoptic)."""

import argparse
import json
from pathlib import Path

import numpy as np

from data.bone_lengths import BONE_MEAN, BONE_NAMES, BONE_STD, bone_table_dict, estimate_bone_table
from data.formats.atomic_io import atomic_write_text
from data.formats.fourd_skeletons import load_4dassoc_skeletons
from data.geometry.calibration import panoptic_world_to_ours
from data.keypoints import PANOPTIC19_TO_COCO23, SHELF14_TO_COCO23, to_coco23
from evaluation.report import format_table

DEFAULT_SHELF = Path("../shared/data/shelf/4d_association/gt.txt")


def shelf_poses(path: str | Path) -> np.ndarray:
    """Every annotated person of a 4D Association gt.txt as COCO-23 poses: -> (N, 23, 4)."""
    persons = [p[:14] for frame in load_4dassoc_skeletons(path) for p in frame.values()]
    return to_coco23(np.stack(persons), SHELF14_TO_COCO23) if persons else np.zeros((0, 23, 4))


def panoptic_poses(folder: str | Path, min_confidence: float = 0.1) -> np.ndarray:
    """Every body of a folder's body3DScene_*.json files: (N, 23, 4) m, z up, valid above min_confidence."""
    bodies = []
    for path in sorted(Path(folder).glob("body3DScene_*.json")):
        for body in json.loads(path.read_text()).get("bodies", []):
            joints = np.asarray(body["joints19"], dtype=np.float64).reshape(-1, 4)
            xyz = panoptic_world_to_ours(joints[:, :3])
            bodies.append(np.column_stack([xyz, (joints[:, 3] > min_confidence).astype(float)]))
    if not bodies:
        raise ValueError(f"{folder}: no body3DScene_*.json file with bodies")
    return to_coco23(np.stack(bodies), PANOPTIC19_TO_COCO23)


def table_rows(mean: np.ndarray, std: np.ndarray, count: np.ndarray) -> list[list[object]]:
    """Rows bone, default mean/SD (cm), estimated mean/SD (cm), samples: (L,) x 3 -> L rows."""
    return [
        [name, 100 * BONE_MEAN[i], 100 * BONE_STD[i], 100 * mean[i], 100 * std[i], int(count[i])]
        for i, name in enumerate(BONE_NAMES)
    ]


def main(argv: list[str] | None = None) -> None:
    """Parse arguments, estimate, print the table, optionally write the JSON."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--shelf", type=Path, default=None, help=f"gt.txt (default {DEFAULT_SHELF} without --panoptic)")
    parser.add_argument("--panoptic", type=Path, nargs="*", default=[], help="hdPose3d_stage1_coco19 folders")
    parser.add_argument("--panoptic-min-confidence", type=float, default=0.1)
    parser.add_argument("--min-count", type=int, default=10, help="bones with fewer samples are not written")
    parser.add_argument("--output", type=Path, default=None, help="write a bone_table JSON here")
    args = parser.parse_args(argv)
    shelf = args.shelf or (DEFAULT_SHELF if not args.panoptic else None)
    sets, sources = [], []
    if shelf is not None:
        sets.append(shelf_poses(shelf))
        sources.append(f"Shelf {shelf}")
    for folder in args.panoptic:
        sets.append(panoptic_poses(folder, args.panoptic_min_confidence))
        sources.append(f"Panoptic {folder}")
    poses = np.concatenate(sets)
    mean, std, count = estimate_bone_table(poses)
    print(f"{len(poses)} poses from {'; '.join(sources)}")
    print(format_table(["bone", "default cm", "SD", "estimated cm", "SD", "n"], table_rows(mean, std, count)))
    if args.output is not None:
        source = "benchmarks/fit_bone_lengths.py from " + "; ".join(sources)
        doc = bone_table_dict(np.where(count >= args.min_count, mean, np.nan), std, count, source=source)
        atomic_write_text(args.output, json.dumps(doc, indent=2))
        print(f"wrote {len(doc['bones'])} bones to {args.output}")


if __name__ == "__main__":
    main()
