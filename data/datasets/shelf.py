"""The Shelf benchmark (frames 300..600, 4D Association's files) as a Sequence, scored by its own protocol."""

from __future__ import annotations

import time
from functools import partial
from pathlib import Path
from typing import Callable

import numpy as np

from data.datasets.files import position_slice
from data.datasets.images import read_frame_images
from data.formats.fourd_detections import FrameCandidates, load_4dassoc_detections
from data.formats.fourd_skeletons import load_4dassoc_skeletons
from data.formats.image_sources import open_source
from data.formats.poses2d_io import read_poses2d
from data.geometry.calibration import load_4dassoc
from data.geometry.camera import Rig
from data.keypoints import FOOT_JOINTS
from data.multiview import Frame, Sequence, ViewDetections


def load_shelf(
    root: str | Path = "../shared/data/shelf",
    detections: str = "4d_association/detection",
    calibration: str = "4d_association/calibration.json",
    gt: str = "4d_association/gt.txt",
    baseline: str | None = "4d_association/skel.txt",
    first_frame: int = 300,
    frames: str | list[int] | None = None,  # positions "start:stop[:step]" in gt.txt, or frame numbers
    min_paf: float = 0.05,
    min_joints: int = 8,
    min_mean_score: float = 0.4,
    bbox_margin: float = 0.1,
    poses2d: str | None = None,
    alpha: float = 0.5,
    drop_feet: bool = False,
    grouper: Callable | None = None,  # (frame_candidates, min_paf=, min_joints=, min_mean_score=, margin=) -> views
    images: str | None = None,  # a folder of camera images: the 2D stage runs on them instead of the detection files
    image_pattern: str = "cam{i}.png",  # a frame's image under it: {i} view, {name} camera, {frame} Shelf frame number
) -> Sequence:
    """The Shelf rig (5 views), one Frame per chosen frame (index: Shelf's number); paths under root unless absolute."""
    root = Path(root)
    rig = load_4dassoc(_under(root, calibration))
    gt_path = _under(root, gt)
    gts = load_4dassoc_skeletons(gt_path)
    numbers = _frame_numbers(frames, len(gts), first_frame, gt_path)
    meta = {"dataset": "shelf", "root": str(root), "first_frame": first_frame, "frames": len(numbers)}
    stage_seconds, frame_images = {}, None
    if images is not None:
        views, frame_images = {}, _image_reader(_under(root, images), image_pattern, rig, numbers)
        source = f"camera images {_under(root, images) / image_pattern} (a 2D stage gives the poses)"
    elif poses2d is None:
        folder = _under(root, detections)
        grouping = dict(min_paf=min_paf, min_joints=min_joints, min_mean_score=min_mean_score, margin=bbox_margin)
        views, stage_seconds["grouping"] = _grouped_views(folder, rig, numbers, first_frame, grouper, grouping)
        source = (
            f"OpenPose BODY_25 candidates of {folder} grouped by PAF (min_paf {min_paf:g}, "
            f"min_joints {min_joints}, min_mean_score {min_mean_score:g})"
        )
    else:
        if not Path(poses2d).is_file():
            raise FileNotFoundError(f"{poses2d}: poses2d.json not found")
        views = read_poses2d(poses2d, list(rig.names), [c.size for c in rig])
        meta["poses2d_frames_not_selected"] = len(set(views) - set(numbers))
        source = f"grouped 2D poses from {poses2d}"
    if drop_feet:
        views = {n: [without_feet(v) for v in vs] for n, vs in views.items()}
        source += "; the 6 foot keypoints removed (dataset.drop_feet)"
    empty = lambda: [ViewDetections.empty() for _ in rig.names]  # noqa: E731
    out = [Frame(n, views.get(n) or empty(), images=frame_images and partial(frame_images, n)) for n in numbers]
    detected = sum(len(v) for f in out for v in f.views)
    description = (
        f"Shelf frames {numbers[0]}-{numbers[-1]} ({len(numbers)}), cameras "
        f"{', '.join(rig.names)}: {source}; {detected / max(len(out), 1):.1f} detections per frame"
    )
    protocol = {"name": "shelf", "gt": {n: gts[n - first_frame] for n in numbers}, "gt_path": gt_path, "alpha": alpha}
    protocol.update(baseline_path=None if baseline is None else _under(root, baseline), first_frame=first_frame)
    return Sequence(rig, out, meta, description=description, protocol_inputs=[protocol], stage_seconds=stage_seconds)


def _image_reader(folder: Path, pattern: str, rig: Rig, numbers: list[int]) -> Callable[[int], list[np.ndarray]]:
    """frame number -> V images (H, W, 3) BGR at the calibration size; the first frame's files are checked now."""
    if "{frame}" not in pattern and len(numbers) > 1:
        raise ValueError(f"image_pattern={pattern!r} names one frame (no {{frame}}); select one with dataset.frames")

    def read(number: int) -> list[np.ndarray]:
        paths = [folder / pattern.format(i=v, name=name, frame=number) for v, name in enumerate(rig.names)]
        return read_frame_images([open_source(p) for p in paths], [0] * len(paths), [c.size for c in rig])

    for v, name in enumerate(rig.names):  # a missing or unreadable image stops the run now, naming it
        open_source(folder / pattern.format(i=v, name=name, frame=numbers[0]))
    return read


def without_feet(view: ViewDetections) -> ViewDetections:
    """A copy of the detections with the 6 COCO-23 foot joints missing (x, y, score 0): (N, 23, 3)."""
    keypoints = view.keypoints.copy()
    keypoints[:, FOOT_JOINTS] = 0.0
    return ViewDetections(keypoints, view.bboxes, view.scores, view.person_ids, view.occluded)


def _under(root: Path, path: str | Path) -> Path:
    """path relative to root unless absolute; a missing path stops with its name."""
    full = Path(path) if Path(path).is_absolute() else root / path
    if not full.exists():
        raise FileNotFoundError(f"{full}: Shelf file not found (root={root})")
    return full


def _frame_numbers(frames: str | list[int] | None, count: int, first: int, gt_path: Path) -> list[int]:
    """Shelf frame numbers chosen: None = all `count` frames from `first`; "a:b[:c]" = file positions; a list."""
    everything = list(range(first, first + count))
    if frames is None:
        return everything
    if isinstance(frames, str):
        chosen = everything[position_slice(frames)]
    else:
        chosen = [int(f) for f in frames]
        outside = [f for f in chosen if f not in everything]
        if outside:
            raise ValueError(f"{gt_path}: frame {outside[0]} requested, the file holds {first}..{first + count - 1}")
    if not chosen:
        raise ValueError(f"frames={frames!r} selects no frame of {gt_path} ({first}..{first + count - 1})")
    return chosen


def _grouped_views(
    folder: Path, rig: Rig, numbers: list[int], first: int, grouper: Callable | None, grouping: dict
) -> tuple[dict[int, list[ViewDetections]], float]:
    """{frame: V ViewDetections} from <folder>/<camera>.txt, and the seconds spent grouping."""
    if grouper is None:
        raise ValueError(
            "load_shelf: grouping the detection files needs a grouper "
            "(dataset.grouper: models.paf_grouping.group_view), or give dataset.poses2d"
        )
    per_camera = [
        _camera_candidates(folder, name, rig.cameras[v].size, numbers, first) for v, name in enumerate(rig.names)
    ]
    t0 = time.perf_counter()
    views = {n: [grouper(c[i], **grouping) for c in per_camera] for i, n in enumerate(numbers)}
    return views, time.perf_counter() - t0


def _camera_candidates(
    folder: Path, name: str, size: tuple[int, int], numbers: list[int], first: int
) -> list[FrameCandidates]:
    """The chosen frames of one camera's detection file."""
    path = folder / f"{name}.txt"
    if not path.is_file():
        raise FileNotFoundError(f"{path}: detection file of camera {name!r} not found")
    frames = load_4dassoc_detections(path, (int(size[0]), int(size[1])))
    if numbers[-1] - first >= len(frames):
        raise ValueError(
            f"{path}: {len(frames)} frames, but frame {numbers[-1]} (position {numbers[-1] - first}) is asked for"
        )
    return [frames[n - first] for n in numbers]
